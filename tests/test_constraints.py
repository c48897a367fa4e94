"""Hard constraints of the three OCP formulations (issue 23, :mod:`ffmpc_core.constraints`).

The rows and their bounds come from the robot's limits; every model (Python and C++) fills the
constraint values g and Jacobians Gx, Gu, checked against crocoddyl's NumDiff and the C++ ones
against the Python ones; a solved OCP whose bounds are active meets them; a measured state
beyond a margin does not make the problem infeasible; a constraint that cannot be met raises and
the polishing loop's MPC stage asks for the safe hold.
"""

from __future__ import annotations

from dataclasses import replace

import crocoddyl
import numpy as np
import pytest

from ffmpc_core.config import FORMULATIONS, ContactConfig, CostWeights, NodeReference, OcpConfig
from ffmpc_core.constraints import (
    CONE_ROWS,
    ConstraintConfig,
    ConstraintViolationError,
    ocp_bounds,
)
from ffmpc_core.errors import ConfigError
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig, MpcMeasurement, problem_bounds
from ffmpc_core.polishing import mpc_config
from ffmpc_core.polishing_loop import MpcStage, PolishingReading
from ffmpc_core.scenario import SCHEMA, load_scenario
from ffmpc_core.tasks import PolishingTask

BACKENDS = ("python", "native")
CONTACT_3D = ContactConfig(dimension=3, stiffness=(1e3, 2e3, 3e3), damping=(50.0, 60.0, 70.0))


def _node(robot, formulation, contact, terminal, backend):
    """A node of ``formulation`` with its constraints (and its bounds object)."""
    bounds = ocp_bounds(robot, formulation, contact, ConstraintConfig())
    weights = CostWeights()
    if formulation == "classical":
        from ffmpc_core.rigid_contact import make_rigid_contact_node

        node = make_rigid_contact_node(
            robot, contact, weights, 0.01, terminal, backend=backend, bounds=bounds, in_contact=True
        )
    elif formulation == "torque_feedback":
        from ffmpc_core.lowpass import make_lowpass_node

        node = make_lowpass_node(
            robot,
            contact,
            weights,
            0.01,
            terminal,
            50.0,
            backend=backend,
            bounds=bounds,
            in_contact=True,
        )
    elif backend == "native":
        from ffmpc_core.native import make_native_soft_contact_node

        node = make_native_soft_contact_node(robot, contact, weights, 0.01, terminal, bounds=bounds)
    else:
        from ffmpc_core.soft_contact import make_soft_contact_node

        node = make_soft_contact_node(robot, contact, weights, 0.01, terminal, bounds=bounds)
    return node, bounds


def _state(rng, robot, formulation, nc):
    q = robot.q_nominal + 0.2 * rng.standard_normal(robot.nv)
    parts = [q, rng.standard_normal(robot.nv)]
    if formulation == "torque_feedback":
        parts.append(robot.gravity(q) + 5.0 * rng.standard_normal(robot.nv))
    elif formulation == "force_feedback":
        parts.append(np.abs(20.0 * rng.standard_normal(nc)) + 1.0)
    return np.concatenate(parts), robot.gravity(q) + 5.0 * rng.standard_normal(robot.nv)


def _cases():
    for formulation in FORMULATIONS:
        for backend in BACKENDS:
            contacts = [ContactConfig()]
            if formulation == "force_feedback":
                contacts.append(CONTACT_3D)
            for contact in contacts:
                for terminal in (False, True):
                    yield formulation, backend, contact, terminal


CASES = list(_cases())
IDS = [f"{f}-{b}-{c.dimension}d-{'terminal' if t else 'running'}" for f, b, c, t in CASES]


# ---------------------------------------------------------------------------- rows and bounds
def test_bounds_are_the_robot_limits_with_the_stated_margins(robot):
    config = ConstraintConfig(
        position_margin=0.05, position_braking_time=0.1, velocity_margin=0.1, torque_margin=0.05
    )
    nv = robot.nv
    for formulation in FORMULATIONS:
        b = ocp_bounds(robot, formulation, ContactConfig(), config)
        # rows are fractions of their limits: v = 0.9·v_max sits on the velocity bound
        x = np.zeros(b.nx)
        x[nv : 2 * nv] = 0.9 * robot.velocity_limit
        np.testing.assert_allclose(b.state_rows(x)[nv : 2 * nv], b.state_upper[nv : 2 * nv])
        np.testing.assert_allclose(b.state_upper[nv : 2 * nv], 0.9)
        # positions: 95 % of the way from the middle of each range to its limit, at rest...
        middle = 0.5 * (robot.position_lower + robot.position_upper)
        half = 0.5 * (robot.position_upper - robot.position_lower)
        x[nv : 2 * nv] = 0.0
        x[:nv] = middle + 0.95 * half
        np.testing.assert_allclose(b.state_rows(x)[:nv], b.state_upper[:nv])
        # ...and the braking look-ahead q + T_b·v: moving out at 1 rad/s, 0.1 rad further
        x[:nv] -= 0.1
        x[nv : 2 * nv] = 1.0
        np.testing.assert_allclose(b.state_rows(x)[:nv], b.state_upper[:nv])
        x[nv : 2 * nv] = 0.9 * robot.velocity_limit
        # the torque u: 95 % of the limit (classical, force-feedback); w: the full limit
        u_limit = 1.0 if formulation == "torque_feedback" else 0.95
        np.testing.assert_allclose(b.control_upper, u_limit)
        np.testing.assert_allclose(b.control_scale * robot.torque_limit, 1.0)
    lpf = ocp_bounds(robot, "torque_feedback", ContactConfig(), config)
    tau = np.zeros(lpf.nx)
    tau[2 * nv :] = -0.95 * robot.torque_limit
    np.testing.assert_allclose(lpf.state_rows(tau)[2 * nv :], lpf.state_lower[2 * nv :])
    ff = ocp_bounds(robot, "force_feedback", ContactConfig(), replace(config, max_force=120.0))
    assert ff.n_state_rows == 2 * nv + 1 and not ff.has_cone
    force = np.zeros(ff.nx)
    force[-1] = 120.0
    assert ff.state_rows(force)[-1] == pytest.approx(ff.state_upper[-1]) == pytest.approx(1.0)
    assert ff.state_lower[-1] == 0.0  # no pulling


def test_friction_cone_rows_are_the_inscribed_pyramid(robot):
    mu = 0.4
    b = ocp_bounds(robot, "force_feedback", CONTACT_3D, ConstraintConfig(friction_coefficient=mu))
    assert b.has_cone and b.n_state_rows == 2 * robot.nv + 3 + CONE_ROWS
    cone = slice(b.nx, b.nx + CONE_ROWS)
    x = np.zeros(b.nx)
    x[-3:] = (mu / np.sqrt(2.0) * 50.0, 0.0, 50.0)  # on the x face of the pyramid (normal z)
    rows = b.state_rows(x)[cone]
    assert min(rows) == pytest.approx(0.0, abs=1e-12) and np.all(rows >= -1e-12)
    x[-3:] = (0.0, 1.01 * mu / np.sqrt(2.0) * 50.0, 50.0)  # just outside along y
    assert min(b.state_rows(x)[cone]) < 0.0
    x[-3:] = (0.2, -0.2, 50.0)  # well inside
    assert np.all(b.state_rows(x)[cone] > 0.0)
    assert np.all(b.state_lower[cone] == 0.0) and np.all(np.isinf(b.state_upper[cone]))


@pytest.mark.parametrize(("formulation", "backend", "contact", "terminal"), CASES, ids=IDS)
def test_constraint_rows_and_jacobians_against_numdiff(
    robot, formulation, backend, contact, terminal
):
    """g = [S·x; c∘u] in every model; Gx, Gu equal crocoddyl's finite differences of g."""
    rng = np.random.default_rng([FORMULATIONS.index(formulation), contact.dimension, terminal])
    node, bounds = _node(robot, formulation, contact, terminal, backend)
    model = node.model
    assert model.ng == bounds.ng(terminal)
    x, u = _state(rng, robot, formulation, contact.dimension)
    data = model.createData()
    numdiff = crocoddyl.ActionModelNumDiff(model, False)
    ndata = numdiff.createData()
    if terminal:
        model.calc(data, x)
        model.calcDiff(data, x)
        numdiff.calc(ndata, x)
        numdiff.calcDiff(ndata, x)
        expected = bounds.state_rows(x)
    else:
        model.calc(data, x, u)
        model.calcDiff(data, x, u)
        numdiff.calc(ndata, x, u)
        numdiff.calcDiff(ndata, x, u)
        expected = np.concatenate([bounds.state_rows(x), bounds.control_scale * u])
        np.testing.assert_allclose(ndata.Gu, data.Gu, atol=1e-6)
    np.testing.assert_allclose(data.g[: model.ng], expected, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(ndata.Gx, data.Gx, atol=1e-6)
    lower, upper = bounds.bounds(terminal)
    np.testing.assert_array_equal(model.g_lb, lower)
    np.testing.assert_array_equal(model.g_ub, upper)


@pytest.mark.parametrize(
    ("formulation", "contact", "terminal"),
    [(f, c, t) for f, b, c, t in CASES if b == "native"],
    ids=[i.replace("-native", "") for i in IDS if "-native-" in i],
)
def test_native_constraint_rows_equal_python(robot, formulation, contact, terminal):
    rng = np.random.default_rng([7, FORMULATIONS.index(formulation), contact.dimension])
    datas = []
    x, u = _state(rng, robot, formulation, contact.dimension)
    for backend in BACKENDS:
        node, _ = _node(robot, formulation, contact, terminal, backend)
        data = node.model.createData()
        if terminal:
            node.model.calc(data, x)
            node.model.calcDiff(data, x)
        else:
            node.model.calc(data, x, u)
            node.model.calcDiff(data, x, u)
        datas.append(data)
    python, native = datas
    for name in ("g", "Gx", "Gu"):
        np.testing.assert_allclose(getattr(native, name), getattr(python, name), rtol=0, atol=1e-14)


def test_unconstrained_models_have_no_rows(robot):
    for formulation in FORMULATIONS:
        config = MpcConfig(
            ocp=OcpConfig(formulation=formulation), constraints=ConstraintConfig(enabled=False)
        )
        assert problem_bounds(robot, config) is None
        mpc = ModelPredictiveController(robot, config, PolishingTask.pressing(_tool(robot)))
        assert all(n.model.ng == 0 for n in (*mpc.nodes, mpc.terminal_node))
        assert mpc.constrained_solver is None


def _tool(robot):
    return robot.contact_placement(robot.q_nominal).translation


# ------------------------------------------------------------------------ relaxation of x̂
def test_measured_state_beyond_a_margin_relaxes_only_that_row(robot):
    b = ocp_bounds(robot, "classical", ContactConfig(), ConstraintConfig())
    nv = robot.nv
    x0 = np.concatenate([robot.q_nominal, np.zeros(nv)])
    margins, relaxed = b.node_bounds(5, x0)
    assert not relaxed
    np.testing.assert_array_equal(
        margins[:, 0], np.broadcast_to(b.state_lower, (5, b.n_state_rows))
    )
    np.testing.assert_array_equal(
        margins[:, 1], np.broadcast_to(b.state_upper, (5, b.n_state_rows))
    )
    x0[nv + 3] = 0.95 * robot.velocity_limit[3]  # beyond the 0.9 bound, inside the limit
    x0[2] = robot.position_upper[2] - 0.01  # beyond the position bound, moving out at 0.1 rad/s
    x0[nv + 2] = 0.1
    with pytest.raises(ConfigError):
        b.node_bounds(5, x0)  # a relaxed row needs the node duration
    dt = 0.003
    bounds, relaxed = b.node_bounds(5, x0, dt=dt)
    assert relaxed and bounds.shape == (5, 2, b.n_state_rows)
    values = b.state_rows(x0)
    decay = np.exp(-dt * np.arange(1, 6) / b.recovery_time)
    for row in (nv + 3, 2):  # the velocity row, the position row q + T_b·v
        margin = b.state_upper[row]
        np.testing.assert_allclose(bounds[:, 1, row], margin + (values[row] - margin) * decay)
        assert np.all(np.diff(bounds[:, 1, row]) < 0.0)  # back towards the margin, node by node
        assert bounds[0, 1, row] < values[row]  # never "further out than now"
    others = np.ones(b.n_state_rows, bool)
    others[[2, nv + 3]] = False
    np.testing.assert_array_equal(bounds[:, 1, others], margins[:, 1, others])
    np.testing.assert_array_equal(bounds[:, 0], margins[:, 0])


def test_torque_feedback_joint_rows_start_at_node_2(robot):
    """Node 1's q and v follow from x̂ alone in the torque-feedback OCP (w₀ moves τ₁ only): those
    rows are free at node 1 and start from the predicted x₁ at node 2; τ rows start at node 1."""
    b = ocp_bounds(robot, "torque_feedback", ContactConfig(), ConstraintConfig())
    nv = robot.nv
    np.testing.assert_array_equal(b.first_node, [2] * (2 * nv) + [1] * nv)
    x0 = np.concatenate([robot.q_nominal, np.zeros(nv), robot.gravity(robot.q_nominal)])
    x1 = x0.copy()
    x1[nv + 6] = 0.95 * robot.velocity_limit[6]  # x₁ beyond the bound: relaxed from node 2 on
    dt = 0.003
    bounds, relaxed = b.node_bounds(4, x0, x1, dt=dt)
    assert relaxed
    assert np.all(np.isinf(bounds[0, :, : 2 * nv]))
    np.testing.assert_array_equal(
        bounds[0, :, 2 * nv :], [b.state_lower[2 * nv :], b.state_upper[2 * nv :]]
    )
    # from x₁ (node 1's time): node k is (k − 1)·Δt after it
    margin = b.state_upper[nv + 6]
    decay = np.exp(-dt * np.arange(1, 4) / b.recovery_time)
    np.testing.assert_allclose(bounds[1:, 1, nv + 6], margin + (0.95 - margin) * decay)
    with pytest.raises(ConfigError):
        b.node_bounds(4, x0, dt=dt)  # x₁ is needed


def test_torque_feedback_solve_from_a_fast_torque_state_is_feasible(robot):
    """τ̂ = g + 1 N·m at rest swings the light wrist beyond its velocity bound at node 1 whatever
    w₀: the solve must not be infeasible by construction (the first solve of test_mpc's eq-15
    test, refused before the node-2 rule)."""
    mpc = ModelPredictiveController(
        robot,
        MpcConfig(ocp=OcpConfig(formulation="torque_feedback")),
        PolishingTask.pressing(_tool(robot)),
    )
    q = robot.q_nominal
    cmd = mpc.step(MpcMeasurement(q=q, v=np.zeros(7), torque=robot.gravity(q) + 1.0), 0.1)
    assert cmd.relaxed and cmd.constraint_violation <= mpc.config.constraints.violation_tolerance


# ------------------------------------------------------------------- solved OCPs, active bounds
class _Hold:
    """A schedule holding one reference (in contact, force ``force`` N, tool at ``position``)."""

    def __init__(self, position, force, dimension=1, posture=None):
        self.ref = NodeReference(
            ee_position=np.asarray(position, float),
            force=np.full(dimension, 0.0) if dimension == 3 else np.array([force]),
            ee_position_weight=100.0,
            force_weight=3.0,
            in_contact=True,
            posture=posture,
            ee_position_diag=np.array([1.0, 1.0, 0.0]),
        )
        if dimension == 3:
            self.ref.force[2] = force

    def reference(self, t, dimension=1):
        return self.ref


def _solve(robot, config, schedule, meas, steps=3):
    mpc = ModelPredictiveController(robot, config, schedule)
    cmd = None
    for k in range(steps):
        cmd = mpc.step(meas, 0.002 * k)
    return mpc, cmd


def test_force_reference_above_the_maximum_is_held_at_the_maximum(robot):
    """Force-feedback, λ̄ = 200 N > max_force = 60 N: every predicted λ ≤ 60 N (to the solver's
    tolerance) while the unconstrained solve plans beyond it."""
    meas = MpcMeasurement(q=robot.q_nominal, v=np.zeros(7), force=np.array([55.0]))
    schedule = _Hold(_tool(robot), 200.0)
    config = MpcConfig(constraints=ConstraintConfig(max_force=60.0))
    free = replace(config, constraints=replace(config.constraints, enabled=False))
    _, unconstrained = _solve(robot, free, schedule, meas)
    assert unconstrained.xs[1:, -1].max() > 60.5  # the bound is active
    _, cmd = _solve(robot, config, schedule, meas)
    assert cmd.xs[1:, -1].max() <= 60.0 * (1.0 + 1e-3)
    assert cmd.constraint_violation <= config.constraints.violation_tolerance
    assert cmd.qp_iterations > 0  # the constrained solver gave the solution


def test_tangential_force_stays_in_the_friction_cone(robot):
    """3-D force-feedback, λ̂ = (15, 0, 50) N inside the pyramid (15/50 < 0.5/√2) and a force
    reference (60, 0, 50) N outside it: the unconstrained plan leaves the cone (|λx|/λz up to
    1.2), the constrained one stays on its face."""
    contact = ContactConfig(dimension=3, stiffness=1e3, damping=50.0)
    schedule = _Hold(_tool(robot), 50.0, dimension=3)
    schedule.ref.force[0] = 60.0
    schedule.ref.ee_position_weight = 0.0
    meas = MpcMeasurement(q=robot.q_nominal, v=np.zeros(7), force=np.array([15.0, 0.0, 50.0]))
    config = MpcConfig(contact=contact)
    free = replace(config, constraints=replace(config.constraints, enabled=False))
    face = config.constraints.friction_coefficient / np.sqrt(2.0)
    _, unconstrained = _solve(robot, free, schedule, meas)
    force = unconstrained.xs[1:, -3:]
    assert np.max(np.abs(force[:, 0]) / force[:, 2]) > 2.0 * face
    _, cmd = _solve(robot, config, schedule, meas)
    force = cmd.xs[1:, -3:]
    assert np.all(np.abs(force[:, 0]) <= face * force[:, 2] + 1e-3 * 150.0)
    assert np.max(np.abs(force[:, 0]) / force[:, 2]) > 0.99 * face  # on the face: active


def test_force_state_never_pulls(robot):
    """λ̄ = 0 N from λ̂ = 2 N, a strong force weight: the plan brings λ to 0, never below."""
    meas = MpcMeasurement(q=robot.q_nominal, v=np.array([0, 0, 0, 0.3, 0, 0, 0]), force=[2.0])
    schedule = _Hold(_tool(robot) + [0, 0, 0.02], 0.0)
    schedule.ref.force_weight = 1e3
    config = MpcConfig(constraints=ConstraintConfig())
    _, cmd = _solve(robot, config, schedule, meas)
    assert cmd.xs[1:, -1].min() >= -1e-3 * 150.0


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_posture_beyond_the_limits_is_stopped_at_the_bounds(robot, formulation):
    """A posture reference 1 rad beyond joint 4's limit, joint 4 already at 85 % of its velocity
    limit: the unconstrained plan breaks the torque and velocity bounds (5× a bound); the
    constrained one meets them all."""
    b = ocp_bounds(robot, formulation, ContactConfig(), ConstraintConfig())
    posture = robot.q_nominal.copy()
    posture[3] = robot.position_upper[3] + 1.0
    schedule = _Hold(_tool(robot), 0.0, posture=posture)
    schedule.ref.in_contact = False
    schedule.ref.ee_position_weight = 0.0
    weights = CostWeights(posture=1.0, state_limit=0.0)
    v = np.zeros(7)
    v[3] = 0.85 * robot.velocity_limit[3]
    meas = MpcMeasurement(
        q=robot.q_nominal, v=v, force=np.array([0.0]), torque=robot.gravity(robot.q_nominal)
    )
    config = MpcConfig(ocp=OcpConfig(formulation=formulation), weights=weights)
    free = replace(config, constraints=replace(config.constraints, enabled=False))
    _, unconstrained = _solve(robot, free, schedule, meas)
    assert b.violation(unconstrained.xs, unconstrained.us)[0] > 0.3  # active, by far
    _, cmd = _solve(robot, config, schedule, meas)
    violation, where = b.violation(cmd.xs, cmd.us)
    assert violation <= 1e-3, where
    assert cmd.constraint_violation == pytest.approx(violation)


def test_a_measured_velocity_beyond_the_margin_is_not_infeasible(robot):
    """x̂ with joint 4 at 97 % of its velocity limit (beyond the 90 % bound): the solve relaxes that
    row, returns a command and plans no faster than now."""
    v = np.zeros(7)
    v[3] = 0.97 * robot.velocity_limit[3]
    meas = MpcMeasurement(q=robot.q_nominal, v=v, force=np.array([10.0]))
    mpc, cmd = _solve(robot, MpcConfig(), _Hold(_tool(robot), 10.0), meas, steps=1)
    assert cmd.relaxed
    assert np.all(np.abs(cmd.xs[1:, 7 + 3]) <= v[3] * (1.0 + 1e-3))
    meas.v = np.zeros(7)
    assert not mpc.step(meas, 0.002).relaxed  # the margins' bounds again


class _Posture:
    """A schedule out of contact whose posture reference lies 1 rad beyond joint 4's upper
    limit: the cost drives joint 4 outward as fast as the bounds let it."""

    def __init__(self, robot):
        posture = robot.q_nominal.copy()
        posture[3] = robot.position_upper[3] + 1.0
        self.ref = NodeReference(
            ee_position=_tool(robot),
            force=np.zeros(1),
            ee_position_weight=0.0,
            force_weight=0.0,
            in_contact=False,
            posture=posture,
        )

    def reference(self, t, dimension=1):
        return self.ref


def _joint4_closed_loop(robot, recovery_time, disturbance, duration=0.1):
    """Classical MPC on a plant that is its own node model (Δt = period = 3 ms) plus an outward
    torque ``disturbance`` on joint 4 that the model does not see (N·m; the actuation gain
    error, the command delay and the table's friction act so on the robot), joint 4 starting at
    97 % of its velocity limit (its bound: 90 %) and the cost driving it outward: joint 4's
    |q̇|/limit after each step."""
    config = MpcConfig(
        ocp=OcpConfig(formulation="classical", period=0.003),
        weights=CostWeights(posture=1.0, state_limit=0.0),
        constraints=ConstraintConfig(recovery_time=recovery_time),
    )
    mpc = ModelPredictiveController(robot, config, _Posture(robot))
    plant = mpc.nodes[0].model
    data = plant.createData()
    nv, limit = robot.nv, robot.velocity_limit[3]
    x = np.concatenate([robot.q_nominal, np.zeros(nv)])
    x[nv + 3] = 0.97 * limit
    push = np.zeros(nv)
    push[3] = disturbance
    ratios = []
    for k in range(round(duration / config.ocp.period)):
        cmd = mpc.step(MpcMeasurement(q=x[:nv], v=x[nv:]), k * config.ocp.period)
        plant.calc(data, x, cmd.torque + push)
        x = np.array(data.xnext)
        ratios.append(x[nv + 3] / limit)
    return np.array(ratios)


def test_a_velocity_beyond_its_bound_is_brought_back_inside(robot):
    """Joint 4 at 97 % of its velocity limit, its bound at 90 %, the cost pushing it outward: the
    relaxed bound decays to the margin's (the default T_r, 10 ms), so the closed loop brings the
    joint back inside within 0.1 s (to e^(−0.1 s/T_r) of the 7 % excess plus the ADMM's
    tolerance eps_abs, 0.1 %), monotonically; holding the bound where the state is ("not further
    out than now", T_r = 10 s here) keeps it at 97 % for ever."""
    recovery_time = ConstraintConfig().recovery_time
    back = _joint4_closed_loop(robot, recovery_time, 0.0)
    assert back[-1] <= 0.9 + 0.07 * np.exp(-0.1 / recovery_time) + 1e-3
    assert np.all(np.diff(back) <= 1e-4)  # monotone, no overshoot
    held = _joint4_closed_loop(robot, 10.0, 0.0)
    assert held.min() >= 0.965


def test_an_unmodelled_outward_torque_does_not_ratchet_a_relaxed_bound(robot):
    """The same loop with 1 N·m on joint 4 that the model does not see: holding the bound where
    the state is lets it follow the joint outward from solve to solve, past the velocity limit
    (the robot's reflex) within 0.1 s; the recovery rule keeps it bounded, inside the limit."""
    held = _joint4_closed_loop(robot, 10.0, 1.0)
    assert held[-1] > 1.05 and np.all(np.diff(held) > 0.0)  # ratchets outward
    recovered = _joint4_closed_loop(robot, ConstraintConfig().recovery_time, 1.0)
    assert recovered.max() < 0.97 and recovered[-1] < 0.95


def test_one_sqp_iteration_per_solve_bounds_the_solve_and_keeps_the_bounds(robot):
    """``constrained_iterations`` 1 (the real-time MPC node's default): λ̄ = 100 N > max_force =
    60 N, so every solve needs SolverCSQP. Each capped solve makes one SQP iteration (one calc,
    one QP of at most ``max_qp_iterations`` ADMM iterations, one line search) where the full
    solves make up to 8. The first, cold one leaves the bound broken beyond the tolerance and is
    refused (ConstraintViolationError: the caller's safe hold), never sent; from the next tick
    on the plans keep the bound and their torque converges to the full solves' (the real-time
    iteration scheme: the warm start carries the iterations over the ticks)."""
    meas = MpcMeasurement(q=robot.q_nominal, v=np.zeros(7), force=np.array([55.0]))
    schedule = _Hold(_tool(robot), 100.0)
    full = MpcConfig(constraints=ConstraintConfig(max_force=60.0))
    capped = replace(full, constrained_iterations=1)
    mpc = ModelPredictiveController(robot, full, schedule)
    reference = [mpc.step(meas, 0.002 * k) for k in range(10)]
    assert reference[0].iterations == full.ocp.max_iterations  # the cap is what bounds it
    mpc = ModelPredictiveController(robot, capped, schedule)
    with pytest.raises(ConstraintViolationError) as info:
        mpc.step(meas, 0.0)
    assert info.value.violation > capped.constraints.violation_tolerance
    commands = [mpc.step(meas, 0.002 * k) for k in range(1, 10)]
    tolerance = capped.constraints.violation_tolerance
    for cmd in commands:
        assert mpc.solver is mpc.constrained_solver
        assert cmd.iterations == 1 and 0 < cmd.qp_iterations <= 101  # (101: the ADMM's cap)
        assert cmd.xs[1:, -1].max() <= 60.0 * (1.0 + tolerance)
        assert cmd.constraint_violation <= tolerance
    assert commands[-1].torque == pytest.approx(reference[-1].torque, abs=0.01 * 320.0)


def test_constrained_iterations_must_not_be_negative():
    with pytest.raises(ConfigError, match="constrained_iterations"):
        MpcConfig(constrained_iterations=-1)


# ------------------------------------------------------------------------- infeasible: refused
def _infeasible_mpc(robot, constrained_iterations=0):
    """An MPC whose node 1 must reach a joint-4 velocity of 0.85·limit in one 3 ms step from
    rest with at most 5 % of the torque limits: no torque can do it."""
    config = MpcConfig(
        constraints=ConstraintConfig(torque_margin=0.95),
        constrained_iterations=constrained_iterations,
    )
    mpc = ModelPredictiveController(robot, config, _Hold(_tool(robot), 10.0))
    b = mpc.bounds
    lower = b.state_lower.copy()
    lower[robot.nv + 3] = 0.85
    mpc.nodes[1].set_state_bounds(lower, b.state_upper)
    return mpc


@pytest.mark.parametrize("iterations", [0, 1])
def test_a_constraint_that_cannot_be_met_raises(robot, iterations):
    """With the SQP iterations of lockstep (0) and the real-time mode's one per solve (1)."""
    mpc = _infeasible_mpc(robot, iterations)
    meas = MpcMeasurement(q=robot.q_nominal, v=np.zeros(7), force=np.array([10.0]))
    with pytest.raises(ConstraintViolationError) as info:
        mpc.step(meas, 0.0)
    assert info.value.violation > mpc.config.constraints.violation_tolerance
    # the solver trades the unreachable velocity row against the torque rows it would need
    assert info.value.where in ("v[3] at node 1", "u[3] at node 0")
    assert mpc._prev_xs is None  # nothing kept: the next solve starts cold


def test_the_mpc_stage_holds_and_counts_a_refused_solve(robot):
    stage = MpcStage(_infeasible_mpc(robot), robot)
    reading = PolishingReading(
        q=robot.q_nominal,
        v=np.zeros(7),
        torque=robot.gravity(robot.q_nominal),
        force=np.array([10.0]),
        force_ok=True,
        solve=True,
        force_sensor=np.array([10.0]),
    )
    decision = stage.step(reading, 0.0)
    assert decision.hold and decision.command is None
    assert stage.failures == 1 and stage.constraint_failures == 1


# --------------------------------------------------------------------------- configuration
def test_constraints_are_on_by_default_everywhere():
    assert ConstraintConfig().enabled and MpcConfig().constraints.enabled
    for name in ("polishing", "polishing_fast", "force_square", "perfect_table", "push", "tilt"):
        scenario = load_scenario(name)
        # the polishing files keep 35 % of the velocity limits free (ConstraintConfig's docstring)
        assert scenario.mpc.constraints == ConstraintConfig(velocity_margin=0.35), name
        assert mpc_config(scenario).constraints.enabled, name


def test_scenario_keys_and_the_real_time_cap():
    names = {n for n in SCHEMA if n.startswith("mpc.constraints.")}
    assert names == {f"mpc.constraints.{f}" for f in ConstraintConfig.__dataclass_fields__}
    scenario = load_scenario(
        "polishing", {"mpc.constraints.enabled": False, "mpc.constraints.max_solve_time": 0.0015}
    )
    assert not mpc_config(scenario).constraints.enabled
    # a wall-clock cap acts in real-time runs only: lockstep runs stay reproducible
    assert mpc_config(scenario).constraints.max_solve_time == 0.0
    assert mpc_config(scenario, real_time=True).constraints.max_solve_time == 0.0015
    with pytest.raises(ConfigError, match="mpc.constraints.velocity_margin"):
        load_scenario("polishing", {"mpc.constraints.velocity_margin": 1.5})


@pytest.mark.parametrize(
    "bad",
    [
        {"velocity_margin": 1.0},
        {"position_margin": -0.1},
        {"position_braking_time": -0.1},
        {"max_force": 0.0},
        {"friction_coefficient": -1.0},
        {"max_qp_iterations": 0},
        {"eps_abs": 0.0},
        {"max_solve_time": -1.0},
        {"violation_tolerance": float("nan")},
    ],
)
def test_bad_constraint_settings_are_refused(bad):
    with pytest.raises(ConfigError):
        ConstraintConfig(**bad)
