"""Force-feedback OCP model: visco-elastic contact in the state (paper section V, eq 16–24).

State ``x = (q, v, λ)`` (rad, rad/s, N), control ``u = τ`` (N·m). The continuous dynamics (eq 20)

    q̈ = M(q)⁻¹ (τ − h(q, v) + Jᵀλ)          (rigid-body dynamics with the contact force applied)
    λ̇ = −K ṗ − B p̈,   p̈ = J q̈ + J̇ v         (eq 18: time derivative of eq 16, fixed anchor)

are integrated with the semi-implicit Euler scheme of eq 24.

Frames and force convention (see also :mod:`ffmpc_core.config`): λ is the force the environment
exerts on the robot at the origin of the robot's ``contact`` frame, in N.

* ``LOCAL_WORLD_ALIGNED`` (the paper's setting): axes of the world frame, origin at the contact
  point. The force is fixed in the world frame; ṗ and p̈ are the velocity and classical
  acceleration of the contact point in world axes, so eq 18 is the exact time derivative of eq 16.
* ``LOCAL``: the contact frame's own (moving) axes. The force is fixed in the contact frame; ṗ and
  p̈ are the contact point's velocity and classical acceleration expressed in the current contact
  axes (``Rᵀ ṗ_world``, ``Rᵀ p̈_world``), as in crocoddyl's LOCAL contacts. Eq 18 then omits the
  terms due to the rotation of the axes (it is exact when the frame does not rotate).

With ``dimension == 1``, λ is the single component along ``normal_axis`` of that frame, and J the
matching row of the contact point's linear Jacobian in that frame; with ``dimension == 3`` all
three components.

Beyond eq 25 (the authors' polishing configurations, shared with the classical and
torque-feedback formulations so that the three have the same ℓ0 of eq 26): the orientation cost
``c·½·‖log(R̄ᵀR(q))‖²`` (R̄ = the contact frame's orientation at the construction-time q̄,
crocoddyl's ``ResidualModelFrameRotation``) and the angular part of the 6-D end-effector velocity
cost ``c·½·‖ω‖²`` (ω = the contact frame's angular velocity in its own axes, LOCAL, the angular
rows of crocoddyl's ``ResidualModelFrameVelocity``), in running and terminal nodes.

Costs (crocoddyl convention, see :mod:`ffmpc_core.config`): each term costs ``c·½·Σ Q_i r_i²``;
running terms are multiplied by Δt, the terminal node keeps the state terms unscaled. The
residuals are stacked in a fixed layout (:data:`RESIDUAL_TERMS`); ``data.r`` holds the weighted
residual ``√(c·Q·Δt)·r`` so that ``cost = ½‖data.r‖²`` and the Gauss-Newton Hessians are
``RxᵀRx``.
"""

from __future__ import annotations

import math

import crocoddyl
import numpy as np
import numpy.typing as npt
import pinocchio as pin

from ffmpc_core.config import ContactConfig, CostWeights, NodeReference
from ffmpc_core.constraints import ConstraintRows, OcpBounds
from ffmpc_core.errors import ConfigError, FfmpcError, InputError, ModelError
from ffmpc_core.robots import RobotModel

LOCAL_WORLD_ALIGNED = "LOCAL_WORLD_ALIGNED"
LOCAL = "LOCAL"

#: Residual blocks of the force-feedback cost, in the order they are stacked in ``data.r``.
#: posture (eq 25.1), joint velocity (25.2), torque (25.3), end-effector position (25.4),
#: end-effector velocity (25.5), force (25.6/21), force rate (29), and the joint-limit barrier
#: on (q, v) (not in the paper; 2·nv rows: the excess x − clip(x, x_lb, x_ub), rad and rad/s),
#: the orientation error log3(R̄ᵀR) (3 rows, rad) and the contact frame's LOCAL angular velocity
#: (3 rows, rad/s) (the authors' ``frameRotation`` and angular ``frameVelocity`` costs).
RESIDUAL_TERMS = (
    "posture",
    "joint_velocity",
    "torque",
    "ee_position",
    "ee_velocity",
    "force",
    "force_rate",
    "state_limit",
    "ee_rotation",
    "ee_angular_velocity",
)
#: Terms of a running node only (zero weight in a terminal node or a call without u).
RUNNING_ONLY_TERMS = ("torque", "force_rate")


def _as_finite_vector(
    value: npt.ArrayLike, n: int, name: str, error: type[FfmpcError] = InputError
) -> np.ndarray:
    """``value`` as a float vector of size ``n`` (a scalar broadcasts); raises on NaN/Inf/size."""
    arr = np.asarray(value, dtype=float)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise error(f"{name} must have {n} entries, got shape {arr.shape}")
    if not np.isfinite(arr).all():
        raise error(f"{name} must be finite, got {arr}")
    return arr


def _non_negative_vector(value: npt.ArrayLike, n: int, name: str) -> np.ndarray:
    arr = _as_finite_vector(value, n, name, ConfigError)
    if np.any(arr < 0.0):
        raise ConfigError(f"{name} must be non-negative, got {arr}")
    return arr


def _skew_into(out: np.ndarray, a: np.ndarray) -> np.ndarray:
    """Write the cross-product matrix [a]× (so that [a]× b = a × b) into ``out`` (3×3)."""
    out[0, 1] = -a[2]
    out[0, 2] = a[1]
    out[1, 0] = a[2]
    out[1, 2] = -a[0]
    out[2, 0] = -a[1]
    out[2, 1] = a[0]
    return out


def visco_elastic_force(
    deflection: npt.ArrayLike,
    velocity: npt.ArrayLike,
    stiffness: npt.ArrayLike,
    damping: npt.ArrayLike,
) -> np.ndarray:
    """Eq 16: the visco-elastic contact force λ = −K Δp − B ṗ, in N.

    Args:
        deflection: Δp = p − p_c, the contact point's position minus the anchor point, m.
        velocity: ṗ, the contact point's velocity, m/s.
        stiffness: K, N/m, scalar or one value per axis (diagonal K).
        damping: B, N·s/m, scalar or one value per axis (diagonal B).

    All vectors are expressed in the same frame (the contact's force frame); the result is the
    force the environment exerts on the robot, in that frame.
    """
    dp = np.atleast_1d(np.asarray(deflection, dtype=float))
    n = dp.shape[0]
    if dp.ndim != 1:
        raise InputError(f"deflection must be a vector, got shape {dp.shape}")
    dp = _as_finite_vector(dp, n, "deflection")
    dv = _as_finite_vector(np.atleast_1d(velocity), n, "velocity")
    K = _non_negative_vector(stiffness, n, "stiffness")
    B = _non_negative_vector(damping, n, "damping")
    return -K * dp - B * dv


def _state_limit_bounds(
    lower: npt.ArrayLike, upper: npt.ArrayLike, n: int
) -> tuple[np.ndarray, np.ndarray]:
    """Joint-limit barrier bounds as two float vectors of ``n`` entries, lower ≤ upper, no NaN
    (±inf allowed: no bound); ConfigError otherwise."""
    lb = np.asarray(lower, dtype=float)
    ub = np.asarray(upper, dtype=float)
    if lb.shape != (n,) or ub.shape != (n,):
        raise ConfigError(f"state-limit bounds must have {n} entries, got {lb.shape}, {ub.shape}")
    if np.isnan(lb).any() or np.isnan(ub).any() or (lb > ub).any():
        raise ConfigError(f"state-limit bounds must be ordered and not NaN, got {lb}, {ub}")
    return lb.copy(), ub.copy()


def check_soft_contact_robot(robot: RobotModel) -> None:
    """ModelError unless the robot suits the state (q, v, λ): nq == nv and a valid contact frame."""
    model = robot.model
    if model.nq != model.nv:
        raise ModelError(
            f"{robot.name}: the soft-contact state (q, v, λ) is a vector state and needs "
            f"nq == nv (got nq={model.nq}, nv={model.nv})"
        )
    if not 0 < robot.contact_frame_id < len(model.frames):
        raise ModelError(f"{robot.name}: bad contact frame id {robot.contact_frame_id}")


def residual_slices(nv: int, nc: int) -> dict[str, slice]:
    """Rows of each term of :data:`RESIDUAL_TERMS` in the stacked residual (nv joints, nc force
    entries)."""
    sizes = (nv, nv, nv, 3, 3, nc, nc, 2 * nv, 3, 3)
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    return {
        name: slice(int(offsets[i]), int(offsets[i + 1])) for i, name in enumerate(RESIDUAL_TERMS)
    }


class SoftContactDynamicsData:
    """Preallocated workspace of :class:`SoftContactDynamics` (one per OCP node / thread).

    After ``calc``: ``ddq`` (q̈, rad/s²), ``force_rate`` (λ̇, N/s), ``rotation`` (R = ⁰R_contact),
    ``position`` (p, m, world), ``ee_velocity`` (ṗ, m/s, world axes), ``frame_velocity`` and
    ``frame_acceleration`` (ṗ, p̈ in the force frame's axes, m/s and m/s²; 3 entries),
    ``force_local`` (the force in contact-frame axes, N), ``fext`` (the same as pinocchio joint
    forces), ``gravity_compensation`` (τ_g, N·m, after ``calc_gravity_compensation``).

    After ``calc_diff``, Jacobians w.r.t. (x, u) = (q, v, λ, τ) stacked column-wise:
    ``ddq_dxu`` (nv × (2nv+nc+nv)) with views ``ddq_dx``, ``ddq_dq``, ``ddq_dv``, ``ddq_dforce``
    (eq 22: M⁻¹Jᵀ), ``ddq_dtau`` (M⁻¹); ``force_rate_dxu`` (nc × ...) with views
    ``force_rate_dx``, ``force_rate_dq``, ``force_rate_dv``, ``force_rate_dforce``,
    ``force_rate_dtau`` (eq 23a–d); ``frame_velocity_dxu``, ``frame_acceleration_dxu`` (ṗ, p̈
    in the force frame); ``contact_jacobian`` (J, the nc rows matching λ, m/rad);
    ``position_dq`` (∂p/∂q, world); ``ee_velocity_dq``, ``ee_velocity_dv`` (∂ṗ_world/∂q, ∂v);
    ``frame_jacobian`` (6×nv LOCAL Jacobian of the contact frame); ``velocity_partials``
    ([∂ν/∂q, ∂ν/∂v] of the contact frame's LOCAL twist ν = (v_lin, ω), 6 × 2nv).
    """

    def __init__(self, dyn: SoftContactDynamics) -> None:
        nv, nc = dyn.nv, dyn.nc
        ndx = 2 * nv + nc
        nxu = ndx + nv
        self.pinocchio = dyn.pin_model.createData()
        self.pinocchio_static = dyn.pin_model.createData()  # for τ_g(q, λ) (v = a = 0)
        self.fext = pin.StdVec_Force()
        for _ in range(dyn.pin_model.njoints):
            self.fext.append(pin.Force.Zero())
        self.fext_joint = self.fext[dyn.parent_joint]  # reference into fext (never resized)
        self.fext_vector = np.zeros(6)
        self.zero_nv = np.zeros(nv)
        # calc
        self.force_frame = np.zeros(3)
        self.force_local = np.zeros(3)
        self.rotation = np.eye(3)
        self.position = np.zeros(3)
        self.linear_velocity_local = np.zeros(3)
        self.angular_velocity_local = np.zeros(3)
        self.classical_acceleration_local = np.zeros(3)
        self.ee_velocity = np.zeros(3)
        self.frame_velocity = np.zeros(3)
        self.frame_acceleration = np.zeros(3)
        self.ddq = np.zeros(nv)
        self.force_rate = np.zeros(nc)
        self.gravity_compensation = np.zeros(nv)
        # calc_diff: stacked Jacobians w.r.t. (q, v, λ, τ) and their views
        sq, sv, sf, st = (
            slice(0, nv),
            slice(nv, 2 * nv),
            slice(2 * nv, ndx),
            slice(ndx, nxu),
        )
        self.ddq_dxu = np.zeros((nv, nxu))
        self.ddq_dx = self.ddq_dxu[:, :ndx]
        self.ddq_dq = self.ddq_dxu[:, sq]
        self.ddq_dv = self.ddq_dxu[:, sv]
        self.ddq_dforce = self.ddq_dxu[:, sf]
        self.ddq_dtau = self.ddq_dxu[:, st]
        self.force_rate_dxu = np.zeros((nc, nxu))
        self.force_rate_dx = self.force_rate_dxu[:, :ndx]
        self.force_rate_dq = self.force_rate_dxu[:, sq]
        self.force_rate_dv = self.force_rate_dxu[:, sv]
        self.force_rate_dforce = self.force_rate_dxu[:, sf]
        self.force_rate_dtau = self.force_rate_dxu[:, st]
        self.frame_velocity_dxu = np.zeros((3, nxu))  # λ and τ columns stay zero
        self.frame_acceleration_dxu = np.zeros((3, nxu))
        self.local_velocity_dqv = np.zeros((3, 2 * nv))
        self.local_acceleration_dxu = np.zeros((3, nxu))
        self.velocity_partials = np.zeros((6, 2 * nv))  # [∂ν/∂q, ∂ν/∂v] (LOCAL twist)
        self.frame_jacobian = self.velocity_partials[:, nv:]
        self.contact_jacobian = np.zeros((nc, nv))
        self.position_dq = np.zeros((3, nv))
        self.ee_velocity_dqv = np.zeros((3, 2 * nv))
        self.ee_velocity_dq = self.ee_velocity_dqv[:, :nv]
        self.ee_velocity_dv = self.ee_velocity_dqv[:, nv:]
        self.gravity_compensation_dq = np.zeros((nv, nv))
        self.gravity_compensation_dforce = np.zeros((nv, nc))
        # scratch
        self.minv_jlin_t = np.zeros((nv, 3))
        self.cross_operator = np.zeros((3, 6))  # [[ω]×, −[v]×]
        self.skew_a = np.zeros((3, 3))
        self.skew_b = np.zeros((3, 3))
        self.tmp_3nv = np.zeros((3, nv))


class SoftContactDynamics:
    """The force-feedback contact dynamics (eq 20) and its derivatives (eq 22, 23a–d).

    Built once from a robot and a contact configuration; create one workspace per user with
    :meth:`create_data`. Stiffness K (N/m) and damping B (N·s/m) are per-axis vectors that can be
    changed at run time with :meth:`set_contact_parameters` (in place, no rebuild).
    """

    def __init__(self, robot: RobotModel, contact: ContactConfig) -> None:
        check_soft_contact_robot(robot)
        model = robot.model
        self.robot = robot
        self.contact = contact
        self.pin_model = model
        self.nv = model.nv
        self.nc = contact.dimension
        self.frame_id = robot.contact_frame_id
        frame = model.frames[self.frame_id]
        self.parent_joint = frame.parentJoint
        self.joint_placement = frame.placement.copy()  # jMf: contact frame in its joint frame
        self.world_aligned = contact.frame_type == LOCAL_WORLD_ALIGNED
        self.rows = np.array([contact.normal_axis]) if contact.dimension == 1 else np.arange(3)
        # A force f (contact-frame axes, at the frame origin) as a spatial force in the joint
        # frame: [jRf f ; jpf × (jRf f)].
        jRf = self.joint_placement.rotation
        jpf = self.joint_placement.translation
        self._force_to_joint = np.vstack([jRf, _skew_into(np.zeros((3, 3)), jpf) @ jRf])
        self.stiffness = contact.stiffness_vector()
        self.damping = contact.damping_vector()

    def create_data(self) -> SoftContactDynamicsData:
        """A fresh preallocated workspace."""
        return SoftContactDynamicsData(self)

    def set_contact_parameters(self, stiffness: npt.ArrayLike, damping: npt.ArrayLike) -> None:
        """Set K (N/m) and B (N·s/m) in place; scalar or one value per force axis (nc)."""
        K = _non_negative_vector(stiffness, self.nc, "stiffness")
        B = _non_negative_vector(damping, self.nc, "damping")
        self.stiffness[:] = K
        self.damping[:] = B

    # ------------------------------------------------------------------ calc
    def _set_external_force(self, data: SoftContactDynamicsData, force: np.ndarray) -> None:
        """Fill ``data.fext`` with λ applied at the contact point (needs data.rotation if LWA)."""
        data.force_frame[:] = 0.0
        data.force_frame[self.rows] = force
        if self.world_aligned:
            np.matmul(data.rotation.T, data.force_frame, out=data.force_local)
        else:
            data.force_local[:] = data.force_frame
        np.matmul(self._force_to_joint, data.force_local, out=data.fext_vector)
        data.fext_joint.vector = data.fext_vector

    def _read_frame_kinematics(self, data: SoftContactDynamicsData) -> None:
        """Copy the contact frame's placement and velocity from ``data.pinocchio``."""
        m, pd, fid = self.pin_model, data.pinocchio, self.frame_id
        oMf = pin.updateFramePlacement(m, pd, fid)
        data.rotation[:] = oMf.rotation
        data.position[:] = oMf.translation
        vel = pin.getFrameVelocity(m, pd, fid, pin.LOCAL)
        data.linear_velocity_local[:] = vel.linear
        data.angular_velocity_local[:] = vel.angular
        np.matmul(data.rotation, data.linear_velocity_local, out=data.ee_velocity)

    def calc(
        self,
        data: SoftContactDynamicsData,
        q: np.ndarray,
        v: np.ndarray,
        force: np.ndarray,
        tau: np.ndarray,
    ) -> None:
        """Eq 20: q̈ (rad/s²) and λ̇ (eq 18, N/s) for q (rad), v (rad/s), λ (N), τ (N·m).

        q̈ comes from pinocchio's ABA with λ applied as an external force at the contact frame
        (eq 20 row 2); λ̇ = −K ṗ − B p̈ with p̈ = J q̈ + J̇ v the classical acceleration of the
        contact point (eq 18), both in the force frame (see the module docstring).
        """
        m, pd = self.pin_model, data.pinocchio
        if self.world_aligned:
            pin.forwardKinematics(m, pd, q)
            data.rotation[:] = pin.updateFramePlacement(m, pd, self.frame_id).rotation
        self._set_external_force(data, force)
        data.ddq[:] = pin.aba(m, pd, q, v, tau, data.fext)
        pin.forwardKinematics(m, pd, q, v, data.ddq)
        self._read_frame_kinematics(data)
        acc = pin.getFrameClassicalAcceleration(m, pd, self.frame_id, pin.LOCAL)
        data.classical_acceleration_local[:] = acc.linear
        if self.world_aligned:
            data.frame_velocity[:] = data.ee_velocity
            np.matmul(data.rotation, data.classical_acceleration_local, out=data.frame_acceleration)
        else:
            data.frame_velocity[:] = data.linear_velocity_local
            data.frame_acceleration[:] = data.classical_acceleration_local
        r = self.rows
        data.force_rate[:] = (
            -self.stiffness * data.frame_velocity[r] - self.damping * data.frame_acceleration[r]
        )

    def calc_kinematics(self, data: SoftContactDynamicsData, q: np.ndarray, v: np.ndarray) -> None:
        """Only the contact frame's placement and velocity (for terminal nodes): ``position``
        (m, world), ``rotation``, ``ee_velocity`` (m/s, world axes)."""
        pin.forwardKinematics(self.pin_model, data.pinocchio, q, v)
        self._read_frame_kinematics(data)

    def calc_gravity_compensation(self, data: SoftContactDynamicsData, q: np.ndarray) -> None:
        """τ_g(q, λ) = g(q) − Jᵀλ (eq 25.3), N·m, into ``data.gravity_compensation``.

        Uses the external force set by the last :meth:`calc` (call it first, same q and λ).
        """
        data.gravity_compensation[:] = pin.computeStaticTorque(
            self.pin_model, data.pinocchio_static, q, data.fext
        )

    def visco_elastic_contact_force(
        self, data: SoftContactDynamicsData, q: np.ndarray, v: np.ndarray, anchor: np.ndarray
    ) -> np.ndarray:
        """Eq 16 through the robot's kinematics: λ^s(q, v, p_c) = −K Δp − B ṗ, N (nc entries).

        ``anchor`` p_c is in m, world frame. Δp = p(q) − p_c and ṗ are expressed in the force
        frame (world axes for LOCAL_WORLD_ALIGNED, current contact axes for LOCAL).
        """
        anchor = _as_finite_vector(anchor, 3, "anchor")
        self.calc_kinematics(data, q, v)
        deflection = data.position - anchor
        if self.world_aligned:
            velocity = data.ee_velocity
        else:
            deflection = data.rotation.T @ deflection
            velocity = data.linear_velocity_local
        r = self.rows
        return visco_elastic_force(deflection[r], velocity[r], self.stiffness, self.damping)

    # -------------------------------------------------------------- derivatives
    def calc_diff(
        self,
        data: SoftContactDynamicsData,
        q: np.ndarray,
        v: np.ndarray,
        force: np.ndarray,
        tau: np.ndarray,
    ) -> None:
        """Eq 22 and 23a–d: derivatives of q̈ and λ̇ w.r.t. q, v, λ and τ (call :meth:`calc` first).

        Frame derivatives are taken in LOCAL (pinocchio), then rotated to world axes with the
        derivative of the rotation added (d(R a) = R (da − [a]× J_ang dq)); for a world-fixed
        force (LOCAL_WORLD_ALIGNED), ∂q̈/∂q gains M⁻¹ J_linᵀ [Rᵀf]× J_ang (J in LOCAL) because
        ABA derivatives hold the force fixed in the joint frame.
        """
        m, pd, fid, nv, r = self.pin_model, data.pinocchio, self.frame_id, self.nv, self.rows
        # (The optimized overload reusing calc's pass needs a WORLD-convention ABA, whose q̈ has
        # ~50× more round-off; the full call keeps q̈ and its derivatives at LOCAL precision.)
        ddq_dq, ddq_dv, Minv = pin.computeABADerivatives(m, pd, q, v, tau, data.fext)
        data.ddq_dq[:] = ddq_dq
        data.ddq_dv[:] = ddq_dv
        data.ddq_dtau[:] = Minv
        Minv = data.ddq_dtau
        pin.computeForwardKinematicsDerivatives(m, pd, q, v, data.ddq)
        v_dq, a_dq, a_dv, a_da = pin.getFrameAccelerationDerivatives(m, pd, fid, pin.LOCAL)
        nu_partials = data.velocity_partials
        nu_partials[:, :nv] = v_dq
        nu_partials[:, nv:] = a_da  # ∂ν/∂v = ∂a/∂q̈ = J (LOCAL)
        J = data.frame_jacobian
        Jl, Ja = J[:3], J[3:]
        R = data.rotation
        MJ = data.minv_jlin_t
        np.matmul(Minv, Jl.T, out=MJ)

        # Eq 22, ∂q̈/∂λ = M⁻¹ Jᵀ; world-fixed force: ∂q̈/∂q += M⁻¹ J_linᵀ [f_local]× J_ang.
        if self.world_aligned:
            S_f = _skew_into(data.skew_a, data.force_local)
            np.matmul(S_f, Ja, out=data.tmp_3nv)
            data.ddq_dq += MJ @ data.tmp_3nv
            Rr = R[r]
            np.matmul(MJ, Rr.T, out=data.ddq_dforce)
            np.matmul(Rr, Jl, out=data.contact_jacobian)
        else:
            data.ddq_dforce[:] = MJ[:, r]
            data.contact_jacobian[:] = Jl[r]
        np.matmul(R, Jl, out=data.position_dq)

        # Local axes: velocity ṽ = v_lin and classical acceleration c = a_lin + ω × v_lin.
        C = data.cross_operator
        _skew_into(C[:, :3], data.angular_velocity_local)
        _skew_into(data.skew_b, data.linear_velocity_local)
        np.negative(data.skew_b, out=C[:, 3:])
        S_v = data.skew_b
        dvel = data.local_velocity_dqv
        dvel[:] = nu_partials[:3]
        dacc = data.local_acceleration_dxu
        np.matmul(Jl, data.ddq_dxu, out=dacc)  # chain rule through q̈ (eq 23, ∂p̈/∂q̈ = J)
        dacc[:, :nv] += a_dq[:3]
        dacc[:, nv : 2 * nv] += a_dv[:3]
        dacc[:, : 2 * nv] += C @ nu_partials

        # World-aligned linear velocity (for the ee-velocity cost), d(R v) = R(dv − [v]× J_ang dq).
        evel = data.ee_velocity_dqv
        evel[:] = dvel
        np.matmul(S_v, Ja, out=data.tmp_3nv)
        evel[:, :nv] -= data.tmp_3nv
        evel[:] = R @ evel

        fvel, facc = data.frame_velocity_dxu, data.frame_acceleration_dxu
        if self.world_aligned:
            fvel[:, : 2 * nv] = evel
            S_c = _skew_into(data.skew_a, data.classical_acceleration_local)
            np.matmul(S_c, Ja, out=data.tmp_3nv)
            dacc[:, :nv] -= data.tmp_3nv
            np.matmul(R, dacc, out=facc)
        else:
            fvel[:, : 2 * nv] = dvel
            facc[:] = dacc

        # Eq 23a–d: ∂λ̇ = −K ∂ṗ − B ∂p̈ (rows matching λ), all columns (q, v, λ, τ) at once.
        out = data.force_rate_dxu
        np.multiply(fvel[r], -self.stiffness[:, None], out=out)
        out -= self.damping[:, None] * facc[r]

    def calc_kinematics_diff(
        self, data: SoftContactDynamicsData, q: np.ndarray, v: np.ndarray
    ) -> None:
        """∂p/∂q, ∂ṗ_world/∂q, ∂ṗ_world/∂v (call :meth:`calc_kinematics` first)."""
        m, pd, nv = self.pin_model, data.pinocchio, self.nv
        pin.computeForwardKinematicsDerivatives(m, pd, q, v, data.zero_nv)
        v_dq, v_dv = pin.getFrameVelocityDerivatives(m, pd, self.frame_id, pin.LOCAL)
        data.velocity_partials[:, :nv] = v_dq
        data.velocity_partials[:, nv:] = v_dv
        Jl, Ja = data.frame_jacobian[:3], data.frame_jacobian[3:]
        R = data.rotation
        np.matmul(R, Jl, out=data.position_dq)
        evel = data.ee_velocity_dqv
        evel[:] = data.velocity_partials[:3]
        S_v = _skew_into(data.skew_b, data.linear_velocity_local)
        np.matmul(S_v, Ja, out=data.tmp_3nv)
        evel[:, :nv] -= data.tmp_3nv
        evel[:] = R @ evel

    def calc_gravity_compensation_diff(self, data: SoftContactDynamicsData, q: np.ndarray) -> None:
        """∂τ_g/∂q and ∂τ_g/∂λ = −Jᵀ (eq 25.3); call :meth:`calc` and :meth:`calc_diff` first."""
        data.gravity_compensation_dq[:] = pin.computeStaticTorqueDerivatives(
            self.pin_model, data.pinocchio_static, q, data.fext
        )
        if self.world_aligned:
            # τ_g contains −J_linᵀ Rᵀ f_w; d(Rᵀ f_w) = [Rᵀ f_w]× J_ang dq.
            J = data.frame_jacobian
            S_f = _skew_into(data.skew_a, data.force_local)
            np.matmul(S_f, J[3:], out=data.tmp_3nv)
            data.gravity_compensation_dq -= J[:3].T @ data.tmp_3nv
        np.negative(data.contact_jacobian.T, out=data.gravity_compensation_dforce)


# ======================================================================= action model
class IntegratedActionModelSoftContact(crocoddyl.ActionModelAbstract):
    """One node of the force-feedback OCP: eq 24 (semi-implicit Euler) + costs eq 25 and 29.

    State x = [q (rad), v (rad/s), λ (N)] on a ``crocoddyl.StateVector(2·nv + nc)``; control
    u = τ (N·m), nu = nv. Next state: v⁺ = v + Δt q̈, q⁺ = q + Δt v⁺, λ⁺ = λ + Δt λ̇.

    A terminal model (``terminal=True``) or a call without u keeps only the state terms (posture,
    joint velocity, ee position, ee velocity, force, joint-limit barrier, orientation, angular
    velocity), not scaled by Δt, and x⁺ = x.

    Costs (weights from :class:`CostWeights`): c1‖q − q̄‖² (rad), c2‖v‖² (rad/s),
    c3‖τ − τ_g(q, λ)‖² (N·m), c4‖p(q) − p̄‖² (m, world), c5‖ṗ‖² (m/s, world axes),
    c6‖λ − λ̄‖² (N), c_λ‖λ̇‖² (N/s, eq 29, Q_λ = identity) and the joint-limit barrier
    c_lim‖x_qv − clip(x_qv, x_lb, x_ub)‖² on x_qv = (q, v) (rad, rad/s; bounds
    :attr:`state_limit_lower` / :attr:`state_limit_upper` from
    ``robot.state_limit_bounds(weights.state_limit_fraction)``, ±inf where a joint has no
    limit). The barrier is crocoddyl's ``ActivationModelQuadraticBarrier`` on the state, as in
    the other formulations: its Jacobian is the identity on the entries at or outside a bound
    and zero inside, so its Gauss-Newton Hessian is the barrier's own. Control limits u_lb/u_ub
    are the robot's torque limits (N·m) for solvers that use them. ``weights.ee_rotation`` c_R
    adds c_R‖log3(R̄ᵀR(q))‖² (rad; R̄ = :attr:`rotation_reference`) and
    ``weights.ee_angular_velocity`` c_ω adds c_ω‖ω‖² (rad/s, LOCAL): the same residuals as the
    classical and torque-feedback models' (crocoddyl's ``ResidualModelFrameRotation`` and the
    angular rows of ``ResidualModelFrameVelocity`` in LOCAL, identity activations).

    References and weights are changed in place with :meth:`set_reference_values`,
    :meth:`set_contact_parameters` and :meth:`set_in_contact`.
    """

    def __init__(
        self,
        robot: RobotModel,
        contact: ContactConfig,
        weights: CostWeights,
        dt: float,
        terminal: bool = False,
        q_reference: np.ndarray | None = None,
        constraint_matrix: np.ndarray | None = None,
        control_scale: np.ndarray | None = None,
    ) -> None:
        dt = float(dt)
        if not np.isfinite(dt) or (dt <= 0.0 and not terminal) or dt < 0.0:
            raise ConfigError(f"dt must be positive and finite, got {dt}")
        self.dynamics = SoftContactDynamics(robot, contact)
        nv, nc = self.dynamics.nv, self.dynamics.nc
        self._slices = residual_slices(nv, nc)
        nr = self._slices[RESIDUAL_TERMS[-1]].stop
        rows = ConstraintRows(constraint_matrix, control_scale, 2 * nv + nc, nv, not terminal)
        crocoddyl.ActionModelAbstract.__init__(
            self, crocoddyl.StateVector(2 * nv + nc), nv, nr, rows.ng, 0, rows.ng_T, 0
        )
        #: The hard-constraint rows g = [S·x; u] (:mod:`ffmpc_core.constraints`); bounds in
        #: ``g_lb``/``g_ub``.
        self.constraint_rows = rows
        self.robot = robot
        self.contact = contact
        self.weights = weights
        self.dt = dt
        self.terminal = bool(terminal)
        self.nv, self.nc, self.ndx = nv, nc, 2 * nv + nc
        self.u_lb = -robot.torque_limit
        self.u_ub = robot.torque_limit.copy()
        # Activations Q_i (Q4 changes per node) and scalar weights c_i (c4, c6 change per node).
        self._diag = {
            "posture": weights.diag("posture", nv),
            "joint_velocity": weights.diag("joint_velocity", nv),
            "torque": weights.diag("torque", nv),
            "ee_position": weights.diag("ee_position", 3),
            "ee_velocity": weights.diag("ee_velocity", 3),
            "force": weights.diag("force", nc),
            "force_rate": np.ones(nc),
            "state_limit": np.ones(2 * nv),
            "ee_rotation": np.ones(3),
            "ee_angular_velocity": np.ones(3),
        }
        self._default_ee_position_diag = self._diag["ee_position"].copy()
        self._c = {
            "posture": weights.posture,
            "joint_velocity": weights.joint_velocity,
            "torque": weights.torque,
            "ee_position": weights.ee_position,
            "ee_velocity": weights.ee_velocity,
            "force": weights.force,
            "force_rate": weights.force_rate,
            "state_limit": weights.state_limit,
            "ee_rotation": weights.ee_rotation,
            "ee_angular_velocity": weights.ee_angular_velocity,
        }
        for name, c in self._c.items():
            if not np.isfinite(c) or c < 0.0:
                raise ConfigError(f"weight {name} must be finite and non-negative, got {c}")
        # References (updated in place).
        q_ref = robot.q_nominal if q_reference is None else q_reference
        self.q_reference = _as_finite_vector(q_ref, nv, "q_reference", ConfigError).copy()
        placement = robot.contact_placement(self.q_reference)
        self.ee_position_reference = placement.translation.copy()
        #: R̄ of the orientation cost: the contact frame's orientation at the construction-time
        #: q̄ (as the classical and torque-feedback models; later q̄ updates do not change it).
        self.rotation_reference = placement.rotation.copy()
        self.force_reference = np.zeros(nc)
        # Joint-limit barrier bounds on (q, v), rad and rad/s (2·nv entries each).
        lower, upper = robot.state_limit_bounds(weights.state_limit_fraction)
        self.state_limit_lower = lower
        self.state_limit_upper = upper
        # Contact parameters: nominal (from the config / learner) and in-contact flag.
        self.nominal_stiffness = self.dynamics.stiffness.copy()
        self.nominal_damping = self.dynamics.damping.copy()
        self.in_contact = True
        # Weight vectors w (cost = ½ Σ w r²): running (× Δt) and state-only (terminal/no u).
        self._w_running = np.zeros(nr)
        self._w_state = np.zeros(nr)
        self._sqrt_w_running = np.zeros(nr)
        self._sqrt_w_state = np.zeros(nr)
        self._update_weights()

    # ------------------------------------------------------------ parameters
    def _update_weights(self) -> None:
        for name in RESIDUAL_TERMS:
            s = self._slices[name]
            c = self._c[name]
            if name == "force" and not self.in_contact:
                c = 0.0
            w = c * self._diag[name]
            self._w_running[s] = self.dt * w
            self._w_state[s] = 0.0 if name in RUNNING_ONLY_TERMS else w
        np.sqrt(self._w_running, out=self._sqrt_w_running)
        np.sqrt(self._w_state, out=self._sqrt_w_state)

    def residual_slice(self, name: str) -> slice:
        """Rows of term ``name`` (see :data:`RESIDUAL_TERMS`) in ``data.r``."""
        return self._slices[name]

    def set_state_limit_bounds(self, lower: npt.ArrayLike, upper: npt.ArrayLike) -> None:
        """Bounds of the joint-limit barrier on (q, v): 2·nv entries each (rad, then rad/s),
        lower ≤ upper, no NaN (±inf: no bound); ConfigError changes nothing."""
        lb, ub = _state_limit_bounds(lower, upper, 2 * self.nv)
        self.state_limit_lower[:] = lb
        self.state_limit_upper[:] = ub

    def weight(self, name: str) -> float:
        """The scalar weight c of term ``name`` as currently set (before the in-contact rule)."""
        return self._c[name]

    def set_weight(self, name: str, value: float) -> None:
        """Set the scalar weight c of term ``name`` (in place)."""
        if name not in self._c:
            raise ConfigError(f"unknown cost term {name!r}; choose one of {RESIDUAL_TERMS}")
        value = float(value)
        if not np.isfinite(value) or value < 0.0:
            raise ConfigError(f"weight {name} must be finite and non-negative, got {value}")
        self._c[name] = value
        self._update_weights()

    def set_reference_values(
        self,
        ee_position: np.ndarray,
        force: np.ndarray,
        ee_position_weight: float,
        force_weight: float,
        in_contact: bool,
        posture: np.ndarray | None = None,
        ee_position_diag: np.ndarray | None = None,
    ) -> None:
        """Update p̄ (m, world), λ̄ (N, force frame), c4, c6, the contact flag, q̄ (rad) and Q4.

        ``ee_position_diag`` is the activation Q4 of the end-effector position cost (3 entries,
        world axes, ≥ 0; tasks give (1, 1, 0) in contact so that the normal direction belongs to
        the force task); None restores ``CostWeights.ee_position_diag``. Nothing changes when
        any value is invalid (InputError).
        """
        p = _as_finite_vector(ee_position, 3, "ee_position")
        f = _as_finite_vector(np.atleast_1d(force), self.nc, "force")
        qb = None if posture is None else _as_finite_vector(posture, self.nv, "posture")
        if ee_position_diag is None:
            q4 = self._default_ee_position_diag
        else:
            q4 = _as_finite_vector(ee_position_diag, 3, "ee_position_diag")
            if (q4 < 0.0).any():
                raise InputError(f"ee_position_diag must be non-negative, got {q4}")
        c4, c6 = float(ee_position_weight), float(force_weight)
        for name, weight in (("ee_position_weight", c4), ("force_weight", c6)):
            if not math.isfinite(weight) or weight < 0.0:
                raise InputError(f"{name} must be finite and non-negative, got {weight}")
        self.ee_position_reference[:] = p
        self.force_reference[:] = f
        if qb is not None:
            self.q_reference[:] = qb
        # The weight vectors are rebuilt only when a weight or the contact flag changes (task
        # phase switches), not on every MPC step.
        c, q4_now = self._c, self._diag["ee_position"]
        weights_changed = c["ee_position"] != c4 or c["force"] != c6 or (q4_now != q4).any()
        if weights_changed:
            c["ee_position"], c["force"] = c4, c6
            q4_now[:] = q4
        if bool(in_contact) != self.in_contact:
            self.set_in_contact(in_contact)
        elif weights_changed:
            self._update_weights()

    def set_in_contact(self, in_contact: bool) -> None:
        """In contact: K, B nominal; otherwise K = B = 0 and c6 = 0 for this node."""
        self.in_contact = bool(in_contact)
        if self.in_contact:
            self.dynamics.set_contact_parameters(self.nominal_stiffness, self.nominal_damping)
        else:
            self.dynamics.set_contact_parameters(0.0, 0.0)
        self._update_weights()

    def set_contact_parameters(self, stiffness: npt.ArrayLike, damping: npt.ArrayLike) -> None:
        """Nominal K (N/m) and B (N·s/m), scalar or per force axis; applied in place."""
        K = _non_negative_vector(stiffness, self.nc, "stiffness")
        B = _non_negative_vector(damping, self.nc, "damping")
        self.nominal_stiffness[:] = K
        self.nominal_damping[:] = B
        self.set_in_contact(self.in_contact)

    # ------------------------------------------------------------ crocoddyl API
    def createData(self) -> IntegratedActionDataSoftContact:  # noqa: N802 (crocoddyl API)
        return IntegratedActionDataSoftContact(self)

    def calc(
        self, data: IntegratedActionDataSoftContact, x: np.ndarray, u: np.ndarray | None = None
    ) -> None:
        """Next state (eq 24) and cost at x = [q, v, λ], u = τ (N·m); u=None: state terms only."""
        nv, dyn, dd = self.nv, self.dynamics, data.dynamics
        q, v, lam = x[:nv], x[nv : 2 * nv], x[2 * nv :]
        r, sl = data.residual, self._slices
        np.subtract(q, self.q_reference, out=r[sl["posture"]])
        r[sl["joint_velocity"]] = v
        np.subtract(lam, self.force_reference, out=r[sl["force"]])
        excess = r[sl["state_limit"]]  # x − clip(x, lb, ub) on (q, v): zero inside the bounds
        np.clip(x[: 2 * nv], self.state_limit_lower, self.state_limit_upper, out=excess)
        np.subtract(x[: 2 * nv], excess, out=excess)
        if self.terminal or u is None:
            dyn.calc_kinematics(dd, q, v)
            r[sl["torque"]] = 0.0
            r[sl["force_rate"]] = 0.0
            data.xnext[:] = x
            sqrt_w = self._sqrt_w_state
        else:
            dyn.calc(dd, q, v, lam, u)
            dyn.calc_gravity_compensation(dd, q)
            np.subtract(u, dd.gravity_compensation, out=r[sl["torque"]])
            r[sl["force_rate"]] = dd.force_rate
            dt = self.dt
            xn = data.xnext_buffer
            np.multiply(dd.ddq, dt, out=xn[nv : 2 * nv])
            xn[nv : 2 * nv] += v
            np.multiply(xn[nv : 2 * nv], dt, out=xn[:nv])
            xn[:nv] += q
            np.multiply(dd.force_rate, dt, out=xn[2 * nv :])
            xn[2 * nv :] += lam
            data.xnext[:] = xn
            sqrt_w = self._sqrt_w_running
        np.subtract(dd.position, self.ee_position_reference, out=r[sl["ee_position"]])
        r[sl["ee_velocity"]] = dd.ee_velocity
        r[sl["ee_rotation"]] = pin.log3(self.rotation_reference.T @ dd.rotation)
        r[sl["ee_angular_velocity"]] = dd.angular_velocity_local
        np.multiply(sqrt_w, r, out=data.weighted_residual)
        data.r[:] = data.weighted_residual
        data.cost = 0.5 * float(data.weighted_residual @ data.weighted_residual)
        self.constraint_rows.calc(data.g, x, None if self.terminal else u)

    def calcDiff(  # noqa: N802 (crocoddyl API)
        self, data: IntegratedActionDataSoftContact, x: np.ndarray, u: np.ndarray | None = None
    ) -> None:
        """Fx, Fu (exact) and Lx, Lu, Gauss-Newton Lxx, Lxu, Luu; call :meth:`calc` first."""
        nv, dyn, dd = self.nv, self.dynamics, data.dynamics
        q, v, lam = x[:nv], x[nv : 2 * nv], x[2 * nv :]
        Rx, Ru, sl = data.Rx, data.Ru, self._slices
        s_ee_p, s_ee_v = sl["ee_position"], sl["ee_velocity"]
        state_only = self.terminal or u is None
        if state_only or u is None:  # `or u is None` repeats state_only for the type checker
            dyn.calc_kinematics_diff(dd, q, v)
            w = self._w_state
        else:
            dyn.calc_diff(dd, q, v, lam, u)
            dyn.calc_gravity_compensation_diff(dd, q)
            w = self._w_running
        Rx[s_ee_p, :nv] = dd.position_dq
        Rx[s_ee_v, :nv] = dd.ee_velocity_dq
        Rx[s_ee_v, nv : 2 * nv] = dd.ee_velocity_dv
        # Orientation: d log3(R̄ᵀR) = Jlog3(R̄ᵀR)·J_ang dq (J LOCAL), crocoddyl's FrameRotation.
        jlog = pin.Jlog3(self.rotation_reference.T @ dd.rotation)
        Rx[sl["ee_rotation"], :nv] = jlog @ dd.frame_jacobian[3:]
        Rx[sl["ee_angular_velocity"], : 2 * nv] = dd.velocity_partials[3:]
        # Barrier: ∂(excess)/∂x = 1 at or beyond a bound, 0 inside (crocoddyl's rule).
        xqv = x[: 2 * nv]
        active = (xqv <= self.state_limit_lower) | (xqv >= self.state_limit_upper)
        Rx[data.state_limit_rows, data.state_limit_cols] = active
        if not state_only:
            s_tau, s_fr = sl["torque"], sl["force_rate"]
            np.negative(dd.gravity_compensation_dq, out=Rx[s_tau, :nv])
            Rx[s_tau, 2 * nv :] = dd.contact_jacobian.T
            Rx[s_fr] = dd.force_rate_dx
            Ru[s_fr] = dd.force_rate_dtau
        # Costs (Gauss-Newton): Lx = Rxᵀ W r, Lxx = Rxᵀ W Rx, ...
        wr = data.wr
        np.multiply(w, data.residual, out=wr)
        WRx, WRu = data.WRx, data.WRu
        np.multiply(w[:, None], Rx, out=WRx)
        np.multiply(w[:, None], Ru, out=WRu)
        data.Lx[:] = Rx.T @ wr
        data.Lxx[:, :] = Rx.T @ WRx
        self.constraint_rows.calc_diff(data.Gx, data.Gu)
        if state_only:
            data.Fx[:, :] = data.identity_ndx
            data.Fu[:, :] = 0.0
            data.Lu[:] = 0.0
            data.Luu[:, :] = 0.0
            data.Lxu[:, :] = 0.0
            return
        data.Lu[:] = Ru.T @ wr
        data.Luu[:, :] = Ru.T @ WRu
        data.Lxu[:, :] = Rx.T @ WRu
        # Dynamics (eq 24): [Fx Fu] = [I 0] + [Δt²; Δt; Δt]·∂f/∂(x, u), plus Δt on ∂q⁺/∂v.
        dt = self.dt
        Fxu = data.Fxu
        Fxu[:] = data.Fxu_base
        Fxu[:nv] += (dt * dt) * dd.ddq_dxu
        Fxu[nv : 2 * nv] += dt * dd.ddq_dxu
        Fxu[2 * nv :] += dt * dd.force_rate_dxu
        data.Fx[:, :] = data.Fx_view
        data.Fu[:, :] = data.Fu_view


class IntegratedActionDataSoftContact(crocoddyl.ActionDataAbstract):
    """Workspace of :class:`IntegratedActionModelSoftContact` (residuals and their Jacobians).

    ``residual``: unweighted stacked residual r (layout :data:`RESIDUAL_TERMS`); ``Rx``, ``Ru``:
    its Jacobians; ``dynamics``: the :class:`SoftContactDynamicsData`.
    """

    def __init__(self, model: IntegratedActionModelSoftContact) -> None:
        crocoddyl.ActionDataAbstract.__init__(self, model)
        nv, nc, ndx, nr = model.nv, model.nc, model.ndx, model.nr
        self.dynamics = model.dynamics.create_data()
        self.residual = np.zeros(nr)
        self.weighted_residual = np.zeros(nr)
        self.wr = np.zeros(nr)
        self.Rx = np.zeros((nr, ndx))
        self.Ru = np.zeros((nr, nv))
        self.WRx = np.zeros((nr, ndx))
        self.WRu = np.zeros((nr, nv))
        sl = model._slices
        # Constant blocks of the residual Jacobians.
        self.Rx[sl["posture"], :nv] = np.eye(nv)
        self.Rx[sl["joint_velocity"], nv : 2 * nv] = np.eye(nv)
        self.Rx[sl["force"], 2 * nv :] = np.eye(nc)
        self.Ru[sl["torque"]] = np.eye(nv)
        # Diagonal of the joint-limit barrier's Jacobian block (set per calcDiff).
        self.state_limit_rows = np.arange(sl["state_limit"].start, sl["state_limit"].stop)
        self.state_limit_cols = np.arange(2 * nv)
        self.xnext_buffer = np.zeros(ndx)
        self.identity_ndx = np.eye(ndx)
        self.Fxu_base = np.zeros((ndx, ndx + nv))
        self.Fxu_base[:, :ndx] = np.eye(ndx)
        self.Fxu_base[:nv, nv : 2 * nv] += model.dt * np.eye(nv)
        self.Fxu = np.zeros((ndx, ndx + nv))
        self.Fx_view = self.Fxu[:, :ndx]
        self.Fu_view = self.Fxu[:, ndx:]


# ======================================================================= node wrapper
def soft_contact_state(q: npt.ArrayLike, v: npt.ArrayLike, force: npt.ArrayLike) -> np.ndarray:
    """The force-feedback state x = [q (rad), v (rad/s), λ (N)] as one vector (validated)."""
    q = np.asarray(q, dtype=float)
    v = np.asarray(v, dtype=float)
    f = np.atleast_1d(np.asarray(force, dtype=float))
    if q.ndim != 1 or v.shape != q.shape or f.ndim != 1 or f.shape[0] not in (1, 3):
        raise InputError(
            f"bad state sizes: q {q.shape}, v {v.shape}, force {f.shape} (force has 1 or 3)"
        )
    x = np.concatenate([q, v, f])
    if not np.all(np.isfinite(x)):
        raise InputError("state must be finite")
    return x


class SoftContactNode:
    """A force-feedback OCP node: the action model plus in-place updates of its references.

    Attributes:
        model: the :class:`IntegratedActionModelSoftContact` (the object never changes).
        bounds: its hard constraints (None: none); the state-only rows' bounds change with
            :meth:`set_state_bounds`.
    """

    def __init__(
        self, model: IntegratedActionModelSoftContact, bounds: OcpBounds | None = None
    ) -> None:
        self.model = model
        self.bounds = bounds
        if bounds is not None:
            self.set_state_bounds(bounds.state_lower, bounds.state_upper)

    def set_state_bounds(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Bounds of the state-only constraint rows (``bounds.n_state_rows`` each; ±inf: none);
        the control rows keep ``bounds``'. ModelError without constraints."""
        if self.bounds is None:
            raise ModelError("this node has no constraints")
        lb, ub = self.bounds.bounds(self.terminal, lower, upper)
        self.model.g_lb = lb
        self.model.g_ub = ub

    @property
    def terminal(self) -> bool:
        """Whether this is the terminal node of the horizon."""
        return self.model.terminal

    def set_reference(self, ref: NodeReference) -> bool:
        """Update p̄ (m, world), λ̄ (N), c4, c6, q̄ (if given), Q4 (``ref.ee_position_diag``;
        None: the CostWeights one) and the contact flag in place.

        Out of contact (``ref.in_contact`` False) the node's K = B = 0 and c6 = 0. Returns
        False: the model object is never replaced, so the solver's problem needs no rebuild.
        """
        self.model.set_reference_values(
            ref.ee_position,
            ref.force,
            ref.ee_position_weight,
            ref.force_weight,
            ref.in_contact,
            ref.posture,
            ref.ee_position_diag,
        )
        return False

    def set_contact_parameters(self, stiffness: npt.ArrayLike, damping: npt.ArrayLike) -> None:
        """Stiffness K (N/m) and damping B (N·s/m), scalar or per force axis, in place."""
        self.model.set_contact_parameters(stiffness, damping)

    def state(self, q: npt.ArrayLike, v: npt.ArrayLike, force: npt.ArrayLike) -> np.ndarray:
        """x = [q, v, λ] for this node (validated against the model's sizes)."""
        x = soft_contact_state(q, v, force)
        if x.shape[0] != self.model.state.nx:
            raise InputError(f"state has {x.shape[0]} entries, expected {self.model.state.nx}")
        return x


def make_soft_contact_node(
    robot: RobotModel,
    contact: ContactConfig,
    weights: CostWeights,
    dt: float,
    terminal: bool,
    q_reference: np.ndarray | None = None,
    bounds: OcpBounds | None = None,
) -> SoftContactNode:
    """Build a force-feedback node (running or terminal) with Δt in s.

    Initial references: q̄ = ``q_reference`` (default the robot's nominal posture), p̄ = the
    contact position at q̄ (m, world), λ̄ = 0, c4 and c6 from ``weights``, in contact.
    ``bounds``: the hard constraints (:func:`ffmpc_core.constraints.ocp_bounds` of the
    force-feedback formulation; None: none).
    """
    matrix = None if bounds is None else bounds.state_matrix
    scale = None if bounds is None else bounds.control_scale
    model = IntegratedActionModelSoftContact(
        robot, contact, weights, dt, terminal, q_reference, matrix, scale
    )
    return SoftContactNode(model, bounds)
