"""The safe-maximal-impact experiment of Dehio & Kheddar 2020 (Sec. VI, Fig. 4) in PyBullet
(or MuJoCo: ``plant.engine``, the same scene, :mod:`sim_bridge.mujoco_plant`).

Setup (``ffmpc study impact``):

* The Panda (torque-controlled, 1 kHz, the plant of :mod:`sim_bridge.plant`) holds its spherical
  tool pointing down, ``approach_height`` (0.46 m, as in the paper) above the top face of a soft
  dice: a 0.16 m cube whose TRUE contact stiffness and damping are set in PyBullet. The dice is
  FIXED (a static body: Bullet's mass 0; the paper's dice weighs 0.1 kg and rests on a table).
  Fixing it makes the tool–dice contact the only compliance: the spherical tool makes one
  contact point (the dice's 5 cm collision margin keeps it the only one in the study's depth
  range, see :class:`~ffmpc_core.impact.scenario.DiceConfig`), so the force is the box's
  nominal ``k·depth + d·rate`` (Bullet applies stiffness per contact point; a dice resting on
  a table would add its 4-point support, 4× stiffer, in series, and its own 0.1 kg mode). The
  values the learner must find are then exactly the ones set in PyBullet.
* Material (our choice; the paper's Fig. 3 values are not in our copy of the text): stiffness
  3000 N/m and damping 20 N·s/m — a foam dice that takes 60 N at 2 cm (12.5 % strain) with a
  lightly damped response (damping ratio ≈ 0.08 with the Panda's ≈ 5 kg effective mass). The
  maximal penetration z̄ = 3 cm (the elastic-domain constraint of eq 12) is also set by the
  robot: the Panda hand's underside is 3.4 cm above the tool tip, deeper than that the hand
  would hit the dice.
* The planner (eq 12–14) starts from a PRIOR material, softer than the truth (2400 N/m,
  15 N·s/m, as from a data sheet): the robot has not touched the dice yet. The RLS learner
  (eq 19–21) is fed from the first contact on and its estimate goes to the force-feedback MPC.
* Strategy of the maximal approach (``strategy``). ``touch_first`` (the default):
  :class:`~ffmpc_core.impact.touch_first.TouchFirstImpactController` first touches the dice at
  the eq 14 bound that is safe for every material of the plausible range around the prior
  (0.4–4× its stiffness and damping: eq 14 solved for each corner, the smallest bound kept),
  regulates a 15 N touch while the learner collects data, plans the strike from the learner's
  confidence interval (or refuses a target the softest material of that interval cannot hold
  within z̄), retracts 6 cm above the touched surface and strikes at the eq 14 bound of the
  learned interval. ``prior``: the paper's scheme with the prior taken as the truth (a dice
  softer than the prior then goes past z̄, a stiffer one beyond the planned force).

Runs (approach × regulation). Every controller is an object of
:mod:`ffmpc_core.impact.controllers`; :class:`~ffmpc_core.impact.controllers.
ImpactTaskController` composes them (built by :func:`~ffmpc_core.impact.scenario.task_config`
from the study's configuration, :mod:`ffmpc_core.impact.scenario`; the metrics are
:mod:`ffmpc_core.impact.metrics`'s, the PyBullet scene :mod:`sim_bridge.scenes`'s); this module
only runs the plant, logs and summarises:

* approach ``maximal``: :class:`~ffmpc_core.impact.control.ImpactController` (Sec. IV-C): every
  cycle (or every ``replan_period``) map the joint limits to the contact space (eq 9–11), solve
  eq 14 for the maximal safe pre-impact velocity and track it; contact is declared at 2 N.
* approach ``baseline`` (the paper's comparison): the contact location as a static target. A
  critically damped second-order reference (:class:`~ffmpc_core.impact.controllers.
  BaselineApproach`, natural frequency ω, 5 rad/s) towards a point
  ``baseline_target_depth`` (5 mm) below the dice's top face, its acceleration saturated at the
  contact-space acceleration bound of eq 10–11, tracked by the same task-space law. Both
  approaches start at that acceleration bound; the baseline, knowing where the dice is, then
  runs faster in free space than the maximal one, whose speed is capped everywhere by the
  pre-impact bound (the impact may come at any step), and brakes. It arrives with a near-zero
  velocity (the target is a bit inside the dice so that the force does reach the 2 N
  threshold; a target exactly on the surface is approached asymptotically, never detected).
* regulation ``admittance`` (the paper): after contact the admittance force controller of
  :class:`~ffmpc_core.impact.control.AdmittanceForceController` drives the position reference to
  60 N (inside ImpactController for the maximal approach; the same update law,
  :class:`~ffmpc_core.impact.controllers.AdmittanceRegulator`, for the baseline).
* regulation ``ff_mpc`` (beyond the paper,
  :class:`~ffmpc_core.impact.controllers.ForceFeedbackHandover`): the force-feedback MPC
  (:class:`~ffmpc_core.mpc.ModelPredictiveController`, visco-elastic contact in the state) with
  the task "press 60 N where you are" (:class:`~ffmpc_core.tasks.PressTask`). It takes over
  once the impact is absorbed: in contact, when the tool moves into the dice no faster than the
  admittance controller's own speed limit (0.1 m/s; for the baseline that is at the contact).
  Until then the controller of the admittance run brakes as eq 14 planned: the planner's
  certificate (z ≤ z̄) assumes that braking, and an MPC with a force cost handed the full impact
  speed keeps pressing while the force is still below 60 N (we measured 46 mm of penetration
  and the hand hitting the dice with a 15 ms horizon, 34 mm with 200 ms). Its contact stiffness
  and damping are the learner's live estimate (``set_contact_parameters`` every MPC period)
  once the estimate is trustworthy (≥ 20 samples, standard errors ≤ 5 %), the prior before.
  MPC: 10 nodes of 20 ms (a 0.2 s horizon, the time scale of the dice–arm oscillation, ≈ 4 Hz;
  the polishing paper's 5 × 3 ms cannot see an impact through) re-solved every 4 ms; posture
  weight 1 and joint-velocity weight 0.1 (the defaults 0.01 let the redundant arm roll about the
  point contact: the impact scenario leaves ee_rotation at 0). The torque goes through the
  joint-limit guard with only the normal force compensated (the one the MPC models) and the contact
  point's tangential acceleration held at zero: the tool sticks on the foam, and compensating
  the measured friction force would push it sideways until it slips.

Joint limits (eq 1b–1e). Every torque sent goes through
:class:`~ffmpc_core.impact.task_space.JointLimitGuard`: a QP that keeps the joint accelerations
within the limits (also against an impact in the next step before contact), the velocities
within the limits over one step and the torques within theirs. The planner and the guard use the
same "control limits" (``limit_margin`` × the data-sheet acceleration and velocity limits), the
margin absorbing what a torque sent at the start of a step cannot know (the change of the
contact force during the step). Before contact the guard also bounds q̈ + Δq̈_impact, with
Δq̈ = M⁻¹ J_linᵀ F_imp the joint acceleration the impact force F_imp ≈ (β + α Δt) ż (prior
material, current speed) would add during the step in which the tool touches. The task-space
law weighs the five directions other than the motion 100× the motion direction (eq 2: ẋ_B = 0):
when a limit is active, the motion direction gives way (a tangential acceleration would change
the sticking friction force unannounced). Violations are counted against the full data-sheet
limits: q̈ is the finite difference of consecutive simulated joint velocities,
``(q̇[k+1] − q̇[k]) / Δt``, the acceleration actually realised over step k.

Signs: ``d = (0, 0, −1)``; the force ``f`` is the world-z component of the force the dice exerts
on the tool (N, > 0 when pressing), which is also the force-feedback MPC's λ.
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import asdict, dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ffmpc_core.errors import ConfigError, FfmpcError, InputError
from ffmpc_core.impact.controllers import (
    APPROACHES,
    REGULATIONS,
    ContactMeasurement,
    ImpactTaskCommand,
    ImpactTaskController,
)
from ffmpc_core.impact.learner import ContactEstimate
from ffmpc_core.impact.limits import joint_limits
from ffmpc_core.impact.memory import RememberedMaterial, recall, remember
from ffmpc_core.impact.metrics import LimitViolations, run_metrics, touch_metrics
from ffmpc_core.impact.scenario import (
    IMPACT_SCHEMA,
    STRATEGIES,
    ImpactStudyConfig,
    check_before_motion,
    dice_measurement,
    start_pose,
    task_config,
)
from ffmpc_core.reflex import reflex_plant
from ffmpc_core.robots import RobotModel, load_robot
from ffmpc_core.runner import LockstepClock, run_scenario
from sim_bridge.scenes import impact_plant_config as plant_config
from studies.execute import (
    RunOutcome,
    canonical_json,
    execute_jobs,
    prepare_output_dir,
    study_cache,
)
from studies.reflexes import reflex_cell, reflex_note
from studies.study import DIVERGENCE_ERRORS

#: How the study's texts name each plant engine.
ENGINE_NAMES = {"pybullet": "PyBullet", "mujoco": "MuJoCo"}

if TYPE_CHECKING:  # the plant imports PyBullet: loaded when a run starts, not to parse
    from sim_bridge.plant import PlantState

__all__ = [
    "DEFAULT_RUNS",
    "ImpactJob",
    "ImpactRun",
    "ImpactStudyResult",
    "default_out_dir",
    "execute_impact_job",
    "format_table",
    "impact_jobs",
    "plot_runs",
    "recall_object",
    "remember_object",
    "run_impact",
    "run_impact_study",
]


@dataclass
class ImpactRun:
    """One run's results.

    Attributes:
        approach, regulation: which run.
        pre_impact_velocity: speed along d at the last force-free sample before contact, m/s.
        contact_time: time the force reached the contact threshold, s (NaN: never).
        steady_time: :func:`~ffmpc_core.impact.metrics.time_to_steady_force` from the contact
            on, s (NaN: never).
        peak_force: N. peak_penetration: below the true top face, m.
        final_force: mean force over the last 0.2 s, N. final_force_error: max |f − target|
            over the last 0.2 s, N.
        violations: see LimitViolations (against the data-sheet limits).
        learned_stiffness, learned_damping: the RLS estimate at the end, N/m, N·s/m (NaN if
            the learner never got enough data); learned_std: their standard errors.
        learner_samples: samples fed to the learner.
        handover_time: when the force-feedback MPC took over, s (NaN: admittance runs).
        wall_time: s. guard_stats: the JointLimitGuard's counters. planner_failures: eq 14
            solves that failed (ImpactController.solver_failures).
        mpc_solve_time_median: s (force-feedback MPC only).
        log: time series (t, speed, force, penetration, bound, phase..., and the joint
            positions ``q`` (rad) and velocities ``v`` (rad/s) at each step).
        strategy: the maximal approach's strategy
            (:data:`~ffmpc_core.impact.scenario.STRATEGIES`; ``prior`` for the baseline, which
            plans nothing).
        touch_time, touch_velocity: the exploratory touch's contact (s) and speed at the last
            force-free sample before it (m/s); NaN without a touch.
        touch_peak_force, touch_peak_penetration: N and m, from the touch to the decision.
        decision_time: when the strike was decided (or refused) from the learned model, s.
        refusal: why the target was refused ("" if it was not); touch-first: contact_time is
            then NaN (no strike); strike-first: the contact was the strike, then the retract.
        strike_knowledge: the material interval the strike was planned with (touch-first) or
            the knowledge at the end (strike-first: the learned interval once decided).
        stopped_short: the regulation stopped at the penetration bound below the target (its
            message with the numbers; "" if it did not).
        reflex: the robot's reflexes over the run (``ffmpc_core.reflex.RobotReflex.report``:
            ``aborted``, the ``event``, the largest ratio of each kind); :attr:`aborted`.
    """

    approach: str
    regulation: str
    pre_impact_velocity: float
    contact_time: float
    steady_time: float
    peak_force: float
    peak_penetration: float
    final_force: float
    final_force_error: float
    violations: LimitViolations
    learned_stiffness: float
    learned_damping: float
    learned_std: tuple[float, float]
    learner_samples: int
    handover_time: float
    wall_time: float
    guard_stats: dict[str, int]
    planner_failures: int
    mpc_solve_time_median: float
    log: dict[str, np.ndarray] = field(repr=False)
    strategy: str = "prior"
    touch_time: float = float("nan")
    touch_velocity: float = float("nan")
    touch_peak_force: float = float("nan")
    touch_peak_penetration: float = float("nan")
    decision_time: float = float("nan")
    refusal: str = ""
    strike_knowledge: str = ""
    reflex: dict[str, Any] = field(default_factory=dict)
    stopped_short: str = ""

    @property
    def name(self) -> str:
        return f"{self.approach}+{self.regulation}"

    @property
    def aborted(self) -> bool:
        """A reflex of the robot stopped it: the run was aborted."""
        return bool(self.reflex.get("aborted", False))

    @property
    def label(self) -> str:
        """The name, with the strategy for the maximal approach."""
        return f"{self.name} [{self.strategy}]" if self.approach == "maximal" else self.name

    def summary(self) -> dict:
        """JSON-friendly, without the time series."""
        out = {k: v for k, v in asdict(self).items() if k != "log"}
        out["violations"] = asdict(self.violations)
        out["violations"]["total"] = self.violations.total
        out["name"] = self.name
        return out

    @classmethod
    def from_summary(cls, summary: dict[str, Any], log: dict[str, np.ndarray]) -> ImpactRun:
        """The run back from its :meth:`summary` (e.g. read from a study's cache) and a log."""
        fields_ = {k: v for k, v in summary.items() if k != "name"}
        violations = {k: v for k, v in fields_.pop("violations").items() if k != "total"}
        fields_["learned_std"] = tuple(fields_["learned_std"])
        return cls(**fields_, violations=LimitViolations(**violations), log=log)


class _ImpactLoop:
    """The impact run's scenario (:class:`~ffmpc_core.runner.LoopScenario`): the controller reads
    :func:`dice_measurement` of the true state, the plant gets the command's torque; the log
    (``t`` s, ``speed`` along d m/s, ``force`` world z on the tool N, ``penetration`` below the
    true top face m, the eq 14 ``bound`` m/s, the phase, the MPC's contact model and blend weight)
    and the joint positions ``qs`` (rad), velocities ``vs`` (rad/s, rows 0..K: the caller writes the
    final state) and torques ``taus`` (N·m) sent."""

    def __init__(self, robot: RobotModel, top: float, steps: int, dt: float) -> None:
        self.robot = robot
        self.data = robot.create_data()
        self.top = top
        self.log: dict[str, np.ndarray] = {
            "t": np.arange(steps) * dt,
            "speed": np.zeros(steps),
            "force": np.zeros(steps),
            "penetration": np.zeros(steps),
            "bound": np.full(steps, np.nan),
            "in_contact_phase": np.zeros(steps, dtype=bool),
            "mpc_stiffness": np.full(steps, np.nan),
            "mpc_damping": np.full(steps, np.nan),
            "phase": np.full(steps, "", dtype="<U13"),  # the maximal approach's phase
            "mpc_weight": np.zeros(steps),  # share of the MPC's torque in the blend
        }
        self.qs = np.zeros((steps + 1, robot.nq))
        self.vs = np.zeros((steps + 1, robot.nv))
        self.taus = np.zeros((steps, robot.nv))

    def measure(self, k: int, t: float, state: PlantState, /) -> ContactMeasurement:
        self.qs[k], self.vs[k] = state.q, state.v
        return dice_measurement(self.robot, self.data, state.q, state.v, state.wrench_world)

    def actuate(
        self, k: int, t: float, state: PlantState, command: ImpactTaskCommand, /
    ) -> np.ndarray:
        return command.torque

    def record(
        self,
        k: int,
        t: float,
        state: PlantState,
        m: ContactMeasurement,
        command: ImpactTaskCommand,
        joint_input: np.ndarray | None,
        /,
    ) -> None:
        log = self.log
        log["speed"][k] = m.speed
        log["force"][k] = m.force
        log["penetration"][k] = self.top - m.position[2]
        log["in_contact_phase"][k] = command.in_contact
        log["bound"][k] = command.pre_impact_velocity
        log["phase"][k] = command.phase
        log["mpc_stiffness"][k] = command.mpc_stiffness
        log["mpc_damping"][k] = command.mpc_damping
        log["mpc_weight"][k] = command.mpc_weight
        self.taus[k] = command.torque


def run_impact(
    approach: str,
    regulation: str,
    config: ImpactStudyConfig | None = None,
    robot: RobotModel | None = None,
) -> ImpactRun:
    """One run of the experiment (see the module docstring), in lockstep simulated time: the
    plant, :class:`~ffmpc_core.impact.controllers.ImpactTaskController` and the log."""
    if approach not in APPROACHES:
        raise ConfigError(f"approach must be one of {APPROACHES}, got {approach!r}")
    if regulation not in REGULATIONS:
        raise ConfigError(f"regulation must be one of {REGULATIONS}, got {regulation!r}")
    cfg = config if config is not None else ImpactStudyConfig()
    wall = time.perf_counter()
    robot = robot if robot is not None else load_robot("panda")
    dice = cfg.dice
    top = dice.top_height
    q0 = start_pose(cfg, robot)
    limits = joint_limits(robot)
    dt = cfg.time_step
    steps = int(round(cfg.duration / dt))
    # Raises InfeasibleTargetError here, before any motion, if no plausible material can hold
    # the target (or the touch force is unsafe for the softest one).
    controller = ImpactTaskController(
        robot, cfg.control_limits(limits), task_config(approach, regulation, cfg)
    )
    learning = controller.learning_approach

    from sim_bridge.scenes import make_plant

    scenario = _ImpactLoop(robot, top, steps, dt)
    with make_plant(robot, plant_config(cfg), cfg.engine) as plant:
        plant.reset(q0)
        stepped = reflex_plant(plant, robot, enabled=cfg.reflex)
        run_scenario(scenario, stepped, [controller], LockstepClock(dt, steps))
        s = plant.state()
        scenario.qs[steps], scenario.vs[steps] = s.q, s.v
    log, qs, vs, taus = scenario.log, scenario.qs, scenario.vs, scenario.taus

    learner = controller.learner
    handover = controller.handover
    guard = controller.guard
    approach_ctrl = controller.approach_controller
    solve_times = [] if handover is None else handover.solve_times
    learned_in_mpc = handover is not None and handover.learned
    metrics = run_metrics(
        cfg, log, qs, vs, taus, limits, controller.contact_time, controller.touch_speed
    )
    try:
        est = learner.estimate()
        learned = (est.stiffness, est.damping, (est.stiffness_std, est.damping_std))
    except InputError:  # never enough contact data
        learned = (float("nan"), float("nan"), (float("nan"), float("nan")))
    touch: dict[str, Any] = {}
    if learning is not None:
        touch = dict(
            touch_metrics(log, learning.touch_time, learning.touch_velocity, learning.decision_time)
        )
        touch.update(
            refusal="" if learning.refusal is None else str(learning.refusal),
            strike_knowledge=learning.knowledge.describe(),
        )
    stopped = controller.stopped_short
    return ImpactRun(
        approach=approach,
        regulation=regulation,
        strategy=cfg.strategy if approach == "maximal" else "prior",
        **touch,
        **metrics,
        learned_stiffness=float(learned[0]),
        learned_damping=float(learned[1]),
        learned_std=(float(learned[2][0]), float(learned[2][1])),
        learner_samples=learner.samples,
        handover_time=(
            float("nan") if controller.handover_time is None else controller.handover_time
        ),
        wall_time=time.perf_counter() - wall,
        guard_stats=dict(guard.stats),
        planner_failures=0 if approach_ctrl is None else approach_ctrl.solver_failures,
        mpc_solve_time_median=float(np.median(solve_times)) if solve_times else float("nan"),
        log=log | {"learned_in_mpc": np.array(learned_in_mpc), "q": qs[:steps], "v": vs[:steps]},
        reflex=stepped.reflex.report(),
        stopped_short="" if stopped is None else stopped.message(),
    )


#: The log series an impact job sends back from its worker (for the figure; float arrays).
PLOT_SERIES = ("t", "speed", "force", "penetration", "bound")


@dataclass(frozen=True)
class ImpactJob:
    """One run of the impact study (a :class:`studies.execute.Job`): the configuration and the
    (approach, regulation) pair; the run is a pure function of them."""

    config: ImpactStudyConfig
    approach: str
    regulation: str

    def key_document(self) -> dict[str, Any]:
        return {
            "study": "impact",
            "run": self.label,
            "config": IMPACT_SCHEMA.flatten(self.config),
            "plot_series": list(PLOT_SERIES),
        }

    def description(self) -> dict[str, Any]:
        return {"study": "impact", "approach": self.approach, "regulation": self.regulation}

    @property
    def label(self) -> str:
        base = f"{self.approach}+{self.regulation}"
        return f"{base} [{self.config.strategy}]" if self.approach == "maximal" else base

    @property
    def cost_rank(self) -> int:
        """The force-feedback MPC runs first (the slowest)."""
        return 0 if self.regulation == "ff_mpc" else 1


def execute_impact_job(job: ImpactJob) -> RunOutcome:
    """Run one impact job (in a Dask worker or in-process): its summary (JSON types) and the
    :data:`PLOT_SERIES` of its log, or the error of a run that diverged (as the polishing
    study's :func:`~studies.study.execute_run`)."""
    import pybullet

    try:
        run = run_impact(job.approach, job.regulation, job.config)
    except ConfigError:
        raise
    except (*DIVERGENCE_ERRORS, pybullet.error) as exc:
        return RunOutcome(job, error=f"{type(exc).__name__}: {exc}")
    summary = json.loads(canonical_json(run.summary()))
    return RunOutcome(job, summary=summary, plot_log={k: run.log[k] for k in PLOT_SERIES})


#: The runs of the study, in table order.
DEFAULT_RUNS = (
    ("maximal", "admittance"),
    ("maximal", "ff_mpc"),
    ("baseline", "admittance"),
    ("baseline", "ff_mpc"),
)
#: The paper's numbers (Sec. VI, Fig. 4), for comparison only.
PAPER = {
    "maximal_contact_time": 0.75,
    "maximal_pre_impact_velocity": 0.898,
    "baseline_contact_time": 1.38,
}


def _fmt(value: float, spec: str) -> str:
    return "—" if not np.isfinite(value) else format(value, spec)


def format_table(runs: list[ImpactRun], config: ImpactStudyConfig) -> str:
    """The study's table (Markdown), one row per run (the maximal approach's strategy in its
    own column), then the learner's estimates and each learning strategy's details."""
    head = (
        "| run | strategy | pre-impact velocity (m/s) | contact (s) | steady force (s) | "
        "peak force (N) | peak penetration (mm) | final force (N) | "
        "violations q / q̇ / q̈ / τ | max q̈/q̈_max | reflex | wall (s) |"
    )
    lines = [head, "|" + "---|" * 11]
    for r in runs:
        v = r.violations
        settle = r.steady_time - r.contact_time
        strategy = r.strategy if r.approach == "maximal" else "—"
        lines.append(
            f"| {r.name} | {strategy} | {_fmt(r.pre_impact_velocity, '.3f')} "
            f"| {_fmt(r.contact_time, '.3f')} "
            f"| {_fmt(r.steady_time, '.3f')} (+{_fmt(settle, '.3f')}) "
            f"| {_fmt(r.peak_force, '.1f')} | {_fmt(1e3 * r.peak_penetration, '.1f')} "
            f"| {_fmt(r.final_force, '.2f')} "
            f"| {v.position} / {v.velocity} / {v.acceleration} / {v.torque} "
            f"| {v.max_ratio['acceleration']:.3f} | {reflex_cell(r.reflex)} | {r.wall_time:.1f} |"
        )
    lines += ["", reflex_note([r.reflex for r in runs])]
    lines += _learner_table(runs, config) + _learning_strategy_tables(runs)
    stopped = [r for r in runs if r.stopped_short]
    if stopped:
        lines += ["", "Stopped short of the target (the regulation's depth bound):", ""]
        lines += [f"- {r.label}: {r.stopped_short}" for r in stopped]
    lines += [
        "",
        f"Steady force: |f − {config.target_force:g}| ≤ {100 * config.steady_band:g} % for "
        f"{config.steady_hold:g} s (time it starts, and + its delay after the contact). "
        "Violations: control steps beyond the data-sheet limits; q̈ = (q̇[k+1] − q̇[k])/Δt of "
        "the simulated q̇; τ counts commanded torques at or over the limit. Paper (real Panda, "
        f"its dice): contact at {PAPER['maximal_contact_time']} s with "
        f"{PAPER['maximal_pre_impact_velocity']} m/s (maximal) vs "
        f"{PAPER['baseline_contact_time']} s (baseline).",
    ]
    return "\n".join(lines)


def _learner_table(runs: list[ImpactRun], config: ImpactStudyConfig) -> list[str]:
    """The learner's estimate at the end of each run against the dice, Markdown lines."""
    dice = config.dice
    lines = [
        "",
        f"Learner (eq 19–21) at the end of each run vs the dice set in the plant "
        f"({ENGINE_NAMES[config.engine]}; stiffness {dice.stiffness:g} N/m, "
        f"damping {dice.damping:g} N·s/m; planner prior "
        f"{config.prior_stiffness:g} N/m, {config.prior_damping:g} N·s/m):",
        "",
        "| run | samples | stiffness α̂ (N/m) | error | damping β̂ (N·s/m) | error | "
        "MPC handover (s) |",
        "|" + "---|" * 7,
    ]
    for r in runs:
        ek = (r.learned_stiffness / dice.stiffness - 1.0) * 100.0
        ed = (r.learned_damping / dice.damping - 1.0) * 100.0 if dice.damping > 0 else np.nan
        lines.append(
            f"| {r.label} | {r.learner_samples} | {_fmt(r.learned_stiffness, '.1f')} "
            f"| {_fmt(ek, '+.1f')} % | {_fmt(r.learned_damping, '.2f')} | {_fmt(ed, '+.1f')} % "
            f"| {_fmt(r.handover_time, '.3f')} |"
        )
    return lines


def _learning_strategy_tables(runs: list[ImpactRun]) -> list[str]:
    """The touch-first runs' touch and the strike-first runs' decision, Markdown lines."""
    lines: list[str] = []
    touched = [r for r in runs if r.approach == "maximal" and r.strategy == "touch_first"]
    if touched:
        lines += [
            "",
            "Touch first (the maximal approach's exploratory touch at the eq 14 bound safe for "
            "the plausible range, then the strike planned from the learned interval):",
            "",
            "| run | touch (s) | touch velocity (m/s) | touch peak force (N) | "
            "touch peak penetration (mm) | decision (s) | strike planned with | refusal |",
            "|" + "---|" * 8,
        ]
        for r in touched:
            lines.append(
                f"| {r.label} | {_fmt(r.touch_time, '.3f')} | {_fmt(r.touch_velocity, '.3f')} "
                f"| {_fmt(r.touch_peak_force, '.1f')} "
                f"| {_fmt(1e3 * r.touch_peak_penetration, '.1f')} "
                f"| {_fmt(r.decision_time, '.3f')} | {r.strike_knowledge} "
                f"| {r.refusal or '—'} |"
            )
    struck = [r for r in runs if r.approach == "maximal" and r.strategy == "strike_first"]
    if struck:
        lines += [
            "",
            "Strike first (the first contact is the task's impact at the eq 14 bound safe for "
            "the knowledge before contact; the target decided in contact from the learned "
            "interval):",
            "",
            "| run | contact (s) | decision (s) | knowledge after the decision | refusal |",
            "|" + "---|" * 5,
        ]
        for r in struck:
            lines.append(
                f"| {r.label} | {_fmt(r.contact_time, '.3f')} | {_fmt(r.decision_time, '.3f')} "
                f"| {r.strike_knowledge} | {r.refusal or '—'} |"
            )
    return lines


#: Line styles of the runs in the figure: colour by run, line style by the maximal
#: approach's strategy (the baseline dashed).
_STYLE = {
    ("maximal", "admittance"): dict(color="black", ls="-"),
    ("maximal", "ff_mpc"): dict(color="tab:red", ls="-"),
    ("baseline", "admittance"): dict(color="tab:cyan", ls="--"),
    ("baseline", "ff_mpc"): dict(color="tab:purple", ls="--"),
}
_STRATEGY_LINE = {"strike_first": "-", "touch_first": ":", "prior": "-."}


def _style(run: ImpactRun, several: bool) -> dict[str, Any]:
    """The figure's style of a run (``several``: the maximal runs of several strategies)."""
    style = dict(_STYLE.get((run.approach, run.regulation), {}))
    if several and run.approach == "maximal":
        style["ls"] = _STRATEGY_LINE.get(run.strategy, "-")
    return style


def plot_runs(runs: list[ImpactRun], config: ImpactStudyConfig, path: Path) -> Path:
    """A figure like the paper's Fig. 4: velocity along the motion (with the eq 14 bound of the
    maximal approach) and contact force over time, every run; PNG at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_v, ax_f, ax_z) = plt.subplots(3, 1, figsize=(7.0, 6.6), sharex=True, dpi=90)
    bound_drawn = False
    several = len({r.strategy for r in runs if r.approach == "maximal"}) > 1
    for r in runs:
        t, log = r.log["t"], r.log
        style = _style(r, several)
        label = (r.label if several else r.name).replace("ff_mpc", "FF-MPC")
        ax_v.plot(t, log["speed"], lw=1.2, label=label, **style)
        if r.approach == "maximal" and not bound_drawn:
            ax_v.plot(
                t,
                log["bound"],
                color="tab:blue",
                lw=5.0,
                alpha=0.3,
                zorder=1,
                label=f"max. safe pre-impact velocity (eq 14, {r.strategy})",
            )
            bound_drawn = True
        ax_f.plot(t, log["force"], lw=1.2, label=label, **style)
        ax_z.plot(t, 1e3 * log["penetration"], lw=1.2, **style)
        if np.isfinite(r.contact_time):
            for ax in (ax_v, ax_f):
                ax.axvline(r.contact_time, color=style.get("color", "gray"), lw=0.6, ls=":")
    ax_f.axhline(config.target_force, color="tab:green", lw=1.5, label="desired force")
    ax_z.axhline(
        1e3 * config.dice.max_penetration, color="gray", lw=1.0, ls="-.", label="max. penetration z̄"
    )
    ax_z.set_ylim(bottom=-5.0)
    ax_v.set_ylabel("velocity along d (m/s)")
    ax_f.set_ylabel("contact force (N)")
    ax_z.set_ylabel("penetration (mm)")
    ax_z.set_xlabel("time (s)")
    ax_v.legend(fontsize=7, loc="upper right")
    ax_f.legend(fontsize=7, loc="upper left")
    ax_z.legend(fontsize=7, loc="upper left")
    for ax in (ax_v, ax_f, ax_z):
        ax.grid(alpha=0.3)
    dice = config.dice
    fig.suptitle(
        f"Panda on a soft dice (k = {dice.stiffness:g} N/m, d = {dice.damping:g} N·s/m): "
        "maximal impact vs baseline",
        fontsize=9,
    )
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


def _read_memory(path: str | Path) -> dict[str, Any]:
    """An object memory file (JSON, :mod:`ffmpc_core.impact.memory`); {} if it does not
    exist, ConfigError if it is not one."""
    path = Path(path)
    if not path.exists():
        return {}
    try:
        memory = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path}: not an object memory ({exc})") from None
    if not isinstance(memory, dict):
        raise ConfigError(f"{path}: not an object memory (a JSON object of objects)")
    return memory


def recall_object(path: str | Path, name: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The ``--set`` values that hand the interval remembered for object ``name`` in the
    memory file ``path`` to the strike-first strategy ({}: no file or no entry); ConfigError if
    ``overrides`` already give them."""
    entry = recall(_read_memory(path), name)
    if entry is None:
        return {}
    values = entry.overrides()
    for key in values:
        if key in overrides:
            raise ConfigError(f"--set {key}: also given by --memory; give it once")
    return values


def remember_object(
    path: str | Path, name: str, runs: list[ImpactRun], config: ImpactStudyConfig
) -> RememberedMaterial | None:
    """Keep in the memory file ``path`` (created if missing, other objects kept) the interval
    learned on object ``name`` by the run with the most learner samples (its end estimate,
    widened as the strike-first strategy widens its own: ``touch.sigmas`` and the floors);
    None, and nothing written, when no run learned a usable estimate."""
    usable = [
        r for r in runs if np.isfinite(r.learned_stiffness) and np.all(np.isfinite(r.learned_std))
    ]
    if not usable:
        return None
    best = max(usable, key=lambda r: r.learner_samples)
    estimate = ContactEstimate(
        best.learned_stiffness,
        best.learned_damping,
        best.learned_std[0],
        best.learned_std[1],
        float("nan"),
        best.learner_samples,
        float("nan"),
    )
    tc = config.touch
    try:
        material = RememberedMaterial.from_estimate(
            estimate, tc.sigmas, tc.stiffness_floor, tc.damping_floor
        )
    except InputError:
        return None
    memory = remember(_read_memory(path), name, material)
    Path(path).write_text(json.dumps(memory, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    return material


def default_out_dir() -> Path:
    """``benchmarks/results/impact_study/<UTC time>`` under the current directory."""
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return Path("benchmarks") / "results" / "impact_study" / stamp


@dataclass
class ImpactStudyResult:
    """Runs, the table (Markdown) and the files written."""

    runs: list[ImpactRun]
    table: str
    files: list[Path]
    wall_time: float


def impact_jobs(
    config: ImpactStudyConfig,
    runs: tuple[tuple[str, str], ...] = DEFAULT_RUNS,
    strategies: tuple[str, ...] | None = None,
) -> list[ImpactJob]:
    """The study's jobs in table order: each maximal run once per strategy of ``strategies``
    (None: ``config.strategy`` only), each baseline run once (with ``config``). Runs
    :func:`check_before_motion` for every strategy (InfeasibleTargetError before any motion)
    and refuses unknown runs or strategies (ConfigError)."""
    names = (config.strategy,) if strategies is None else tuple(strategies)
    for name in names:
        if name not in STRATEGIES:
            raise ConfigError(f"strategy must be one of {STRATEGIES}, got {name!r}")
    if not names or len(set(names)) != len(names):
        raise ConfigError(f"strategies must be distinct and at least one, got {names}")
    for approach, regulation in runs:
        if approach not in APPROACHES or regulation not in REGULATIONS:
            raise ConfigError(f"unknown run {approach}+{regulation}")
    configs = [config if n == config.strategy else replace(config, strategy=n) for n in names]
    jobs = []
    for approach, regulation in runs:
        for cfg in configs if approach == "maximal" else [config]:
            if approach == "maximal":
                check_before_motion(cfg)  # refuse before any motion
            jobs.append(ImpactJob(cfg, approach, regulation))
    return jobs


def run_impact_study(
    config: ImpactStudyConfig | None = None,
    runs: tuple[tuple[str, str], ...] = DEFAULT_RUNS,
    out_dir: Path | None = None,
    force: bool = False,
    progress: bool = True,
    command_line: str = "",
    *,
    strategies: tuple[str, ...] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    cache: bool = True,
    fresh: bool = False,
) -> ImpactStudyResult:
    """Run ``runs`` (:func:`impact_jobs`: the maximal ones once per strategy of
    ``strategies``, default ``config.strategy``; through :func:`studies.execute.execute_jobs`:
    a Dask ``LocalCluster`` of ``workers`` processes by default, ``1`` in this process, or the
    workers of a running ``scheduler``), write ``results.json``, ``table.md`` and
    ``impact_fig4.png`` into ``out_dir`` (refused if it exists, unless ``force`` or it holds an
    interrupted study: ``cache/`` and no ``results.json``, then the finished runs are read from
    its cache)."""
    cfg = config if config is not None else ImpactStudyConfig()
    # refuse before any motion (and before writing anything)
    jobs = impact_jobs(cfg, runs, strategies)
    out = prepare_output_dir(
        out_dir if out_dir is not None else default_out_dir(), force, resume=cache and not fresh
    )
    start = time.perf_counter()
    run_cache = study_cache(out, cache)
    batch = execute_jobs(
        jobs,
        execute_impact_job,
        workers,
        progress,
        scheduler=scheduler,
        cache=run_cache,
        fresh=fresh,
    )
    failures = [o for o in batch.outcomes if o.summary is None]
    if failures:
        raise FfmpcError("; ".join(f"{o.spec.label} diverged: {o.error}" for o in failures))
    results = [ImpactRun.from_summary(o.summary or {}, o.plot_log or {}) for o in batch.outcomes]
    if progress:
        for r in results:
            print(
                f"  {r.label}: contact {_fmt(r.contact_time, '.3f')} s, {r.violations.total} "
                f"limit violations, {r.wall_time:.1f} s wall",
                flush=True,
            )
    table = format_table(results, cfg)
    wall = time.perf_counter() - start
    figure = plot_runs(results, cfg, out / "impact_fig4.png")
    document = {
        "command_line": command_line,
        "created": datetime.now(timezone.utc).isoformat(),
        "python": platform.python_version(),
        "plant_engine": cfg.engine,
        "config": json.loads(json.dumps(asdict(cfg), default=str)),
        "paper": PAPER,
        "runs": [r.summary() for r in results],
        "wall_time_s": wall,
        "execution": {**batch.execution(run_cache), "workers": batch.workers},
    }
    (out / "results.json").write_text(json.dumps(document, indent=2, default=float) + "\n")
    (out / "table.md").write_text(table + "\n")
    return ImpactStudyResult(
        runs=results,
        table=table,
        files=[out / "table.md", out / "results.json", figure],
        wall_time=wall,
    )
