"""The safe-maximal-impact experiment in PyBullet (studies.impact_study) and the joint-limit
guard it runs with (ffmpc_core.impact.task_space.JointLimitGuard).

The closed-loop runs (module fixture, ~15–30 s) re-solve eq 9–14 every 5 ms instead of every
1 ms (``replan_period``) to stay fast; ``ffmpc study impact`` uses every cycle by default.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.control import CartesianCommand, ImpactControllerConfig
from ffmpc_core.impact.deformation import SoftMaterial
from ffmpc_core.impact.limits import joint_limits
from ffmpc_core.impact.metrics import count_limit_violations, time_to_steady_force
from ffmpc_core.impact.scenario import IMPACT_SCHEMA, ImpactStudyConfig, start_configuration
from ffmpc_core.impact.task_space import (
    JointLimitGuard,
    JointLimitGuardConfig,
    TaskSpaceInverseDynamics,
    external_joint_torque,
)
from ffmpc_core.robots import load_robot
from ffmpc_core.tasks import PressTask
from studies.impact_study import (
    DEFAULT_RUNS,
    format_table,
    impact_jobs,
    plot_runs,
    recall_object,
    remember_object,
    run_impact,
    run_impact_study,
)

LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
# The paper's scheme (plan from the prior as if it were the truth); the touch-first strategy,
# the study's default, is tested in tests/faults/test_impact_model_error.py.
CONFIG = ImpactStudyConfig(replan_period=0.005, strategy="prior")


@pytest.fixture(scope="module")
def robot():
    return load_robot("panda")


@pytest.fixture(scope="module")
def runs(robot):
    """maximal+admittance (2.3 s: contact ≈ 1.0 s, steady ≈ 1.8 s), maximal+FF-MPC (2 s) and
    baseline+admittance (1.8 s: contact ≈ 1.43 s)."""
    return {
        "maximal+admittance": run_impact("maximal", "admittance", replace(CONFIG, duration=2.3)),
        "maximal+ff_mpc": run_impact("maximal", "ff_mpc", replace(CONFIG, duration=2.0)),
        "baseline+admittance": run_impact("baseline", "admittance", replace(CONFIG, duration=1.8)),
    }


def test_maximal_approach_touches_sooner_and_faster(runs):
    maximal, baseline = runs["maximal+admittance"], runs["baseline+admittance"]
    assert np.isfinite(maximal.contact_time) and np.isfinite(baseline.contact_time)
    assert maximal.contact_time < baseline.contact_time - 0.2  # s
    # a real impact vs a near-zero-velocity touch
    assert maximal.pre_impact_velocity > 0.3  # m/s
    assert baseline.pre_impact_velocity < 0.05  # m/s
    # the impact happens at the eq 14 bound of the last approach cycle (within 5 %)
    log = maximal.log
    k = int(np.searchsorted(log["t"], maximal.contact_time))
    bound = log["bound"][k - 1]
    assert maximal.pre_impact_velocity == pytest.approx(bound, rel=0.05)
    assert maximal.planner_failures == 0


def test_no_joint_limit_is_violated(runs):
    for name, run in runs.items():
        v = run.violations
        assert v.total == 0, (name, v)
        assert v.max_ratio["acceleration"] < 1.0, name


def test_penetration_stays_in_the_elastic_domain(runs):
    """Eq 12's z̄ holds for the maximal impact. The planner counts z from the detection point,
    which lies at most one step of motion (ż_imp·Δt ≈ 0.5 mm) below the true surface."""
    zbar = CONFIG.dice.max_penetration
    for name in ("maximal+admittance", "maximal+ff_mpc"):
        run = runs[name]
        slack = run.pre_impact_velocity * CONFIG.time_step
        assert run.peak_penetration <= zbar + slack, name
        assert run.peak_penetration > 0.8 * zbar  # the impact used the material, m


def test_learner_recovers_the_dice_set_in_pybullet(runs):
    """RLS (eq 19–21) after the run vs the box's PyBullet values (one tool contact point, so
    the nominal ones). Stiffness within 5 %: z is measured from the last force-free sample, at
    most ż_imp·Δt ≈ 0.5 mm above the true surface, a bias of ≈ 0.5 mm / 20 mm = 2.5 % at the
    ≈ 20 mm of pressing. Damping within 10 %: it is identified from the impact only (the one
    phase with a large ż), where Bullet's contact uses the velocity and depth of the start of
    the step (≈ 1 ms lag at ż̈ ≈ 10 m/s², a few % of β ż)."""
    dice = CONFIG.dice
    for name, run in runs.items():
        assert run.learned_stiffness == pytest.approx(dice.stiffness, rel=0.05), name
        assert run.learned_damping == pytest.approx(dice.damping, rel=0.10), name
    # and the prior the planner started from was wrong by more than that
    assert abs(CONFIG.prior_stiffness / dice.stiffness - 1.0) > 0.1


def test_ff_mpc_holds_the_target_force_with_the_learned_model(runs):
    """After the handover the force-feedback MPC (its K, B from the learner, live) holds 60 N.
    No sensor noise here: the MPC's remaining error is the bias of its regularising costs
    (posture, torque), measured at ~0.02 N; 0.5 N (< 1 %) leaves a 20× margin."""
    run = runs["maximal+ff_mpc"]
    assert np.isfinite(run.handover_time) and run.handover_time > run.contact_time
    assert bool(run.log["learned_in_mpc"])
    t = run.log["t"]
    tail = t >= t[-1] - 0.2
    assert np.abs(run.log["force"][tail] - CONFIG.target_force).max() < 0.5
    # the MPC's contact model at the end is the learner's, not the prior
    assert run.log["mpc_stiffness"][-1] == pytest.approx(CONFIG.dice.stiffness, rel=0.05)
    assert run.log["mpc_damping"][-1] == pytest.approx(CONFIG.dice.damping, rel=0.10)
    # it settles (5 % band for 0.2 s) sooner after the contact than the admittance controller
    adm = runs["maximal+admittance"]
    assert np.isfinite(run.steady_time)
    assert run.steady_time - run.contact_time < adm.steady_time - adm.contact_time


def test_table_and_figure(runs, tmp_path):
    table = format_table(list(runs.values()), CONFIG)
    for name in runs:
        assert f"| {name} |" in table
    path = plot_runs(list(runs.values()), CONFIG, tmp_path / "fig.png")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert 10_000 < path.stat().st_size < 200_000


def test_jobs_per_strategy_and_the_strategy_column(runs):
    """--strategies: the maximal runs once per strategy, the baseline once; the table names
    each maximal run's strategy."""
    names = ("strike_first", "touch_first", "prior")
    jobs = impact_jobs(CONFIG, DEFAULT_RUNS, names)
    assert [j.label for j in jobs] == [
        "maximal+admittance [strike_first]",
        "maximal+admittance [touch_first]",
        "maximal+admittance [prior]",
        "maximal+ff_mpc [strike_first]",
        "maximal+ff_mpc [touch_first]",
        "maximal+ff_mpc [prior]",
        "baseline+admittance",
        "baseline+ff_mpc",
    ]
    assert [j.config.strategy for j in jobs[:3]] == list(names)
    assert jobs[-1].config == CONFIG
    assert [j.config for j in impact_jobs(CONFIG)] == [CONFIG] * 4
    for bad in (("fastest",), ("prior", "prior"), ()):
        with pytest.raises(ConfigError):
            impact_jobs(CONFIG, DEFAULT_RUNS, bad)
    with pytest.raises(ConfigError, match="unknown run"):
        impact_jobs(CONFIG, (("maximal", "pid"),))
    struck = replace(runs["maximal+admittance"], strategy="strike_first")
    table = format_table([struck, runs["maximal+admittance"], runs["baseline+admittance"]], CONFIG)
    assert "| maximal+admittance | strike_first |" in table
    assert "| maximal+admittance | prior |" in table and "| baseline+admittance | — |" in table
    assert "Strike first" in table and "| maximal+admittance [strike_first] |" in table


def test_object_memory_file(runs, tmp_path):
    """--memory: the interval learned by the run with the most samples is kept per object (the
    other objects kept), handed back as the strike-first strategy's --set values; a value also
    given by --set, or a file that is no memory, is refused."""
    path = tmp_path / "memory.json"
    assert recall_object(path, "dice", {}) == {}  # no file yet
    path.write_text(
        json.dumps(
            {"cup": {"stiffness": [1, 2], "damping": [0, 1], "estimate": [1.5, 0.5], "samples": 9}}
        )
    )
    kept = remember_object(path, "dice", list(runs.values()), CONFIG)
    best = max(runs.values(), key=lambda r: r.learner_samples)
    assert kept is not None and kept.samples == best.learner_samples
    assert kept.estimate == (best.learned_stiffness, best.learned_damping)
    lo, hi = kept.stiffness
    assert lo < CONFIG.dice.stiffness < hi
    values = recall_object(path, "dice", {})
    assert values == kept.overrides()
    assert "cup" in json.loads(path.read_text())
    cfg = IMPACT_SCHEMA.build(values, CONFIG)
    assert cfg.strike.remembered_stiffness == pytest.approx(kept.stiffness)
    with pytest.raises(ConfigError, match="also given by --memory"):
        recall_object(path, "dice", {"strike.remembered_damping": [1.0, 2.0]})
    path.write_text("[1, 2]")
    with pytest.raises(ConfigError, match="not an object memory"):
        recall_object(path, "dice", {})


def test_study_refuses_to_overwrite(tmp_path):
    with pytest.raises(ConfigError, match="--force"):
        run_impact_study(CONFIG, runs=(), out_dir=tmp_path, progress=False)


def test_metrics_on_known_data():
    t = np.arange(1000) * 1e-3
    f = np.where(t < 0.5, 0.0, 60.0)
    f[700] = 50.0  # a dip out of the 5 % band
    assert time_to_steady_force(t, f, 60.0, 0.05, 0.2, 0.0) == pytest.approx(0.701)
    assert np.isnan(time_to_steady_force(t, f, 60.0, 0.05, 0.5, 0.0))
    robot = load_robot("panda")
    lim = joint_limits(robot)
    n = 5
    q = np.tile(robot.q_nominal, (n + 1, 1))
    v = np.zeros((n + 1, 7))
    tau = np.zeros((n, 7))
    v[2, 3] = 0.5 * lim.velocity[3]
    v[3, 3] = v[2, 3] + 1.5 * lim.acceleration[3] * 1e-3  # one step at 1.5 q̈_max
    v[4, 6] = 1.01 * lim.velocity[6]
    q[1, 0] = lim.position_upper[0] + 1e-3
    tau[0, 4] = lim.torque[4]
    viol = count_limit_violations(q, v, tau, 1e-3, lim)
    assert (viol.position, viol.velocity, viol.torque) == (1, 1, 1)
    assert viol.acceleration == 4  # steps 2→3 (1.5×), 3→4 (back down), 4→5 and 3→4 on joint 7
    assert viol.max_ratio["velocity"] == pytest.approx(1.01)


def test_config_validation():
    with pytest.raises(ConfigError):
        ImpactStudyConfig(limit_margin=1.5)
    with pytest.raises(ConfigError):
        ImpactStudyConfig(mpc_period=0.0025)  # not a whole number of 1 ms steps
    with pytest.raises(ConfigError):
        replace(CONFIG.dice, max_penetration=0.2)
    with pytest.raises(ConfigError):
        ImpactControllerConfig(
            direction=np.array([0.0, 0.0, -1.0]),
            material=SoftMaterial(3000.0, 20.0, 0.03),
            replan_period=-1.0,
        )
    with pytest.raises(ConfigError):
        PressTask(position=np.array([0.0, np.nan, 0.0]))
    ref = PressTask(position=np.array([0.5, 0.0, 0.1]), force=60.0).reference(1.0)
    assert ref.in_contact and ref.force[-1] == 60.0
    assert np.allclose(ref.ee_position_diag, [1.0, 1.0, 0.0])


# ----------------------------------------------------------------------------------- guard


def _frame(robot, q, v):
    model, data, fid = robot.model, robot.create_data(), robot.contact_frame_id
    pin.forwardKinematics(model, data, q, v, np.zeros(7))
    pin.computeJointJacobians(model, data, q)
    pin.updateFramePlacements(model, data)
    J = pin.getFrameJacobian(model, data, fid, LWA)
    drift = pin.getFrameClassicalAcceleration(model, data, fid, LWA).linear
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    h = pin.nonLinearEffects(model, data, q, v)
    return data.oMf[fid], J, drift, M, h


def _command(position, rotation):
    return CartesianCommand(
        phase="approach",
        position=position,
        velocity=np.zeros(3),
        acceleration=np.zeros(3),
        rotation=rotation,
        pre_impact_velocity=0.0,
        force=0.0,
        target_force=0.0,
    )


def test_guard_equals_the_plain_law_when_no_limit_is_active(robot):
    q = start_configuration(robot, np.array([0.6, 0.0, 0.3]))
    v = np.full(7, 0.05)
    oMf, *_ = _frame(robot, q, v)
    cmd = _command(oMf.translation + [0.0, 0.0, -1e-3], oMf.rotation)
    guard = JointLimitGuard(robot, joint_limits(robot), JointLimitGuardConfig(regularization=1e-9))
    plain = TaskSpaceInverseDynamics(robot).torque(cmd, q, v, np.array([0.0, 0.0, 5.0]))
    guarded = TaskSpaceInverseDynamics(robot, guard=guard).torque(
        cmd, q, v, np.array([0.0, 0.0, 5.0])
    )
    assert guard.stats["active"] == 0
    assert np.allclose(guarded, plain, atol=1e-4)


def test_guard_keeps_a_violent_demand_within_the_limits(robot):
    """A 20 cm position error with the law's gains asks for ~80 m/s²: the guarded torque's joint
    accelerations stay in the box, the velocities within their limits after one step, and the
    motion still goes towards the target."""
    lim = joint_limits(robot)
    q = start_configuration(robot, np.array([0.6, 0.0, 0.3]))
    v = 0.8 * lim.velocity * np.array([1, -1, 1, -1, 1, -1, 1])
    oMf, J, drift, M, h = _frame(robot, q, v)
    cmd = _command(oMf.translation + [0.0, 0.0, -0.2], oMf.rotation)
    guard = JointLimitGuard(robot, lim, JointLimitGuardConfig(dt=1e-3))
    tau = TaskSpaceInverseDynamics(robot, guard=guard).torque(cmd, q, v)
    qdd = np.linalg.solve(M, tau - h)
    assert guard.stats["active"] == 1
    assert np.all(np.abs(qdd) <= lim.acceleration + 1e-6)
    assert np.all(np.abs(v + qdd * 1e-3) <= lim.velocity + 1e-9)
    assert np.all(np.abs(tau) <= lim.torque)
    unguarded = TaskSpaceInverseDynamics(robot).torque(cmd, q, v)
    assert np.abs(np.linalg.solve(M, unguarded - h) / lim.acceleration).max() > 2.0


def test_guard_is_robust_to_an_impact_in_the_next_step(robot):
    """Before contact, the joints may accelerate only so much that the uncompensated impact
    force adds no limit violation (the paper's premise: the impact happens at the next step)."""
    lim = joint_limits(robot)
    q = start_configuration(robot, np.array([0.6, 0.0, 0.1]))
    v = np.zeros(7)
    oMf, J, drift, M, h = _frame(robot, q, v)
    cmd = _command(oMf.translation + [0.0, 0.0, -0.2], oMf.rotation)
    guard = JointLimitGuard(robot, lim)
    impact = np.array([0.0, 0.0, 15.0])  # N, on the robot
    tau = TaskSpaceInverseDynamics(robot, guard=guard).torque(cmd, q, v, impact_force=impact)
    qdd_free = np.linalg.solve(M, tau - h)
    qdd_hit = np.linalg.solve(M, tau - h + J[:3].T @ impact)
    limit = guard.config.margin * lim.acceleration + 1e-6
    assert np.all(np.abs(qdd_free) <= limit) and np.all(np.abs(qdd_hit) <= limit)
    plain = TaskSpaceInverseDynamics(robot, guard=JointLimitGuard(robot, lim)).torque(cmd, q, v)
    assert np.abs(np.linalg.solve(M, plain - h + J[:3].T @ impact) / limit).max() > 1.0


def test_admissible_torque_projects_and_holds_directions(robot):
    lim = joint_limits(robot)
    q = start_configuration(robot, np.array([0.6, 0.0, 0.1]))
    v = np.full(7, 0.1)
    oMf, J, drift, M, h = _frame(robot, q, v)
    guard = JointLimitGuard(robot, lim)
    tau_ok = h + M @ (0.1 * lim.acceleration)
    assert np.allclose(guard.admissible_torque(tau_ok, q, v), tau_ok)  # already admissible
    rng = np.random.default_rng(3)
    tau_big = rng.uniform(-1.0, 1.0, 7) * lim.torque
    out = guard.admissible_torque(tau_big, q, v)
    qdd = np.linalg.solve(M, out - h)
    assert np.all(np.abs(qdd) <= guard.config.margin * lim.acceleration + 1e-6)
    lateral = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    held = guard.admissible_torque(tau_ok, q, v, held_directions=lateral)
    acc = J[:3] @ np.linalg.solve(M, held - h) + drift
    free = J[:3] @ np.linalg.solve(M, tau_ok - h) + drift
    assert np.abs(acc[:2]).max() < 1e-2 * np.abs(free[:2]).max()
    # The M-metric projection changes the torque by a pure tangential force at the contact point
    # (Δτ = J_tᵀ μ): exactly the reaction a sticking contact would add, so the joint
    # accelerations commanded are the ones realised.
    rows = lateral @ J[:3]
    mu, *_ = np.linalg.lstsq(rows.T, held - tau_ok, rcond=None)
    assert np.linalg.norm(rows.T @ mu - (held - tau_ok)) < 1e-3 * np.linalg.norm(held - tau_ok)


def test_external_joint_torque_of_a_force_and_a_wrench(robot):
    q = start_configuration(robot, np.array([0.6, 0.0, 0.2]))
    _, J, *_ = _frame(robot, q, np.zeros(7))
    f = np.array([1.0, -2.0, 60.0])
    m = np.array([0.04, -0.02, 0.0])
    assert np.allclose(external_joint_torque(J, f), J[:3].T @ f)
    assert np.allclose(external_joint_torque(J, np.concatenate([f, m])), J.T @ np.r_[f, m])
    # a moment m is a pair of forces: f at the origin and the same force 1 mm aside (m = r × f)
    r = np.array([0.001, 0.0, 0.0])
    assert np.allclose(
        external_joint_torque(J, np.concatenate([f, np.cross(r, f)])),
        (J[:3] - pin.skew(r) @ J[3:]).T @ f,
    )
    with pytest.raises(InputError):
        external_joint_torque(J, np.zeros(4))
