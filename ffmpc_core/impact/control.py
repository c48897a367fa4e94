"""The impact control scheme (Dehio & Kheddar 2020, Sec. IV-C, Fig. 2) as a controller object.

Every cycle before contact, the controller expects the impact at the next step along the motion
direction ``d`` (unit, world frame), maps the joint limits to the contact space (eq 9–11),
solves eq 14 for the maximal safe pre-impact velocity and commands the end-effector to track it
(ramped up at the contact-space acceleration bound). When the measured pressing force reaches the
contact threshold (2 N in the paper) it switches, for good, to an admittance force controller that
regulates the force to the target (60 N in the paper).

The output is a Cartesian command for the contact frame (world frame). Mapping it to joint
torques is robot-specific and lives in :mod:`ffmpc_core.impact.task_space`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError, InputError, SolverError
from ffmpc_core.impact.deformation import (
    SoftMaterial,
    deformation_dynamics,
    measured_deformation,
    unit_direction,
)
from ffmpc_core.impact.learner import RecursiveContactLearner
from ffmpc_core.impact.limits import ContactSpaceMapper, JointLimits
from ffmpc_core.impact.planner import ImpactPlanner, PenetrationPlan, PlannerConfig
from ffmpc_core.robots import RobotModel

__all__ = [
    "APPROACH",
    "CONTACT",
    "AdmittanceForceController",
    "CartesianCommand",
    "ImpactController",
    "ImpactControllerConfig",
    "ImpactMeasurement",
    "StoppedShort",
    "stop_short_event",
]

APPROACH = "approach"
CONTACT = "contact"


@dataclass(frozen=True)
class AdmittanceForceController:
    """Admittance force control along ``d`` (the task of Bouyarmane et al. 2019, ref. [31]).

    The reference velocity (m/s) follows ``v ← γ v + (1 − γ) clip(G (f_des − f), ±v_max)``:
    admittance ``G`` (m/(N·s)), filter ``γ`` per step of ``nominal_dt`` (s), ``v_max`` (m/s).
    The position reference is the integral of ``v``. ``f`` is the measured pressing force (N).
    The reference never goes deeper than :func:`admittance_step`'s ``max_position``, the
    contact's surface + :meth:`max_depth`: z̄ less ``depth_margin`` (m; at rest at that depth
    on a 1200 N/m dice the tool sat 1.1 mm below its reference).
    """

    admittance: float = param(2e-3, "m/(N·s)", (1e-9, 1.0), "admittance G")
    max_velocity: float = param(0.1, "m/s", (1e-6, 10.0), "v_max")
    velocity_filter: float = param(0.8, "", (0.0, 1.0), "γ per nominal_dt, in [0, 1)")
    nominal_dt: float = param(1e-3, "s", (1e-6, 1.0), "step of γ")
    depth_margin: float = param(0.002, "m", (0.0, 0.5), "the depth bound is this far above z̄")

    def __post_init__(self) -> None:
        if not (self.admittance > 0 and self.max_velocity > 0 and self.nominal_dt > 0):
            raise ConfigError("admittance, max_velocity and nominal_dt must be positive")
        if not (np.isfinite(self.depth_margin) and self.depth_margin >= 0):
            raise ConfigError("depth_margin must be ≥ 0 (m)")
        if not 0.0 <= self.velocity_filter < 1.0:
            raise ConfigError("velocity_filter must be in [0, 1)")

    def max_depth(self, max_penetration: float) -> float:
        """The deepest reference below the contact's surface, m: z̄ (``max_penetration``, m)
        less ``depth_margin`` (at least half of z̄)."""
        return max(max_penetration - self.depth_margin, 0.5 * max_penetration)

    def velocity(self, previous: float, force: float, target_force: float, dt: float) -> float:
        """One update of the reference velocity (m/s) over ``dt`` s."""
        raw = float(
            np.clip(self.admittance * (target_force - force), -self.max_velocity, self.max_velocity)
        )
        gamma = self.velocity_filter ** (dt / self.nominal_dt) if dt > 0 else 1.0
        return gamma * previous + (1.0 - gamma) * raw


@dataclass(frozen=True)
class ImpactControllerConfig:
    """Parameters of the control scheme.

    Attributes:
        direction: unit motion direction, world frame (e.g. ``[0, 0, -1]`` = downwards).
        material: stiffness (N/m), damping (N·s/m) and maximal penetration z̄ (m) used for
            planning (e.g. from :class:`RecursiveContactLearner`).
        target_force: force to regulate after contact, N (paper: 60).
        contact_threshold: pressing force that declares the contact, N (paper: 2).
        planner: eq 12–14 parameters (paper: h = 20, Δt = 25 ms); its ``solver`` (daqp|osqp)
            also selects how the eq 9–11 mapping is solved.
        n_directions: eq 10 weight directions (vertices).
        max_approach_velocity: optional cap on the approach speed, m/s (inf = none).
        admittance: the post-contact force controller.
        learn_online: update the recursive learner during contact (Sec. V-B).
        replan_period: how often the approach re-maps the limits and re-solves eq 14, s. 0 (the
            default) = every cycle, as in the paper (1 kHz); a positive period reuses the last
            bound in between (for slow machines: the bound is an upper bound that changes with
            the configuration only).
    """

    direction: np.ndarray
    material: SoftMaterial
    target_force: float = 60.0
    contact_threshold: float = 2.0
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    n_directions: int = 8
    max_approach_velocity: float = np.inf
    admittance: AdmittanceForceController = field(default_factory=AdmittanceForceController)
    learn_online: bool = True
    replan_period: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "direction", unit_direction(self.direction))
        if not (np.isfinite(self.target_force) and self.target_force > 0):
            raise ConfigError("target_force must be positive (N)")
        if not (
            np.isfinite(self.contact_threshold) and 0 < self.contact_threshold < self.target_force
        ):
            raise ConfigError("contact_threshold must be in (0, target_force) (N)")
        if not self.max_approach_velocity > 0:
            raise ConfigError("max_approach_velocity must be positive (m/s)")
        if not (np.isfinite(self.replan_period) and self.replan_period >= 0):
            raise ConfigError("replan_period must be finite and ≥ 0 (s)")


@dataclass(frozen=True)
class ImpactMeasurement:
    """What the controller reads each cycle.

    Attributes:
        q: joint positions, rad. v: joint velocities, rad/s.
        force: 3-vector, N, world frame: the force the environment exerts on the robot at the
            contact frame (pressing along ``d`` gives ``force ≈ −f d``).
    """

    q: np.ndarray
    v: np.ndarray
    force: np.ndarray


@dataclass(frozen=True)
class CartesianCommand:
    """Reference for the contact frame, world frame.

    Attributes:
        phase: ``"approach"`` or ``"contact"``.
        position: m. velocity: m/s. acceleration: feed-forward, m/s². rotation: 3×3 (hold).
        pre_impact_velocity: the eq 14 bound of this cycle (m/s; NaN after contact).
        force: measured pressing force along ``d``, N. target_force: N.
        plan: the eq 14 plan of this cycle (None after contact or when the solve failed).
    """

    phase: str
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    rotation: np.ndarray
    pre_impact_velocity: float
    force: float
    target_force: float
    plan: PenetrationPlan | None = None


@dataclass(frozen=True)
class AdmittanceReference:
    """The post-contact admittance task's state along the push direction d: the reference
    position (m, from the task's origin) and velocity (m/s)."""

    position: float
    velocity: float


@dataclass(frozen=True)
class StoppedShort:
    """The regulation reached the penetration bound below its target force (the target is
    unreachable for this material within z̄): it stopped there and holds.

    Attributes:
        time: s, when the reference first stopped at the bound. force: N, measured then.
        target_force: N. depth: the bound below the contact's surface, m.
        max_penetration: z̄, m.
    """

    time: float
    force: float
    target_force: float
    depth: float
    max_penetration: float

    def message(self) -> str:
        """One line with the numbers."""
        return (
            f"target {self.target_force:g} N not reached: the regulation stopped "
            f"{1e3 * self.depth:.1f} mm deep (z̄ = {1e3 * self.max_penetration:.1f} mm) with "
            f"{self.force:.1f} N at t = {self.time:.3f} s and holds there"
        )


def stop_short_event(
    reference: AdmittanceReference,
    max_position: float,
    force: float,
    target_force: float,
    admittance: AdmittanceForceController,
    max_penetration: float,
    t: float,
) -> StoppedShort | None:
    """A :class:`StoppedShort` when the admittance ``reference`` (after its step) stands at
    ``max_position`` (m along d) while the measured ``force`` (N) is below ``target_force``
    (N), else None; the admittance's depth below z̄ (``max_penetration``, m) and ``t`` (s)
    for the report."""
    if reference.position >= max_position and force < target_force:
        return StoppedShort(
            float(t),
            float(force),
            float(target_force),
            admittance.max_depth(max_penetration),
            float(max_penetration),
        )
    return None


def admittance_step(
    admittance: AdmittanceForceController,
    reference: AdmittanceReference,
    origin: np.ndarray,
    rotation: np.ndarray,
    direction: np.ndarray,
    force: float,
    target_force: float,
    dt: float,
    phase: str = CONTACT,
    max_position: float = float("inf"),
) -> tuple[CartesianCommand, AdmittanceReference]:
    """One cycle of the post-contact admittance task (Sec. VI), the one function every impact
    controller uses after contact: the reference velocity along d (m/s) follows
    :class:`AdmittanceForceController` towards ``target_force`` (N) from the measured ``force``
    (N), the reference position along d is its integral over ``dt`` (s) from ``origin`` (m,
    world), the lateral position and the orientation ``rotation`` are held.

    ``max_position`` (m along d from ``origin``): the reference never goes deeper — the
    material's bound z̄ below the contact's surface. A target the material cannot hold within
    it is stopped short of: the reference stops there and stays at rest (its velocity is not
    allowed to point deeper), the force is what the material gives at that depth.

    Returns the Cartesian command and the new reference."""
    velocity = admittance.velocity(reference.velocity, force, target_force, dt)
    position = reference.position + velocity * dt
    if position >= max_position:
        position, velocity = max_position, min(velocity, 0.0)
    command = CartesianCommand(
        phase=phase,
        position=origin + position * direction,
        velocity=velocity * direction,
        acceleration=np.zeros(3),
        rotation=rotation.copy(),
        pre_impact_velocity=float("nan"),
        force=force,
        target_force=target_force,
    )
    return command, AdmittanceReference(position, velocity)


class ImpactController:
    """Fig. 2 as ``reset()`` / ``step(measurement, t) -> CartesianCommand``; reads no clock.

    Args:
        robot: robot model (its ``contact`` frame is the end-effector).
        limits: eq 1 joint limits.
        config: see :class:`ImpactControllerConfig`.
        learner: the eq 19–21 learner this controller feeds and reads (default: its own
            :class:`RecursiveContactLearner`; the impact graph's planner node gives one that
            holds the contact learner node's estimates).
    """

    def __init__(
        self,
        robot: RobotModel,
        limits: JointLimits,
        config: ImpactControllerConfig,
        *,
        learner: RecursiveContactLearner | None = None,
    ) -> None:
        self.robot = robot
        self.limits = limits
        self.config = config
        self.mapper = ContactSpaceMapper(
            robot, limits, config.direction, config.n_directions, solver=config.planner.solver
        )
        self.planner = ImpactPlanner(config.planner)
        self.learner = learner if learner is not None else RecursiveContactLearner()
        self._data = robot.create_data()
        self.reset()

    def reset(self) -> None:
        """Back to the approach phase; the next step takes the current pose as the hold pose."""
        self.phase = APPROACH
        self.material = self.config.material
        self._t_prev: float | None = None
        self._v_ref = 0.0
        self._hold_position: np.ndarray | None = None
        self._hold_rotation: np.ndarray | None = None
        self._x_ref = 0.0
        self._contact_position: np.ndarray | None = None
        self.contact_time: float | None = None
        self.contact_velocity: float | None = None
        self.solver_failures = 0
        self._last_plan: tuple[float, float, float, float, PenetrationPlan | None] | None = None
        self._free_along = 0.0  # along d at the last force-free sample, m
        # the admittance reference's deepest point (m along d from the hold point): the
        # surface of the contact + z̄ (inf before contact)
        self._regulation_limit = float("inf")
        #: the regulation's first stop at the penetration bound short of its target
        self.stopped_short: StoppedShort | None = None
        self.learner.reset()

    def _frame_state(
        self, q: np.ndarray, v: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        model, data, fid = self.robot.model, self._data, self.robot.contact_frame_id
        pin.forwardKinematics(model, data, q, v)
        pin.updateFramePlacements(model, data)
        oMf = data.oMf[fid]
        vel = pin.getFrameVelocity(model, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        return oMf.translation.copy(), oMf.rotation.copy(), vel.linear.copy()

    def _validate(self, m: ImpactMeasurement, t: float) -> tuple[np.ndarray, ...]:
        n = self.robot.nv
        q = np.asarray(m.q, dtype=float)
        v = np.asarray(m.v, dtype=float)
        f = np.asarray(m.force, dtype=float)
        if q.shape != (n,) or v.shape != (n,) or f.shape != (3,):
            raise InputError(f"measurement needs q, v of size {n} and a 3-vector force")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v)) and np.all(np.isfinite(f))):
            raise InputError("measurement contains NaN/Inf")
        if not np.isfinite(t) or (self._t_prev is not None and t < self._t_prev):
            raise InputError(f"time must be finite and non-decreasing, got {t}")
        return q, v, f

    def _cycle_state(self, measurement: ImpactMeasurement, t: float) -> tuple:
        """Validate a measurement at t (s) and advance the clock: (q rad, v rad/s, Δt s, p m,
        R, ṗ m/s of the contact frame in world, position along d from the hold point m, speed
        along d m/s, pressing force −dᵀf N)."""
        q, v, f_world = self._validate(measurement, t)
        d = self.config.direction
        dt = 0.0 if self._t_prev is None else t - self._t_prev
        self._t_prev = t
        p, R, pdot = self._frame_state(q, v)
        if self._hold_position is None:
            self._hold_position, self._hold_rotation = p.copy(), R.copy()
        along = float(d @ (p - self._hold_position))
        return q, v, dt, p, R, pdot, along, float(d @ pdot), float(-d @ f_world)

    def _hold_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The hold pose (p m, R; world) latched by the first :meth:`_cycle_state`."""
        assert self._hold_position is not None and self._hold_rotation is not None
        return self._hold_position, self._hold_rotation

    def step(self, measurement: ImpactMeasurement, t: float) -> CartesianCommand:
        """One control cycle at time ``t`` (s)."""
        q, v, dt, p, R, pdot, along, speed, force = self._cycle_state(measurement, t)
        cfg = self.config

        if self.phase == APPROACH and force <= 0.0:
            self._free_along = along
        if self.phase == APPROACH and force >= cfg.contact_threshold:
            self.phase = CONTACT
            self.contact_time = t
            self.contact_velocity = speed
            self._contact_position = p.copy()
            self._regulation_limit = self._free_along + cfg.admittance.max_depth(
                cfg.material.max_penetration
            )
            self._x_ref = along
            self._v_ref = speed
        if self.phase == CONTACT:
            return self._contact_step(p, pdot, along, speed, force, dt)
        return self._approach_step(q, v, along, speed, force, dt, t)

    def _approach_step(
        self,
        q: np.ndarray,
        v: np.ndarray,
        along: float,
        speed: float,
        force: float,
        dt: float,
        t: float,
    ) -> CartesianCommand:
        cfg = self.config
        last = self._last_plan
        if last is not None and t - last[0] < cfg.replan_period - 1e-9:
            _, bound, acc_lo, acc_hi, plan = last
            return self._approach_command(along, force, dt, bound, acc_lo, acc_hi, plan)
        plan = None
        try:
            bounds = self.mapper.update(q, v)
            dyn = deformation_dynamics(
                self.material.stiffness,
                self.material.damping,
                bounds.effective_mass,
                cfg.planner.dt,
            )
            plan = self.planner.max_pre_impact_velocity(dyn, bounds, self.material)
            bound = max(plan.pre_impact_velocity, 0.0)
            acc_lo, acc_hi = bounds.acceleration_range(0.0)
        except SolverError:
            # No certified bound this cycle: command rest (the safe side) and count it.
            self.solver_failures += 1
            bound, acc_lo, acc_hi = 0.0, 0.0, 0.0
        self._last_plan = (t, bound, acc_lo, acc_hi, plan)
        return self._approach_command(along, force, dt, bound, acc_lo, acc_hi, plan)

    def _approach_command(
        self,
        along: float,
        force: float,
        dt: float,
        bound: float,
        acc_lo: float,
        acc_hi: float,
        plan: PenetrationPlan | None,
    ) -> CartesianCommand:
        """Track the bound ``bound`` (m/s), ramped at the contact-space acceleration bound."""
        cfg = self.config
        target = min(bound, cfg.max_approach_velocity)
        previous = self._v_ref
        ramped = previous + max(acc_hi, 0.0) * dt
        self._v_ref = max(min(target, ramped), 0.0)
        acc_ff = 0.0 if dt <= 0 else (self._v_ref - previous) / dt
        acc_ff = float(np.clip(acc_ff, min(acc_lo, 0.0), max(acc_hi, 0.0)))
        d = cfg.direction
        hold_position, hold_rotation = self._hold_pose()
        return CartesianCommand(
            phase=APPROACH,
            position=hold_position + along * d,
            velocity=self._v_ref * d,
            acceleration=acc_ff * d,
            rotation=hold_rotation.copy(),
            pre_impact_velocity=bound,
            force=force,
            target_force=cfg.target_force,
            plan=plan,
        )

    def _contact_step(
        self,
        p: np.ndarray,
        pdot: np.ndarray,
        along: float,
        speed: float,
        force: float,
        dt: float,
    ) -> CartesianCommand:
        cfg = self.config
        d = cfg.direction
        if cfg.learn_online:
            assert self._contact_position is not None  # latched when CONTACT began
            z = measured_deformation(p, self._contact_position, d)
            self.learner.update(z, speed, force)
        return self._admittance_command(force, cfg.target_force, dt, CONTACT)

    def _admittance_command(
        self, force: float, target_force: float, dt: float, phase: str
    ) -> CartesianCommand:
        """:func:`admittance_step` from the held pose, on this controller's reference, never
        deeper than the regulation limit (records :attr:`stopped_short`)."""
        hold_position, hold_rotation = self._hold_pose()
        command, reference = admittance_step(
            self.config.admittance,
            AdmittanceReference(self._x_ref, self._v_ref),
            hold_position,
            hold_rotation,
            self.config.direction,
            force,
            target_force,
            dt,
            phase,
            self._regulation_limit,
        )
        self._x_ref, self._v_ref = reference.position, reference.velocity
        if self.stopped_short is None and self._t_prev is not None:
            self.stopped_short = stop_short_event(
                reference,
                self._regulation_limit,
                force,
                target_force,
                self.config.admittance,
                self.config.material.max_penetration,
                self._t_prev,
            )
        return command
