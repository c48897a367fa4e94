"""Soft impact-aware preview control (Dehio & Kheddar 2020, Sec. IV-A/B, eq 12–14, appendix B/C).

The penetration is previewed over ``h`` steps of Δt from the instant of contact (``z_1 = 0``,
``ż_1 = ż_imp``): inputs ``u_1 … u_h`` (m/s²), states ``s_1 … s_{h+1}`` (m, m/s), accelerations
``z̈_1 … z̈_h`` (eq 8, m/s²) and forces ``f_i = E s_i`` (eq 3, N). Constraints of eq 12:

* ``0 ≤ z_i ≤ z̄`` for i = 2…h+1 (``z_1 = 0`` by construction; m),
* ``ż̲ ≤ ż_i ≤ ż̄`` for i = 1…h+1 (m/s; ``ż_1 = ż_imp`` is bounded too),
* ``P [z̈_i; f_i] ≤ p`` for i = 1…h (eq 11),
* ``ż_{h+1} = 0`` (the penetration ends at rest).

With h = 20 and 6 half-planes this is 4(h+1) + 6h = 204 one-sided inequalities, the count the
paper reports. All rows are condensed (the states eliminated through the dynamics, eq 13) into
``lower ≤ K ż_imp + X U ≤ upper``; the paper's equality rows ``X U = k − K ż_imp`` are rows with
``lower = upper``.

Solvers (``PlannerConfig.solver``):

* ``"daqp"`` (default): eq 14 is set up once in a DAQP workspace (a dual active-set solver,
  exact on the active set); every cycle the condensed rows are rebuilt in preallocated arrays
  (:class:`_Eq14Workspace`) and the solve starts from the previous cycle's working set. Eq 12
  is solved by DAQP from scratch (not on the hot path).
* ``"osqp"``: both problems are set up once in OSQP with a fixed sparsity pattern; every cycle
  only the numbers are updated in place and the solve is warm-started from the previous
  solution (kept as a reference; ADMM needs hundreds of iterations on these LP-like problems).

Either way a failed solve is redone by HiGHS on the LP variant (:func:`_highs_max_velocity`,
counted in ``ImpactPlanner.stats``), so the returned velocity is always an exact optimum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import daqp
import numpy as np
import osqp
import scipy.sparse as sp
from scipy.optimize import linprog

from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError, InputError, SolverError
from ffmpc_core.impact.deformation import DeformationDynamics, SoftMaterial, simulate_deformation
from ffmpc_core.impact.limits import (
    DAQP_INF,
    DAQP_LP_SETTINGS,
    DAQP_SOLVED,
    MAPPER_SOLVERS,
    ContactSpaceBounds,
    _SparsePattern,
)

__all__ = [
    "ConstraintRows",
    "ImpactPlanner",
    "PenetrationCost",
    "PenetrationPlan",
    "PLANNER_SOLVERS",
    "PlannerConfig",
    "constraint_violation",
    "penetration_constraints",
    "penetration_cost",
    "pre_impact_cost",
    "prediction_matrices",
]

_COSTS = ("qp", "lp")
#: Solvers of eq 12/14 (and of the eq 9–11 mapping, see ContactSpaceMapper).
PLANNER_SOLVERS = MAPPER_SOLVERS


@dataclass(frozen=True)
class PlannerConfig:
    """Parameters of eq 12–14.

    Attributes:
        horizon: h, number of preview steps (paper: 20).
        dt: Δt, s (paper: 0.025 → a 0.5 s preview).
        cost: ``"qp"`` for eq 14 (secondary objective in the null space of the velocity
            maximisation) or ``"lp"`` for its LP variant (cost ``−ż_imp`` only).
        control_effort_weight: weight of ``Σ u_i²`` in eq 12, s⁴/m².
        force_tracking_weight: ω_f of ``Σ ω_f (f_des − f_i)²`` in eq 12, 1/N².
        target_force: f_des, N (used only with ``force_tracking_weight > 0``).
        velocity_weight: ``−r`` of eq 14 (s/m): the linear reward on ż_imp ("r → −∞"); it
            must dominate the secondary cost. With finite weights the QP optimum can stop short
            of the true maximum (the safe side): with the defaults we measured gaps up to ~1 %
            on stiff materials; a larger ratio closes the gap but makes OSQP's polish fail more
            often (then HiGHS solves the LP variant, slower). ``cost="lp"`` is always exact.
        velocity_regularization: ``R`` of eq 14 (s/m), small and > 0 (positive definiteness).
        max_halfplanes: number of rows reserved for eq 11 per step (≥ the mapper's directions).
        solver: ``"daqp"`` (default; warm-started dual active set, exact on its active set) or
            ``"osqp"`` (ADMM + polish, the reference). The controller uses the same choice for
            the eq 9–11 mapping.
        eps: OSQP absolute/relative tolerance of eq 14 (``solver="osqp"``); the solution is then
            polished (exact active-set solve). A solve whose polish fails is redone by HiGHS.
        primal_tol: DAQP primal feasibility tolerance (``solver="daqp"``) on the unit-normalised
            rows (m, m/s, m/s² per unit row norm; see ImpactPlanner.feasibility_tolerance).
            1e-9 made DAQP stop at its noise floor (exit flag 4) on some of our problems.
        input_scale: internal scaling of u (m/s²) so that OSQP sees [ż_imp, u/input_scale] of
            similar magnitude; rows are also normalised. Does not change the solution.
    """

    horizon: int = param(20, "steps", (2, 1000), "h of eq 12-14")
    dt: float = param(0.025, "s", (1e-4, 1.0), "Δt of eq 12-14")
    cost: str = param("qp", "", ["qp", "lp"], "eq 14 (qp) or its LP variant")
    control_effort_weight: float = param(
        1e-2, "s⁴/m²", (1e-12, math.inf), "weight of Σ u_i² (eq 12)"
    )
    force_tracking_weight: float = param(0.0, "1/N²", (0.0, math.inf), "ω_f of eq 12")
    target_force: float = param(0.0, "N", (0.0, 500.0), "f_des of eq 12 (with ω_f > 0)")
    velocity_weight: float = param(1e3, "s/m", (1e-12, math.inf), "−r of eq 14")
    velocity_regularization: float = param(1e-2, "s/m", (1e-12, math.inf), "R of eq 14")
    max_halfplanes: int = param(8, "", (3, 1000), "eq 11 rows per step")
    solver: str = param("daqp", "", ["daqp", "osqp"], "QP solver of eq 9-14")
    eps: float = param(1e-4, "", (1e-12, 1.0), "OSQP tolerance")
    primal_tol: float = param(1e-7, "", (1e-15, 1.0), "DAQP primal feasibility tolerance")
    input_scale: float = param(100.0, "m/s²", (1e-6, 1e6), "internal scaling of u")

    def __post_init__(self) -> None:
        if int(self.horizon) != self.horizon or self.horizon < 2:
            raise ConfigError(f"horizon must be an integer ≥ 2, got {self.horizon}")
        if not (np.isfinite(self.dt) and self.dt > 0):
            raise ConfigError(f"dt must be positive, got {self.dt}")
        if self.cost not in _COSTS:
            raise ConfigError(f"cost must be one of {_COSTS}, got {self.cost!r}")
        for name in ("control_effort_weight", "force_tracking_weight"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) >= 0):
                raise ConfigError(f"{name} must be finite and ≥ 0")
        if self.control_effort_weight <= 0:
            raise ConfigError("control_effort_weight must be > 0 (eq 12 needs W positive definite)")
        if self.solver not in PLANNER_SOLVERS:
            raise ConfigError(f"solver must be one of {PLANNER_SOLVERS}, got {self.solver!r}")
        positive = (
            "velocity_weight",
            "velocity_regularization",
            "eps",
            "primal_tol",
            "input_scale",
        )
        for name in positive:
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ConfigError(f"{name} must be finite and > 0")
        if self.max_halfplanes < 3:
            raise ConfigError("max_halfplanes must be ≥ 3")


def prediction_matrices(
    dynamics: DeformationDynamics, horizon: int
) -> tuple[np.ndarray, np.ndarray]:
    """Condensed eq 6: ``s = S_imp ż_imp + S_u U`` for ``s = [s_1; …; s_{h+1}]`` (2(h+1),).

    With ``s_1 = [0, ż_imp]``: ``s_i = A_d^{i−1} e2 ż_imp + Σ_{j<i} A_d^{i−1−j} B_d u_j``.
    Returns ``S_imp`` (2(h+1),) and ``S_u`` (2(h+1)×h).
    """
    A, B = dynamics.A_d, dynamics.B_d[:, 0]
    powers = np.empty((horizon + 1, 2, 2))
    powers[0] = np.eye(2)
    for k in range(1, horizon + 1):
        powers[k] = A @ powers[k - 1]
    S_imp = powers[:, :, 1].reshape(-1)
    gains = powers[:horizon] @ B  # A^k B, k = 0..h−1, shape (h, 2)
    i = np.arange(horizon + 1)[:, None]
    j = np.arange(horizon)[None, :]
    lag = i - 1 - j
    blocks = np.where((lag >= 0)[:, :, None], gains[np.clip(lag, 0, None)], 0.0)  # (h+1, h, 2)
    S_u = blocks.transpose(0, 2, 1).reshape(2 * (horizon + 1), horizon)
    return S_imp, S_u


@dataclass(frozen=True)
class ConstraintRows:
    """Condensed eq 12 constraints ``lower ≤ K ż_imp + X U ≤ upper`` (eq 13 in two-sided form).

    Row blocks, in order: deformation (h rows, m), deformation rate (h+1 rows, m/s), eq 11
    half-planes (h·max_halfplanes rows, m/s²; unused rows are zero with infinite bounds), and the
    terminal rest condition (1 row, m/s).
    """

    K: np.ndarray
    X: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


def penetration_constraints(
    dynamics: DeformationDynamics,
    bounds: ContactSpaceBounds,
    material: SoftMaterial,
    horizon: int,
    max_halfplanes: int,
    predictions: tuple[np.ndarray, np.ndarray] | None = None,
) -> ConstraintRows:
    """Build the eq 12 constraints for the deformation dynamics and contact-space bounds."""
    h = horizon
    S_imp, S_u = predictions if predictions is not None else prediction_matrices(dynamics, h)
    P, p = bounds.halfplane_normals, bounds.halfplane_offsets
    n_p = P.shape[0]
    if n_p > max_halfplanes:
        raise ConfigError(f"{n_p} half-planes exceed max_halfplanes={max_halfplanes}")
    Zi, Zu = S_imp[0::2], S_u[0::2]  # z_1..z_{h+1}
    Vi, Vu = S_imp[1::2], S_u[1::2]  # ż_1..ż_{h+1}
    C, D, E = dynamics.C[0], dynamics.D[0, 0], dynamics.E[0]
    # z̈_i = C s_i + D u_i, f_i = E s_i, i = 1..h.
    acc_i = C[0] * Zi[:h] + C[1] * Vi[:h]
    acc_u = C[0] * Zu[:h] + C[1] * Vu[:h] + D * np.eye(h)
    frc_i = E[0] * Zi[:h] + E[1] * Vi[:h]
    frc_u = E[0] * Zu[:h] + E[1] * Vu[:h]
    hp_i = np.zeros((h, max_halfplanes))
    hp_u = np.zeros((h, max_halfplanes, h))
    hp_up = np.full((h, max_halfplanes), np.inf)
    hp_i[:, :n_p] = acc_i[:, None] * P[:, 0] + frc_i[:, None] * P[:, 1]
    hp_u[:, :n_p] = (
        acc_u[:, None, :] * P[None, :, 0, None] + frc_u[:, None, :] * P[None, :, 1, None]
    )
    hp_up[:, :n_p] = p
    K = np.concatenate([Zi[1:], Vi, hp_i.reshape(-1), [Vi[-1]]])
    X = np.vstack([Zu[1:], Vu, hp_u.reshape(h * max_halfplanes, h), Vu[-1:]])
    lower = np.concatenate(
        [
            np.zeros(h),
            np.full(h + 1, bounds.velocity_lower),
            np.full(h * max_halfplanes, -np.inf),
            [0.0],
        ]
    )
    upper = np.concatenate(
        [
            np.full(h, material.max_penetration),
            np.full(h + 1, bounds.velocity_upper),
            hp_up.reshape(-1),
            [0.0],
        ]
    )
    return ConstraintRows(K=K, X=X, lower=lower, upper=upper)


@dataclass(frozen=True)
class PenetrationCost:
    """Eq 12/13 cost ``½ Uᵀ W U + Uᵀ (y + Y ż_imp)``: W (h×h), y (h,), Y (h,)."""

    W: np.ndarray
    y: np.ndarray
    Y: np.ndarray


def penetration_cost(
    dynamics: DeformationDynamics,
    config: PlannerConfig,
    predictions: tuple[np.ndarray, np.ndarray] | None = None,
) -> PenetrationCost:
    """Eq 12 cost: ``Σ_i ω_f (f_des − f_i)² + w_u Σ_i u_i²`` over f_1 … f_{h+1} in eq 13 form.

    With ``f = g ż_imp + G U`` (N): ``W = 2(ω_f GᵀG + w_u I)``, ``y = −2 ω_f f_des Gᵀ1``,
    ``Y = 2 ω_f Gᵀ g`` (constant terms dropped).
    """
    h = config.horizon
    S_imp, S_u = predictions if predictions is not None else prediction_matrices(dynamics, h)
    E = dynamics.E[0]
    g = E[0] * S_imp[0::2] + E[1] * S_imp[1::2]
    G = E[0] * S_u[0::2] + E[1] * S_u[1::2]
    wf, wu = config.force_tracking_weight, config.control_effort_weight
    W = 2.0 * (wf * G.T @ G + wu * np.eye(h))
    y = -2.0 * wf * config.target_force * G.sum(axis=0)
    Y = 2.0 * wf * G.T @ g
    return PenetrationCost(W=W, y=y, Y=Y)


def pre_impact_cost(cost: PenetrationCost, config: PlannerConfig) -> tuple[np.ndarray, np.ndarray]:
    """Eq 14 (appendix B/C): ``W̃ = [[RRᵀ + Yᵀ W⁻¹ Y, Yᵀ], [Y, W]]`` and ``w̃ = [r; y]``.

    ``r = −velocity_weight`` (the paper's ``r → −∞``) and ``R = velocity_regularization``; W̃ is
    positive definite for any R ≠ 0 (appendix C). Returns ``(W̃, w̃)`` for ``Ũ = [ż_imp; U]``.
    """
    h = config.horizon
    Wt = np.empty((h + 1, h + 1))
    Wt[0, 0] = config.velocity_regularization**2 + cost.Y @ np.linalg.solve(cost.W, cost.Y)
    Wt[0, 1:] = cost.Y
    Wt[1:, 0] = cost.Y
    Wt[1:, 1:] = cost.W
    wt = np.concatenate([[-config.velocity_weight], cost.y])
    return Wt, wt


@dataclass(frozen=True)
class PenetrationPlan:
    """A previewed penetration (eq 12) or the maximal pre-impact plan (eq 14).

    Attributes:
        pre_impact_velocity: ż_imp, m/s along the motion direction.
        inputs: u_1 … u_h, m/s².
        states: s_1 … s_{h+1} ((h+1)×2; m, m/s), by feed-forward simulation of eq 6.
        accelerations: z̈_1 … z̈_h (m/s², eq 8). forces: f_1 … f_{h+1} (N, eq 3).
        max_violation: largest violation of an eq 12 constraint by the simulated plan, in the
            constraint's own units (m, m/s or m/s²); 0 when feasible (DAQP: evaluated on the
            condensed rows, the same states up to rounding).
        iterations: solver iterations (OSQP: ADMM; DAQP: active-set changes).
        solve_time: solver time, s.
        solver: ``"daqp"``, ``"osqp"`` or ``"highs"`` (fallback after a failed solve).
    """

    pre_impact_velocity: float
    inputs: np.ndarray
    states: np.ndarray
    accelerations: np.ndarray
    forces: np.ndarray
    max_violation: float
    iterations: int
    solve_time: float
    solver: str = "osqp"


def constraint_violation(
    states: np.ndarray,
    accelerations: np.ndarray,
    forces: np.ndarray,
    bounds: ContactSpaceBounds,
    material: SoftMaterial,
) -> float:
    """Largest violation of the eq 12 constraints by a simulated penetration (0 if none).

    Checks ``z_1 = 0``, ``0 ≤ z ≤ z̄`` (m), ``ż̲ ≤ ż ≤ ż̄`` (m/s), ``P [z̈_i; f_i] ≤ p`` for
    i = 1…h (m/s²) and ``ż_{h+1} = 0`` directly on the arrays, independently of the condensed rows.
    """
    z, zd = states[:, 0], states[:, 1]
    h = accelerations.size
    hp = np.column_stack([accelerations, forces[:h]]) @ bounds.halfplane_normals.T
    parts = [
        [abs(z[0])],
        -z,
        z - material.max_penetration,
        bounds.velocity_lower - zd,
        zd - bounds.velocity_upper,
        (hp - bounds.halfplane_offsets).reshape(-1),
        [abs(zd[-1])],
    ]
    return float(max(0.0, max(np.max(np.asarray(x)) for x in parts)))


def _row_pattern(horizon: int, max_halfplanes: int) -> np.ndarray:
    """Structural nonzeros of ``[K, X]`` (columns ż_imp, u_1..u_h)."""
    h = horizon
    i_z = np.arange(2, h + 2)  # z_2..z_{h+1} depend on u_1..u_{i-1}
    i_v = np.arange(1, h + 2)  # ż_1..ż_{h+1}
    j = np.arange(1, h + 1)[None, :]
    z_rows = j <= (i_z[:, None] - 1)
    v_rows = j <= (i_v[:, None] - 1)
    hp_rows = np.repeat(j <= np.arange(1, h + 1)[:, None], max_halfplanes, axis=0)
    term = np.ones((1, h), dtype=bool)
    X = np.vstack([z_rows, v_rows, hp_rows, term])
    return np.column_stack([np.ones(X.shape[0], dtype=bool), X])


def _highs_max_velocity(rows: ConstraintRows) -> tuple[np.ndarray, float]:
    """LP variant of eq 14 by HiGHS: ``max ż_imp`` s.t. the condensed rows; returns (Ũ, time s)."""
    A = np.column_stack([rows.K, rows.X])
    eq = rows.lower == rows.upper
    up = np.isfinite(rows.upper) & ~eq
    lo = np.isfinite(rows.lower) & ~eq
    c = np.zeros(A.shape[1])
    c[0] = -1.0
    res = linprog(
        c,
        A_ub=np.vstack([A[up], -A[lo]]),
        b_ub=np.concatenate([rows.upper[up], -rows.lower[lo]]),
        A_eq=A[eq],
        b_eq=rows.lower[eq],
        bounds=[(None, None)] * A.shape[1],
        method="highs",
    )
    if res.status != 0:
        raise SolverError(f"eq 14 (HiGHS): {res.message}")
    return res.x, float(getattr(res, "runtime", 0.0) or 0.0)


class _Eq14Workspace:
    """The condensed eq 12–14 rows in preallocated arrays, rebuilt in place every cycle.

    Same rows, order and units as :func:`penetration_constraints` (which stays the readable
    reference; a test checks both agree), built from the 2×2 recurrences ``A_d^k e2`` and
    ``A_d^k B_d`` (scalar loop) and a fixed Toeplitz index instead of the matrix powers. Zero
    padding rows get bounds ±``DAQP_INF`` (DAQP ignores zero rows and infinite bounds). DAQP
    gets the rows scaled to unit norm (``An``, ``lower_n``, ``upper_n``): its ``primal_tol``
    bounds ``A x − b`` of the rows it is given (measured), so it then means the same for every
    row. Variables ``[ż_imp, u_1 … u_h]``.
    """

    def __init__(self, horizon: int, max_halfplanes: int) -> None:
        h, nh = horizon, max_halfplanes
        self.h, self.nh = h, nh
        self.n_rows = h + (h + 1) + h * nh + 1
        self.A = np.zeros((self.n_rows, h + 1))
        self.lower = np.zeros(self.n_rows)
        self.upper = np.zeros(self.n_rows)
        self.norms = np.ones(self.n_rows)
        self.An = np.zeros_like(self.A)
        self.lower_n = np.zeros(self.n_rows)
        self.upper_n = np.zeros(self.n_rows)
        self.sense = np.zeros(self.n_rows, dtype=np.int32)
        self.sense[-1] = 5  # ż_{h+1} = 0: an equality row
        # All numbers of the rows come from one vector, filled by the scalar recurrences:
        # [0, z_1..z_{h+1} per unit ż_imp, ż_1..ż_{h+1} per unit ż_imp, (A^l B)_z, (A^l B)_ż for
        # l = 0..h−1]; state k (0-based) depends on u_j through the gain of lag k−1−j ≥ 0.
        self._vec = np.zeros(1 + 2 * (h + 1) + 2 * h)
        k = np.arange(h + 1)[:, None]
        j = np.arange(h)[None, :]
        lag = k - 1 - j
        off_z, off_v = 1, 2 + h
        off_gz, off_gv = 2 * h + 3, 3 * h + 3
        idx_z = np.zeros((h + 1, h + 1), dtype=np.intp)
        idx_v = np.zeros((h + 1, h + 1), dtype=np.intp)
        idx_z[:, 0] = off_z + np.arange(h + 1)
        idx_v[:, 0] = off_v + np.arange(h + 1)
        idx_z[:, 1:] = np.where(lag >= 0, off_gz + lag, 0)
        idx_v[:, 1:] = np.where(lag >= 0, off_gv + lag, 0)
        self._idx_top = np.concatenate([idx_z[1:], idx_v])  # rows z_2..z_{h+1}, ż_1..ż_{h+1}
        self._idx_states = np.stack([idx_z[:h], idx_v[:h]], axis=1)  # (h, 2, h+1): s_1..s_h
        self._zv = np.zeros((h, 2, h + 1))
        self._ce = np.zeros((2, 2))
        self._af = np.zeros((h, 2, h + 1))
        self.acc = self._af[:, 0]  # [K | X] rows of z̈_1..z̈_h (eq 8)
        self.frc = self._af[:, 1]  # [K | X] rows of f_1..f_h (eq 3)
        self._diag = (np.arange(h), np.arange(1, h + 1))  # u_i in the row of z̈_i
        self._rows_top = slice(0, 2 * h + 1)
        self._rows_z = slice(0, h)
        self._rows_v = slice(h, 2 * h + 1)
        self._rows_hp = slice(2 * h + 1, 2 * h + 1 + h * nh)
        self.lower[self._rows_hp] = -DAQP_INF

    def update(
        self, dynamics: DeformationDynamics, bounds: ContactSpaceBounds, material: SoftMaterial
    ) -> None:
        """Rebuild the rows for this cycle's dynamics (eq 3–8) and bounds (eq 9–11)."""
        h, nh = self.h, self.nh
        P, p = bounds.halfplane_normals, bounds.halfplane_offsets
        n_p = P.shape[0]
        if n_p > nh:
            raise ConfigError(f"{n_p} half-planes exceed max_halfplanes={nh}")
        (a11, a12), (a21, a22) = dynamics.A_d.tolist()
        b1, b2 = dynamics.B_d[:, 0].tolist()
        vec = self._vec
        off_v, off_gz, off_gv = 2 + h, 2 * h + 3, 3 * h + 3
        x1, x2 = 0.0, 1.0  # A^k e2
        y1, y2 = b1, b2  # A^k B
        for k in range(h + 1):
            vec[1 + k] = x1
            vec[off_v + k] = x2
            x1, x2 = a11 * x1 + a12 * x2, a21 * x1 + a22 * x2
            if k < h:
                vec[off_gz + k] = y1
                vec[off_gv + k] = y2
                y1, y2 = a11 * y1 + a12 * y2, a21 * y1 + a22 * y2
        A = self.A
        np.take(vec, self._idx_top, out=A[self._rows_top])
        A[-1] = A[2 * h]  # ż_{h+1}
        np.take(vec, self._idx_states, out=self._zv)
        ce = self._ce
        ce[0] = dynamics.C[0]
        ce[1] = dynamics.E[0]
        np.matmul(ce, self._zv, out=self._af)  # [z̈_i; f_i] = [C; E] s_i (+ D u_i below)
        self.acc[self._diag] += dynamics.D[0, 0]
        hp = A[self._rows_hp].reshape(h, nh, h + 1)  # a view
        np.matmul(P, self._af, out=hp[:, :n_p])  # P [z̈_i; f_i] for every step i
        up_hp = self.upper[self._rows_hp].reshape(h, nh)  # a view
        up_hp[:, :n_p] = p
        if n_p < nh:
            hp[:, n_p:] = 0.0
            up_hp[:, n_p:] = DAQP_INF
        self.upper[self._rows_z] = material.max_penetration
        self.lower[self._rows_v] = bounds.velocity_lower
        self.upper[self._rows_v] = bounds.velocity_upper
        # Unit rows for DAQP: its primal_tol applies to A x − b of the rows it is given.
        norms = self.norms
        np.sqrt(np.einsum("ij,ij->i", A, A), out=norms)
        norms[norms == 0.0] = 1.0
        np.divide(A, norms[:, None], out=self.An)
        np.divide(self.lower, norms, out=self.lower_n)
        np.divide(self.upper, norms, out=self.upper_n)
        self.lower_n[self._rows_hp] = -DAQP_INF
        up_n = self.upper_n[self._rows_hp]  # a view
        up_n[self.upper[self._rows_hp] >= DAQP_INF] = DAQP_INF

    def predictions(self) -> tuple[np.ndarray, np.ndarray]:
        """``(S_imp, S_u)`` of :func:`prediction_matrices` from the current rows."""
        h = self.h
        S = np.zeros((h + 1, 2, h + 1))
        S[1:, 0] = self.A[self._rows_z]
        S[:, 1] = self.A[self._rows_v]
        rows = S.reshape(2 * (h + 1), h + 1)
        return rows[:, 0].copy(), rows[:, 1:].copy()

    def violation(self, x: np.ndarray) -> float:
        """Largest violation of the rows by ``x = [ż_imp, U]`` in their own units (m, m/s,
        m/s²; 0 if none): :func:`constraint_violation` on the condensed states (``z_1 = 0``
        holds by construction), without re-simulating."""
        Ax = self.A @ x
        return float(max(0.0, np.max(Ax - self.upper), np.max(self.lower - Ax)))

    def plan_arrays(
        self, x: np.ndarray, dynamics: DeformationDynamics
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """States (h+1)×2 (m, m/s), accelerations (h,) (m/s², eq 8) and forces (h+1,) (N, eq 3)
        of ``x = [ż_imp, u_1 … u_h]`` from the condensed rows (eq 6; the same numbers as
        :func:`simulate_deformation` up to rounding)."""
        h = self.h
        states = np.empty((h + 1, 2))
        states[0, 0] = 0.0
        states[1:, 0] = self.A[self._rows_z] @ x
        states[:, 1] = self.A[self._rows_v] @ x
        return states, self.acc @ x, states @ dynamics.E[0]


class ImpactPlanner:
    """Eq 12 (penetration QP for a given ż_imp) and eq 14 (maximal ż_imp), set up once.

    Call :meth:`max_pre_impact_velocity` every control cycle with the current deformation
    dynamics (eq 3–8) and contact-space bounds (eq 9–11); :meth:`plan_penetration` solves eq 12
    for a given pre-impact velocity.

    ``solver="daqp"`` (default): eq 14 lives in one DAQP workspace set up at the first call; each
    call rebuilds the rows in place (:class:`_Eq14Workspace`), updates the workspace and solves
    from the previous cycle's working set (exact on its active set; inactive rows within
    ``primal_tol``). ``solver="osqp"``: each problem keeps one OSQP instance with a fixed
    sparsity pattern, updated in place and warm-started; eq 14 is solved to ``eps`` and polished.
    With either, a failed solve is redone by HiGHS on the LP variant, so the returned velocity is
    always an exact optimum (:attr:`stats` counts solves, failures and these fallbacks).
    """

    def __init__(self, config: PlannerConfig | None = None) -> None:
        self.config = config if config is not None else PlannerConfig()
        cfg = self.config
        h = cfg.horizon
        self.stats = {"solves": 0, "failures": 0, "highs_fallbacks": 0}
        self._q_lp = np.zeros(h + 1)
        self._q_lp[0] = -1.0
        if cfg.solver == "daqp":
            self._work = _Eq14Workspace(h, cfg.max_halfplanes)
            self._daqp: daqp.Model | None = None
            self._const_hessian: np.ndarray | None = None
            if cfg.cost == "lp":
                self._const_hessian = np.zeros((h + 1, h + 1))
            elif cfg.force_tracking_weight == 0.0:
                # ω_f = 0: W = 2 w_u I, y = Y = 0 whatever the dynamics, so W̃ and w̃ are fixed.
                W = 2.0 * cfg.control_effort_weight * np.eye(h)
                zero = np.zeros(h)
                self._const_hessian, self._const_cost = pre_impact_cost(
                    PenetrationCost(W=W, y=zero, Y=zero), cfg
                )
            return
        mask = _row_pattern(h, cfg.max_halfplanes)
        self._n_rows = mask.shape[0]
        settings = dict(
            verbose=False,
            polishing=True,
            polish_refine_iter=5,
            eps_abs=cfg.eps,
            eps_rel=cfg.eps,
            max_iter=20000,
            warm_starting=True,
            rho=10.0,
        )
        # eq 14: variables [ż_imp, U / input_scale].
        self._scale = np.concatenate([[1.0], np.full(h, cfg.input_scale)])
        self._max_A = _SparsePattern(mask)
        if cfg.cost == "qp":
            self._max_P: _SparsePattern | None = _SparsePattern(
                np.triu(np.ones((h + 1, h + 1), dtype=bool))
            )
            P0 = self._max_P.matrix
        else:
            self._max_P = None
            P0 = sp.csc_matrix((h + 1, h + 1))
        self._max = osqp.OSQP()
        self._max.setup(
            P0,
            np.zeros(h + 1),
            self._max_A.matrix,
            np.zeros(self._n_rows),
            np.ones(self._n_rows),
            **settings,
        )
        # eq 12: variables U / input_scale, ż_imp given (a strictly convex QP: tighter eps).
        self._pen_A = _SparsePattern(mask[:, 1:])
        self._pen_P = _SparsePattern(np.triu(np.ones((h, h), dtype=bool)))
        self._pen = osqp.OSQP()
        self._pen.setup(
            self._pen_P.matrix,
            np.zeros(h),
            self._pen_A.matrix,
            np.zeros(self._n_rows),
            np.ones(self._n_rows),
            **dict(settings, eps_abs=1e-7, eps_rel=1e-7),
        )

    def _check(self, dynamics: DeformationDynamics, bounds: ContactSpaceBounds) -> None:
        if abs(dynamics.dt - self.config.dt) > 1e-12:
            raise ConfigError(f"dynamics dt={dynamics.dt} differs from planner dt={self.config.dt}")
        if not bounds.velocity_lower <= 0.0 <= bounds.velocity_upper:
            raise InputError(
                f"velocity bounds [{bounds.velocity_lower}, {bounds.velocity_upper}] exclude 0"
            )

    @staticmethod
    def _normalised(
        A: np.ndarray, rows: ConstraintRows
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows scaled to unit norm (padding rows left as they are)."""
        norms = np.linalg.norm(A, axis=1)
        norms[norms == 0.0] = 1.0
        return A / norms[:, None], rows.lower / norms, rows.upper / norms

    def _plan(
        self,
        zdot_imp: float,
        U: np.ndarray,
        dynamics: DeformationDynamics,
        bounds: ContactSpaceBounds,
        material: SoftMaterial,
        iterations: int,
        solve_time: float,
        solver: str,
    ) -> PenetrationPlan:
        states, acc, forces = simulate_deformation(dynamics, np.array([0.0, zdot_imp]), U)
        return PenetrationPlan(
            pre_impact_velocity=float(zdot_imp),
            inputs=np.array(U, dtype=float),
            states=states,
            accelerations=acc,
            forces=forces,
            max_violation=constraint_violation(states, acc, forces, bounds, material),
            iterations=int(iterations),
            solve_time=float(solve_time),
            solver=solver,
        )

    def constraints(
        self, dynamics: DeformationDynamics, bounds: ContactSpaceBounds, material: SoftMaterial
    ) -> tuple[ConstraintRows, tuple[np.ndarray, np.ndarray]]:
        """The condensed eq 12 rows and the prediction matrices for this cycle."""
        self._check(dynamics, bounds)
        cfg = self.config
        pred = prediction_matrices(dynamics, cfg.horizon)
        rows = penetration_constraints(
            dynamics, bounds, material, cfg.horizon, cfg.max_halfplanes, pred
        )
        return rows, pred

    def feasibility_tolerance(
        self,
        plan: PenetrationPlan,
        dynamics: DeformationDynamics,
        bounds: ContactSpaceBounds,
        material: SoftMaterial,
        eq12: bool = False,
    ) -> np.ndarray:
        """Per-row tolerance (the rows of :meth:`constraints`, in their own units m, m/s, m/s²)
        to which the solver that produced ``plan`` guarantees them; ``eq12=True`` for a plan of
        :meth:`plan_penetration` (ż_imp fixed, variables U only).

        * ``"daqp"``: ``primal_tol`` on the unit-normalised rows DAQP is given, plus the
          rounding of its primal recovery ``x = R⁻¹(u − v)``: DAQP works in ``u = R x + v``
          (``RᵀR = H + eps_prox I``: eq 14's W̃, eq 12's W or the LP variant's proximal weight;
          ``v = R⁻ᵀ f``, ~1e5 with eq 14's large velocity weight), which loses about
          ``‖v‖`` × 1e4 ε (ε the double precision) per unit of ``‖(A R⁻¹)_i‖``;
        * ``"osqp"``: OSQP's termination test ``‖A x − z‖∞ ≤ eps_abs + eps_rel·max(‖A x‖∞, ‖z‖∞)``
          on the problem it was given (rows normalised after ``input_scale``; eps = ``eps`` for
          eq 14, 1e-7 for eq 12); its polish is only accepted if it does not increase that
          residual;
        * ``"highs"``: HiGHS's primal feasibility tolerance, 1e-7, on the raw rows.

        Each is converted to the raw rows' units by the row norms, plus a rounding allowance of
        1e-12 × (|row|·|x| + |bound|) for the condensed-versus-simulated evaluation.
        """
        cfg = self.config
        rows, _ = self.constraints(dynamics, bounds, material)
        x = np.concatenate([[plan.pre_impact_velocity], plan.inputs])
        A = np.column_stack([rows.K, rows.X])
        finite = np.where(np.isfinite(rows.upper), np.abs(rows.upper), 0.0)
        finite = np.maximum(finite, np.where(np.isfinite(rows.lower), np.abs(rows.lower), 0.0))
        rounding = 1e-12 * (np.abs(A) @ np.abs(x) + finite)
        if plan.solver == "highs":
            return 1e-7 + rounding
        lower, upper = rows.lower, rows.upper
        x0 = x[0]
        if eq12:  # the ż_imp column moves to the bounds
            lower, upper = lower - rows.K * x0, upper - rows.K * x0
            A, x = rows.X, x[1:]
        if plan.solver == "daqp":
            if eq12:
                H = penetration_cost(dynamics, cfg).W
            elif cfg.cost == "lp":
                H = DAQP_LP_SETTINGS["eps_prox"] * np.eye(cfg.horizon + 1)
            else:
                H, _ = pre_impact_cost(penetration_cost(dynamics, cfg), cfg)
            if eq12:
                pen = penetration_cost(dynamics, cfg)
                f = pen.y + pen.Y * x0
            elif cfg.cost == "lp":
                f = self._q_lp
            else:
                f = pre_impact_cost(penetration_cost(dynamics, cfg), cfg)[1]
            R = np.linalg.cholesky(H).T  # H = Rᵀ R
            M = np.linalg.solve(R.T, A.T).T  # A R⁻¹
            v = np.linalg.solve(R.T, f)
            recovery = 1e4 * np.finfo(float).eps * np.linalg.norm(v) * np.linalg.norm(M, axis=1)
            return cfg.primal_tol * np.linalg.norm(A, axis=1) + recovery + rounding
        if plan.solver != "osqp":
            raise ConfigError(f"unknown solver {plan.solver!r} in the plan")
        scale = np.full(cfg.horizon, cfg.input_scale)
        if not eq12:
            scale = np.concatenate([[1.0], scale])
        As = A * scale
        norms = np.linalg.norm(As, axis=1)
        norms[norms == 0.0] = 1.0
        Ax = (As / norms[:, None]) @ (x / scale)
        z = np.clip(Ax, lower / norms, upper / norms)
        eps = 1e-7 if eq12 else cfg.eps
        tol = eps + eps * max(np.max(np.abs(Ax)), np.max(np.abs(z)))
        return tol * norms + rounding

    def max_pre_impact_velocity(
        self,
        dynamics: DeformationDynamics,
        bounds: ContactSpaceBounds,
        material: SoftMaterial,
    ) -> PenetrationPlan:
        """Eq 14 (or its LP variant): the largest ż_imp (m/s) with a feasible penetration."""
        if self.config.solver == "daqp":
            return self._max_daqp(dynamics, bounds, material)
        return self._max_osqp(dynamics, bounds, material)

    def _eq14_cost(self, dynamics: DeformationDynamics) -> tuple[np.ndarray, np.ndarray, bool]:
        """``(W̃, w̃, changed)`` of eq 14 (LP variant: zero Hessian, cost −ż_imp)."""
        cfg = self.config
        if cfg.cost == "lp":
            assert self._const_hessian is not None  # zeros, set in __init__ for the LP variant
            return self._const_hessian, self._q_lp, False
        if self._const_hessian is not None:
            return self._const_hessian, self._const_cost, False
        Wt, wt = pre_impact_cost(penetration_cost(dynamics, cfg, self._work.predictions()), cfg)
        return Wt, wt, True

    def _max_daqp(
        self,
        dynamics: DeformationDynamics,
        bounds: ContactSpaceBounds,
        material: SoftMaterial,
    ) -> PenetrationPlan:
        self._check(dynamics, bounds)
        work = self._work
        work.update(dynamics, bounds, material)
        H, f, h_changed = self._eq14_cost(dynamics)
        self.stats["solves"] += 1
        for _attempt in range(2):
            if self._daqp is None:
                self._daqp = daqp.Model()
                settings = {"primal_tol": self.config.primal_tol}
                if self.config.cost == "lp":
                    settings.update(DAQP_LP_SETTINGS)
                self._daqp.settings = settings
                exitflag, _ = self._daqp.setup(
                    H, f, work.An, work.upper_n, work.lower_n, work.sense
                )
            else:
                kw = dict(A=work.An, bupper=work.upper_n, blower=work.lower_n)
                if h_changed:
                    kw.update(H=H, f=f)
                exitflag = self._daqp.update(**kw)
            if exitflag >= 0:
                x, _, exitflag, info = self._daqp.solve()
            if exitflag in DAQP_SOLVED:
                states, acc, forces = work.plan_arrays(x, dynamics)
                return PenetrationPlan(
                    pre_impact_velocity=float(x[0]),
                    inputs=x[1:].copy(),
                    states=states,
                    accelerations=acc,
                    forces=forces,
                    max_violation=work.violation(x),
                    iterations=int(info["iterations"]),
                    solve_time=float(info["solve_time"]),
                    solver="daqp",
                )
            # A failed warm start: drop the working set and solve once from scratch.
            self._daqp = None
            self.stats["failures"] += 1
        rows, _ = self.constraints(dynamics, bounds, material)
        return self._highs_fallback(rows, dynamics, bounds, material)

    def _max_osqp(
        self,
        dynamics: DeformationDynamics,
        bounds: ContactSpaceBounds,
        material: SoftMaterial,
    ) -> PenetrationPlan:
        cfg = self.config
        rows, pred = self.constraints(dynamics, bounds, material)
        A, lo, up = self._normalised(np.column_stack([rows.K, rows.X]) * self._scale, rows)
        kw = dict(Ax=self._max_A.values(A), l=lo, u=up)
        if self._max_P is not None:
            Wt, wt = pre_impact_cost(penetration_cost(dynamics, cfg, pred), cfg)
            kw.update(Px=self._max_P.values(Wt * np.outer(self._scale, self._scale)))
            kw.update(q=wt * self._scale)
        else:
            kw.update(q=self._q_lp)
        self._max.update(**kw)
        self.stats["solves"] += 1
        res = self._max.solve(raise_error=False)
        if res.info.status_val == osqp.SolverStatus.OSQP_SOLVED and res.info.status_polish == 1:
            x = res.x * self._scale
            return self._plan(
                x[0], x[1:], dynamics, bounds, material, res.info.iter, res.info.solve_time, "osqp"
            )
        self.stats["failures"] += 1
        return self._highs_fallback(rows, dynamics, bounds, material)

    def _highs_fallback(
        self,
        rows: ConstraintRows,
        dynamics: DeformationDynamics,
        bounds: ContactSpaceBounds,
        material: SoftMaterial,
    ) -> PenetrationPlan:
        """The eq 9–11 LP by HiGHS, when the QP solver failed (counted in ``stats``)."""
        self.stats["highs_fallbacks"] += 1
        x, runtime = _highs_max_velocity(rows)
        return self._plan(x[0], x[1:], dynamics, bounds, material, 0, runtime, "highs")

    def plan_penetration(
        self,
        dynamics: DeformationDynamics,
        bounds: ContactSpaceBounds,
        material: SoftMaterial,
        pre_impact_velocity: float,
    ) -> PenetrationPlan:
        """Eq 12: the penetration inputs for a given ż_imp (m/s); :class:`SolverError` if
        infeasible (ż_imp above the maximal safe pre-impact velocity)."""
        zdot = float(pre_impact_velocity)
        if not np.isfinite(zdot):
            raise InputError("pre_impact_velocity must be finite")
        cfg = self.config
        rows, pred = self.constraints(dynamics, bounds, material)
        cost = penetration_cost(dynamics, cfg, pred)
        if cfg.solver == "daqp":
            return self._plan_penetration_daqp(zdot, rows, cost, dynamics, bounds, material)
        su = cfg.input_scale
        shifted = ConstraintRows(
            K=rows.K, X=rows.X, lower=rows.lower - rows.K * zdot, upper=rows.upper - rows.K * zdot
        )
        A, lo, up = self._normalised(rows.X * su, shifted)
        self._pen.update(
            Px=self._pen_P.values(cost.W * su * su),
            q=(cost.y + cost.Y * zdot) * su,
            Ax=self._pen_A.values(A),
            l=lo,
            u=up,
        )
        res = self._pen.solve(raise_error=False)
        if res.info.status_val != osqp.SolverStatus.OSQP_SOLVED:
            raise SolverError(f"eq 12: OSQP status {res.info.status}")
        return self._plan(
            zdot, res.x * su, dynamics, bounds, material, res.info.iter, res.info.solve_time, "osqp"
        )

    def _plan_penetration_daqp(
        self,
        zdot: float,
        rows: ConstraintRows,
        cost: PenetrationCost,
        dynamics: DeformationDynamics,
        bounds: ContactSpaceBounds,
        material: SoftMaterial,
    ) -> PenetrationPlan:
        """Eq 12 by DAQP from scratch (strictly convex: W positive definite)."""
        shifted = ConstraintRows(
            K=rows.K, X=rows.X, lower=rows.lower - rows.K * zdot, upper=rows.upper - rows.K * zdot
        )
        A, lo, up = self._normalised(rows.X, shifted)
        lo = np.where(np.isfinite(lo), lo, -DAQP_INF)
        up = np.where(np.isfinite(up), up, DAQP_INF)
        sense = np.where(rows.lower == rows.upper, 5, 0).astype(np.int32)
        x, _, exitflag, info = daqp.solve(
            cost.W, cost.y + cost.Y * zdot, A, up, lo, sense, primal_tol=self.config.primal_tol
        )
        if exitflag not in DAQP_SOLVED:
            raise SolverError(f"eq 12: DAQP exit flag {exitflag}")
        return self._plan(
            zdot, x, dynamics, bounds, material, info["iterations"], info["solve_time"], "daqp"
        )
