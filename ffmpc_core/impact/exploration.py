"""The contact learner's exploration routine (Dehio & Kheddar 2020, Sec. V and VI) as a
controller object: a guarded approach finds the surface, then the exploration motion
(:func:`~ffmpc_core.impact.learner.exploration_reference`: a sinusoidal penetration, then
impacts) is tracked while the recursive learner (eq 19–21) is fed ``(z, ż, f)``.

Frames and signs: the object's surface is horizontal and ``d = (0, 0, −1)`` (world frame);
``z = dᵀ (p − p_s)`` (m, > 0 inside) from the contact-frame position ``p`` and the surface
position ``p_s`` (the last force-free sample of the guarded approach); ``ż`` along d (m/s);
``f`` the pressing force (N, > 0 pressing).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.control import CartesianCommand
from ffmpc_core.impact.controllers import ContactMeasurement
from ffmpc_core.impact.deformation import (
    DOWN,
    measured_deformation,
    one_step_impact_force,
    predicted_force_increase,
)
from ffmpc_core.impact.learner import ExplorationReference, RecursiveContactLearner
from ffmpc_core.impact.limits import JointLimits, motion_basis
from ffmpc_core.impact.task_space import (
    JointLimitGuard,
    JointLimitGuardConfig,
    TaskSpaceGains,
    TaskSpaceInverseDynamics,
)
from ffmpc_core.robots import RobotModel, mass_matrix

__all__ = [
    "DOWN",
    "ExplorationCommand",
    "ExplorationController",
    "ExplorationControllerConfig",
    "measured_deformation",
    "sticking_contact_force",
]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def sticking_contact_force(
    normal_force: float,
    inverse_inertia: np.ndarray,
    friction: float,
    direction: np.ndarray = DOWN,
) -> np.ndarray:
    """The force (N, world frame, on the robot) of a contact that pushes back by
    ``normal_force`` (N) against the motion direction ``d`` and sticks.

    A normal force alone would also accelerate the contact point sideways (the arm's inverse
    operational-space inertia ``A = J_lin M⁻¹ J_linᵀ`` (m/(N·s²)) couples the directions);
    a sticking contact prevents that with a tangential friction force: with ``n = −d`` and a
    tangent basis ``T``, ``F = f_n n + T F_t`` where ``(Tᵀ A T) F_t = −Tᵀ A n f_n``, clipped to
    the friction cone ``|F_t| ≤ μ f_n``. Measured at the impacts: the friction force is ~28 %
    of the normal force, and its joint accelerations (0.16 of joint 2's limit on the rubber)
    are what the guard must also expect from an impact.
    """
    A = np.asarray(inverse_inertia, dtype=float)
    if A.shape != (3, 3) or not np.all(np.isfinite(A)):
        raise InputError("inverse_inertia must be a finite 3×3 matrix")
    if not (np.isfinite(normal_force) and normal_force >= 0 and friction >= 0):
        raise InputError("normal_force and friction must be finite and >= 0")
    basis = motion_basis(direction)[:3, :3]  # columns: d and two tangents
    n, T = -basis[:, 0], basis[:, 1:]
    tangential = -np.linalg.solve(T.T @ A @ T, T.T @ A @ n) * normal_force
    norm = float(np.linalg.norm(tangential))
    if norm > friction * normal_force:
        tangential *= friction * normal_force / norm
    return normal_force * n + T @ tangential


@dataclass(frozen=True)
class ExplorationControllerConfig:
    """One exploration's control.

    Attributes:
        reference: the exploration motion relative to the surface (sampled every time step).
        start_height: world z of the contact frame at the start, m (the guarded approach's
            position reference descends from it).
        start_clearance: how far above the surface the start is expected, m (the approach's
            z reference starts at −start_clearance).
        approach_speed: guarded-approach speed, m/s. contact_threshold: force that ends it, N.
        max_approach_time: s; ConfigError if no contact by then.
        time_step: control period, s (one sample of ``reference`` per step).
        friction: Coulomb coefficient of the tool–object contact (for the sticking force).
        prior_stiffness, prior_damping: what the guard assumes for an impact before the
            learner is confident (N/m, N·s/m).
        learner_min_samples, learner_max_relative_std: when the learner is confident enough
            to predict the next force for the guard.
        guard: the joint-limit QP. gains: task-space PD gains.
    """

    reference: ExplorationReference
    start_height: float
    guard: JointLimitGuardConfig
    start_clearance: float = 0.003
    approach_speed: float = 0.005
    contact_threshold: float = 2.0
    max_approach_time: float = 3.0
    time_step: float = 1e-3
    friction: float = 0.5
    prior_stiffness: float = 2e4
    prior_damping: float = 100.0
    learner_min_samples: int = 50
    learner_max_relative_std: float = 0.05
    gains: TaskSpaceGains = field(default_factory=TaskSpaceGains)

    def __post_init__(self) -> None:
        positive = {
            "start_clearance": self.start_clearance,
            "approach_speed": self.approach_speed,
            "contact_threshold": self.contact_threshold,
            "max_approach_time": self.max_approach_time,
            "time_step": self.time_step,
            "prior_stiffness": self.prior_stiffness,
            "learner_max_relative_std": self.learner_max_relative_std,
        }
        for name, value in positive.items():
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"ExplorationControllerConfig.{name} must be positive")
        if not np.isfinite(self.start_height):
            raise ConfigError("ExplorationControllerConfig.start_height must be finite (m)")
        if not (np.isfinite(self.friction) and self.friction >= 0):
            raise ConfigError("ExplorationControllerConfig.friction must be >= 0")
        if not (np.isfinite(self.prior_damping) and self.prior_damping >= 0):
            raise ConfigError("ExplorationControllerConfig.prior_damping must be >= 0")

    @property
    def approach_steps(self) -> int:
        """Control periods the guarded approach may take."""
        return int(round(self.max_approach_time / self.time_step))


@dataclass(frozen=True)
class ExplorationCommand:
    """One cycle's output of :class:`ExplorationController`.

    Attributes:
        done: the exploration motion is over (no torque: stop the loop).
        torque: joint torques, N·m (None when done).
        phase: −1 guarded approach, 0 sinusoid, k ≥ 1 the k-th impact.
        z: measured deformation, m. z_ref: its reference, m.
        fed: the sample went to the learner. onset: the first in-contact sample of an episode
            (not fed: Bullet's force is partial in the crossing step).
    """

    done: bool
    torque: np.ndarray | None
    phase: int
    z: float
    z_ref: float
    fed: bool
    onset: bool


class ExplorationController:
    """Guarded approach, then the exploration motion with online learning:
    ``reset()`` / ``step(measurement, t) -> ExplorationCommand``.

    Each cycle: find the surface (the last force-free sample before ``contact_threshold``);
    feed ``(z, ż, f)`` to :attr:`learner` for every in-contact sample but the first of an
    episode (and to :attr:`with_onset` for all, for comparison); track the reference along d
    with the task-space law inside the joint-limit guard, telling the guard the force the next
    step may add: the learned model's prediction ``α̂ (z + ż Δt) + β̂ ż − f`` once the learner
    is confident, else the prior's one-step impact force while out of contact, as the force of
    a sticking contact (:func:`sticking_contact_force`).

    Args:
        robot: the robot model (contact frame = end-effector). limits: joint limits of the guard.
        config: see :class:`ExplorationControllerConfig`.

    Raises (from :meth:`step`): ConfigError when in contact at the start or no contact within
    ``max_approach_time``.
    """

    def __init__(
        self, robot: RobotModel, limits: JointLimits, config: ExplorationControllerConfig
    ) -> None:
        self.robot = robot
        self.config = config
        self.guard = JointLimitGuard(robot, limits, config.guard)
        self.law = TaskSpaceInverseDynamics(robot, config.gains, guard=self.guard)
        self.learner = RecursiveContactLearner()
        self.with_onset = RecursiveContactLearner()
        self._data = robot.create_data()
        self.reset()

    def reset(self) -> None:
        """Back to the guarded approach; learners emptied."""
        self.learner.reset()
        self.with_onset.reset()
        self.first_moment = np.zeros(2)  # Σ [z, ż] of the samples fed to `learner` (m, m/s)
        self.surface: np.ndarray | None = None
        self._last_free: np.ndarray | None = None
        self._k = 0
        self._k_start: int | None = None
        self._was_in_contact = False
        self._hold: tuple[np.ndarray, np.ndarray] | None = None
        self._t_prev: float | None = None

    def step(self, measurement: ContactMeasurement, t: float) -> ExplorationCommand:
        """One cycle at ``t`` (s, from the start of the approach)."""
        if not np.isfinite(t) or (self._t_prev is not None and t < self._t_prev):
            raise InputError(f"time must be finite and non-decreasing, got {t} s")
        self._t_prev = t
        cfg = self.config
        m = measurement
        k = self._k
        self._k += 1
        if self._hold is None:
            self._hold = (m.position[:2].copy(), m.rotation.copy())
        force, speed, p = m.force, m.speed, m.position
        in_contact = force > 0.0
        if self.surface is None:  # the guarded approach
            if not in_contact:
                self._last_free = p.copy()
            if force >= cfg.contact_threshold:
                if self._last_free is None:
                    raise ConfigError("in contact at the start: increase start_clearance")
                self.surface = self._last_free
                self._k_start = k
            elif k >= cfg.approach_steps:
                raise ConfigError(
                    f"no contact within {cfg.max_approach_time} s of guarded approach"
                )
        reference = self.surface if self.surface is not None else self._last_free
        if reference is None:  # touching from the first cycle on, below the threshold
            raise ConfigError("in contact at the start: increase start_clearance")
        z = measured_deformation(p, reference)

        ref = cfg.reference
        if self.surface is None:
            z_ref = -cfg.start_clearance + cfg.approach_speed * t
            zd_ref, zdd_ref, phase = cfg.approach_speed, 0.0, -1
            target_z = cfg.start_height - cfg.approach_speed * t
        else:
            assert self._k_start is not None  # set with surface
            i = k - self._k_start
            if i >= ref.time.size:
                return ExplorationCommand(
                    True, None, int(ref.phase[-1]), z, float("nan"), False, False
                )
            z_ref = float(ref.deformation[i])
            zd_ref = float(ref.deformation_rate[i])
            zdd_ref = float(ref.deformation_acceleration[i])
            phase = int(ref.phase[i])
            target_z = self.surface[2] - z_ref

        # learning (eq 19–20): every in-contact sample but the first of an episode
        fed = onset = False
        if self.surface is not None and in_contact:
            self.with_onset.update(z, speed, force)
            if self._was_in_contact:
                self.learner.update(z, speed, force)
                self.first_moment += (z, speed)
                fed = True
            else:
                onset = True
        self._was_in_contact = in_contact

        # tracking, with the force the next step may add handed to the guard
        dt = cfg.time_step
        est = self.learner.confident_estimate(cfg.learner_min_samples, cfg.learner_max_relative_std)
        if est is not None:
            push = predicted_force_increase(est.stiffness, est.damping, z, speed, force, dt)
        else:
            push = (
                0.0
                if in_contact
                else one_step_impact_force(cfg.prior_stiffness, cfg.prior_damping, speed, dt)
            )
        hold_xy, rotation = self._hold
        command = CartesianCommand(
            phase="explore",
            position=np.array([hold_xy[0], hold_xy[1], target_z]),
            velocity=zd_ref * DOWN,
            acceleration=zdd_ref * DOWN,
            rotation=rotation,
            pre_impact_velocity=float("nan"),
            force=force,
            target_force=0.0,
        )
        impact = None
        if push > 0.0:
            model, data, fid = self.robot.model, self._data, self.robot.contact_frame_id
            pin.computeJointJacobians(model, data, m.q)
            J = pin.getFrameJacobian(model, data, fid, _LWA)[:3]
            M = mass_matrix(model, data, m.q)
            impact = sticking_contact_force(push, J @ np.linalg.solve(M, J.T), cfg.friction)
        tau = self.law.torque(command, m.q, m.v, m.wrench, impact_force=impact)
        return ExplorationCommand(False, tau, phase, z, z_ref, fed, onset)
