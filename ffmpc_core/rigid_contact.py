"""Classical MPC formulation (Kleff et al. 2024, Sec. III-C): rigid contact, x = (q, v), u = τ.

The continuous dynamics (eq 5–6) are the primal solution of the KKT system of Gauss' principle
(eq 3–4); the contact force λ^r(x, u) is its dual (eq 5b). Crocoddyl's
``DifferentialActionModelContactFwdDynamics`` solves exactly that system; its
``IntegratedActionModelEuler`` is the semi-implicit Euler scheme of eq 8
(v⁺ = v + Δt·q̈, q⁺ = q ⊕ Δt·v⁺, running cost × Δt).

Contact model (``ContactConfig``), at the robot's ``contact`` frame:

* 1-D: crocoddyl ``ContactModel1D``; the force axis is ``normal_axis`` of the frame
  (``LOCAL_WORLD_ALIGNED``: world axes at the contact point — the paper's setting, Sec. VI-A;
  ``LOCAL``: the contact frame's own axes). Crocoddyl reads the axis from a rotation R with
  Rᵀ·e_z = axis (:func:`contact_axis_rotation`).
* 3-D: crocoddyl ``ContactModel3D`` in the same frame type.

λ is the force the environment exerts on the robot, in N, in that frame (along the axis for 1-D):
pushing down on a horizontal table gives λ > 0 (see :mod:`ffmpc_core.config`).

**Baumgarte stabilisation.** The rigid constraint (3b) is imposed as
J·q̈ + J̇·q̇ = −K_d·J·q̇ (position gain 0, velocity gain K_d, crocoddyl gains ``[0, K_d]``).
No position gain on purpose: a position term pulls the contact point towards a fixed anchor, and
the controller does not know the table's height and tilt exactly (Sec. VI-B), so the anchor would
be wrong and the model would predict a spurious force to "correct" a position error that is not
there. The velocity term only says "the normal velocity dies out": when the measured state
has a normal velocity (sliding along an unknown tilt, sensing noise) the prediction decelerates it
with time constant 1/K_d instead of letting it drift through the surface for the whole horizon.
Default K_d = 50 s⁻¹ (crocoddyl's own examples use ``[0, 50]``): time constant 20 ms, about the
horizon of the paper (5 nodes × 3 ms), and K_d·Δt = 0.15 ≪ 1, so the discrete decay is smooth.

**Costs** ℓ0 (eq 25, = eq 27 for this formulation), crocoddyl convention c·½·Σ Q_i r_i²:

================== ========================================================================
``posture``        eq 25.1, ``ResidualModelState`` (q part), weight c1
``joint_velocity`` eq 25.2, ``ResidualModelState`` (v part), weight c2
``torque``         eq 25.3, τ − τ_g(q, λ) with τ_g = g(q) − J(q)ᵀλ (running only)
``ee_position``    eq 25.4, ``ResidualModelFrameTranslation`` of the contact frame, weight c4
``ee_velocity``    eq 25.5, linear velocity of the contact point in world axes, weight c5
``force``          eq 25.6 / 7, ``ResidualModelContactForce`` (running, in contact only), c6
``state_limit``    joint-limit barrier on (q, v): ``ResidualModelState`` under crocoddyl's
                   ``ActivationModelQuadraticBarrier`` (bounds: ``state_limit_fraction`` of the
                   robot's position range and velocity limits), weight c_lim; not in the paper
================== ========================================================================

Terminal nodes keep the state terms only (posture, joint_velocity, ee_position, ee_velocity,
state_limit).

Two crocoddyl 3.2.1 built-ins are *not* used because they are wrong (measured against finite
differences in ``tests/test_rigid_contact.py``):

* ``ResidualModelContactControlGrav`` copies the contact ``fext`` vector when its data is created
  (``fext = d->contacts->fext``), so it never sees the contact force: it computes τ − g(q), not
  τ − g(q) + Jᵀλ. :class:`ResidualModelContactGravityTorque` replaces it, with the exact
  derivatives (through ∂λ^r/∂x, ∂λ^r/∂u and the world-fixed force direction).
* ``ResidualModelFrameVelocity`` in ``LOCAL_WORLD_ALIGNED`` takes pinocchio's LWA velocity
  derivatives, which are not the derivatives of the world-aligned vector (26 % off).
  For an isotropic Q5 we use the ``LOCAL`` residual instead (same norm, exact derivatives, C++);
  otherwise :class:`ResidualModelFrameLinearVelocityWorld` (exact).

**Backends.** The two residuals above exist twice: the Python classes of this module (the readable
reference) and their C++ ports in ``ffmpc_core._native`` (``cpp/residuals.cpp``, same residuals
and derivatives, held equal by ``tests/test_native_lowpass.py``). ``backend="native"`` (the
default of every builder) puts the C++ ones in the cost model, so the whole node runs in C++;
``backend="python"`` the Python ones.

**Switching contact on/off.** A running node owns two prebuilt action models (in contact and
free). :meth:`RigidContactNode.set_reference` points ``model`` at the right one and returns True
when it changed, so the caller does ``problem.updateModel(k, node.model)`` — crocoddyl then
creates fresh data for the node. Toggling crocoddyl's ``changeContactStatus`` on one model was
not chosen: it would keep the force cost (and its residual data bound to the contact data)
evaluating a deactivated contact, with data created before the toggle — behaviour crocoddyl does
not document — whereas two prebuilt models cost nothing per MPC cycle and a switch (a task-phase
change) just allocates one node's data.
"""

from __future__ import annotations

import math
from types import ModuleType
from typing import Any

import crocoddyl
import numpy as np
import numpy.typing as npt
import pinocchio as pin

from ffmpc_core.config import BACKENDS, ContactConfig, CostWeights, NodeReference
from ffmpc_core.constraints import ConstraintRows, OcpBounds
from ffmpc_core.errors import ConfigError, InputError, ModelError
from ffmpc_core.robots import RobotModel

#: Default Baumgarte velocity gain K_d, 1/s (see module docstring): ``ContactConfig``'s, which
#: the node builders use when given no gain (scenario ``mpc.contact.baumgarte_velocity_gain``).
DEFAULT_BAUMGARTE_VELOCITY_GAIN = ContactConfig.baumgarte_velocity_gain

#: Name of the contact in crocoddyl's ``ContactModelMultiple``.
CONTACT_NAME = "contact"

#: Default implementation of the custom residuals (and of the low-pass integrator of
#: ffmpc_core.lowpass): ``"native"`` = C++ from ffmpc_core._native; ``"python"`` = the reference
#: classes (config.BACKENDS).
DEFAULT_BACKEND = "native"

#: Names of the cost terms of ℓ0 (eq 25.1–25.6) in crocoddyl's ``CostModelSum``.
COST_POSTURE = "posture"
COST_JOINT_VELOCITY = "joint_velocity"
COST_TORQUE = "torque"
COST_EE_POSITION = "ee_position"
COST_EE_VELOCITY = "ee_velocity"
COST_EE_ROTATION = "ee_rotation"
COST_EE_ANGULAR_VELOCITY = "ee_angular_velocity"
COST_FORCE = "force"
#: Name of the joint-limit barrier on x = (q, v) (``CostWeights.state_limit``).
COST_STATE_LIMIT = "state_limit"
#: Name of the hard constraints in crocoddyl's ``ConstraintModelManager`` (issue 23): the rows of
#: :mod:`ffmpc_core.constraints` (the box on x = (q, v) at every node, on the torque u in running
#: nodes), :class:`ResidualModelConstraintRows`.
CONSTRAINT_LIMITS = "limits"


def check_backend(backend: str) -> bool:
    """True for ``"native"``, False for ``"python"``; :class:`ConfigError` otherwise."""
    if backend not in BACKENDS:
        raise ConfigError(f"backend must be one of {BACKENDS}, got {backend!r}")
    return backend == "native"


def native_module() -> ModuleType:
    """The compiled module ``ffmpc_core._native`` (C++ models); :class:`ModelError` when it was
    not built (``make native``)."""
    try:
        import ffmpc_core._native as _native  # (this form lets mypy skip the compiled module)
    except ImportError as exc:
        raise ModelError(
            f"the native backend needs the compiled module ffmpc_core._native ({exc}); "
            "build it with `make native` or use backend='python'"
        ) from exc
    return _native


def contact_axis_rotation(normal_axis: int) -> np.ndarray:
    """Rotation R given to crocoddyl's ``ContactModel1D`` so that its force axis Rᵀ·e_z is axis
    ``normal_axis`` (0=x, 1=y, 2=z) of the contact's frame (dimensionless 3×3)."""
    if normal_axis not in (0, 1, 2):
        raise ConfigError(f"normal_axis must be 0, 1 or 2, got {normal_axis}")
    axis = np.eye(3)[normal_axis]
    return pin.Quaternion.FromTwoVectors(axis, np.array([0.0, 0.0, 1.0])).matrix()


def make_contact_model(
    state: crocoddyl.StateMultibody,
    frame_id: int,
    contact: ContactConfig,
    nu: int,
    baumgarte_velocity_gain: float = DEFAULT_BAUMGARTE_VELOCITY_GAIN,
) -> crocoddyl.ContactModelMultiple:
    """The rigid contact of eq 3b at frame ``frame_id``, with Baumgarte gains ``[0, K_d]`` (1/s)."""
    if not np.isfinite(baumgarte_velocity_gain) or baumgarte_velocity_gain < 0:
        raise ConfigError(f"baumgarte_velocity_gain must be >= 0, got {baumgarte_velocity_gain}")
    gains = np.array([0.0, float(baumgarte_velocity_gain)])
    if contact.dimension == 1:
        rotation = contact_axis_rotation(contact.normal_axis)
        model = crocoddyl.ContactModel1D(
            state, frame_id, 0.0, contact.pin_frame, rotation, nu, gains
        )
    else:
        model = crocoddyl.ContactModel3D(state, frame_id, np.zeros(3), contact.pin_frame, nu, gains)
    contacts = crocoddyl.ContactModelMultiple(state, nu)
    contacts.addContact(CONTACT_NAME, model)
    return contacts


class ResidualModelContactGravityTorque(crocoddyl.ResidualModelAbstract):
    """Eq 25.3 in contact: r = τ − τ_g(q, λ^r(x, u)), τ_g(q, λ) = g(q) − J(q)ᵀλ, N·m.

    λ^r is the rigid contact force of the same node (dual of eq 4), read from the contact data of
    the differential model after its calc; the derivatives are exact:
    ∂r/∂q = −∂τ_g/∂q|_λ + Jᵀ·∂λ^r/∂q, ∂r/∂v = Jᵀ·∂λ^r/∂v, ∂r/∂u = I + Jᵀ·∂λ^r/∂u, where the
    force is held fixed in its own frame (world axes for ``LOCAL_WORLD_ALIGNED``). Only for a
    ``DifferentialActionModelContactFwdDynamics`` built with ``enable_force=True``.
    """

    def __init__(self, state: crocoddyl.StateMultibody, nu: int, world_aligned: bool) -> None:
        super().__init__(state, state.nv, nu, True, True, True)
        self._pin_model = state.pinocchio
        self._nq = state.nq
        self._nv = state.nv
        self._world_aligned = bool(world_aligned)
        self._eye = np.eye(nu)

    def createData(  # noqa: N802 (crocoddyl API)
        self, collector: Any
    ) -> ResidualDataContactGravityTorque:
        return ResidualDataContactGravityTorque(self, collector)

    def calc(self, data: Any, x: np.ndarray, u: np.ndarray | None = None) -> None:
        q = x[: self._nq]
        if u is None:  # no control, no force: r = −g(q) (crocoddyl's convention for calc(x))
            data.r[:] = -pin.computeGeneralizedGravity(self._pin_model, data.pin_data, q)
            return
        data.r[:] = u - pin.computeStaticTorque(self._pin_model, data.pin_data, q, data.fext)

    def calcDiff(  # noqa: N802 (crocoddyl API)
        self, data: Any, x: np.ndarray, u: np.ndarray | None = None
    ) -> None:
        q = x[: self._nq]
        nv = self._nv
        if u is None:
            data.Rx[:, :nv] = -pin.computeGeneralizedGravityDerivatives(
                self._pin_model, data.pin_data, q
            )
            data.Rx[:, nv:] = 0.0
            return
        # ∂τ_g/∂q with the force fixed in its joint frame, then the world-fixed correction.
        dtau_g_dq = pin.computeStaticTorqueDerivatives(self._pin_model, data.pin_data, q, data.fext)
        contact = data.contact
        if self._world_aligned:
            dtau_g_dq += contact.dtau_dq
        if data.nc == 1:  # eigenpy hands 1-row matrices over as 1-D arrays
            jt_df_dx = np.outer(contact.Jc, contact.df_dx)
            jt_df_du = np.outer(contact.Jc, contact.df_du)
        else:
            jac_t = contact.Jc.T
            jt_df_dx = jac_t @ contact.df_dx
            jt_df_du = jac_t @ contact.df_du
        jt_df_dx[:, :nv] -= dtau_g_dq
        jt_df_du += self._eye
        data.Rx[:, :] = jt_df_dx
        data.Ru[:, :] = jt_df_du


class ResidualDataContactGravityTorque(crocoddyl.ResidualDataAbstract):
    """Workspace of :class:`ResidualModelContactGravityTorque` (private pinocchio data)."""

    def __init__(self, model: ResidualModelContactGravityTorque, collector: Any) -> None:
        super().__init__(model, collector)
        contacts = collector.contacts
        self.fext = contacts.fext  # reference to the live vector, updated by the DAM
        self.contact = contacts.contacts[CONTACT_NAME]
        self.nc = int(np.size(contacts.a0))
        self.pin_data = model._pin_model.createData()


class ResidualModelFrameLinearVelocityWorld(crocoddyl.ResidualModelAbstract):
    """Eq 25.5: ṗ(q, q̇), linear velocity of the frame origin in world axes
    (pinocchio ``LOCAL_WORLD_ALIGNED``), m/s, with exact derivatives.

    With ṗ = R·v_l (R = world rotation of the frame, v_l its LOCAL linear velocity):
    ∂ṗ/∂q = R·(∂v_l/∂q − [v_l]×·J_ω), ∂ṗ/∂v = R·J_v (LOCAL Jacobian blocks J_v, J_ω).
    """

    def __init__(self, state: crocoddyl.StateMultibody, frame_id: int, nu: int) -> None:
        super().__init__(state, 3, nu, True, True, False)
        self._pin_model = state.pinocchio
        self._frame_id = int(frame_id)
        self._nq = state.nq
        self._nv = state.nv
        self._zero_a = np.zeros(state.nv)

    def createData(  # noqa: N802 (crocoddyl API)
        self, collector: Any
    ) -> ResidualDataFrameLinearVelocityWorld:
        return ResidualDataFrameLinearVelocityWorld(self, collector)

    def calc(self, data: Any, x: np.ndarray, u: np.ndarray | None = None) -> None:
        # The differential model has run forward kinematics with (q, v) in the shared data.
        data.r[:] = pin.getFrameVelocity(
            self._pin_model, data.shared_pin, self._frame_id, pin.LOCAL_WORLD_ALIGNED
        ).linear

    def calcDiff(  # noqa: N802 (crocoddyl API)
        self, data: Any, x: np.ndarray, u: np.ndarray | None = None
    ) -> None:
        model, pd, fid, nv = self._pin_model, data.pin_data, self._frame_id, self._nv
        q, v = x[: self._nq], x[self._nq :]
        pin.computeForwardKinematicsDerivatives(model, pd, q, v, self._zero_a)
        dv_dq, dv_dv = pin.getFrameVelocityDerivatives(model, pd, fid, pin.LOCAL)
        rotation = pin.updateFramePlacement(model, pd, fid).rotation
        v_local = pin.getFrameVelocity(model, pd, fid, pin.LOCAL).linear
        data.Rx[:, :nv] = rotation @ (dv_dq[:3] - pin.skew(v_local) @ dv_dv[3:])
        data.Rx[:, nv:] = rotation @ dv_dv[:3]


class ResidualDataFrameLinearVelocityWorld(crocoddyl.ResidualDataAbstract):
    """Workspace of :class:`ResidualModelFrameLinearVelocityWorld` (private pinocchio data)."""

    def __init__(self, model: ResidualModelFrameLinearVelocityWorld, collector: Any) -> None:
        super().__init__(model, collector)
        self.shared_pin = collector.pinocchio
        self.pin_data = model._pin_model.createData()


def _quad(weights: np.ndarray) -> crocoddyl.ActivationModelWeightedQuad:
    return crocoddyl.ActivationModelWeightedQuad(np.asarray(weights, dtype=float))


def make_state_limit_cost(
    state: crocoddyl.StateMultibody, robot: RobotModel, weights: CostWeights
) -> crocoddyl.CostModelResidual:
    """The joint-limit barrier on x = (q, v) (rad, rad/s): crocoddyl's ``ResidualModelState``
    (r = x ⊖ 0 = x for these arms' revolute joints) under ``ActivationModelQuadraticBarrier``
    with the bounds of ``robot.state_limit_bounds(weights.state_limit_fraction)``. Its cost is
    ½·Σ (r_i − clip(r_i, lb_i, ub_i))² (times c_lim = ``weights.state_limit`` in the cost sum):
    zero inside the bounds, quadratic in the excess outside."""
    lower, upper = robot.state_limit_bounds(weights.state_limit_fraction)
    residual = crocoddyl.ResidualModelState(state, state.zero(), state.nv)
    activation = crocoddyl.ActivationModelQuadraticBarrier(crocoddyl.ActivationBounds(lower, upper))
    return crocoddyl.CostModelResidual(state, activation, residual)


def make_costs(
    state: crocoddyl.StateMultibody,
    robot: RobotModel,
    contact: ContactConfig,
    weights: CostWeights,
    *,
    in_contact: bool,
    terminal: bool,
    q_reference: np.ndarray,
    builtin_residuals: bool = False,
    backend: str = DEFAULT_BACKEND,
    terminal_torque: bool = False,
) -> crocoddyl.CostModelSum:
    """The cost ℓ0 of eq 25 (running) or its state terms (terminal), see the module docstring.

    The references start at p̄ = p(q̄), λ̄ = 0; the weights at ``weights`` (c4, c6 are then set
    per node by :meth:`CommonCostHandles.apply`). ``backend``: C++ (``"native"``) or Python
    (``"python"``) custom residuals (module docstring).

    ``builtin_residuals=True`` uses crocoddyl's own ``ResidualModelContactControlGrav`` for eq 25.3
    in contact: all-C++, but in crocoddyl 3.2.1 it ignores the contact force (τ − g(q)). It
    exists only as the speed reference of ``ffmpc bench mpc``; never control with it.

    Beyond eq 25 (the authors' polishing configurations): ``weights.ee_rotation`` > 0 adds
    c·½·‖log(R̄ᵀR(q))‖² (R̄ = the contact frame's orientation at q̄), ``weights.ee_angular_velocity``
    > 0 adds c·½·‖ω‖² (the frame's angular velocity in its own axes), in running and terminal
    nodes. ``terminal_torque`` (a terminal node of the torque-feedback model) with
    ``weights.lowpass_terminal_torque`` > 0 adds c·½·‖u − g(q)‖²_Q3 to the terminal costs: the
    low-pass integrator evaluates it at u = τ, the filtered torque of its state.
    """
    nv, nu, fid = state.nv, state.nv, robot.contact_frame_id
    native = native_module() if check_backend(backend) else None
    costs = crocoddyl.CostModelSum(state, nu)
    x_reference = np.concatenate([q_reference, np.zeros(nv)])
    zeros = np.zeros(nv)

    posture = crocoddyl.ResidualModelState(state, x_reference, nu)
    act = _quad(np.concatenate([weights.diag("posture", nv), zeros]))
    costs.addCost(COST_POSTURE, crocoddyl.CostModelResidual(state, act, posture), weights.posture)

    velocity = crocoddyl.ResidualModelState(state, x_reference, nu)
    act = _quad(np.concatenate([zeros, weights.diag("joint_velocity", nv)]))
    costs.addCost(
        COST_JOINT_VELOCITY,
        crocoddyl.CostModelResidual(state, act, velocity),
        weights.joint_velocity,
    )

    p_reference = robot.contact_placement(q_reference).translation
    ee = crocoddyl.ResidualModelFrameTranslation(state, fid, p_reference, nu)
    act = _quad(weights.diag("ee_position", 3))
    costs.addCost(
        COST_EE_POSITION, crocoddyl.CostModelResidual(state, act, ee), weights.ee_position
    )

    q5 = weights.diag("ee_velocity", 3)
    if np.all(q5 == q5[0]):  # isotropic: ‖R·v_l‖ = ‖v_l‖, use crocoddyl's exact LOCAL residual
        ee_vel = crocoddyl.ResidualModelFrameVelocity(state, fid, pin.Motion.Zero(), pin.LOCAL, nu)
        act = _quad(np.concatenate([q5, np.zeros(3)]))
    else:
        world_velocity = (
            ResidualModelFrameLinearVelocityWorld
            if native is None
            else native.ResidualModelFrameLinearVelocityWorld
        )
        ee_vel = world_velocity(state, fid, nu)
        act = _quad(q5)
    costs.addCost(
        COST_EE_VELOCITY, crocoddyl.CostModelResidual(state, act, ee_vel), weights.ee_velocity
    )

    if weights.ee_rotation > 0.0:
        rotation = crocoddyl.ResidualModelFrameRotation(
            state, fid, robot.contact_placement(q_reference).rotation, nu
        )
        costs.addCost(
            COST_EE_ROTATION,
            crocoddyl.CostModelResidual(state, _quad(np.ones(3)), rotation),
            weights.ee_rotation,
        )
    if weights.ee_angular_velocity > 0.0:
        angular = crocoddyl.ResidualModelFrameVelocity(state, fid, pin.Motion.Zero(), pin.LOCAL, nu)
        act = _quad(np.concatenate([np.zeros(3), np.ones(3)]))
        costs.addCost(
            COST_EE_ANGULAR_VELOCITY,
            crocoddyl.CostModelResidual(state, act, angular),
            weights.ee_angular_velocity,
        )

    costs.addCost(
        COST_STATE_LIMIT, make_state_limit_cost(state, robot, weights), weights.state_limit
    )

    if terminal:
        if terminal_torque and weights.lowpass_terminal_torque > 0.0:
            torque = crocoddyl.ResidualModelControlGrav(state, nu)
            act = _quad(weights.diag("torque", nv))
            costs.addCost(
                COST_TORQUE,
                crocoddyl.CostModelResidual(state, act, torque),
                weights.lowpass_terminal_torque,
            )
        return costs

    if in_contact and builtin_residuals:
        torque = crocoddyl.ResidualModelContactControlGrav(state, nu)
    elif in_contact:
        world_aligned = contact.pin_frame == pin.LOCAL_WORLD_ALIGNED
        if native is None:
            torque = ResidualModelContactGravityTorque(state, nu, world_aligned)
        else:
            torque = native.ResidualModelContactGravityTorque(
                state, nu, world_aligned, CONTACT_NAME
            )
    else:
        torque = crocoddyl.ResidualModelControlGrav(state, nu)
    act = _quad(weights.diag("torque", nv))
    costs.addCost(COST_TORQUE, crocoddyl.CostModelResidual(state, act, torque), weights.torque)

    if in_contact:
        nc = contact.dimension
        force = crocoddyl.ResidualModelContactForce(state, fid, pin.Force.Zero(), nc, nu, True)
        act = _quad(weights.diag("force", nc))
        costs.addCost(COST_FORCE, crocoddyl.CostModelResidual(state, act, force), weights.force)
    return costs


class ResidualModelConstraintRows(crocoddyl.ResidualModelAbstract):
    """The hard-constraint rows of a classical node as a crocoddyl residual (issue 23):
    r = [S·x; c ∘ u] (:class:`ffmpc_core.constraints.ConstraintRows`; the control rows in a
    running node only), each row a fraction of its limit; Rx = [S; 0], Ru = [0; diag(c)].
    ``ffmpc_core._native.ResidualModelConstraintRows`` is its C++ port."""

    def __init__(
        self,
        state: crocoddyl.StateAbstract,
        nu: int,
        state_matrix: np.ndarray,
        control_scale: np.ndarray,
        control: bool,
    ) -> None:
        rows = ConstraintRows(state_matrix, control_scale, state.nx, nu, control)
        if rows.n_state == 0:
            raise ConfigError("ResidualModelConstraintRows: the constraint matrix has no rows")
        super().__init__(state, rows.ng, nu, True, True, rows.control)
        self.rows = rows

    def calc(self, data: Any, x: np.ndarray, u: np.ndarray | None = None) -> None:
        self.rows.calc(data.r, x, u)

    def calcDiff(  # noqa: N802 (crocoddyl API)
        self, data: Any, x: np.ndarray, u: np.ndarray | None = None
    ) -> None:
        self.rows.calc_diff(data.Rx, data.Ru)


def make_constraints(
    state: crocoddyl.StateMultibody, bounds: OcpBounds, terminal: bool, backend: str
) -> crocoddyl.ConstraintModelManager:
    """The hard constraints of a classical node (issue 23, :mod:`ffmpc_core.constraints`): one
    crocoddyl ``ConstraintModelResidual`` over :class:`ResidualModelConstraintRows` (its C++
    port for ``backend="native"``) — the box on x = (q, v) and, in a running node, on the
    torque u — with ``bounds``' bounds; a terminal node's rows are its state's only."""
    nu = state.nv
    args = (state, nu, bounds.state_matrix, bounds.control_scale, not terminal)
    if check_backend(backend):
        residual = native_module().ResidualModelConstraintRows(*args)
    else:
        residual = ResidualModelConstraintRows(*args)
    lower, upper = bounds.bounds(terminal)
    manager = crocoddyl.ConstraintModelManager(state, nu)
    manager.addConstraint(
        CONSTRAINT_LIMITS,
        crocoddyl.ConstraintModelResidual(state, residual, lower, upper, terminal),
    )
    return manager


def make_differential_model(
    robot: RobotModel,
    contact: ContactConfig,
    weights: CostWeights,
    *,
    in_contact: bool,
    terminal: bool,
    q_reference: np.ndarray | None = None,
    baumgarte_velocity_gain: float | None = None,
    builtin_residuals: bool = False,
    backend: str = DEFAULT_BACKEND,
    terminal_torque: bool = False,
    bounds: OcpBounds | None = None,
) -> crocoddyl.DifferentialActionModelAbstract:
    """Continuous dynamics (eq 5–6; free dynamics when not in contact) with the cost ℓ0.

    Control: joint torque τ, N·m (full actuation). A terminal model has the state terms only
    and free dynamics (a terminal node has no dynamics). ``backend``, ``terminal_torque``: see
    :func:`make_costs`. ``baumgarte_velocity_gain``: K_d, 1/s (None: ``contact``'s).
    ``bounds``: the hard constraints of the classical formulation (:func:`make_constraints`;
    None: none). The torque-feedback model keeps its constraints in its integrator instead.
    """
    if baumgarte_velocity_gain is None:
        baumgarte_velocity_gain = contact.baumgarte_velocity_gain
    q_reference = _check_posture(robot, robot.q_nominal if q_reference is None else q_reference)
    state = crocoddyl.StateMultibody(robot.model)
    actuation = crocoddyl.ActuationModelFull(state)
    in_contact = bool(in_contact) and not terminal
    costs = make_costs(
        state,
        robot,
        contact,
        weights,
        in_contact=in_contact,
        terminal=terminal,
        q_reference=q_reference,
        builtin_residuals=builtin_residuals,
        backend=backend,
        terminal_torque=terminal_torque,
    )
    constraints = None if bounds is None else make_constraints(state, bounds, terminal, backend)
    if not in_contact:
        if constraints is None:
            return crocoddyl.DifferentialActionModelFreeFwdDynamics(state, actuation, costs)
        return crocoddyl.DifferentialActionModelFreeFwdDynamics(
            state, actuation, costs, constraints
        )
    contacts = make_contact_model(
        state, robot.contact_frame_id, contact, actuation.nu, baumgarte_velocity_gain
    )
    if constraints is None:
        return crocoddyl.DifferentialActionModelContactFwdDynamics(
            state, actuation, contacts, costs, 0.0, True
        )
    return crocoddyl.DifferentialActionModelContactFwdDynamics(
        state, actuation, contacts, costs, constraints, 0.0, True
    )


def _check_posture(robot: RobotModel, q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, dtype=float)
    if q.shape != (robot.nq,) or not np.all(np.isfinite(q)):
        raise InputError(f"posture reference must be {robot.nq} finite values (rad), got {q!r}")
    return q.copy()


def _is_finite_vector(value: npt.ArrayLike, n: int) -> bool:
    arr = np.asarray(value, dtype=float)
    return arr.shape == (n,) and bool(np.isfinite(arr).all())


def check_node_reference(ref: NodeReference, contact: ContactConfig, nq: int) -> None:
    """Raise :class:`InputError` unless ``ref`` has the right sizes and finite, valid values."""
    if not _is_finite_vector(ref.ee_position, 3):
        raise InputError(f"ee_position must be 3 finite values (m), got {ref.ee_position!r}")
    if not _is_finite_vector(ref.force, contact.dimension):
        raise InputError(f"force must be {contact.dimension} finite values (N), got {ref.force!r}")
    for name in ("ee_position_weight", "force_weight"):
        w = getattr(ref, name)
        if not math.isfinite(w) or w < 0:
            raise InputError(f"{name} must be finite and >= 0, got {w!r}")
    if ref.posture is not None and not _is_finite_vector(ref.posture, nq):
        raise InputError(f"posture must be {nq} finite values (rad), got {ref.posture!r}")
    d = ref.ee_position_diag
    if d is not None and (not _is_finite_vector(d, 3) or bool((np.asarray(d) < 0).any())):
        raise InputError(f"ee_position_diag must be 3 finite values >= 0, got {d!r}")


class CommonCostHandles:
    """Handles on the per-node references of ℓ0 in one differential model: p̄, c4, Q4, λ̄, c6, q̄.

    Q4 (the activation of the end-effector position cost) is changed in place on the crocoddyl
    ``ActivationModelWeightedQuad``. crocoddyl 3.2.1 copies the new weights into the Hessian of
    the activation data at the next ``calcDiff`` of ONE data only (a flag of the model), so a
    model must have a single data alive when its Q4 changes — as in the MPC's shooting problem,
    where each node model has exactly one; data created after the change are always right.
    """

    def __init__(
        self,
        differential: crocoddyl.DifferentialActionModelAbstract,
        nv: int,
        ee_position_diag: np.ndarray,
    ) -> None:
        costs = differential.costs.costs
        self._nv = nv
        self._posture = costs[COST_POSTURE].cost.residual
        self._ee_item = costs[COST_EE_POSITION]
        self._ee_residual = self._ee_item.cost.residual
        self._ee_activation = self._ee_item.cost.activation
        self._default_ee_diag = np.array(ee_position_diag, dtype=float)
        self._ee_diag = self._default_ee_diag.copy()  # what the activation holds now
        self._force_item = costs[COST_FORCE] if COST_FORCE in costs else None
        self._force_residual = None if self._force_item is None else self._force_item.cost.residual
        self._force_linear = np.zeros(3)  # what the force residual's reference holds now
        self._c4 = float(self._ee_item.weight)
        self._c6 = None if self._force_item is None else float(self._force_item.weight)
        self._zero3 = np.zeros(3)
        self._x_reference = np.zeros(2 * nv)

    def apply(self, ref: NodeReference) -> None:
        """Copy the references of ``ref`` into the cost model (in place; validated before).

        ``ref.ee_position_diag`` None restores ``CostWeights.ee_position_diag``.
        """
        self._ee_residual.reference = np.asarray(ref.ee_position, dtype=float)
        # Weights and the force reference are written only when they change (phase switches,
        # the force ramp): each write crosses into crocoddyl.
        c4 = float(ref.ee_position_weight)
        if c4 != self._c4:
            self._ee_item.weight = self._c4 = c4
        diag = self._default_ee_diag if ref.ee_position_diag is None else ref.ee_position_diag
        if (self._ee_diag != diag).any():
            self._ee_diag[:] = diag
            self._ee_activation.weights = self._ee_diag
        if self._force_item is not None and self._force_residual is not None:
            f = np.asarray(ref.force, dtype=float)
            linear = self._force_linear
            if f.size == 1:
                changed = linear[2] != f[0]
                linear[2] = f[0]
            else:
                changed = bool((linear != f).any())
                linear[:] = f
            if changed:
                self._force_residual.reference = pin.Force(linear, self._zero3)
            c6 = float(ref.force_weight)
            if c6 != self._c6:
                self._force_item.weight = self._c6 = c6
        if ref.posture is not None:
            self._x_reference[: self._nv] = ref.posture
            self._posture.reference = self._x_reference


def rigid_contact_force(
    differential_data: crocoddyl.DifferentialActionDataAbstract, contact: ContactConfig
) -> np.ndarray:
    """λ^r(x, u) of eq 5b (the dual of eq 4) after the differential model's calc, N.

    In the contact's frame (along its axis for 1-D); zeros for free dynamics.
    """
    if isinstance(differential_data, crocoddyl.DifferentialActionDataContactFwdDynamics):
        return np.array(differential_data.pinocchio.lambda_c, dtype=float).reshape(
            contact.dimension
        )
    if isinstance(differential_data, crocoddyl.DifferentialActionDataFreeFwdDynamics):
        return np.zeros(contact.dimension)
    raise ModelError(f"not a rigid-contact or free differential data: {type(differential_data)}")


class SwitchableContactNode:
    """``set_reference`` of the nodes that hold a free and an in-contact model (classical and
    torque-feedback): attributes ``robot``, ``contact``, ``terminal``, ``in_contact``, ``model``,
    ``_models`` {bool: model} and ``_handles`` {bool: cost handles of that model}."""

    # Declared for the type checker; each subclass sets them in its __init__.
    robot: RobotModel
    contact: ContactConfig
    terminal: bool
    in_contact: bool
    model: crocoddyl.ActionModelAbstract
    _models: dict[bool, crocoddyl.ActionModelAbstract]
    _handles: dict[bool, CommonCostHandles]

    def set_reference(self, ref: NodeReference) -> bool:
        """Select contact/free dynamics and update its p̄, λ̄, c4, Q4, c6 (and q̄) in place.

        Only the selected model's costs are written (the other one gets them when it is
        selected again). Returns True iff ``model`` is now a different object: the caller must
        then call ``problem.updateModel(k, node.model)``. A terminal node never switches.
        """
        check_node_reference(ref, self.contact, self.robot.nq)
        status = False if self.terminal else bool(ref.in_contact)
        self._handles[status].apply(ref)
        if status == self.in_contact:
            return False
        self.in_contact = status
        self.model = self._models[status]
        return True


class RigidContactNode(SwitchableContactNode):
    """One node of the classical OCP (Sec. III-C) with switchable contact.

    Attributes:
        model: the crocoddyl action model to put in the ``ShootingProblem`` (an
            ``IntegratedActionModelEuler``, eq 8).
        in_contact: whether ``model`` has the rigid contact (always False for a terminal node,
            which has no dynamics).
        terminal: whether this is the terminal node (state costs only, not × Δt).
        dt: integration step Δt, s.
        contact: the contact configuration.
        backend: ``"native"`` or ``"python"`` custom residuals (module docstring).
    """

    def __init__(
        self,
        robot: RobotModel,
        contact: ContactConfig,
        weights: CostWeights,
        dt: float,
        terminal: bool,
        q_reference: np.ndarray | None,
        in_contact: bool,
        baumgarte_velocity_gain: float | None,
        builtin_residuals: bool = False,
        backend: str = DEFAULT_BACKEND,
        bounds: OcpBounds | None = None,
    ) -> None:
        if not np.isfinite(dt) or dt <= 0:
            raise ConfigError(f"dt must be > 0 s, got {dt}")
        check_backend(backend)
        self.backend = backend
        self.bounds = bounds
        self.robot = robot
        self.contact = contact
        self.dt = float(dt)
        self.terminal = bool(terminal)
        kwargs: dict[str, Any] = dict(
            q_reference=q_reference,
            baumgarte_velocity_gain=baumgarte_velocity_gain,
            builtin_residuals=builtin_residuals,
            backend=backend,
            bounds=bounds,
        )
        self._models: dict[bool, crocoddyl.IntegratedActionModelEuler] = {}
        self._handles: dict[bool, CommonCostHandles] = {}
        for status in (False,) if self.terminal else (False, True):
            dam = make_differential_model(
                robot, contact, weights, in_contact=status, terminal=self.terminal, **kwargs
            )
            self._models[status] = crocoddyl.IntegratedActionModelEuler(dam, self.dt)
            self._handles[status] = CommonCostHandles(dam, robot.nv, weights.diag("ee_position", 3))
        self.in_contact = bool(in_contact) and not self.terminal
        self.model = self._models[self.in_contact]

    def contact_force(self, data: crocoddyl.ActionDataAbstract) -> np.ndarray:
        """λ^r of this node (eq 8b) from ``data`` (created by ``model``) after calc, N."""
        return rigid_contact_force(data.differential, self.contact)

    def set_state_bounds(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Bounds of the state rows on x = (q, v) (``bounds.n_state_rows`` each, fractions of
        the limits; ±inf: none) in both models (contact and free); the torque rows keep
        ``bounds``'. ModelError without constraints."""
        if self.bounds is None:
            raise ModelError("this node has no constraints")
        lb, ub = self.bounds.bounds(self.terminal, lower, upper)
        for model in self._models.values():
            item = model.differential.constraints.constraints[CONSTRAINT_LIMITS]
            item.constraint.updateBounds(lb, ub)


def make_rigid_contact_node(
    robot: RobotModel,
    contact: ContactConfig,
    weights: CostWeights,
    dt: float,
    terminal: bool,
    q_reference: np.ndarray | None = None,
    *,
    in_contact: bool = False,
    baumgarte_velocity_gain: float | None = None,
    builtin_residuals: bool = False,
    backend: str = DEFAULT_BACKEND,
    bounds: OcpBounds | None = None,
) -> RigidContactNode:
    """Build a node of the classical OCP (eq 5–8, cost eq 27); see :class:`RigidContactNode`.

    Args:
        robot: the arm; the contact is at its ``contact`` frame.
        contact: 1-D/3-D, frame type and axis (stiffness/damping are not used here).
        weights: c1…c6 and Q1…Q6 of eq 25.
        dt: Δt of the semi-implicit Euler step (eq 8), s.
        terminal: terminal node (state terms only, no Δt factor).
        q_reference: q̄ of eq 25.1, rad (default: ``robot.q_nominal``).
        in_contact: initial dynamics (switch later with ``set_reference``).
        baumgarte_velocity_gain: K_d, 1/s (module docstring; None: ``contact``'s).
        builtin_residuals: benchmark reference only (see :func:`make_costs`).
        backend: ``"native"`` (C++ custom residuals) or ``"python"`` (module docstring).
        bounds: the hard constraints (:func:`ffmpc_core.constraints.ocp_bounds` of the
            classical formulation, :func:`make_constraints`; None: none).
    """
    return RigidContactNode(
        robot,
        contact,
        weights,
        dt,
        terminal,
        q_reference,
        in_contact,
        baumgarte_velocity_gain,
        builtin_residuals,
        backend,
        bounds,
    )
