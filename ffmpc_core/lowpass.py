"""Torque-feedback MPC formulation (Kleff et al. 2024, Sec. IV): low-pass actuation.

State x = (q, v, τ) (rad, rad/s, N·m), control u = w (unfiltered torque, N·m); the actuation is
the first-order filter τ̇ = ω_c·(w − τ) (eq 9), ω_c = 2π·f_c. The rigid contact model of the
classical formulation is unchanged, but it is driven by the *filtered* torque τ of the state, so
the contact force λ^r(x) depends on the state only (eq 10b).

Crocoddyl 3.2.1 has no low-pass-filter integrator and its ``IntegratedActionModelEuler`` assumes
a tangent of size 2·nv, so :class:`IntegratedActionModelLPF` is a Python
``crocoddyl.ActionModelAbstract`` on a ``StateVector(3·nv)`` (valid because the arms have
nq == nv: their configuration space is Euclidean). It wraps a differential model of
:mod:`ffmpc_core.rigid_contact` (contact or free dynamics, cost ℓ0) whose control is τ.

The Python class is the readable reference; ``ffmpc_core._native.IntegratedActionModelLPF``
(``cpp/lowpass.cpp``) is its C++ port with the same step, cost, derivatives and attributes
(``differential``, ``dt``, ``cutoff_frequency``, ``alpha``, ``lowpass_input_weight``, ``nv``;
data ``differential``, ``torque_residual``, ``lowpass_residual``), held equal to it by
``tests/test_native_lowpass.py``. :func:`make_lowpass_model` picks one by ``backend``
(``"native"`` by default, as every node builder here; see :mod:`ffmpc_core.rigid_contact`).

Discrete dynamics (eq 14a): q̈ from the differential model at (q, v, τ_a); semi-implicit Euler
v⁺ = v + Δt·q̈, q⁺ = q + Δt·v⁺; the filter under zero-order hold τ⁺ = α·τ + (1 − α)·w with
α = exp(−ω_c·Δt) (eq 13). τ_a, the torque the joints accelerate under during the interval, is
chosen by ``torque_integration`` (:func:`applied_torque_gains`): ``"current"`` τ_a = τ, the paper's
eq 14a, in which the control w of node k first moves the joints at node k + 1; or ``"next"``
τ_a = τ⁺, the authors' ``tau_plus_integration`` option, in which w acts in its own interval as
the classical MPC's control does (docs/results/tuning.md measures both).

Running cost: Δt·[ℓ0(q, v, τ_a) + c_w·½·‖w − τ_g(q, λ^r)‖²] (eq 28, Q_w = I: ``CostWeights`` has
no diagonal for it), with τ_g = g(q) − J(q)ᵀλ^r the same gravity-under-contact torque as in
eq 25.3. Terminal cost: the state terms of ℓ0 on (q, v) (no Δt factor) plus, as in the authors'
configuration (``ctrlRegGravWeightTerminal``), c3_T·½‖τ − g(q)‖²_Q3 on the filtered torque τ of
the state (``CostWeights.lowpass_terminal_torque``; 0 removes it). ℓ0 includes the joint-limit
barrier of the classical formulation
(``state_limit``: crocoddyl's ``ResidualModelState`` under ``ActivationModelQuadraticBarrier``,
:func:`ffmpc_core.rigid_contact.make_state_limit_cost`), so in this state it acts on the (q, v)
part; the filtered torque τ has no barrier (the torque limits saturate the command instead).
All first derivatives are exact (chain rule through the differential model's Fx, Fu and its
cost derivatives: ℓ0's derivatives w.r.t. its control become derivatives w.r.t. the τ part of
the state). Hessians are crocoddyl's Gauss-Newton ones, mapped the same way.
"""

from __future__ import annotations

import math

import crocoddyl
import numpy as np

from ffmpc_core.config import TORQUE_INTEGRATIONS, ContactConfig, CostWeights
from ffmpc_core.constraints import ConstraintRows, OcpBounds
from ffmpc_core.errors import ConfigError, InputError, ModelError
from ffmpc_core.rigid_contact import (
    COST_TORQUE,
    DEFAULT_BACKEND,
    CommonCostHandles,
    SwitchableContactNode,
    check_backend,
    make_differential_model,
    native_module,
    rigid_contact_force,
)
from ffmpc_core.robots import RobotModel

#: The paper's cut-off frequency of the actuation model (Sec. VI-B.3), Hz.
PAPER_CUTOFF_FREQUENCY = 50.0


def lowpass_alpha(cutoff_frequency: float, dt: float) -> float:
    """α = exp(−ω_c·Δt), ω_c = 2π·f_c (eq 13): the filter's memory per step (dimensionless).

    Args:
        cutoff_frequency: f_c in Hz, in [0, ∞]; ∞ gives α = 0 (no filtering, pure one-step delay
            τ_{k+1} = w_k, footnote 2) and 0 gives α = 1 (w blocked). The paper notes that in
            practice f_c should stay below the Nyquist frequency 1/(2·Δt); this is not enforced.
        dt: Δt in s, > 0.
    """
    if math.isnan(cutoff_frequency) or cutoff_frequency < 0:
        raise ConfigError(f"cutoff_frequency must be in [0, inf] Hz, got {cutoff_frequency}")
    if not math.isfinite(dt) or dt <= 0:
        raise ConfigError(f"dt must be > 0 s, got {dt}")
    return math.exp(-2.0 * math.pi * cutoff_frequency * dt)


def lowpass_filter_step(tau: np.ndarray, w: np.ndarray, alpha: float) -> np.ndarray:
    """τ_{k+1} = α·τ_k + (1 − α)·w_k (eq 13): the filter of eq 9 under zero-order hold, N·m."""
    return alpha * tau + (1.0 - alpha) * w


def applied_torque_gains(torque_integration: str, alpha: float) -> tuple[float, float]:
    """(s_x, s_u) of τ_a = s_x·τ + s_u·w: (1, 0) for ``"current"`` (τ_a = τ, eq 14a), (α, 1 − α)
    for ``"next"`` (τ_a = τ⁺ of eq 13, the authors' ``tau_plus_integration``).
    ConfigError for another name."""
    if torque_integration not in TORQUE_INTEGRATIONS:
        raise ConfigError(
            f"torque_integration must be one of {TORQUE_INTEGRATIONS}, got {torque_integration!r}"
        )
    return (1.0, 0.0) if torque_integration == "current" else (alpha, 1.0 - alpha)


def check_lowpass_arguments(
    differential: crocoddyl.DifferentialActionModelAbstract,
    dt: float,
    cutoff_frequency: float,
    lowpass_input_weight: float,
) -> None:
    """Raise :class:`ModelError` / :class:`ConfigError` unless the arguments of a low-pass model
    are valid: nq == nv == nu, Δt > 0 s, f_c in [0, ∞] Hz, c_w ≥ 0 (1/(N·m)²)."""
    nv = differential.state.nv
    if differential.state.nq != nv:
        raise ModelError("the low-pass model needs nq == nv (Euclidean configuration space)")
    if differential.nu != nv:
        raise ModelError(f"the differential model must be fully actuated (nu={nv})")
    if not math.isfinite(lowpass_input_weight) or lowpass_input_weight < 0:
        raise ConfigError(f"lowpass_input_weight must be >= 0, got {lowpass_input_weight}")
    lowpass_alpha(cutoff_frequency, dt)  # validates f_c and Δt


def make_lowpass_model(
    differential: crocoddyl.DifferentialActionModelAbstract,
    dt: float,
    cutoff_frequency: float,
    lowpass_input_weight: float = 0.0,
    backend: str = DEFAULT_BACKEND,
    constraint_matrix: np.ndarray | None = None,
    control_rows: bool = True,
    control_scale: np.ndarray | None = None,
    torque_integration: str = "current",
) -> crocoddyl.ActionModelAbstract:
    """The low-pass integrator (eq 13–14, 28) around ``differential``: the C++ port
    (``backend="native"``) or the Python :class:`IntegratedActionModelLPF` (``"python"``).

    Same arguments and units as :class:`IntegratedActionModelLPF`; validated here for both.
    """
    if not check_backend(backend):
        return IntegratedActionModelLPF(
            differential,
            dt,
            cutoff_frequency,
            lowpass_input_weight,
            constraint_matrix,
            control_rows,
            control_scale,
            torque_integration,
        )
    check_lowpass_arguments(differential, dt, cutoff_frequency, lowpass_input_weight)
    applied_torque_gains(torque_integration, 0.0)  # validates the name
    nv = differential.state.nv
    matrix = np.zeros((0, 3 * nv)) if constraint_matrix is None else constraint_matrix
    return native_module().IntegratedActionModelLPF(
        differential,
        float(dt),
        float(cutoff_frequency),
        float(lowpass_input_weight),
        COST_TORQUE,
        np.asarray(matrix, dtype=np.float64),
        np.ones(nv) if control_scale is None else np.asarray(control_scale, np.float64),
        bool(control_rows),
        torque_integration,
    )


class IntegratedActionModelLPF(crocoddyl.ActionModelAbstract):
    """Eq 13–14 and eq 28 as a crocoddyl action model on x = (q, v, τ), u = w.

    Args:
        differential: a differential model of :mod:`ffmpc_core.rigid_contact` (control τ, cost
            ℓ0). A running one must have the ``torque`` cost (eq 25.3), whose residual
            τ − τ_g(q, λ^r) gives τ_g and its derivatives for the c_w term.
        dt: Δt, s.
        cutoff_frequency: f_c, Hz (see :func:`lowpass_alpha`).
        lowpass_input_weight: c_w of eq 28, 1/(N·m)².
        constraint_matrix: the state-only hard-constraint rows S on (q, v, τ) (None: none;
            :class:`ffmpc_core.constraints.ConstraintRows`: g = [S·x; c ∘ w], bounds in
            ``g_lb``/``g_ub``).
        control_rows: whether g also has the rows c ∘ w (a running node; False: terminal).
        control_scale: c (nv; default 1), see ``constraint_matrix``.
        torque_integration: ``"current"`` (q̈ and ℓ0 at the state's τ, eq 14a) or ``"next"``
            (at τ⁺ = α·τ + (1 − α)·w, the authors' ``tau_plus_integration``).

    Called as ``calc(data, x)`` (a terminal node) it evaluates the differential model's cost on
    (q, v) only and leaves x unchanged, as crocoddyl's own integrators do; when that (terminal)
    differential model has the ``torque`` cost (``CostWeights.lowpass_terminal_torque`` > 0,
    :func:`ffmpc_core.rigid_contact.make_costs`), its cost is evaluated at control τ, the
    filtered torque of the state: c3·½‖τ − g(q)‖² regularises the terminal torque.
    """

    def __init__(
        self,
        differential: crocoddyl.DifferentialActionModelAbstract,
        dt: float,
        cutoff_frequency: float,
        lowpass_input_weight: float = 0.0,
        constraint_matrix: np.ndarray | None = None,
        control_rows: bool = True,
        control_scale: np.ndarray | None = None,
        torque_integration: str = "current",
    ) -> None:
        check_lowpass_arguments(differential, dt, cutoff_frequency, lowpass_input_weight)
        nv = differential.state.nv
        rows = ConstraintRows(constraint_matrix, control_scale, 3 * nv, nv, control_rows)
        super().__init__(crocoddyl.StateVector(3 * nv), nv, 0, rows.ng, 0, rows.ng_T, 0)
        self.constraint_rows = rows
        self.differential = differential
        self.dt = float(dt)
        self.cutoff_frequency = float(cutoff_frequency)
        self.alpha = lowpass_alpha(cutoff_frequency, dt)
        self.lowpass_input_weight = float(lowpass_input_weight)
        self.torque_integration = torque_integration
        #: τ_a = state_gain·τ + control_gain·w (:func:`applied_torque_gains`)
        self.state_gain, self.control_gain = applied_torque_gains(torque_integration, self.alpha)
        self.nv = nv
        self._eye = np.eye(nv)
        self._dtau_next_dx = np.zeros((nv, 3 * nv))
        self._dtau_next_dx[:, 2 * nv :] = self.alpha * self._eye

    def createData(self) -> IntegratedActionDataLPF:  # noqa: N802 (crocoddyl API)
        return IntegratedActionDataLPF(self)

    def calc(
        self, data: IntegratedActionDataLPF, x: np.ndarray, u: np.ndarray | None = None
    ) -> None:
        nv, dt = self.nv, self.dt
        dd = data.differential
        if u is None:
            if data.torque_residual is None:
                self.differential.calc(dd, x[: 2 * nv])
            else:  # the terminal torque term: the differential cost at control τ
                self.differential.calc(dd, x[: 2 * nv], x[2 * nv :])
            data.xnext[:] = x
            data.cost = dd.cost
            self.constraint_rows.calc(data.g, x)
            return
        tau = x[2 * nv :]
        tau_a = data.applied_torque
        tau_a[:] = self.state_gain * tau + self.control_gain * u
        self.differential.calc(dd, x[: 2 * nv], tau_a)
        v_next = x[nv : 2 * nv] + dt * dd.xout
        xnext = data.xnext
        xnext[:nv] = x[:nv] + dt * v_next
        xnext[nv : 2 * nv] = v_next
        xnext[2 * nv :] = lowpass_filter_step(tau, u, self.alpha)
        r_w = data.lowpass_residual
        r_w[:] = u - self._gravity_torque(data, tau_a)
        data.cost = dt * (dd.cost + 0.5 * self.lowpass_input_weight * float(r_w @ r_w))
        self.constraint_rows.calc(data.g, x, u)

    def _gravity_torque(self, data: IntegratedActionDataLPF, tau: np.ndarray) -> np.ndarray:
        """τ_g(q, λ^r) = τ_a − r_torque after the differential calc at τ_a = ``tau``, N·m."""
        if data.torque_residual is None:
            raise ModelError("a running low-pass model needs the 'torque' cost (eq 25.3)")
        return tau - data.torque_residual.r

    def calcDiff(  # noqa: N802 (crocoddyl API)
        self, data: IntegratedActionDataLPF, x: np.ndarray, u: np.ndarray | None = None
    ) -> None:
        nv, dt = self.nv, self.dt
        dd = data.differential
        if u is None:  # terminal: x⁺ = x, cost ℓ0(q, v) [+ c3·½‖τ − g(q)‖²]
            data.Fx[:, :] = np.eye(3 * nv)
            data.Fu[:, :] = 0.0
            data.Lx[:] = 0.0
            data.Lxx[:, :] = 0.0
            n2 = 2 * nv
            if data.torque_residual is None:
                self.differential.calcDiff(dd, x[:n2])
            else:  # derivatives w.r.t. the control τ are derivatives w.r.t. the τ state
                self.differential.calcDiff(dd, x[:n2], x[n2:])
                data.Lx[n2:] = dd.Lu
                data.Lxx[:n2, n2:] = dd.Lxu
                data.Lxx[n2:, :n2] = dd.Lxu.T
                data.Lxx[n2:, n2:] = dd.Luu
            data.Lx[:n2] = dd.Lx
            data.Lxx[:n2, :n2] = dd.Lxx
            self.constraint_rows.calc_diff(data.Gx, data.Gu)
            return
        n2 = 2 * nv
        sx, su = self.state_gain, self.control_gain
        tau_a = data.applied_torque
        tau_a[:] = sx * x[n2:] + su * u
        self.differential.calcDiff(dd, x[:n2], tau_a)
        # v⁺ = v + Δt·q̈(q, v, τ_a); q⁺ = q + Δt·v⁺; τ⁺ = α·τ + (1 − α)·w; τ_a = s_x·τ + s_u·w
        dv_next = np.concatenate((dd.Fx, sx * dd.Fu), axis=1)
        dv_next *= dt
        dv_next[:, nv:n2] += self._eye
        dq_next = dt * dv_next
        dq_next[:, :nv] += self._eye
        Fx = data.Fx
        Fx[:nv] = dq_next
        Fx[nv:n2] = dv_next
        Fx[n2:] = self._dtau_next_dx
        Fu = data.Fu
        Fu[nv:n2] = (dt * su) * dd.Fu
        Fu[:nv] = dt * Fu[nv:n2]
        Fu[n2:] = (1.0 - self.alpha) * self._eye

        # In y = (q, v, τ_a): ℓ0 with u = τ_a (its control derivatives are τ_a derivatives), then
        # eq 28: r_w = w − τ_g(y), ∂τ_g/∂(q, v) = −R_x, ∂τ_g/∂τ_a = I − R_u (G = ∂τ_g/∂y);
        # M = H0 + c_w·GᵀG and h = g0 − c_w·Gᵀr_w, mapped to (x, w) by J = ∂y/∂x =
        # diag(I, s_x·I) and ∂y/∂w = s_u·E_τ (Gauss-Newton in r_w).
        cw = self.lowpass_input_weight
        residual = data.torque_residual
        if residual is None:
            raise ModelError("a running low-pass model needs the 'torque' cost (eq 25.3)")
        r_w = u - tau_a + residual.r
        G = data.dtau_g_dx
        G[:, :n2] = residual.Rx
        G[:, n2:] = residual.Ru
        G *= -1.0
        G[:, n2:] += self._eye
        M = data.hessian
        M[:n2, :n2] = dd.Lxx
        M[:n2, n2:] = dd.Lxu
        M[n2:, :n2] = dd.Lxu.T
        M[n2:, n2:] = dd.Luu
        M += cw * (G.T @ G)
        h = np.concatenate((dd.Lx, dd.Lu))
        h -= cw * (G.T @ r_w)
        scale = np.ones(3 * nv)
        scale[n2:] = sx  # J as a diagonal
        G_tau = G[:, n2:]
        data.Lxx[:, :] = (dt * scale[:, None] * scale[None, :]) * M
        data.Lx[:] = (dt * scale) * h
        data.Lxu[:, :] = (dt * scale[:, None]) * (su * M[:, n2:] - cw * G.T)
        data.Lu[:] = dt * (su * h[n2:] + cw * r_w)
        data.Luu[:, :] = dt * (
            su * su * M[n2:, n2:] - (cw * su) * (G_tau + G_tau.T) + cw * self._eye
        )
        self.constraint_rows.calc_diff(data.Gx, data.Gu)


class IntegratedActionDataLPF(crocoddyl.ActionDataAbstract):
    """Workspace of :class:`IntegratedActionModelLPF`.

    Attributes:
        differential: the differential model's data (holds q̈, λ^r, ℓ0 after calc).
        torque_residual: that data's eq 25.3 residual data (None for a terminal model).
        lowpass_residual: w − τ_g of eq 28 after calc, N·m.
        applied_torque: τ_a, the torque q̈ and ℓ0 were computed at, after calc, N·m.
    """

    def __init__(self, model: IntegratedActionModelLPF) -> None:
        super().__init__(model)
        nv = model.nv
        self.differential = model.differential.createData()
        costs = self.differential.costs.costs
        self.torque_residual = costs[COST_TORQUE].residual if COST_TORQUE in costs else None
        self.lowpass_residual = np.zeros(nv)
        self.applied_torque = np.zeros(nv)
        self.dtau_g_dx = np.zeros((nv, 3 * nv))
        self.hessian = np.zeros((3 * nv, 3 * nv))


class LowPassNode(SwitchableContactNode):
    """One node of the torque-feedback OCP (Sec. IV-C) with switchable contact.

    Attributes:
        model: the low-pass integrator (:func:`make_lowpass_model`) to put in the
            ``ShootingProblem``.
        in_contact: whether ``model`` has the rigid contact (always False when terminal).
        terminal: terminal node (state terms of ℓ0 on (q, v) only).
        dt: Δt, s. cutoff_frequency: f_c, Hz. alpha: α of eq 13.
        contact: the contact configuration.
        backend: ``"native"`` (C++ integrator and residuals) or ``"python"``.
    """

    def __init__(
        self,
        robot: RobotModel,
        contact: ContactConfig,
        weights: CostWeights,
        dt: float,
        terminal: bool,
        cutoff_frequency: float,
        q_reference: np.ndarray | None,
        in_contact: bool,
        baumgarte_velocity_gain: float | None,
        backend: str = DEFAULT_BACKEND,
        bounds: OcpBounds | None = None,
        torque_integration: str = "current",
    ) -> None:
        check_backend(backend)
        self.backend = backend
        self.torque_integration = torque_integration
        self.bounds = bounds
        self.robot = robot
        self.contact = contact
        self.dt = float(dt)
        self.terminal = bool(terminal)
        self.cutoff_frequency = float(cutoff_frequency)
        self.alpha = lowpass_alpha(cutoff_frequency, dt)
        self._models: dict[bool, crocoddyl.ActionModelAbstract] = {}
        self._handles: dict[bool, CommonCostHandles] = {}
        for status in (False,) if self.terminal else (False, True):
            dam = make_differential_model(
                robot,
                contact,
                weights,
                in_contact=status,
                terminal=self.terminal,
                q_reference=q_reference,
                baumgarte_velocity_gain=baumgarte_velocity_gain,
                backend=backend,
                terminal_torque=True,
            )
            self._models[status] = make_lowpass_model(
                dam,
                self.dt,
                cutoff_frequency,
                weights.lowpass_input,
                backend,
                None if bounds is None else bounds.state_matrix,
                not self.terminal,
                None if bounds is None else bounds.control_scale,
                torque_integration,
            )
            self._handles[status] = CommonCostHandles(dam, robot.nv, weights.diag("ee_position", 3))
        self.in_contact = bool(in_contact) and not self.terminal
        self.model = self._models[self.in_contact]
        if bounds is not None:
            self.set_state_bounds(bounds.state_lower, bounds.state_upper)

    def set_state_bounds(self, lower: np.ndarray, upper: np.ndarray) -> None:
        """Bounds of the state-only constraint rows on (q, v, τ) (``bounds.n_state_rows``
        each; ±inf: none) in both models (contact and free); w's rows keep ``bounds``'.
        ModelError without constraints."""
        if self.bounds is None:
            raise ModelError("this node has no constraints")
        lb, ub = self.bounds.bounds(self.terminal, lower, upper)
        for model in self._models.values():
            model.g_lb = lb
            model.g_ub = ub

    def contact_force(self, data: IntegratedActionDataLPF) -> np.ndarray:
        """λ^r(x) of this node (eq 14b) from ``data`` (created by ``model``) after calc, N."""
        return rigid_contact_force(data.differential, self.contact)


def make_lowpass_node(
    robot: RobotModel,
    contact: ContactConfig,
    weights: CostWeights,
    dt: float,
    terminal: bool,
    cutoff_frequency: float,
    q_reference: np.ndarray | None = None,
    *,
    in_contact: bool = False,
    baumgarte_velocity_gain: float | None = None,
    backend: str = DEFAULT_BACKEND,
    bounds: OcpBounds | None = None,
    torque_integration: str = "current",
) -> LowPassNode:
    """Build a node of the torque-feedback OCP (eq 10–14, cost eq 28).

    Args:
        robot, contact, weights, q_reference, in_contact, baumgarte_velocity_gain: as for
            :func:`ffmpc_core.rigid_contact.make_rigid_contact_node` (c_w = weights.lowpass_input).
        dt: Δt, s.
        terminal: terminal node.
        cutoff_frequency: f_c of the actuation filter, Hz (paper: 50 Hz).
        backend: ``"native"`` (C++) or ``"python"`` (the reference classes).
        bounds: the hard constraints (:func:`ffmpc_core.constraints.ocp_bounds` of the
            torque-feedback formulation: rows on (q, v, τ) and on w; None: none).
        torque_integration: ``"current"`` (eq 14a) or ``"next"`` (q̈ at τ⁺: the authors'
            ``tau_plus_integration``; :func:`applied_torque_gains`).
    """
    if not math.isfinite(dt) or dt <= 0:
        raise ConfigError(f"dt must be > 0 s, got {dt}")
    return LowPassNode(
        robot,
        contact,
        weights,
        dt,
        terminal,
        cutoff_frequency,
        q_reference,
        in_contact,
        baumgarte_velocity_gain,
        backend,
        bounds,
        torque_integration,
    )


def interpolation_epsilon(replanning_period: float, dt: float) -> float:
    """ε of eq 15: the MPC re-planning period over the OCP step Δt, clipped to [0, 1].

    The paper says "the ratio between the OCP sampling step Δt and the MPC re-planning step";
    we read it as the fraction of the first OCP interval that has elapsed when the next plan
    arrives, T_mpc/Δt, because the stated purpose is to avoid sending τ₁*, which "may lie too far
    in the future when the OCP sampling frequency is lower than the MPC re-planning frequency"
    (T_mpc < Δt, so ε < 1 interpolates; the literal Δt/T_mpc would be > 1 and extrapolate). The
    authors' code (``force-feedback`` repository) also uses ``dt_mpc / dt_ocp``. Clipped to 1
    when T_mpc ≥ Δt (τ₁* is then sent as is). Both arguments in s.
    """
    if not math.isfinite(replanning_period) or replanning_period <= 0:
        raise ConfigError(f"replanning_period must be > 0 s, got {replanning_period}")
    if not math.isfinite(dt) or dt <= 0:
        raise ConfigError(f"dt must be > 0 s, got {dt}")
    return min(1.0, replanning_period / dt)


def interpolate_torque(
    measured_torque: np.ndarray, predicted_torque: np.ndarray, epsilon: float
) -> np.ndarray:
    """τ̃ = τ₀* + ε·(τ₁* − τ₀*) (eq 15), the joint torque sent to the robot, N·m.

    Args:
        measured_torque: τ₀* = τ̂, the measured joint torque the OCP started from, N·m.
        predicted_torque: τ₁*, the optimal *filtered* torque of the next node, N·m.
        epsilon: ε in [0, 1], see :func:`interpolation_epsilon`.
    """
    tau0 = np.asarray(measured_torque, dtype=float)
    tau1 = np.asarray(predicted_torque, dtype=float)
    if tau0.ndim != 1 or tau0.shape != tau1.shape:
        raise InputError(f"torque shapes differ or are not vectors: {tau0.shape} vs {tau1.shape}")
    if not (np.all(np.isfinite(tau0)) and np.all(np.isfinite(tau1))):
        raise InputError("torques must be finite")
    if not (0.0 <= epsilon <= 1.0):  # also rejects NaN
        raise InputError(f"epsilon must be in [0, 1], got {epsilon}")
    return tau0 + epsilon * (tau1 - tau0)
