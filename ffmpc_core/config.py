"""Configuration shared by the three OCP formulations: cost weights, contact model, node references.

Cost convention (crocoddyl's): a term with weight ``c`` and diagonal activation ``Q`` costs
``c · ½ · Σ Q_i r_i²``. Running costs are multiplied by the node's Δt (as crocoddyl's Euler
integrator does); the terminal node keeps only the state terms, not multiplied by Δt.

Force convention: λ is the force the environment exerts on the robot at the contact point, in N.
In the paper's 1-D setting it is the component along the world z axis of the frame centred at the
contact point with world-aligned axes (pinocchio ``LOCAL_WORLD_ALIGNED``); pushing down on a
horizontal table gives λ > 0. The controllers never know the table's true tilt.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError

FORMULATIONS = ("classical", "torque_feedback", "force_feedback")
#: The torque q̈ of a torque-feedback node is computed at (OcpConfig.torque_integration).
TORQUE_INTEGRATIONS = ("current", "next")
#: Implementations of the project's own action models: C++ (ffmpc_core.native) or the Python
#: reference (MpcConfig.backend, scenario mpc.backend).
BACKENDS = ("native", "python")
#: The τ entry of the torque-feedback MPC's state (MpcConfig.torque_state, scenario
#: mpc.torque_state): the measured joint torque τ̂ (eq 10/15) or the last torque sent.
TORQUE_STATES = ("measured", "commanded")
_FRAME_TYPES = {
    "LOCAL_WORLD_ALIGNED": pin.ReferenceFrame.LOCAL_WORLD_ALIGNED,
    "LOCAL": pin.ReferenceFrame.LOCAL,
}


def _diag(values: npt.ArrayLike, n: int, name: str) -> np.ndarray:
    try:
        arr = np.broadcast_to(np.asarray(values, dtype=float), (n,)).copy()
    except ValueError:
        raise ConfigError(f"{name} must be a scalar or have {n} entries, got {values!r}") from None
    if np.any(arr < 0) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite and non-negative, got {arr}")
    return arr


@dataclass(frozen=True)
class CostWeights:
    """Weights of the common cost ℓ0 (eq 25.1–25.6) and of the formulation-specific terms.

    Each ``c_*`` is a scalar weight; each ``*_diag`` is the diagonal of the activation ``Q_i``
    (a scalar broadcasts to every entry).
    """

    posture: float = 1e-2  # c1 on ‖q − q̄‖², 1/rad² (eq 25.1)
    posture_diag: tuple[float, ...] | float = 1.0
    joint_velocity: float = 1e-2  # c2 on ‖q̇‖², s²/rad² (eq 25.2)
    joint_velocity_diag: tuple[float, ...] | float = 1.0
    torque: float = 1e-4  # c3 on ‖τ − τ_g(q, λ)‖², 1/(N·m)² (eq 25.3)
    torque_diag: tuple[float, ...] | float = 1.0
    ee_position: float = 1e2  # c4 on ‖p(q) − p̄(t)‖², 1/m² (eq 25.4); per node from the task
    ee_position_diag: tuple[float, ...] | float = 1.0
    ee_velocity: float = 1.0  # c5 on ‖ṗ(q, q̇)‖² (linear, world-aligned), s²/m² (eq 25.5)
    ee_velocity_diag: tuple[float, ...] | float = 1.0
    force: float = 1e-2  # c6 on ‖λ − λ̄(t)‖², 1/N² (eq 25.6); per node from the task
    force_diag: tuple[float, ...] | float = 1.0
    lowpass_input: float = 1e-4  # c_w on ‖w − τ_g(q, λ)‖², 1/(N·m)² (eq 28, torque-feedback)
    force_rate: float = 1e-6  # c_λ on ‖λ̇‖², s²/N² (eq 29, force-feedback)
    #: c on ‖log(R̄ᵀR(q))‖² (rad², R̄: the contact frame's orientation at q̄), 1/rad²: the
    #: orientation cost of the authors' polishing configurations (``frameRotation``), not in
    #: eq 25. All three formulations (running and terminal nodes; 0: no term).
    ee_rotation: float = 0.0
    #: c on ‖ω‖² (the contact frame's angular velocity, its own axes), s²/rad²: with
    #: ``ee_velocity`` it makes the 6-D end-effector velocity cost of the authors'
    #: configurations (``frameVelocity``, all six axes). All three formulations.
    ee_angular_velocity: float = 0.0
    #: c3 of ‖τ − g(q)‖² (activation ``torque_diag``) at the torque-feedback model's TERMINAL
    #: node, on the filtered torque τ of its state (not × Δt), 1/(N·m)²; 0: the terminal node
    #: has no torque term. Default: the authors' ``ctrlRegGravWeightTerminal`` (1e-4).
    lowpass_terminal_torque: float = 1e-4
    #: c_lim of the joint-limit barrier on x = (q, v): c_lim·½·‖x − clip(x, x_lb, x_ub)‖², zero
    #: inside the bounds, quadratic outside (1/rad² on the position excess, s²/rad² on the
    #: velocity excess). Every formulation has it (running and terminal nodes); the bounds are
    #: ``RobotModel.state_limit_bounds(state_limit_fraction)``. The node-graph scenario files set
    #: it per formulation (classical 1, torque-feedback 100, force-feedback 0.01: README).
    state_limit: float = 1e-2
    #: Fraction of the limits inside which the barrier is zero: |v| ≤ fraction·velocity_limit
    #: (rad/s), q within fraction of the position range about its middle (rad; joints with finite
    #: position limits only). In (0, 1].
    state_limit_fraction: float = 0.9

    def diag(self, name: str, n: int) -> np.ndarray:
        """The activation diagonal of term ``name`` (e.g. ``"posture"``) as an array of size n."""
        return _diag(getattr(self, f"{name}_diag"), n, f"{name}_diag")

    def with_(self, **changes: Any) -> CostWeights:
        """A copy with the named weights changed (``weights.with_(force=10.0)``)."""
        return replace(self, **changes)


#: The :class:`CostWeights` scalars c that a running MPC changes in place
#: (``ModelPredictiveController.set_cost_weight``; the MPC node's live parameters). Not c4, c6
#: (the task sets them per node) nor c_w (built into the low-pass integrator).
LIVE_COST_WEIGHTS = ("posture", "joint_velocity", "torque", "ee_velocity", "force_rate")


@dataclass(frozen=True)
class OcpConfig:
    """The optimal control problem an MPC solves and how often and how far it solves it (paper
    VI-B3 and VII-A4 defaults). :class:`~ffmpc_core.mpc.MpcConfig` holds it (``ocp``); the
    scenario's ``mpc`` section holds it too (``mpc.formulation``, ``mpc.horizon``, …).

    Attributes:
        formulation: ``"classical"``, ``"torque_feedback"`` or ``"force_feedback"``.
        horizon: number of OCP nodes N (paper: 5).
        dt: OCP node duration Δt, s (paper: 3 ms).
        period: re-planning period of the MPC, s (paper: 500 Hz → 2 ms).
        max_iterations: SQP iterations per solve (paper: 8).
        kkt_tolerance: SQP termination tolerance on the KKT residual (paper: 1e-4).
        cutoff_frequency: low-pass actuation cut-off f_c, Hz (torque-feedback; paper: 50 Hz).
        torque_integration: the torque q̈ of a torque-feedback node is computed at:
            ``"current"``, the node's filtered torque τ (eq 14a, the paper), or ``"next"``,
            τ⁺ = α·τ + (1 − α)·w (the authors' ``tau_plus_integration``), with which the MPC
            sends τ₁* (ε = 1 in eq 15: τ₁* is the torque its plan applies from now on).
            :func:`ffmpc_core.lowpass.applied_torque_gains`.
    """

    formulation: str = param("force_feedback", "", list(FORMULATIONS), "OCP formulation")
    horizon: int = param(5, "nodes", (1, 1000), "OCP nodes N")
    dt: float = param(0.003, "s", (1e-5, 1.0), "OCP node duration")
    period: float = param(
        0.002, "s", (1e-5, 1.0), "re-planning period (a multiple of plant.time_step)"
    )
    max_iterations: int = param(8, "", (1, 1000), "SQP iterations per solve")
    kkt_tolerance: float = param(1e-4, "", (1e-12, 1.0), "SQP KKT tolerance")
    cutoff_frequency: float = param(50.0, "Hz", (1e-3, 1e4), "low-pass actuation cut-off f_c")
    torque_integration: str = param(
        "current",
        "",
        list(TORQUE_INTEGRATIONS),
        "torque-feedback q̈ at the state's τ (current, eq 14a) or at τ⁺ (next, tau_plus)",
    )

    def __post_init__(self) -> None:
        if self.formulation not in FORMULATIONS:
            raise ConfigError(
                f"formulation must be one of {FORMULATIONS}, got {self.formulation!r}"
            )
        if self.horizon < 1 or self.dt <= 0 or self.period <= 0:
            raise ConfigError("horizon must be >= 1 and dt, period > 0")
        if self.cutoff_frequency <= 0 or self.max_iterations < 1 or self.kkt_tolerance <= 0:
            raise ConfigError("cutoff_frequency, max_iterations, kkt_tolerance must be > 0")
        if self.torque_integration not in TORQUE_INTEGRATIONS:
            raise ConfigError(
                f"torque_integration must be one of {TORQUE_INTEGRATIONS}, "
                f"got {self.torque_integration!r}"
            )


@dataclass(frozen=True)
class ContactConfig:
    """The contact model the OCP assumes at the robot's ``contact`` frame.

    Attributes:
        dimension: 1 (normal force only, the paper's polishing setting) or 3.
        frame_type: ``"LOCAL_WORLD_ALIGNED"`` (origin at the contact point, world axes; the paper's
            setting) or ``"LOCAL"`` (the contact frame's own axes).
        normal_axis: for 1-D contact, the axis (0=x, 1=y, 2=z) of that frame carrying the force.
        stiffness: K of the visco-elastic model (eq 16), N/m, scalar or one per force axis.
        damping: B of the visco-elastic model (eq 16), N·s/m, scalar or one per force axis.
        baumgarte_velocity_gain: K_d of the rigid contact models, 1/s (not used by the
            visco-elastic one).
        friction_coefficient: Coulomb friction coefficient μ of the surface along its plane,
            which the δo predictor applies (:mod:`ffmpc_core.contact_friction`); 0 = the
            paper's pure sliding contact. The OCPs never model it.
        friction_velocity: v_s of that friction's tanh, m/s.
        friction_in_measured_force: the force-feedback MPC removes that friction's share along
            the assumed normal from the measured normal force (a tilted surface).
        sliding_filter_time, sliding_min_speed: the sliding direction's filter time constant
            (s) and the speed from which that correction applies (m/s).
    """

    dimension: int = param(1, "", [1, 3], "contact force entries: 1 (normal) or 3")
    frame_type: str = param(
        "LOCAL_WORLD_ALIGNED", "", ["LOCAL_WORLD_ALIGNED", "LOCAL"], "frame of the force"
    )
    normal_axis: int = param(2, "", [0, 1, 2], "axis of the 1-D force: 0 x, 1 y, 2 z")
    stiffness: float | tuple[float, ...] = param(
        1e3, "N/m", (0.0, 1e9), "K of the visco-elastic contact (eq 16)"
    )
    damping: float | tuple[float, ...] = param(
        1e2, "N·s/m", (0.0, 1e6), "B of the visco-elastic contact (eq 16)"
    )
    #: K_d of the rigid contact's Baumgarte stabilisation (classical and torque-feedback), 1/s:
    #: the contact acceleration constraint is a_c + K_d·v_c = 0. The authors' code uses 10.
    baumgarte_velocity_gain: float = param(
        50.0,
        "1/s",
        (0.0, 1e4),
        "K_d of the rigid contact's Baumgarte stabilisation (classical, torque-feedback)",
    )
    friction_coefficient: float = param(
        0.0,
        "",
        (0.0, 10.0),
        "Coulomb friction μ of the surface in the δo predictor (0: the paper's sliding contact)",
    )
    friction_velocity: float = param(0.01, "m/s", (1e-6, 10.0), "v_s of that friction's tanh")
    #: The force-feedback MPC's measured normal force without the friction's share: on a
    #: surface tilted away from the assumed normal the Coulomb drag (μ =
    #: ``friction_coefficient``) has a part along that normal, which the 1-D force state would
    #: take for pressing (:func:`ffmpc_core.contact_friction.normal_force_without_friction`;
    #: measured in docs/results/paper.md). The normal entry of the force (1-D or 3-D contact).
    friction_in_measured_force: bool = param(
        False, "", None, "remove the friction drag's share from the measured normal force (FF)"
    )
    #: Time constant of the sliding velocity's low-pass filter for that correction, s
    #: (:class:`ffmpc_core.contact_friction.SlidingDirectionEstimator`).
    sliding_filter_time: float = param(
        0.02, "s", (0.0, 10.0), "low-pass time constant of the sliding direction"
    )
    #: Filtered sliding speed below which the correction is off (direction unknown), m/s.
    sliding_min_speed: float = param(
        0.05, "m/s", (1e-6, 10.0), "sliding speed from which the friction correction applies"
    )

    def __post_init__(self) -> None:
        if self.dimension not in (1, 3):
            raise ConfigError(f"contact dimension must be 1 or 3, got {self.dimension}")
        if self.frame_type not in _FRAME_TYPES:
            raise ConfigError(f"frame_type must be one of {tuple(_FRAME_TYPES)}")
        if self.normal_axis not in (0, 1, 2):
            raise ConfigError("normal_axis must be 0, 1 or 2")

        self.stiffness_vector()
        self.damping_vector()
        kd = float(self.baumgarte_velocity_gain)
        if not (np.isfinite(kd) and kd >= 0.0):
            raise ConfigError(f"baumgarte_velocity_gain must be finite and >= 0 1/s, got {kd}")
        mu, vs = float(self.friction_coefficient), float(self.friction_velocity)
        if not (np.isfinite(mu) and mu >= 0.0):
            raise ConfigError(f"friction_coefficient must be finite and >= 0, got {mu}")
        if not (np.isfinite(vs) and vs > 0.0):
            raise ConfigError(f"friction_velocity must be finite and > 0 m/s, got {vs}")

    @property
    def pin_frame(self) -> pin.ReferenceFrame:
        """``frame_type`` as pinocchio's reference frame (``LOCAL`` or ``LOCAL_WORLD_ALIGNED``)."""
        return _FRAME_TYPES[self.frame_type]

    def stiffness_vector(self) -> np.ndarray:
        """K as a vector of size ``dimension``, N/m."""
        return _diag(self.stiffness, self.dimension, "stiffness")

    def damping_vector(self) -> np.ndarray:
        """B as a vector of size ``dimension``, N·s/m."""
        return _diag(self.damping, self.dimension, "damping")


@dataclass
class NodeReference:
    """What the task asks of one OCP node (one instant of the horizon).

    Attributes:
        ee_position: p̄(t), desired contact-frame position, m, world frame.
        force: λ̄(t), desired contact force, N, ``dimension`` entries (see module docstring).
        ee_position_weight: c4 for this node (the task phases change it).
        force_weight: c6 for this node.
        in_contact: whether the model of this node has the contact (rigid for classical and
            torque-feedback; visco-elastic for force-feedback, whose K and B are zeroed otherwise).
    """

    ee_position: np.ndarray
    force: np.ndarray
    ee_position_weight: float
    force_weight: float
    in_contact: bool
    posture: np.ndarray | None = field(default=None)  # q̄ (rad); None keeps the model's own
    #: Q4 for this node (3 entries, world axes); None keeps CostWeights.ee_position_diag. Tasks
    #: zero the normal (z) entry in contact so the normal direction belongs to the force task.
    ee_position_diag: np.ndarray | None = field(default=None)

    @classmethod
    def empty(cls, dimension: int = 1) -> NodeReference:
        """A preallocated reference (zeros, out of contact, Q4 = 1) for ``reference_into``:
        ``dimension`` force entries, ``ee_position_diag`` allocated, no posture."""
        if dimension not in (1, 3):
            raise ConfigError(f"force dimension must be 1 or 3, got {dimension}")
        return cls(
            ee_position=np.zeros(3),
            force=np.zeros(dimension),
            ee_position_weight=0.0,
            force_weight=0.0,
            in_contact=False,
            ee_position_diag=np.ones(3),
        )
