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

Both problems are set up once in OSQP with a fixed sparsity pattern; every cycle only the
numbers are updated in place and the solve is warm-started from the previous solution.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import osqp
import scipy.sparse as sp
from scipy.optimize import linprog

from ffmpc_core.errors import ConfigError, InputError, SolverError
from ffmpc_core.impact.deformation import DeformationDynamics, SoftMaterial, simulate_deformation
from ffmpc_core.impact.limits import ContactSpaceBounds, _SparsePattern

__all__ = [
    "ConstraintRows",
    "ImpactPlanner",
    "PenetrationCost",
    "PenetrationPlan",
    "PlannerConfig",
    "constraint_violation",
    "penetration_constraints",
    "penetration_cost",
    "pre_impact_cost",
    "prediction_matrices",
]

_COSTS = ("qp", "lp")


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
        eps: OSQP absolute/relative tolerance of eq 14; the solution is then polished (exact
            active-set solve). A solve whose polish fails is redone by HiGHS (see ImpactPlanner).
        input_scale: internal scaling of u (m/s²) so that OSQP sees [ż_imp, u/input_scale] of
            similar magnitude; rows are also normalised. Does not change the solution.
    """

    horizon: int = 20
    dt: float = 0.025
    cost: str = "qp"
    control_effort_weight: float = 1e-2
    force_tracking_weight: float = 0.0
    target_force: float = 0.0
    velocity_weight: float = 1e3
    velocity_regularization: float = 1e-2
    max_halfplanes: int = 8
    eps: float = 1e-4
    input_scale: float = 100.0

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
        for name in ("velocity_weight", "velocity_regularization", "eps", "input_scale"):
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
            constraint's own units (m, m/s or m/s²); 0 when feasible.
        iterations: OSQP iterations. solve_time: solver time, s.
        solver: ``"osqp"`` or ``"highs"`` (fallback after a failed OSQP polish).
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


class ImpactPlanner:
    """Eq 12 (penetration QP for a given ż_imp) and eq 14 (maximal ż_imp), set up once in OSQP.

    Call :meth:`max_pre_impact_velocity` every control cycle with the current deformation
    dynamics (eq 3–8) and contact-space bounds (eq 9–11); :meth:`plan_penetration` solves eq 12
    for a given pre-impact velocity. Each problem keeps one OSQP instance with a fixed sparsity
    pattern: every call updates its numbers in place and OSQP warm-starts from the previous
    solution. Eq 14 is solved to ``eps`` and polished (the polish solves the identified active set
    exactly); if OSQP or its polish fails, the LP variant is solved by HiGHS instead, so the
    returned velocity is always an exact optimum (:attr:`stats` counts these fallbacks).
    """

    def __init__(self, config: PlannerConfig | None = None) -> None:
        self.config = config if config is not None else PlannerConfig()
        cfg = self.config
        h = cfg.horizon
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
            self._max_P = _SparsePattern(np.triu(np.ones((h + 1, h + 1), dtype=bool)))
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
        self._q_lp = np.zeros(h + 1)
        self._q_lp[0] = -1.0
        self.stats = {"solves": 0, "highs_fallbacks": 0}

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

    def max_pre_impact_velocity(
        self,
        dynamics: DeformationDynamics,
        bounds: ContactSpaceBounds,
        material: SoftMaterial,
    ) -> PenetrationPlan:
        """Eq 14 (or its LP variant): the largest ż_imp (m/s) with a feasible penetration."""
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
