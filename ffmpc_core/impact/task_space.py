"""Cartesian command → joint torques: a task-space inverse-dynamics law (robot-specific part).

For the contact frame (pinocchio ``LOCAL_WORLD_ALIGNED``; linear m, m/s, angular rad, rad/s):

1. desired task acceleration (6,)::

       ẍ* = [a_ff + K_d (v_ref − v) + K_p (p_ref − p);  −D_ω ω + K_ω log3(R_ref Rᵀ)]

2. joint accelerations: the primary task plus, as the paper's secondary task, the smallest joint
   acceleration (Moore–Penrose solution) with a small null-space joint damping against
   self-motion drift::

       q̈ = J⁺ (ẍ* − J̇ q̇) + (I − J⁺ J)(−k_null q̇)

3. inverse dynamics with the measured contact force (the force the environment exerts on the
   robot, world frame, N) compensated::

       τ = M q̈ + h − J_linᵀ F_ext,   saturated to the torque limits (N·m).

With a :class:`JointLimitGuard`, step 2 becomes a QP that keeps q̈ within the joint limits (eq 1b–1e
over one control step, and robust to an impact at the next step): the weighted least-squares
version of the same law, ``min ‖W^½ (J q̈ + J̇ q̇ − ẍ*)‖² + ε ‖q̈ − q̈_null‖²``, whose solution equals
the unconstrained law above (for ε → 0) whenever no limit is active. Without the guard a large
task-acceleration demand (an admittance reference braking the end-effector at impact) is passed on
to the joints unbounded.

Gains: ``K_p`` 1/s², ``K_d`` 1/s, ``K_ω`` 1/s², ``D_ω`` 1/s, ``k_null`` 1/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import osqp
import pinocchio as pin
from scipy.optimize import lsq_linear

from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.control import CartesianCommand
from ffmpc_core.impact.limits import JointLimits, _SparsePattern
from ffmpc_core.robots import RobotModel, mass_matrix

__all__ = [
    "AccelerationBox",
    "external_joint_torque",
    "JointLimitGuard",
    "JointLimitGuardConfig",
    "TaskSpaceGains",
    "TaskSpaceInverseDynamics",
]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


def external_joint_torque(jacobian: np.ndarray, external: np.ndarray) -> np.ndarray:
    """Joint torque (N·m) of an external force or wrench on the contact frame: ``J_linᵀ f`` for a
    force ``f`` (3,), ``Jᵀ [f; m]`` for a wrench (6,), both at the contact frame origin in world
    axes (pinocchio ``LOCAL_WORLD_ALIGNED``; N, N·m). The moment matters when the contact point
    is off the frame origin (a tilted spherical tool): 0.04 N·m on the Panda's wrist is ~8 % of
    its acceleration limit."""
    w = np.asarray(external, dtype=float).reshape(-1)
    if w.shape not in ((3,), (6,)) or not np.all(np.isfinite(w)):
        raise InputError(f"external force must be 3 or a wrench 6 finite numbers, got {w.shape}")
    return jacobian[: w.size].T @ w


@dataclass(frozen=True)
class TaskSpaceGains:
    """Gains of the law (see the module docstring for units)."""

    position: float = param(400.0, "1/s²", (0.0, 1e6), "task-space PD: position gain")
    velocity: float = param(40.0, "1/s", (0.0, 1e6), "task-space PD: velocity gain")
    orientation: float = param(400.0, "1/s²", (0.0, 1e6), "task-space PD: orientation gain")
    angular_velocity: float = param(40.0, "1/s", (0.0, 1e6), "task-space PD: angular velocity gain")
    null_damping: float = param(10.0, "1/s", (0.0, 1e6), "null-space joint damping")
    pinv_damping: float = param(1e-6, "", (0.0, 1.0), "damping of the task Jacobian pseudo-inverse")

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"TaskSpaceGains.{name} must be finite and ≥ 0")


@dataclass(frozen=True)
class JointLimitGuardConfig:
    """Parameters of :class:`JointLimitGuard`.

    Attributes:
        dt: control period, s (the step over which the velocity limit must still hold).
        margin: fraction (0, 1] of the acceleration and velocity limits the QP may use. The rest
            absorbs what the law cannot know when it sends the torque: the change of the contact
            force during the step (≈ α ż Δt) that the force compensation sees one step late.
        task_weights: weights of the 6 task rows (linear x, y, z; angular x, y, z, world axes) in
            the least-squares objective; they only matter when a limit is active.
        regularization: ε of the secondary objective ε‖q̈ − q̈_null‖² (s⁴·…); small, > 0.
        hold_weight: weight (kg·m²/m² …, relative to the inertia metric) of the held directions
            of :meth:`JointLimitGuard.admissible_torque`.
        eps: OSQP tolerance (the solution is then polished).
    """

    dt: float = 1e-3
    margin: float = 0.9
    task_weights: tuple[float, ...] = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
    regularization: float = 1e-6
    eps: float = 1e-7
    hold_weight: float = 1e3

    def __post_init__(self) -> None:
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ConfigError("JointLimitGuardConfig.dt must be positive (s)")
        if not 0.0 < self.margin <= 1.0:
            raise ConfigError("JointLimitGuardConfig.margin must be in (0, 1]")
        w = np.asarray(self.task_weights, dtype=float)
        if w.shape != (6,) or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise ConfigError("task_weights must be 6 positive numbers")
        if not (self.regularization > 0 and self.eps > 0 and self.hold_weight > 0):
            raise ConfigError("regularization, eps and hold_weight must be positive")


@dataclass(frozen=True)
class AccelerationBox:
    """Admissible joint accelerations for the next control step, rad/s² (see
    :meth:`JointLimitGuard.acceleration_box`).

    Attributes:
        lower, upper: the box.
        impact_robust: per joint, whether the box also keeps ``q̈ + Δq̈_impact`` within the limits
            (False where that was impossible together with the other bounds).
    """

    lower: np.ndarray
    upper: np.ndarray
    impact_robust: np.ndarray


class JointLimitGuard:
    """Keeps the commanded joint accelerations and torques within eq 1b–1e, as the paper's QP
    controller does (Sec. VI: "a QP-control framework"): every control step one small QP::

        min_q̈  ½ q̈ᵀ H q̈ + gᵀ q̈
        s.t.   lower ≤ q̈ ≤ upper                                   (the acceleration box)
               τ̲ ≤ M q̈ + h − J_linᵀ F_ext ≤ τ̄                     (eq 1e, N·m)

    solved by OSQP (set up once, updated in place, warm-started, polished). The box combines

    * eq 1d: ``|q̈| ≤ margin · q̈_max``;
    * eq 1c over one step: ``|q̇ + q̈ Δt| ≤ margin · q̇_max``;
    * eq 1b as in :func:`~ffmpc_core.impact.limits.position_aware_velocity_limits` (the joint can
      still brake before its position limit at ``margin · q̈_max``), over one step;
    * the impact (optional): the torque of this step is sent before the contact force is measured.
      If the contact starts during the step, the force ``F_imp`` (world frame, on the robot) acts
      uncompensated and the joints accelerate by ``q̈ + Δq̈`` with ``Δq̈ = M⁻¹ J_linᵀ F_imp``. The
      paper's premise is that the impact happens at the next step, so before contact we also
      require ``|q̈ + Δq̈| ≤ margin · q̈_max`` (where this contradicts the other bounds for a joint,
      that joint keeps the plain box and :attr:`stats` counts it).

    If OSQP fails, the unconstrained optimum clipped to the box is used (counted in ``stats``).
    """

    def __init__(
        self,
        robot: RobotModel,
        limits: JointLimits,
        config: JointLimitGuardConfig | None = None,
    ) -> None:
        if limits.velocity.size != robot.nv:
            raise ConfigError(f"limits are for {limits.velocity.size} joints, robot has {robot.nv}")
        self.robot = robot
        self.limits = limits
        self.config = config if config is not None else JointLimitGuardConfig()
        n = robot.nv
        self._n = n
        self._data = robot.create_data()
        self._P = _SparsePattern(np.triu(np.ones((n, n), dtype=bool)))
        self._A = _SparsePattern(np.vstack([np.eye(n), np.ones((n, n))]).astype(bool))
        self._A_dense = np.zeros((2 * n, n))
        self._A_dense[:n] = np.eye(n)
        self._solver = osqp.OSQP()
        self._solver.setup(
            self._P.matrix,
            np.zeros(n),
            self._A.matrix,
            -np.ones(2 * n),
            np.ones(2 * n),
            verbose=False,
            polishing=True,
            polish_refine_iter=5,
            eps_abs=self.config.eps,
            eps_rel=self.config.eps,
            max_iter=4000,
            warm_starting=True,
        )
        self.stats = {
            "solves": 0,
            "active": 0,
            "torque_qp": 0,
            "fallbacks": 0,
            "impact_not_robust": 0,
        }

    def kinematics(
        self, q: np.ndarray, v: np.ndarray
    ) -> tuple[pin.SE3, np.ndarray, pin.Motion, pin.Motion, np.ndarray, np.ndarray]:
        """Contact frame placement, Jacobian (6×n, LOCAL_WORLD_ALIGNED), velocity, classical
        acceleration drift J̇q̇, M (kg·m²) and h (N·m) at (q rad, v rad/s)."""
        model, data, fid = self.robot.model, self._data, self.robot.contact_frame_id
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if q.shape != (model.nq,) or v.shape != (model.nv,):
            raise InputError("q and v have the wrong size")
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise InputError("q and v must be finite")
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        J = pin.getFrameJacobian(model, data, fid, _LWA)
        vel = pin.getFrameVelocity(model, data, fid, _LWA)
        drift = pin.getFrameClassicalAcceleration(model, data, fid, _LWA)
        M = mass_matrix(model, data, q)
        h = pin.nonLinearEffects(model, data, q, v).copy()
        return data.oMf[fid], J, vel, drift, M, h

    def acceleration_box(
        self,
        q: np.ndarray,
        v: np.ndarray,
        impact_acceleration: np.ndarray | None = None,
    ) -> AccelerationBox:
        """The admissible q̈ (rad/s²) of the class docstring; ``impact_acceleration`` is Δq̈."""
        cfg, lim = self.config, self.limits
        a_max = cfg.margin * lim.acceleration
        v_max = cfg.margin * lim.velocity
        # eq 1b: the speed from which the joint still stops before its position limit.
        v_up = np.minimum(v_max, np.sqrt(2.0 * a_max * np.maximum(lim.position_upper - q, 0.0)))
        v_lo = -np.minimum(v_max, np.sqrt(2.0 * a_max * np.maximum(q - lim.position_lower, 0.0)))
        lower = np.clip((v_lo - v) / cfg.dt, -a_max, a_max)
        upper = np.clip((v_up - v) / cfg.dt, -a_max, a_max)
        robust = np.zeros(self._n, dtype=bool)
        if impact_acceleration is not None:
            dqdd = np.asarray(impact_acceleration, dtype=float)
            lo2 = np.maximum(lower, -a_max - dqdd)
            hi2 = np.minimum(upper, a_max - dqdd)
            robust = lo2 <= hi2
            lower = np.where(robust, lo2, lower)
            upper = np.where(robust, hi2, upper)
            self.stats["impact_not_robust"] += int(np.count_nonzero(~robust))
        return AccelerationBox(lower=lower, upper=upper, impact_robust=robust)

    def solve(
        self,
        H: np.ndarray,
        g: np.ndarray,
        box: AccelerationBox,
        M: np.ndarray,
        torque_offset: np.ndarray,
    ) -> np.ndarray:
        """The QP of the class docstring: q̈ (rad/s²). ``torque_offset`` = h − J_linᵀ F_ext (N·m),
        so that τ = M q̈ + torque_offset.

        Solved as a bounded least-squares problem ``min ½‖R q̈ + R⁻ᵀ g‖²`` (``RᵀR = H``) over the
        acceleration box by BVLS (scipy, an exact active-set method); only if that solution
        breaks a torque limit is the full QP solved by OSQP (polished). Should OSQP fail as well,
        the BVLS solution is returned and the torque saturates (``stats["fallbacks"]``).
        """
        n = self._n
        tau_max = self.robot.torque_limit
        tau_lo, tau_hi = -tau_max - torque_offset, tau_max - torque_offset
        self.stats["solves"] += 1
        free = np.linalg.solve(H, -g)
        in_box = np.all(free >= box.lower) and np.all(free <= box.upper)
        tau_free = M @ free
        if in_box and np.all(tau_free >= tau_lo) and np.all(tau_free <= tau_hi):
            return free  # no limit active: the plain law
        self.stats["active"] += 1
        R = np.linalg.cholesky(H).T  # H = Rᵀ R
        target = np.linalg.solve(R.T, -g)
        # BVLS needs lower < upper: a joint pinned at one value gets a 1e-9 rad/s² wide box.
        upper = np.maximum(box.upper, box.lower + 1e-9)
        res = lsq_linear(R, target, bounds=(box.lower, upper), method="bvls")
        qdd = np.clip(res.x, box.lower, box.upper)
        tau = M @ qdd
        if np.all(tau >= tau_lo - 1e-9) and np.all(tau <= tau_hi + 1e-9):
            return qdd
        self.stats["torque_qp"] += 1
        self._A_dense[n:] = M
        self._solver.update(
            Px=self._P.values(np.triu(H)),
            q=g,
            Ax=self._A.values(self._A_dense),
            l=np.concatenate([box.lower, tau_lo]),
            u=np.concatenate([box.upper, tau_hi]),
        )
        self._solver.warm_start(x=qdd)
        out = self._solver.solve(raise_error=False)
        # Polish status 1: the active set was solved exactly; 2: no active constraint was
        # detected at the ADMM solution (accurate to eps). Anything else: fall back.
        if out.info.status_val != osqp.SolverStatus.OSQP_SOLVED or out.info.status_polish not in (
            1,
            2,
        ):
            self.stats["fallbacks"] += 1
            return qdd
        return np.clip(out.x, box.lower, box.upper)  # remove the last 1e-9 of solver tolerance

    def admissible_torque(
        self,
        torque: np.ndarray,
        q: np.ndarray,
        v: np.ndarray,
        external_force: np.ndarray | None = None,
        impact_force: np.ndarray | None = None,
        held_directions: np.ndarray | None = None,
    ) -> np.ndarray:
        """The torque (N·m) closest to ``torque`` whose joint accelerations are admissible.

        The desired acceleration is ``q̈_d = M⁻¹ (τ − h + Jᵀ F_ext)`` (``F_ext``: the measured
        force (3,) or wrench (6,) on the robot, see :func:`external_joint_torque`); the result
        minimises ``‖q̈ − q̈_d‖²_M`` (= ``(τ' − τ)ᵀ M⁻¹ (τ' − τ)``) over the admissible set.
        Used to run any torque controller (e.g. the force-feedback MPC) inside the limits.

        ``held_directions`` (k×3 unit vectors, world frame): directions in which the contact
        point cannot move (a sticking frictional contact). The objective then also drives the
        contact point's acceleration along them to zero (weight ``config.hold_weight``): a
        command that asks for such an acceleration is not realised anyway (the friction force
        changes instead, one step before the force compensation knows it) and its joint
        accelerations would not be the ones this guard admitted.
        """
        _, J, _, drift, M, h = self.kinematics(q, v)
        offset = h.copy()
        if external_force is not None:
            offset -= external_joint_torque(J, external_force)
        tau = np.asarray(torque, dtype=float)
        qdd_des = np.linalg.solve(M, tau - offset)
        impact = None
        if impact_force is not None:
            impact = np.linalg.solve(M, J[:3].T @ np.asarray(impact_force, dtype=float))
        box = self.acceleration_box(np.asarray(q, float), np.asarray(v, float), impact)
        H = M.copy()
        g = -M @ qdd_des
        if held_directions is not None:
            dirs = np.atleast_2d(np.asarray(held_directions, dtype=float))
            if dirs.shape[1] != 3 or not np.all(np.isfinite(dirs)):
                raise InputError("held_directions must be k×3 finite unit vectors")
            rows = dirs @ J[:3]
            w = self.config.hold_weight
            H += w * rows.T @ rows
            g += w * rows.T @ (dirs @ drift.linear)
        qdd = self.solve(H, g, box, M, offset)
        return self.robot.clip_torque(M @ qdd + offset)


class TaskSpaceInverseDynamics:
    """The law of the module docstring, with preallocated pinocchio data.

    Args:
        robot: the robot model (contact frame = end-effector).
        gains: PD gains.
        guard: optional joint-limit QP (see the module docstring); None = the plain law.
    """

    def __init__(
        self,
        robot: RobotModel,
        gains: TaskSpaceGains | None = None,
        guard: JointLimitGuard | None = None,
    ) -> None:
        self.robot = robot
        self.gains = gains if gains is not None else TaskSpaceGains()
        self.guard = guard
        self._data = robot.create_data()
        if guard is not None:
            self._W = np.diag(np.asarray(guard.config.task_weights, dtype=float))

    def torque(
        self,
        command: CartesianCommand,
        q: np.ndarray,
        v: np.ndarray,
        external_force: np.ndarray | None = None,
        impact_force: np.ndarray | None = None,
    ) -> np.ndarray:
        """Joint torques (N·m) realising ``command`` at (q rad, v rad/s).

        ``external_force``: the measured force (3,) or wrench ``[f; m]`` (6,) the environment
        exerts on the robot at the contact frame origin (world axes, N and N·m), compensated.
        ``impact_force``: with a guard, the force (world frame, N, on the robot) that an impact
        during the next step would add uncompensated; the joint accelerations are kept
        admissible with and without it. Ignored without a guard.
        """
        if self.guard is not None:
            return self._guarded_torque(command, q, v, external_force, impact_force)
        model, data, fid = self.robot.model, self._data, self.robot.contact_frame_id
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if q.shape != (model.nq,) or v.shape != (model.nv,):
            raise InputError("q and v have the wrong size")
        g = self.gains
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        oMf = data.oMf[fid]
        J = pin.getFrameJacobian(model, data, fid, _LWA)
        vel = pin.getFrameVelocity(model, data, fid, _LWA)
        drift = pin.getFrameClassicalAcceleration(model, data, fid, _LWA)
        xdd = self._task_acceleration(command, oMf, vel, drift)
        JJt = J @ J.T + g.pinv_damping * np.eye(6)
        Jpinv = J.T @ np.linalg.inv(JJt)
        qdd = Jpinv @ xdd + (np.eye(model.nv) - Jpinv @ J) @ (-g.null_damping * v)
        M = mass_matrix(model, data, q)
        tau = M @ qdd + pin.nonLinearEffects(model, data, q, v)
        if external_force is not None:
            tau -= external_joint_torque(J, external_force)
        return self.robot.clip_torque(tau)

    def _task_acceleration(
        self, command: CartesianCommand, oMf: pin.SE3, vel: pin.Motion, drift: pin.Motion
    ) -> np.ndarray:
        """Step 1 of the module docstring minus the drift: ``ẍ* − J̇ q̇`` (6,), m/s², rad/s²."""
        g = self.gains
        lin = (
            command.acceleration
            + g.velocity * (command.velocity - vel.linear)
            + g.position * (command.position - oMf.translation)
        )
        ang = g.orientation * pin.log3(command.rotation @ oMf.rotation.T) - g.angular_velocity * (
            vel.angular
        )
        return np.concatenate([lin, ang]) - np.concatenate([drift.linear, drift.angular])

    def _guarded_torque(
        self,
        command: CartesianCommand,
        q: np.ndarray,
        v: np.ndarray,
        external_force: np.ndarray | None,
        impact_force: np.ndarray | None,
    ) -> np.ndarray:
        guard = self.guard
        assert guard is not None  # called only when there is a guard (torque())
        oMf, J, vel, drift, M, h = guard.kinematics(q, v)
        v = np.asarray(v, dtype=float)
        xdd = self._task_acceleration(command, oMf, vel, drift)
        eps = guard.config.regularization
        qdd_null = -self.gains.null_damping * v
        JtW = J.T @ self._W
        H = JtW @ J + eps * np.eye(self.robot.nv)
        grad = -JtW @ xdd - eps * qdd_null
        offset = h
        if external_force is not None:
            offset = h - external_joint_torque(J, external_force)
        impact = None
        if impact_force is not None:
            impact = np.linalg.solve(M, J[:3].T @ np.asarray(impact_force, dtype=float))
        box = guard.acceleration_box(np.asarray(q, dtype=float), v, impact)
        qdd = guard.solve(H, grad, box, M, offset)
        return self.robot.clip_torque(M @ qdd + offset)
