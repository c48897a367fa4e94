"""The contact learner's exploration routine (Dehio & Kheddar 2020, Sec. V and VI) in PyBullet.

``ffmpc study explore``: the Panda explores a soft object whose TRUE stiffness and damping are
set in PyBullet, and the recursive learner (eq 19–21) recovers them online.

Set-up (the impact study's, :mod:`ffmpc_core.impact.scenario`; the configuration, schema and
materials are there, the PyBullet scene is :func:`sim_bridge.scenes.exploration_plant_config`): the
object is a fixed 0.16 m cube (:class:`~ffmpc_core.impact.scenario.DiceConfig`, Bullet mass 0)
touched by the plant's spherical tool at one contact point, so the force is exactly the box's
``k·depth + d·rate``: the values the learner must find are the ones set in PyBullet. The tool starts
``start_clearance`` above the top face in :func:`~ffmpc_core.impact.scenario.start_configuration`
(tool pointing down). The tool sphere has a 4 cm radius
(:data:`sim_bridge.scenes.EXPLORATION_TOOL_RADIUS`, the plant's default is 1 cm) so that its centre
stays above the surface for any z ≤ z̄ ≤ 3 cm. Measured with the 1 cm sphere: once its centre was
below the surface (z = 11–11.7 mm), Bullet's persistent contact manifold held a second contact point
for 7 steps, doubling the force (+11 N) and biasing β̂ by +26 % (foam, one sine period and one 0.2
m/s impact). The run logs the number of contact points per step (``log["contact_points"]``); with
the 4 cm sphere it never exceeded 1 in any run. The paper's end-effector is a flat disc 0.13 m
across: a larger sphere is also closer to it.

Procedure (the controller is :class:`~ffmpc_core.impact.exploration.ExplorationController`;
this module runs the plant, logs and takes the checkpoints):

1. **Guarded approach** at ``approach_speed`` until the measured force reaches
   ``contact_threshold``. The surface is the contact-frame position at the LAST FORCE-FREE
   sample before that (see "How z is measured").
2. **Exploration motion**: :func:`~ffmpc_core.impact.learner.exploration_reference`, a
   sinusoidal penetration within the elastic bound z̄ (amplitude 0.6 z̄), then impacts at
   0.15–0.35 m/s that stop at 0.6 z̄, tracked along ``d = (0, 0, −1)`` by the task-space
   inverse-dynamics law with the measured contact wrench compensated
   (:class:`~ffmpc_core.impact.task_space.TaskSpaceInverseDynamics`) inside the joint-limit QP
   (:class:`~ffmpc_core.impact.task_space.JointLimitGuard`, ``limit_margin`` × the data-sheet
   limits, the five directions other than d weighted 100×, as in the impact study).
3. **Learning**: every control cycle in contact, ``(z, ż, f)`` goes to
   :class:`~ffmpc_core.impact.learner.RecursiveContactLearner`; the estimate with its standard
   errors is taken after the sinusoid and after each impact (when the tool is out again).

How z is measured (our choice): from forward kinematics, ``z = dᵀ (p − p_s)`` with ``p`` the
contact-frame position and ``p_s`` the position at the last force-free sample of the guarded
approach (the paper's "reference position that coincides with the soft material's initial contact
position", Sec. III-A; Sec. V: "the contact state is recorded via forward kinematics"). ``ż = dᵀ J
q̇``. Why not PyBullet's contact distance: (a) a robot has no such signal, and (b) measured: Bullet
reports the distance found by the collision detection at the START of the step, while the force is
that of the END-of-step state (its soft contact is implicit), so the distance lags by one step,
``z_bullet ≈ z − ż Δt``, and the fit attributes ``α Δt`` to the damping: +15 % on the dice (α Δt = 3
N·s/m on β = 20 N·s/m), see :attr:`ExplorationRun. alternatives`. Why not the box's nominal top
face: Bullet's effective surface lies 10 µm inside it (the same 10 µm as the plant's measured "0.2 %
deeper" static push). The FK surface is found by the contact itself, so it sees Bullet's effective
surface, and its error is one step of approach at most: ``0 ≤ z_measured − z_true < approach_speed ·
Δt`` (5 µm by default), whose effect on the estimate is bounded by
:func:`~ffmpc_core.impact.metrics. surface_offset_bias` (the "z" part of the confidence printed).
The force is the simulator's, noise-free (as in the impact study): with a noisy force sensor the
surface can only be found at a threshold of several σ, and that offset (threshold / α: 0.7 mm for 2
N on the dice, ≈ −5 % on α̂) would dominate; eq 3 has no intercept to absorb it. Not modelled here.

Which samples are fed: every sample with a positive force (the simulated force is exact, so a
positive force means contact; Bullet's contact cannot pull, so samples where α z + β ż < 0
during a fast retreat carry zero force and are not in the linear regime) EXCEPT the first one
of each contact episode. Measured: in the step in which the tool crosses the surface, Bullet's
speculative contact acts only from the crossing on, and the reported force is eq 3's force
times the fraction of the step spent in contact (``≈ z / (ż Δt)``): up to 5 N short at a
0.3 m/s impact on the dice. Those few samples sit at the largest ż and bias β̂ by ≈ −0.8 % on the
dice; a second learner fed with them as well (the plain "while in contact" rule) is kept for
comparison (:attr:`~ffmpc_core.impact.metrics.Checkpoint.with_onset`). All other samples fit
eq 3 to 0.3 mN rms.

Joint limits: before the learner is confident, the guard is told the force an impact during the next
step could add uncompensated, ``(β_p + α_p Δt) max(ż, 0)`` from a prior (the stiffest material
expected; ``ffmpc_core.impact.deformation.one_step_impact_force``); afterwards the learned model
predicts the next force increase, ``α̂ (z + ż Δt) + β̂ ż − f``
(``ffmpc_core.impact.deformation.predicted_force_increase``), with the friction force of a sticking
contact added (:func:`~ffmpc_core.impact.exploration.sticking_contact_force`). Violations are
counted against the full data-sheet limits
(:func:`~ffmpc_core.impact.metrics.count_limit_violations`).

Signs: ``d = (0, 0, −1)``; ``f`` is the world-z component of the force the object exerts on the
tool (N, > 0 when pressing); ``z`` > 0 inside the object (m), ``ż`` > 0 moving in (m/s).
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_core.impact.controllers import ContactMeasurement, contact_measurement
from ffmpc_core.impact.exploration import (
    ExplorationCommand,
    ExplorationController,
    ExplorationControllerConfig,
)
from ffmpc_core.impact.learner import (
    ContactEstimate,
    RecursiveContactLearner,
    fit_stiffness_damping,
    stack_data,
)
from ffmpc_core.impact.limits import joint_limits
from ffmpc_core.impact.metrics import (
    Checkpoint,
    LimitViolations,
    count_limit_violations,
    surface_offset_bias,
)
from ffmpc_core.impact.scenario import (
    DOWN,
    EXPLORATION_SCHEMA,
    MATERIALS,
    ExplorationConfig,
    Material,
    start_configuration,
)
from ffmpc_core.impact.task_space import JointLimitGuardConfig
from ffmpc_core.reflex import reflex_plant
from ffmpc_core.robots import RobotModel, load_robot
from ffmpc_core.runner import LockstepClock, run_scenario
from studies.execute import (
    RunOutcome,
    canonical_json,
    execute_jobs,
    prepare_output_dir,
    study_cache,
)
from studies.reflexes import reflex_cell, reflex_note
from studies.study import DIVERGENCE_ERRORS

if TYPE_CHECKING:  # the plant imports PyBullet: loaded when a run starts, not to parse
    from sim_bridge.plant import Plant, PlantState

__all__ = [
    "ExplorationJob",
    "execute_exploration_job",
    "ExplorationRun",
    "format_checkpoints",
    "format_summary",
    "run_exploration",
    "run_exploration_study",
]


@dataclass
class ExplorationRun:
    """One exploration's results.

    Attributes:
        material: the truth.
        surface_height: the surface found by the guarded approach (world z, m);
            surface_offset: ``surface_height − nominal top face`` (m).
        checkpoints: after the sinusoid and after each impact.
        alternatives: eq 17 (batch) on the same samples with other z measurements: "nominal top"
            (z from the box's nominal top face) and "bullet distance" (PyBullet's contact
            distance), each ``(α̂, β̂)``.
        peak_penetration: largest z of the run, m. max_tracking_error: largest |z − z_ref|, m.
        violations: against the data-sheet limits. guard_stats: the guard's counters.
        onset_samples: contact episodes' first samples (not fed to the main learner).
        wall_time: s. log: time series (t, z, zd, force, z_ref, phase, fed, onset, ...).
        reflex: the robot's reflexes over the run (``ffmpc_core.reflex.RobotReflex.report``);
            :attr:`aborted`: a reflex stopped the robot.
    """

    material: Material
    surface_height: float
    surface_offset: float
    checkpoints: list[Checkpoint]
    alternatives: dict[str, tuple[float, float]]
    peak_penetration: float
    max_tracking_error: float
    violations: LimitViolations
    guard_stats: dict[str, int]
    onset_samples: int
    wall_time: float
    log: dict[str, np.ndarray] = field(repr=False)
    reflex: dict[str, Any] = field(default_factory=dict)

    @property
    def final(self) -> Checkpoint:
        return self.checkpoints[-1]

    @property
    def aborted(self) -> bool:
        """A reflex of the robot stopped it: the run was aborted."""
        return bool(self.reflex.get("aborted", False))

    def summary(self) -> dict[str, Any]:
        """JSON-friendly, without the time series."""
        return {k: v for k, v in asdict(self).items() if k != "log"}

    @classmethod
    def from_summary(cls, summary: dict[str, Any]) -> ExplorationRun:
        """The run back from its :meth:`summary` (e.g. read from a study's cache), no log."""
        d = dict(summary)
        m = dict(d.pop("material"))
        m["impact_velocities"] = tuple(m["impact_velocities"])
        checkpoints = [
            Checkpoint(
                **{
                    **c,
                    "estimate": ContactEstimate(**c["estimate"]),
                    "with_onset": ContactEstimate(**c["with_onset"]),
                    "z_bias_bound": tuple(c["z_bias_bound"]),
                }
            )
            for c in d.pop("checkpoints")
        ]
        violations = LimitViolations(**d.pop("violations"))
        alternatives = {k: (float(v[0]), float(v[1])) for k, v in d.pop("alternatives").items()}
        return cls(
            **d,
            material=Material(**m),
            checkpoints=checkpoints,
            violations=violations,
            alternatives=alternatives,
            log={},
        )


def _tool_contact(plant: Plant, body: int) -> tuple[float, int]:
    """PyBullet's contact distance of the tool on ``body`` as a depth (m, > 0 inside; NaN
    without a contact point) and the number of contact points."""
    import pybullet as pb  # (loaded with the plant; not needed to parse a study's settings)

    points = pb.getContactPoints(
        bodyA=plant.body, bodyB=body, linkIndexA=plant.tool_link, physicsClientId=plant.client_id
    )
    depth = -min(p[8] for p in points) if points else float("nan")
    return depth, len(points)


class _ExplorationLoop:
    """The exploration's scenario (:class:`~ffmpc_core.runner.LoopScenario`): the controller
    reads the contact measurement of the true state (the pressing force is the world-z force on
    the tool, d = DOWN), the plant gets the command's torque until the controller is done; the
    log (module docstring's z, ż, f, references, depths, phases), the joint positions ``qs``
    (rad), velocities ``vs`` (rad/s) and torques ``taus`` (N·m), and the checkpoints, taken
    once a phase's contact is over (reference back above the surface)."""

    def __init__(
        self,
        robot: RobotModel,
        controller: ExplorationController,
        material: Material,
        top: float,
        n_max: int,
        z_error: float,
        progress: bool,
    ) -> None:
        self.robot = robot
        self.data = robot.create_data()
        self.controller = controller
        self.material = material
        self.top = top
        self.z_error = z_error
        self.progress = progress
        self.plant: Plant | None = None  # set once the plant is open
        self.box = -1
        self.log: dict[str, np.ndarray] = {
            name: np.full(n_max, np.nan)
            for name in ("t", "z", "zd", "force", "z_ref", "depth_nominal", "depth_bullet")
        }
        self.log["phase"] = np.full(n_max, -1, dtype=int)  # -1 = guarded approach
        self.log["fed"] = np.zeros(n_max, dtype=bool)
        self.log["onset"] = np.zeros(n_max, dtype=bool)
        self.log["contact_points"] = np.zeros(n_max, dtype=int)
        self.qs = np.zeros((n_max + 1, robot.nq))
        self.vs = np.zeros((n_max + 1, robot.nv))
        self.taus = np.zeros((n_max, robot.nv))
        self.checkpoints: list[Checkpoint] = []
        self.pending = 0  # next checkpoint: phase 0 = sinusoid, k = impact k
        self.phase_peak = 0.0
        self.touch_speed = float("nan")

    def measure(self, k: int, t: float, state: PlantState, /) -> ContactMeasurement:
        assert self.plant is not None
        self.qs[k], self.vs[k] = state.q, state.v
        wrench = state.wrench_world
        m = contact_measurement(
            self.robot, self.data, state.q, state.v, wrench, DOWN, force=float(wrench[2])
        )
        log = self.log
        log["t"][k] = t
        log["force"][k] = m.force
        log["zd"][k] = m.speed
        log["depth_nominal"][k] = self.top - m.position[2]
        log["depth_bullet"][k], log["contact_points"][k] = _tool_contact(self.plant, self.box)
        return m

    def actuate(
        self, k: int, t: float, state: PlantState, command: ExplorationCommand, /
    ) -> np.ndarray | None:
        return None if command.done else command.torque

    def record(
        self,
        k: int,
        t: float,
        state: PlantState,
        m: ContactMeasurement,
        command: ExplorationCommand,
        joint_input: np.ndarray | None,
        /,
    ) -> None:
        log = self.log
        log["z"][k] = command.z
        if joint_input is None:
            return
        phase = command.phase
        log["z_ref"][k] = command.z_ref
        log["phase"][k] = phase
        log["fed"][k] = command.fed
        log["onset"][k] = command.onset
        if command.onset and phase >= 1 and self.pending == phase:
            self.touch_speed = float(log["zd"][k - 1])
        if phase >= 0:
            self.phase_peak = max(self.phase_peak, command.z)
        if phase > self.pending and command.z_ref < 0.0:
            c = self.controller
            self.checkpoints.append(
                _checkpoint(
                    self.pending,
                    t,
                    c.learner,
                    c.with_onset,
                    c.first_moment,
                    self.z_error,
                    self.touch_speed,
                    self.phase_peak,
                )
            )
            if self.progress:
                print(_format_checkpoint_line(self.checkpoints[-1], self.material), flush=True)
            self.pending += 1
            self.phase_peak, self.touch_speed = 0.0, float("nan")
        self.taus[k] = joint_input


def run_exploration(
    config: ExplorationConfig | None = None,
    robot: RobotModel | None = None,
    progress: bool = False,
) -> ExplorationRun:
    """One exploration (module docstring), in lockstep simulated time: the plant,
    :class:`~ffmpc_core.impact.exploration.ExplorationController`, the checkpoints and the log.
    With ``progress`` the estimate is printed at each checkpoint."""
    cfg = config if config is not None else ExplorationConfig()
    wall = time.perf_counter()
    robot = robot if robot is not None else load_robot("panda")
    mat = cfg.material
    obj = mat.dice()
    top = obj.top_height
    x0, y0 = obj.position_xy
    q0 = start_configuration(robot, np.array([x0, y0, top + cfg.start_clearance]))
    limits = joint_limits(robot)
    dt = cfg.time_step
    w = cfg.lateral_weight
    from sim_bridge.plant import Plant
    from sim_bridge.scenes import exploration_plant_config

    plant_cfg = exploration_plant_config(obj, dt)
    ref = cfg.reference()
    controller = ExplorationController(
        robot,
        limits,
        ExplorationControllerConfig(
            reference=ref,
            start_height=top + cfg.start_clearance,
            guard=JointLimitGuardConfig(
                dt=dt, margin=cfg.limit_margin, task_weights=(w, w, 1.0, w, w, w)
            ),
            start_clearance=cfg.start_clearance,
            approach_speed=cfg.approach_speed,
            contact_threshold=cfg.contact_threshold,
            max_approach_time=cfg.max_approach_time,
            time_step=dt,
            friction=obj.lateral_friction * plant_cfg.tool.lateral_friction,  # Bullet multiplies
            prior_stiffness=cfg.prior_stiffness,
            prior_damping=cfg.prior_damping,
            learner_min_samples=cfg.learner_min_samples,
            learner_max_relative_std=cfg.learner_max_relative_std,
            gains=cfg.gains,
        ),
    )
    learner, with_onset = controller.learner, controller.with_onset
    n_max = controller.config.approach_steps + ref.time.size
    z_error = cfg.approach_speed * dt  # bound on z_measured − z_true, m

    scenario = _ExplorationLoop(robot, controller, mat, top, n_max, z_error, progress)
    with Plant(robot, plant_cfg) as plant:
        plant.reset(q0)
        scenario.plant, scenario.box = plant, plant.soft_boxes[0]
        stepped = reflex_plant(plant, robot, enabled=cfg.reflex)
        k = run_scenario(scenario, stepped, [controller], LockstepClock(dt, n_max))
        s = plant.state()
        scenario.qs[k], scenario.vs[k] = s.q, s.v
    log, qs, vs, taus = scenario.log, scenario.qs, scenario.vs, scenario.taus
    checkpoints, pending = scenario.checkpoints, scenario.pending
    touch_speed, phase_peak = scenario.touch_speed, scenario.phase_peak
    surface = controller.surface
    if surface is None:
        raise ConfigError("the exploration never found the surface")
    checkpoints.append(
        _checkpoint(
            pending,
            k * dt,
            learner,
            with_onset,
            controller.first_moment,
            z_error,
            touch_speed,
            phase_peak,
        )
    )
    if progress:
        print(_format_checkpoint_line(checkpoints[-1], mat), flush=True)
    log = {name: series[:k] for name, series in log.items()}
    # q̈ realised over each step, as a fraction of the data-sheet limit (worst joint)
    log["acceleration_ratio"] = np.max(
        np.abs(np.diff(vs[: k + 1], axis=0)) / dt / limits.acceleration, axis=1
    )
    fed = log["fed"]
    alternatives: dict[str, tuple[float, float]] = {}
    for name in ("nominal top", "bullet distance"):
        depth = log["depth_nominal" if name == "nominal top" else "depth_bullet"][fed]
        S, F = stack_data(depth, log["zd"][fed], log["force"][fed])
        stiffness, damping = fit_stiffness_damping(S, F)
        alternatives[name] = (float(stiffness), float(damping))
    explored = log["phase"] >= 0
    return ExplorationRun(
        material=mat,
        surface_height=float(surface[2]),
        surface_offset=float(surface[2] - top),
        checkpoints=checkpoints,
        alternatives=alternatives,
        peak_penetration=float(np.max(log["z"][explored])),
        max_tracking_error=float(np.max(np.abs(log["z"] - log["z_ref"])[explored])),
        violations=count_limit_violations(qs[: k + 1], vs[: k + 1], taus[:k], dt, limits),
        guard_stats=dict(controller.guard.stats),
        onset_samples=int(np.count_nonzero(log["onset"])),
        wall_time=time.perf_counter() - wall,
        log=log,
        reflex=stepped.reflex.report(),
    )


def _checkpoint(
    phase: int,
    t: float,
    learner: RecursiveContactLearner,
    with_onset: RecursiveContactLearner,
    sum_s: np.ndarray,
    z_error: float,
    touch_speed: float,
    peak: float,
) -> Checkpoint:
    est = learner.estimate()
    bias = np.abs(surface_offset_bias(est.stiffness, learner.SSt, sum_s, z_error))
    return Checkpoint(
        label="sinusoid" if phase == 0 else f"impact {phase}",
        time=float(t),
        estimate=est,
        z_bias_bound=(float(bias[0]), float(bias[1])),
        with_onset=with_onset.estimate(),
        pre_impact_velocity=float(touch_speed),
        peak_penetration=float(peak),
    )


def _format_checkpoint_line(c: Checkpoint, material: Material) -> str:
    e = c.estimate
    ea, eb = c.relative_errors(material)
    wa, wb = c.interval()
    v = "" if not np.isfinite(c.pre_impact_velocity) else f" at {c.pre_impact_velocity:.3f} m/s"
    return (
        f"  {material.name} after {c.label}{v}: α̂ = {e.stiffness:.2f} ± {wa:.2f} N/m "
        f"({100 * ea:+.3f} %), β̂ = {e.damping:.3f} ± {wb:.3f} N·s/m ({100 * eb:+.3f} %), "
        f"{e.samples} samples"
    )


def format_checkpoints(run: ExplorationRun) -> str:
    """One material's checkpoints as a Markdown table."""
    m = run.material
    lines = [
        f"{m.name}: truth α = {m.stiffness:g} N/m, β = {m.damping:g} N·s/m, "
        f"z̄ = {1e3 * m.max_penetration:g} mm ({m.note})",
        "",
        "| after | pre-impact v (m/s) | peak z (mm) | samples | α̂ (N/m) | ± 2se + z-bound "
        "| α error | β̂ (N·s/m) | ± 2se + z-bound | β error | covers | β error with onsets |",
        "|" + "---|" * 12,
    ]
    for c in run.checkpoints:
        e = c.estimate
        ea, eb = c.relative_errors(m)
        wa, wb = c.interval()
        eb_on = c.with_onset.damping / m.damping - 1.0 if m.damping > 0 else float("nan")
        v = "—" if not np.isfinite(c.pre_impact_velocity) else f"{c.pre_impact_velocity:.3f}"
        lines.append(
            f"| {c.label} | {v} | {1e3 * c.peak_penetration:.2f} | {e.samples} "
            f"| {e.stiffness:.2f} | {wa:.3f} | {100 * ea:+.4f} % | {e.damping:.4f} | {wb:.4f} "
            f"| {100 * eb:+.4f} % | {'yes' if c.covers(m) else 'NO'} | {100 * eb_on:+.3f} % |"
        )
    return "\n".join(lines)


def format_summary(runs: list[ExplorationRun]) -> str:
    """The final relative errors of every material, and the alternatives' errors."""
    lines = [
        "| material | α (N/m) | β (N·s/m) | α̂ error | β̂ error | β̂ error with onsets "
        "| α̂, β̂ errors with z from the nominal top | ... from Bullet's contact distance "
        "| surface offset (µm) | peak z / z̄ | violations | reflex | wall (s) |",
        "|" + "---|" * 13,
    ]
    for r in runs:
        m, c = r.material, r.final
        ea, eb = c.relative_errors(m)
        eb_on = c.with_onset.damping / m.damping - 1.0
        alt = []
        for name in ("nominal top", "bullet distance"):
            a, b = r.alternatives[name]
            alt.append(f"{100 * (a / m.stiffness - 1):+.3f} %, {100 * (b / m.damping - 1):+.2f} %")
        lines.append(
            f"| {m.name} | {m.stiffness:g} | {m.damping:g} | {100 * ea:+.4f} % | {100 * eb:+.4f} % "
            f"| {100 * eb_on:+.3f} % | {alt[0]} | {alt[1]} | {1e6 * r.surface_offset:+.1f} "
            f"| {r.peak_penetration / m.max_penetration:.2f} | {r.violations.total} "
            f"| {reflex_cell(r.reflex)} | {r.wall_time:.1f} |"
        )
    lines += ["", reflex_note([r.reflex for r in runs])]
    return "\n".join(lines)


@dataclass(frozen=True)
class ExplorationJob:
    """One exploration (a :class:`studies.execute.Job`): its configuration, material included;
    the run is a pure function of it."""

    config: ExplorationConfig

    def key_document(self) -> dict[str, Any]:
        return {
            "study": "explore",
            "config": EXPLORATION_SCHEMA.flatten(self.config),
            "material": asdict(self.config.material),
        }

    def description(self) -> dict[str, Any]:
        return {"study": "explore", "material": self.config.material.name}

    @property
    def label(self) -> str:
        return self.config.material.name

    @property
    def cost_rank(self) -> int:
        return 0


def execute_exploration_job(job: ExplorationJob) -> RunOutcome:
    """Run one exploration (in a Dask worker or in-process): its summary in JSON types, or the
    error of a run that diverged."""
    import pybullet

    try:
        run = run_exploration(job.config)
    except ConfigError:
        raise
    except (*DIVERGENCE_ERRORS, pybullet.error) as exc:
        return RunOutcome(job, error=f"{type(exc).__name__}: {exc}")
    return RunOutcome(job, summary=json.loads(canonical_json(run.summary())))


def run_exploration_study(
    materials: tuple[str, ...] = ("foam", "dice", "rubber"),
    base: ExplorationConfig | None = None,
    progress: bool = True,
    *,
    out_dir: str | os.PathLike | None = None,
    force: bool = False,
    workers: int | None = None,
    scheduler: str | None = None,
    cache: bool = True,
    fresh: bool = False,
) -> list[ExplorationRun]:
    """Run the exploration on each named material of
    :data:`~ffmpc_core.impact.scenario.MATERIALS` (same settings) as :class:`ExplorationJob` s
    through :func:`studies.execute.execute_jobs` (a Dask ``LocalCluster`` of ``workers``
    processes by default, ``1`` in this process, or the workers of a running ``scheduler``).
    With ``out_dir`` (refused if it exists, unless ``force`` or it holds an interrupted study)
    ``results.json`` and ``tables.md`` are written there and, with ``cache``, each finished run
    is cached in ``out_dir/cache`` (a restart reads them back; ``fresh`` runs them again). The
    runs come back without their time series."""
    unknown = [name for name in materials if name not in MATERIALS]
    if unknown:
        raise ConfigError(f"unknown materials {unknown}; choose from {sorted(MATERIALS)}")
    if not materials:
        raise ConfigError("choose at least one material")
    cfg = base if base is not None else ExplorationConfig()
    resume = cache and not fresh
    out = None if out_dir is None else prepare_output_dir(out_dir, force, resume=resume)
    start = time.perf_counter()
    jobs = [ExplorationJob(replace(cfg, material=MATERIALS[name])) for name in materials]
    run_cache = None if out is None else study_cache(out, cache)
    batch = execute_jobs(
        jobs,
        execute_exploration_job,
        workers,
        progress,
        scheduler=scheduler,
        cache=run_cache,
        fresh=fresh,
    )
    failed = [o for o in batch.outcomes if o.summary is None]
    if failed:
        raise FfmpcError("; ".join(f"{o.spec.label} diverged: {o.error}" for o in failed))
    runs = [ExplorationRun.from_summary(o.summary or {}) for o in batch.outcomes]
    if progress:
        for r in runs:
            for c in r.checkpoints:
                print(_format_checkpoint_line(c, r.material), flush=True)
    if out is not None:
        tables = "\n\n".join([*(format_checkpoints(r) for r in runs), format_summary(runs)])
        (out / "tables.md").write_text(tables + "\n", encoding="utf-8")
        document = {
            "config": EXPLORATION_SCHEMA.flatten(cfg),
            "runs": [r.summary() for r in runs],
            "wall_time_s": time.perf_counter() - start,
            "execution": {**batch.execution(run_cache), "workers": batch.workers},
        }
        (out / "results.json").write_text(canonical_json(document) + "\n", encoding="utf-8")
    return runs
