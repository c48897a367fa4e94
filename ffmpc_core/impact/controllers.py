"""The impact experiment's controllers (Dehio & Kheddar 2020, Sec. VI) as controller objects.

Each has the shape of the MPC controllers: parameters in a frozen config dataclass, the mutable
workspace in the object, ``reset()`` and ``step(measurement, t) -> command``; none reads a clock.

* :class:`AdmittanceRegulator`: the post-contact admittance task (Sec. VI,
  :func:`~ffmpc_core.impact.control.admittance_step`) from a latched contact pose.
* :class:`BaselineApproach`: the paper's comparison approach, a critically damped reference to
  a static target along ``d``, its acceleration saturated at the contact-space bound (eq 10–11).
* The maximal approach (eq 9–14 every cycle) is :class:`~ffmpc_core.impact.control.
  ImpactController` (the paper's scheme), :class:`~ffmpc_core.impact.touch_first.
  TouchFirstImpactController` (touch, learn, strike) or :class:`~ffmpc_core.impact.
  strike_first.StrikeFirstImpactController` (the first contact is the impact; decide in
  contact), built by :func:`maximal_approach`.
* :class:`ForceFeedbackHandover`: the force-feedback MPC taking over after the impact, its
  torque blended in and kept admissible by the joint-limit guard.
* :class:`ImpactTaskController`: the whole experiment's control (approach, contact, learner,
  admittance or hand-over) from the measurement to the joint torque.

Frames and signs as in :mod:`ffmpc_core.impact.control`: ``d`` unit, world frame; speeds along
``d`` (m/s, > 0 moving in); the pressing force ``f`` (N, > 0 pressing) is ``−dᵀ F`` of the force
``F`` the environment exerts on the robot at the contact frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ffmpc_core.config import ContactConfig, CostWeights, OcpConfig
from ffmpc_core.constraints import ConstraintConfig
from ffmpc_core.errors import ConfigError, InputError, SolverError
from ffmpc_core.impact.control import (
    AdmittanceForceController,
    AdmittanceReference,
    CartesianCommand,
    ImpactController,
    ImpactControllerConfig,
    ImpactMeasurement,
    StoppedShort,
    admittance_step,
    stop_short_event,
)
from ffmpc_core.impact.deformation import (
    SoftMaterial,
    measured_deformation,
    one_step_impact_force,
    unit_direction,
)
from ffmpc_core.impact.learner import RecursiveContactLearner
from ffmpc_core.impact.limits import ContactSpaceMapper, JointLimits
from ffmpc_core.impact.robust import admits_target
from ffmpc_core.impact.strike_first import StrikeFirstConfig, StrikeFirstImpactController
from ffmpc_core.impact.task_space import (
    JointLimitGuard,
    JointLimitGuardConfig,
    TaskSpaceInverseDynamics,
)
from ffmpc_core.impact.touch_first import (
    TouchCycleInputs,
    TouchFirstConfig,
    TouchFirstImpactController,
)
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig, MpcMeasurement
from ffmpc_core.robots import RobotModel
from ffmpc_core.tasks import PhaseWeights, PressTask

__all__ = [
    "APPROACHES",
    "REGULATIONS",
    "AdmittanceConfig",
    "AdmittanceRegulator",
    "BaselineApproach",
    "BaselineApproachConfig",
    "ContactMeasurement",
    "ExternalApproach",
    "ForceFeedbackHandover",
    "HandoverCommand",
    "HandoverConfig",
    "ImpactTaskCommand",
    "ImpactTaskConfig",
    "ImpactTaskController",
    "contact_measurement",
]

#: The approaches (before contact) and the regulations (after) of :class:`ImpactTaskController`.
APPROACHES = ("maximal", "baseline")
#: The regulations after contact: the paper's admittance, or the hand-over to the FF-MPC.
REGULATIONS = ("admittance", "ff_mpc")
_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def _positive(owner: str, **values: float) -> None:
    for name, value in values.items():
        if not (np.isfinite(value) and value > 0):
            raise ConfigError(f"{owner}.{name} must be positive and finite, got {value}")


@dataclass(frozen=True)
class ContactMeasurement:
    """One cycle's measurement of the robot and its contact frame (world frame).

    Attributes:
        q: joint positions, rad. v: joint velocities, rad/s.
        position: contact-frame origin, m. rotation: contact-frame orientation (3×3).
        speed: contact-frame velocity along d, m/s (> 0 moving in).
        force: pressing force along d, N (> 0 pressing).
        wrench: ``[F; M]`` the environment exerts on the robot at the contact frame origin
            (world axes; N, N·m).
    """

    q: np.ndarray
    v: np.ndarray
    position: np.ndarray
    rotation: np.ndarray
    speed: float
    force: float
    wrench: np.ndarray

    def __post_init__(self) -> None:
        shapes = {"position": (3,), "rotation": (3, 3), "wrench": (6,)}
        for name, shape in shapes.items():
            value = np.asarray(getattr(self, name), dtype=float)
            if value.shape != shape or not np.all(np.isfinite(value)):
                raise InputError(f"ContactMeasurement.{name} must be finite of shape {shape}")
        q, v = np.asarray(self.q, dtype=float), np.asarray(self.v, dtype=float)
        if q.ndim != 1 or v.ndim != 1 or not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise InputError("ContactMeasurement.q and .v must be finite vectors")
        if not (np.isfinite(self.speed) and np.isfinite(self.force)):
            raise InputError("ContactMeasurement.speed and .force must be finite")


def contact_measurement(
    robot: RobotModel,
    data: pin.Data,
    q: np.ndarray,
    v: np.ndarray,
    wrench: np.ndarray,
    direction: np.ndarray,
    force: float | None = None,
) -> ContactMeasurement:
    """Forward kinematics of the contact frame (``data`` is updated) into a measurement.

    ``wrench``: (6,) on the robot, world axes (N, N·m); ``direction``: unit d, world.
    ``force``: the pressing force along d (N); default ``−dᵀ F``."""
    model, fid = robot.model, robot.contact_frame_id
    pin.forwardKinematics(model, data, q, v)
    pin.updateFramePlacements(model, data)
    oMf = data.oMf[fid]
    d = np.asarray(direction, dtype=float)
    speed = float(d @ pin.getFrameVelocity(model, data, fid, _LWA).linear)
    w = np.asarray(wrench, dtype=float)
    pressing = float(-(d @ w[:3])) if force is None else float(force)
    return ContactMeasurement(
        q=q,
        v=v,
        position=oMf.translation.copy(),
        rotation=oMf.rotation.copy(),
        speed=speed,
        force=pressing,
        wrench=w,
    )


def _check_time(t: float, previous: float | None) -> None:
    if not np.isfinite(t) or (previous is not None and t < previous):
        raise InputError(f"time must be finite and non-decreasing, got {t} s")


# ---------------------------------------------------------------------------- admittance
@dataclass(frozen=True)
class AdmittanceConfig:
    """The post-contact admittance task.

    Attributes:
        admittance: the force controller (admittance, filter, speed limit).
        direction: unit push direction d, world frame.
        target_force: N (paper: 60).
        time_step: control period, s (the reference is integrated over it each step).
        max_penetration: z̄, m: how far below the contact's surface the reference may go
            (reported in :class:`~ffmpc_core.impact.control.StoppedShort`; the depth itself is
            :meth:`AdmittanceRegulator.start`'s).
    """

    direction: np.ndarray
    target_force: float = 60.0
    time_step: float = 1e-3
    admittance: AdmittanceForceController = field(default_factory=AdmittanceForceController)
    max_penetration: float = float("inf")

    def __post_init__(self) -> None:
        object.__setattr__(self, "direction", unit_direction(self.direction))
        _positive("AdmittanceConfig", target_force=self.target_force, time_step=self.time_step)
        if not self.max_penetration > 0:
            raise ConfigError("AdmittanceConfig.max_penetration must be > 0 (m)")


class AdmittanceRegulator:
    """Sec. VI's admittance task as ``reset()`` / ``start(...)`` / ``step(measurement, t)``.

    :meth:`start` latches the contact pose (origin m, rotation, world), the speed along d
    (m/s) the reference starts from and the deepest reference (m along d from the origin: the
    surface + z̄); each :meth:`step` then moves the reference along d by
    :func:`~ffmpc_core.impact.control.admittance_step` from the measured pressing force, and
    records :attr:`stopped_short` the first time it stops at that depth below the target."""

    def __init__(self, config: AdmittanceConfig) -> None:
        self.config = config
        self.reset()

    def reset(self) -> None:
        """Forget the contact pose; :meth:`start` must come before the next :meth:`step`."""
        self._origin: np.ndarray | None = None
        self._rotation: np.ndarray | None = None
        self.reference = AdmittanceReference(0.0, 0.0)
        self._t_prev: float | None = None
        self.max_position = float("inf")
        self.stopped_short: StoppedShort | None = None

    @property
    def started(self) -> bool:
        """True once :meth:`start` latched a contact pose."""
        return self._origin is not None

    def start(
        self,
        origin: np.ndarray,
        rotation: np.ndarray,
        speed: float,
        max_position: float = float("inf"),
    ) -> None:
        """Latch the task's origin (m, world), its held orientation, the initial reference
        speed along d (m/s, usually the speed at contact) and the deepest reference
        ``max_position`` (m along d from the origin; inf: none)."""
        o = np.asarray(origin, dtype=float)
        R = np.asarray(rotation, dtype=float)
        if o.shape != (3,) or R.shape != (3, 3) or not np.isfinite(speed):
            raise InputError("start needs a 3-vector origin, a 3×3 rotation and a finite speed")
        if np.isnan(max_position) or max_position <= 0.0:
            raise InputError(f"max_position must be > 0 (m along d), got {max_position}")
        self._origin, self._rotation = o.copy(), R.copy()
        self.reference = AdmittanceReference(0.0, float(speed))
        self.max_position = float(max_position)

    def step(self, measurement: ContactMeasurement, t: float) -> CartesianCommand:
        """One cycle at ``t`` (s): the command of the contact frame (world frame)."""
        if self._origin is None or self._rotation is None:
            raise InputError("AdmittanceRegulator.step before start(): no contact pose")
        _check_time(t, self._t_prev)
        self._t_prev = t
        cfg = self.config
        command, self.reference = admittance_step(
            cfg.admittance,
            self.reference,
            self._origin,
            self._rotation,
            cfg.direction,
            measurement.force,
            cfg.target_force,
            cfg.time_step,
            max_position=self.max_position,
        )
        if self.stopped_short is None:
            self.stopped_short = stop_short_event(
                self.reference,
                self.max_position,
                measurement.force,
                cfg.target_force,
                cfg.admittance,
                cfg.max_penetration,
                t,
            )
        return command


# ---------------------------------------------------------------------------- baseline
@dataclass(frozen=True)
class BaselineApproachConfig:
    """The paper's comparison approach (Sec. VI).

    Attributes:
        direction: unit motion direction d, world frame.
        distance: the static target along d from the start pose, m.
        frequency: ω of the critically damped reference, rad/s.
        refresh: how often the contact-space acceleration bound (eq 10–11) is re-mapped, s.
        time_step: control period, s (the reference is integrated over it each step).
    """

    direction: np.ndarray
    distance: float
    frequency: float = 5.0
    refresh: float = 1e-3
    time_step: float = 1e-3

    def __post_init__(self) -> None:
        object.__setattr__(self, "direction", unit_direction(self.direction))
        _positive(
            "BaselineApproachConfig",
            distance=self.distance,
            frequency=self.frequency,
            refresh=self.refresh,
            time_step=self.time_step,
        )


class BaselineApproach:
    """Critically damped reference ``ẍ = ω²(x_T − x) − 2ω ẋ`` along d to the static target
    ``x_T`` (m), ``ẍ`` clipped to the contact-space acceleration range (eq 10–11, refreshed
    every ``refresh`` s; no certified bound → no acceleration), integrated semi-implicitly.
    The start pose (the hold pose) is latched by the first :meth:`step` after :meth:`reset`."""

    def __init__(
        self, robot: RobotModel, limits: JointLimits, config: BaselineApproachConfig
    ) -> None:
        self.config = config
        self.mapper = ContactSpaceMapper(robot, limits, config.direction)
        self.reset()

    def reset(self) -> None:
        """Reference back to the start (x = 0 m, ẋ = 0 m/s); the next step latches the pose."""
        self.position = 0.0
        self.velocity = 0.0
        self._acc = (0.0, 0.0)
        self._t_map: float | None = None
        self._t_prev: float | None = None
        self._hold: tuple[np.ndarray, np.ndarray] | None = None

    def step(self, measurement: ContactMeasurement, t: float) -> CartesianCommand:
        """One cycle at ``t`` (s): the command of the contact frame (world frame)."""
        _check_time(t, self._t_prev)
        self._t_prev = t
        cfg = self.config
        if self._hold is None:
            self._hold = (measurement.position.copy(), measurement.rotation.copy())
        if self._t_map is None or t - self._t_map >= cfg.refresh - 1e-9:
            try:
                self._acc = self.mapper.update(measurement.q, measurement.v).acceleration_range(0.0)
            except SolverError:
                self._acc = (0.0, 0.0)  # no certified bound: do not accelerate
            self._t_map = t
        lo, hi = min(self._acc[0], 0.0), max(self._acc[1], 0.0)
        w, dt, d = cfg.frequency, cfg.time_step, cfg.direction
        demand = w * w * (cfg.distance - self.position) - 2.0 * w * self.velocity
        acc = float(np.clip(demand, lo, hi))
        self.velocity += acc * dt
        self.position += self.velocity * dt
        return CartesianCommand(
            phase="approach",
            position=self._hold[0] + self.position * d,
            velocity=self.velocity * d,
            acceleration=acc * d,
            rotation=self._hold[1],
            pre_impact_velocity=float("nan"),
            force=0.0,
            target_force=0.0,
        )


# ---------------------------------------------------------------------------- hand-over
def handover_mpc_weights() -> CostWeights:
    """The hand-over MPC's default cost weights (posture 1, joint velocity 0.1: the defaults
    0.01 let the redundant arm roll about the point contact)."""
    return CostWeights(posture=1.0, joint_velocity=0.1)


@dataclass(frozen=True)
class HandoverConfig:
    """The force-feedback MPC's take-over after the impact.

    Attributes:
        direction: unit push direction d, world frame.
        target_force: N. time_step: control period, s.
        handover_speed: the MPC takes over once the tool, in contact, moves into the object no
            faster than this, m/s (``symmetric_speed``: moves either way no faster than this).
        blend: the MPC's torque is blended in linearly over this long, s (0 = switch).
        mpc_period, mpc_horizon, mpc_dt: MPC re-solve period (s, whole control periods),
            nodes, node length (s).
        mpc_force_weight: c6 of the pressing nodes. mpc_weights: the other cost weights.
        prior_stiffness, prior_damping: the MPC's contact model before the learner is
            confident, N/m, N·s/m.
        learner_min_samples, learner_max_relative_std: when the learner's estimate replaces
            the prior (checked every MPC period).
        mpc_constraints: the MPC's hard constraints (:mod:`ffmpc_core.constraints`, default
            settings) on or off. Off by default here: with them on, the hand-over MPC on the
            model-error dice of the impact study raised ``ConstraintViolationError`` on the
            force box (2400/7.5, 7200/7.5, 7200/15 N/m, N·s/m) or ended in a position or
            velocity reflex stop (4800/7.5, 4800/15, 7200/45), where without them every run
            kept every limit; the joint-limit guard bounds the hand-over's q̈ either way.
    """

    direction: np.ndarray
    target_force: float = 60.0
    time_step: float = 1e-3
    handover_speed: float = 0.1
    symmetric_speed: bool = False
    blend: float = 0.05
    mpc_period: float = 0.004
    mpc_horizon: int = 10
    mpc_dt: float = 0.02
    mpc_force_weight: float = 3.0
    mpc_weights: CostWeights = field(default_factory=handover_mpc_weights)
    prior_stiffness: float = 2400.0
    prior_damping: float = 15.0
    learner_min_samples: int = 20
    learner_max_relative_std: float = 0.05
    mpc_constraints: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "direction", unit_direction(self.direction))
        _positive(
            "HandoverConfig",
            target_force=self.target_force,
            time_step=self.time_step,
            handover_speed=self.handover_speed,
            mpc_period=self.mpc_period,
            mpc_dt=self.mpc_dt,
            prior_stiffness=self.prior_stiffness,
        )
        if not (np.isfinite(self.blend) and self.blend >= 0):
            raise ConfigError("HandoverConfig.blend must be >= 0 (s)")
        if not (np.isfinite(self.prior_damping) and self.prior_damping >= 0):
            raise ConfigError("HandoverConfig.prior_damping must be >= 0 (N·s/m)")
        every = self.mpc_period / self.time_step
        if abs(every - round(every)) > 1e-9 or round(every) < 1:
            raise ConfigError("HandoverConfig.mpc_period must be a whole number of time steps")

    @property
    def mpc_every(self) -> int:
        """Control periods between MPC solves."""
        return int(round(self.mpc_period / self.time_step))


@dataclass(frozen=True)
class HandoverCommand:
    """The hand-over's output: ``torque`` (N·m, admissible for the guard's limits), its blend
    ``weight`` in [0, 1] against the controller it takes over from, and the contact model the
    MPC used (stiffness N/m, damping N·s/m; ``learned``: from the learner, not the prior);
    ``force``: the contact force (N) the MPC's last solve predicts at its next node."""

    torque: np.ndarray
    weight: float
    stiffness: float
    damping: float
    learned: bool
    force: float = float("nan")


class ForceFeedbackHandover:
    """The force-feedback MPC (:class:`~ffmpc_core.mpc.ModelPredictiveController`, task "press
    ``target_force`` where you are": :class:`~ffmpc_core.tasks.PressTask`) taking over in
    contact, with the learner's live estimate as its contact model.

    The first :meth:`step` after :meth:`reset` engages it at the measured pose: the MPC is built
    there (posture reference = the measured q). Every ``mpc_period`` the MPC is re-solved (with
    the learner's estimate once it is confident); every step its torque goes through the
    joint-limit guard with only the normal force compensated and the contact point's lateral
    acceleration held at zero (a sticking contact). :meth:`ready` says when to engage.

    Args:
        robot: the robot model. guard: the joint-limit QP (shared with the torque law).
        learner: the contact learner whose estimate the MPC takes (fed by someone else).
        config: see :class:`HandoverConfig`.
    """

    def __init__(
        self,
        robot: RobotModel,
        guard: JointLimitGuard,
        learner: RecursiveContactLearner,
        config: HandoverConfig,
    ) -> None:
        self.robot = robot
        self.guard = guard
        self.learner = learner
        self.config = config
        d = config.direction
        # −d without negative zeros; the two directions orthogonal to d, held by friction.
        self._normal = np.where(d == 0.0, 0.0, -d)
        basis = np.linalg.svd(d.reshape(1, 3))[2]
        self._lateral = basis[1:] if abs(d[2]) != 1.0 else np.array([[1.0, 0, 0], [0, 1.0, 0]])
        self.reset()

    def reset(self) -> None:
        """Disengaged; the next :meth:`step` builds a new MPC."""
        self.mpc: ModelPredictiveController | None = None
        self.engage_time: float | None = None
        self._steps = 0
        self._torque = np.zeros(self.robot.nv)
        self._contact = (self.config.prior_stiffness, self.config.prior_damping)
        self._force = float("nan")
        self.learned = False
        self.solve_times: list[float] = []
        self._t_prev: float | None = None

    @property
    def engaged(self) -> bool:
        """True once a :meth:`step` built the MPC."""
        return self.mpc is not None

    def ready(self, in_contact: bool, speed: float) -> bool:
        """Whether to engage now: in contact, moving in (either way with ``symmetric_speed``)
        no faster than ``handover_speed`` (m/s)."""
        limit = self.config.handover_speed
        if not in_contact or speed > limit:
            return False
        return not self.config.symmetric_speed or abs(speed) <= limit

    def _build(self, measurement: ContactMeasurement) -> ModelPredictiveController:
        cfg = self.config
        return ModelPredictiveController(
            self.robot,
            MpcConfig(
                ocp=OcpConfig(
                    formulation="force_feedback",
                    horizon=cfg.mpc_horizon,
                    dt=cfg.mpc_dt,
                    period=cfg.mpc_period,
                ),
                contact=ContactConfig(stiffness=cfg.prior_stiffness, damping=cfg.prior_damping),
                weights=cfg.mpc_weights,
                q_reference=tuple(float(x) for x in measurement.q),
                constraints=ConstraintConfig(enabled=cfg.mpc_constraints),
            ),
            PressTask(
                position=measurement.position,
                force=cfg.target_force,
                weights=PhaseWeights(force=cfg.mpc_force_weight),
            ),
        )

    def step(self, measurement: ContactMeasurement, t: float) -> HandoverCommand:
        """One cycle at ``t`` (s); the first one after :meth:`reset` engages the MPC."""
        _check_time(t, self._t_prev)
        self._t_prev = t
        cfg = self.config
        if self.mpc is None:
            self.mpc = self._build(measurement)
            self.engage_time = t
        m = measurement
        if self._steps % cfg.mpc_every == 0:
            est = self.learner.confident_estimate(
                cfg.learner_min_samples, cfg.learner_max_relative_std
            )
            if est is not None:
                self.mpc.set_contact_parameters(est.stiffness, est.damping)
                self._contact = (est.stiffness, est.damping)
                self.learned = True
            command = self.mpc.step(MpcMeasurement(q=m.q, v=m.v, force=np.array([m.force])), t)
            self._torque = command.torque
            self._force = float(command.xs[min(1, len(command.xs) - 1)][2 * self.robot.nv])
            self.solve_times.append(command.solve_time)
        # The MPC models the normal force only: compensate that one (and the measured moment:
        # the contact point is off the frame origin when the tool tilts) and keep the contact
        # point's tangential acceleration at zero, so that the sticking friction carries no
        # load (compensating the measured friction force would push the tool sideways).
        normal = np.concatenate([m.force * self._normal, m.wrench[3:]])
        torque = self.guard.admissible_torque(
            self._torque, m.q, m.v, normal, held_directions=self._lateral
        )
        self._steps += 1
        blend = cfg.blend
        weight = 1.0 if blend <= 0 else min(self._steps * cfg.time_step / blend, 1.0)
        return HandoverCommand(
            torque, weight, *self._contact, learned=self.learned, force=self._force
        )


# ---------------------------------------------------------------------------- the whole task
@dataclass(frozen=True)
class ImpactTaskConfig:
    """The impact experiment's control (Sec. VI): one approach, then one regulation.

    Attributes:
        approach: ``maximal`` (eq 9–14 every cycle) or ``baseline`` (:data:`APPROACHES`).
        regulation: ``admittance`` (the paper) or ``ff_mpc`` (the hand-over to the
            force-feedback MPC) (:data:`REGULATIONS`).
        controller: the maximal approach's configuration; its direction, PRIOR material,
            target force, contact threshold and admittance serve every approach.
        touch: the touch-first strategy of the maximal approach; None = plan from the prior
            as if it were the truth (the paper's scheme).
        strike: with ``touch`` (its shared parameters), the strike-first strategy instead
            (:class:`~ffmpc_core.impact.strike_first.StrikeFirstImpactController`).
        surface: the object's expected surface point (m, world frame) the strike-first
            approach brakes before (None: unknown).
        baseline: the baseline approach (required for ``approach="baseline"``).
        handover: the hand-over (required for ``regulation="ff_mpc"``).
        guard: the joint-limit QP every torque goes through.
        time_step: control period, s.
    """

    approach: str
    regulation: str
    controller: ImpactControllerConfig
    guard: JointLimitGuardConfig
    time_step: float = 1e-3
    touch: TouchFirstConfig | None = None
    strike: StrikeFirstConfig | None = None
    surface: np.ndarray | None = None
    baseline: BaselineApproachConfig | None = None
    handover: HandoverConfig | None = None

    def __post_init__(self) -> None:
        if self.strike is not None and self.touch is None:
            raise ConfigError("ImpactTaskConfig: the strike-first strategy needs `touch` too")
        if self.approach not in APPROACHES:
            raise ConfigError(f"approach must be one of {APPROACHES}, got {self.approach!r}")
        if self.regulation not in REGULATIONS:
            raise ConfigError(f"regulation must be one of {REGULATIONS}, got {self.regulation!r}")
        _positive("ImpactTaskConfig", time_step=self.time_step)
        if self.approach == "baseline" and self.baseline is None:
            raise ConfigError("ImpactTaskConfig: the baseline approach needs `baseline`")
        if self.regulation == "ff_mpc" and self.handover is None:
            raise ConfigError("ImpactTaskConfig: the ff_mpc regulation needs `handover`")


@dataclass(frozen=True)
class ImpactTaskCommand:
    """One cycle's output of :class:`ImpactTaskController`.

    Attributes:
        torque: joint torques to apply, N·m. in_contact: the contact has been declared.
        phase: the maximal approach's phase, ``ff_mpc`` once the MPC alone acts, else "".
        pre_impact_velocity: the maximal approach's eq 14 bound this cycle, m/s (else NaN).
        mpc_weight: the MPC's share of the torque. mpc_stiffness, mpc_damping: its contact
            model (N/m, N·s/m; NaN before the hand-over). mpc_learned: that model is the
            learner's. mpc_force: the MPC's predicted contact force at its next node (N; NaN
            before the hand-over).
    """

    torque: np.ndarray
    in_contact: bool
    phase: str
    pre_impact_velocity: float
    mpc_weight: float
    mpc_stiffness: float
    mpc_damping: float
    mpc_learned: bool = False
    mpc_force: float = float("nan")


@dataclass(frozen=True)
class ExternalApproach:
    """The maximal approach's part of one cycle when it runs elsewhere (the impact graph's
    planner node), computed from the same measurement.

    Attributes:
        command: the approach's Cartesian command of the cycle.
        phase: the approach controller's phase after its step.
        touch: with a learning strategy (touch-first, strike-first), its inputs from before
            its step
            (:meth:`~ffmpc_core.impact.touch_first.TouchFirstImpactController.cycle_inputs`);
            None with the paper's scheme.
        stopped_short: the approach controller's regulation has stopped at its depth bound
            short of the target (:attr:`~ffmpc_core.impact.control.ImpactController.
            stopped_short`; the paper's scheme hands over no more then), None: not.
    """

    command: CartesianCommand
    phase: str
    touch: TouchCycleInputs | None = None
    stopped_short: StoppedShort | None = None


def maximal_approach(
    robot: RobotModel,
    limits: JointLimits,
    config: ImpactTaskConfig,
    learner: RecursiveContactLearner | None = None,
) -> ImpactController:
    """The maximal approach's controller of ``config``'s strategy: the paper's scheme
    (:class:`ImpactController`, its own learner), touch-first or strike-first (with
    ``learner``, default their own). The ROS-free task controller and the impact planner node
    build it with this one function. Raises InfeasibleTargetError before any motion (see the
    strategies)."""
    ctrl = config.controller
    if config.touch is None:
        return ImpactController(robot, limits, ctrl)
    if config.strike is None:
        return TouchFirstImpactController(robot, limits, ctrl, config.touch, learner=learner)
    return StrikeFirstImpactController(
        robot,
        limits,
        ctrl,
        config.touch,
        config.strike,
        surface=config.surface,
        learner=learner,
    )


class ImpactTaskController:
    """Measurement → joint torque for one run of the impact experiment (Sec. VI).

    Each cycle: declare the contact at ``contact_threshold`` (with the touch-first strategy,
    only the strike's contact counts); feed the learner (eq 19–20, deformation from the last
    force-free sample) unless a learning strategy's controller (touch-first, strike-first)
    learns itself; predict the force an impact during the next step would add (eq 3 one step
    ahead, for the guard); engage the hand-over when it is ready and allowed (a learning
    strategy says when; otherwise once the learner admits the target and the regulation has
    not stopped short of it); command the approach (maximal or baseline) or, after contact,
    the admittance task (never deeper than its depth bound below the contact's surface),
    through the task-space law inside the joint-limit guard, blended with the MPC's admissible
    torque (the admissible set is convex in τ: the blend is admissible).

    Args:
        robot: the robot model (contact frame = end-effector).
        limits: the control limits the planner and the guard use.
        config: see :class:`ImpactTaskConfig`.
        learner: the learner the hand-over reads and this controller feeds (default: its own
            :class:`RecursiveContactLearner`, or the learning strategy's; the impact graph's
            controller node gives one that holds the contact learner node's estimates). With
            a learning strategy this controller never feeds it (the strategy's feeding rule
            does, where it runs).
        external_approach: the maximal approach runs elsewhere (the impact planner node):
            :meth:`step` then takes its part of the cycle (:class:`ExternalApproach`); only
            with a given ``learner``.

    Raises:
        InfeasibleTargetError: touch-first and strike-first, before any motion (see them).

    Attributes: ``learner``, ``guard``, ``approach_controller`` (maximal: the
    :class:`ImpactController`, else None), ``learning_approach`` (the same object with a
    learning strategy, else None), ``baseline``, ``admittance``, ``handover``; after steps
    ``contact_time`` (s), ``touch_speed`` (m/s at the last force-free sample before contact),
    ``handover_time`` (s), :attr:`stopped_short`.
    """

    def __init__(
        self,
        robot: RobotModel,
        limits: JointLimits,
        config: ImpactTaskConfig,
        *,
        learner: RecursiveContactLearner | None = None,
        external_approach: bool = False,
    ) -> None:
        self.robot = robot
        self.config = config
        ctrl = config.controller
        self.guard = JointLimitGuard(robot, limits, config.guard)
        self.law = TaskSpaceInverseDynamics(robot, guard=self.guard)
        self.approach_controller: ImpactController | None = None
        self.learning_approach: TouchFirstImpactController | None = None
        self.baseline: BaselineApproach | None = None
        self.external_approach = external_approach and config.approach == "maximal"
        if self.external_approach and learner is None:
            raise ConfigError(
                "an external maximal approach (the impact planner node) needs the learner the "
                "hand-over reads"
            )
        #: a learning strategy of the maximal approach (touch-first or strike-first; here or
        #: external): its feeding rule feeds the learner, its inputs gate the contact
        self.gated_strategy = config.approach == "maximal" and config.touch is not None
        if config.approach == "maximal" and not self.external_approach:
            self.approach_controller = maximal_approach(robot, limits, config, learner)
            if isinstance(self.approach_controller, TouchFirstImpactController):
                self.learning_approach = self.approach_controller
        elif config.approach == "baseline":
            assert config.baseline is not None  # checked by ImpactTaskConfig
            self.baseline = BaselineApproach(robot, limits, config.baseline)
        self.admittance = AdmittanceRegulator(
            AdmittanceConfig(
                direction=ctrl.direction,
                target_force=ctrl.target_force,
                time_step=config.time_step,
                admittance=ctrl.admittance,
                max_penetration=ctrl.material.max_penetration,
            )
        )
        # The touch-first controller's rule feeds the learner (during the touch and after the
        # strike): the MPC then takes its estimate. Otherwise this controller feeds it.
        self.learner = (
            self.learning_approach.learner
            if self.learning_approach is not None
            else (learner if learner is not None else RecursiveContactLearner())
        )
        self.handover: ForceFeedbackHandover | None = None
        if config.regulation == "ff_mpc":
            assert config.handover is not None  # checked by ImpactTaskConfig
            self.handover = ForceFeedbackHandover(robot, self.guard, self.learner, config.handover)
        self.reset()

    def reset(self) -> None:
        """Back to the approach; every part reset, the learner emptied."""
        for part in (self.approach_controller, self.baseline, self.admittance, self.handover):
            if part is not None:
                part.reset()
        if self.learning_approach is None:  # (a learning approach resets its learner)
            self.learner.reset()
        self.contact_time: float | None = None
        self.touch_position: np.ndarray | None = None
        self.touch_speed = float("nan")
        self.handover_time: float | None = None
        self._hold_rotation: np.ndarray | None = None
        self._external_stopped: StoppedShort | None = None

    @property
    def prior(self) -> SoftMaterial:
        """The planning material before any learning (N/m, N·s/m, m)."""
        return self.config.controller.material

    def _impact_force(
        self, m: ContactMeasurement, in_contact: bool, touch: TouchCycleInputs | None
    ) -> np.ndarray | None:
        """Force (N, world, on the robot) an impact during the next step would add."""
        d, dt = self.config.controller.direction, self.config.time_step
        if touch is not None:
            # The touch-first knowledge's material: f ≈ (β + α Δt) ż.
            return -touch.impact_force * d
        if not in_contact:
            prior = self.prior
            return -one_step_impact_force(prior.stiffness, prior.damping, m.speed, dt) * d
        return None

    def _handover_allowed(
        self, touch: TouchCycleInputs | None, approach: ExternalApproach | None
    ) -> bool:
        """Whether the force-feedback MPC may take over the regulation (it presses for the
        target and does not know z̄): a learning strategy says so (strike-first: once the
        target is admitted from the learned interval); otherwise once the learner this
        controller feeds admits the target (:func:`~ffmpc_core.impact.robust.admits_target`)
        and the regulation has not stopped short of it."""
        if touch is not None:
            return touch.handover_allowed
        if self.stopped_short is not None:
            return False
        h = self.config.handover
        assert h is not None  # only asked with the ff_mpc regulation
        estimate = self.learner.confident_estimate(
            h.learner_min_samples, h.learner_max_relative_std
        )
        material = self.config.controller.material
        return estimate is not None and admits_target(
            estimate, self.config.controller.target_force, material.max_penetration
        )

    @property
    def stopped_short(self) -> StoppedShort | None:
        """The regulation's stop at its depth bound short of the target (None: not): the
        maximal approach's (here, or the external one's of the last cycle) or the baseline's
        admittance task's."""
        if self.approach_controller is not None:
            return self.approach_controller.stopped_short
        if self.external_approach:
            return self._external_stopped
        return self.admittance.stopped_short

    def step(
        self,
        measurement: ContactMeasurement,
        t: float,
        approach: ExternalApproach | CartesianCommand | None = None,
    ) -> ImpactTaskCommand:
        """One cycle at ``t`` (s). ``approach``: with ``external_approach``, the maximal
        approach's part of this cycle (the impact planner's, computed from the same
        measurement; a bare command for the paper's scheme); required then, refused
        otherwise."""
        m = measurement
        if (approach is not None) != self.external_approach:
            raise InputError(
                "an approach command is required with an external maximal approach, and only then"
            )
        if isinstance(approach, CartesianCommand):
            approach = ExternalApproach(approach, approach.phase)
        ctrl = self.config.controller
        touch: TouchCycleInputs | None = None
        if self.learning_approach is not None:
            touch = self.learning_approach.cycle_inputs(
                m.speed, self.config.time_step, m.force, m.position
            )
        elif approach is not None and self.gated_strategy:
            if approach.touch is None:
                raise InputError("the touch-first approach's cycle inputs are missing")
            touch = approach.touch
        if self._hold_rotation is None:
            self._hold_rotation = m.rotation.copy()
        if self.contact_time is None:
            if m.force <= 0.0:
                self.touch_position, self.touch_speed = m.position.copy(), m.speed
            elif m.force >= ctrl.contact_threshold and (touch is None or touch.strike):
                # (the touch-first controller's exploratory touch is not the contact)
                self.contact_time = t
                if self.touch_position is None:  # in contact from the start (not expected)
                    self.touch_position, self.touch_speed = m.position.copy(), m.speed
                # the reference stops z̄ below the last force-free sample
                depth = float(ctrl.direction @ (m.position - self.touch_position))
                self.admittance.start(
                    m.position,
                    self._hold_rotation,
                    m.speed,
                    max(ctrl.admittance.max_depth(ctrl.material.max_penetration) - depth, 1e-6),
                )
        in_contact = self.contact_time is not None
        if in_contact and m.force > 0.0 and not self.gated_strategy:
            assert self.touch_position is not None  # latched with the contact
            z = measured_deformation(m.position, self.touch_position, ctrl.direction)
            self.learner.update(z, m.speed, m.force)
        impact_force = self._impact_force(m, in_contact, touch)

        nan = float("nan")
        handover = self.handover
        mpc: HandoverCommand | None = None
        if handover is not None and (
            handover.engaged
            or (handover.ready(in_contact, m.speed) and self._handover_allowed(touch, approach))
        ):
            if not handover.engaged:
                self.handover_time = t
            mpc = handover.step(m, t)
        weight = 0.0 if mpc is None else mpc.weight
        phase, bound = "", nan
        if weight < 1.0:
            if approach is not None:
                cmd = approach.command
                bound, phase = cmd.pre_impact_velocity, approach.phase
            elif self.approach_controller is not None:
                F = m.wrench[:3].copy()
                cmd = self.approach_controller.step(ImpactMeasurement(m.q, m.v, F), t)
                bound, phase = cmd.pre_impact_velocity, self.approach_controller.phase
            elif in_contact:
                cmd = self.admittance.step(m, t)
            else:
                assert self.baseline is not None  # built for the baseline approach
                cmd = self.baseline.step(m, t)
            tau = self.law.torque(cmd, m.q, m.v, m.wrench, impact_force=impact_force)
            if mpc is not None and weight > 0.0:
                # Both torques are admissible for this state (each through the guard) and the
                # admissible set is convex in τ: the blend is admissible too.
                tau = (1.0 - weight) * tau + weight * mpc.torque
        else:
            assert mpc is not None
            tau, phase = mpc.torque, "ff_mpc"
            # the approach controller is not stepped here: keep learning (an external one, the
            # planner node's, is stepped on and learns with the same rule)
            if self.learning_approach is not None:
                self.learning_approach.learn(m.position, m.speed, m.force)
        if approach is not None:  # its state after its step, as an approach stepped here
            self._external_stopped = approach.stopped_short
        return ImpactTaskCommand(
            torque=tau,
            in_contact=in_contact,
            phase=phase,
            pre_impact_velocity=bound,
            mpc_weight=weight,
            mpc_stiffness=nan if mpc is None else mpc.stiffness,
            mpc_damping=nan if mpc is None else mpc.damping,
            mpc_learned=mpc is not None and mpc.learned,
            mpc_force=nan if mpc is None else mpc.force,
        )
