"""Joint-space limits mapped to the contact space (Dehio & Kheddar 2020, Sec. III-B, eq 1, 2, 9–11).

Frames and units: the motion direction ``d`` is a unit vector in the world frame; the Jacobian is
the contact frame's, in pinocchio's ``LOCAL_WORLD_ALIGNED`` frame (6×n: linear m/rad on top,
angular rad/rad below). Contact-space quantities are scalars along ``d``: deformation rate ż
(m/s), acceleration z̈ (m/s²) and the pressing force f ≥ 0 (N, the force the robot exerts on the
material along ``d``; the material pushes the robot with ``−f·d``).

Three implementations are provided on purpose:

* the named functions :func:`deformation_velocity_bounds` (eq 9),
  :func:`acceleration_force_vertices` (eq 10) and :func:`halfplanes_from_vertices` (eq 11, Qhull)
  solve with HiGHS (``scipy.optimize.linprog``): a clear reference, ~1 ms per LP;
* :class:`ContactSpaceMapper` with ``solver="daqp"`` (the default hot path): eq 9 in closed form
  (:func:`deformation_velocity_bounds_closed_form`), the eq 10 LPs reduced to the task null
  space (:func:`task_reduction`) and solved by one warm-started DAQP workspace, eq 11 in closed
  form from the ordered support points (:func:`halfplanes_from_support_points`);
* :class:`ContactSpaceMapper` with ``solver="osqp"``: one OSQP instance per LP, built once and
  updated in place, polished so that LP solutions are exact vertices (kept as a reference).

All take their data from the same builders (:func:`velocity_lp_data`, :func:`vertex_lp_data`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypedDict

import daqp
import numpy as np
import osqp
import pinocchio as pin
import scipy.sparse as sp
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, QhullError

from ffmpc_core.datasheet import PANDA
from ffmpc_core.errors import ConfigError, InputError, SolverError
from ffmpc_core.impact.deformation import effective_mass_from, unit_direction
from ffmpc_core.robots import RobotModel, mass_matrix

__all__ = [
    "MAPPER_SOLVERS",
    "PANDA_ACCELERATION_LIMIT",
    "ContactSpaceBounds",
    "ContactSpaceMapper",
    "JointLimits",
    "acceleration_force_vertices",
    "deformation_velocity_bounds",
    "deformation_velocity_bounds_closed_form",
    "halfplanes_from_support_points",
    "halfplanes_from_vertices",
    "joint_limits",
    "motion_basis",
    "position_aware_velocity_limits",
    "split_jacobian",
    "task_reduction",
    "velocity_lp_data",
    "vertex_directions",
    "vertex_lp_data",
]

#: Franka Emika Panda data sheet ("Robot and interface specifications", limits in joint space):
#: maximum joint accelerations q̈_max, rad/s² (:data:`ffmpc_core.datasheet.PANDA`, where the
#: torque, velocity and position limits of :class:`RobotModel` come from too).
PANDA_ACCELERATION_LIMIT = np.array(PANDA.acceleration)

#: Solvers of :class:`ContactSpaceMapper` (and :class:`~ffmpc_core.impact.planner.ImpactPlanner`).
MAPPER_SOLVERS = ("daqp", "osqp")
#: DAQP's infinity: bounds at or beyond it are ignored by the solver.
DAQP_INF = 1e30
#: DAQP exit flags counted as solved (1: optimal, 2: optimal with soft constraints); anything
#: else (e.g. 4, which DAQP 0.11 returned when primal_tol was below its noise floor) is a failure.
DAQP_SOLVED = (1, 2)
#: DAQP settings for LPs (zero Hessian: DAQP iterates proximal-point QPs). With its defaults
#: (proximal weight 1e-6 when needed, automatic stopping) the eq 14 LP stopped up to 4e-5 m/s
#: short of HiGHS's optimum with row violations up to 2e-8; a proximal weight of 1e-3 and a
#: 1e-12 stopping tolerance gave ≤ 4e-9 m/s and ≤ 2e-12 on the same problems.
DAQP_LP_SETTINGS = {"eps_prox": 1e-3, "eta_prox": 1e-12}

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
_OSQP_LP_SETTINGS = dict(
    verbose=False,
    polishing=True,
    polish_refine_iter=5,
    eps_abs=1e-6,
    eps_rel=1e-6,
    max_iter=4000,
    warm_starting=True,
)


@dataclass(frozen=True)
class JointLimits:
    """Symmetric joint limits of eq 1b–1e (one entry per joint).

    Attributes:
        position_lower, position_upper: q̲, q̄ (rad).
        velocity: |q̇| ≤ velocity (rad/s).
        acceleration: |q̈| ≤ acceleration (rad/s²).
        torque: |τ| ≤ torque (N·m).
    """

    position_lower: np.ndarray
    position_upper: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    torque: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.velocity).size
        for name in ("position_lower", "position_upper", "velocity", "acceleration", "torque"):
            arr = np.asarray(getattr(self, name), dtype=float)
            if arr.shape != (n,) or not np.all(np.isfinite(arr)):
                raise ConfigError(f"JointLimits.{name} must be a finite vector of size {n}")
            object.__setattr__(self, name, arr.copy())
        if np.any(self.velocity <= 0) or np.any(self.acceleration <= 0) or np.any(self.torque <= 0):
            raise ConfigError("velocity, acceleration and torque limits must be positive")
        if np.any(self.position_lower >= self.position_upper):
            raise ConfigError("position_lower must be below position_upper")


def joint_limits(robot: RobotModel, acceleration_limit: np.ndarray | None = None) -> JointLimits:
    """Eq 1b–1e limits of ``robot``: positions, velocities and torques from the model.

    Acceleration limits are not in the URDF: the robot's data sheet's are used by default
    (:attr:`RobotModel.datasheet`: the Panda's :data:`PANDA_ACCELERATION_LIMIT`); a robot whose
    data sheet has none (the iiwa) needs ``acceleration_limit`` (rad/s²) explicitly (no
    invented default).
    """
    if acceleration_limit is None:
        acceleration_limit = robot.datasheet.acceleration
        if acceleration_limit is None:
            raise ConfigError(
                f"no data-sheet joint acceleration limits for {robot.name!r}: "
                "pass acceleration_limit"
            )
    return JointLimits(
        position_lower=robot.position_lower,
        position_upper=robot.position_upper,
        velocity=robot.velocity_limit,
        acceleration=np.asarray(acceleration_limit, dtype=float),
        torque=robot.torque_limit,
    )


def motion_basis(direction: np.ndarray) -> np.ndarray:
    """Eq 2: orthonormal 6×6 basis ``O = [o1, o2..6]`` with ``o1 = [d; 0]``.

    ``o2, o3`` complete ``d`` to an orthonormal basis of the linear velocities (world frame) and
    ``o4..6`` are the angular axes, so ``O`` is orthogonal (``Oᵀ O = I``).
    """
    d = unit_direction(direction)
    # Householder reflection mapping e1 to d: an orthogonal matrix whose first column is d.
    e1 = np.array([1.0, 0.0, 0.0])
    w = e1 - d
    nw = float(w @ w)
    H = np.eye(3) if nw < 1e-24 else np.eye(3) - 2.0 * np.outer(w, w) / nw
    basis = np.zeros((6, 6))
    basis[:3, :3] = H
    basis[3:, 3:] = np.eye(3)
    return basis


def split_jacobian(jacobian: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq 2: ``J_A = o1ᵀ J`` (n,) along the motion and ``J_B = o2..6ᵀ J`` (5×n)."""
    JO = basis.T @ jacobian
    return JO[0].copy(), JO[1:].copy()


def position_aware_velocity_limits(
    q: np.ndarray, limits: JointLimits
) -> tuple[np.ndarray, np.ndarray]:
    """Joint velocity bounds (rad/s) combining eq 1c with the position limits eq 1b.

    The paper lists eq 1b but does not say how it enters the contact-space mapping. We bound the
    velocity by the speed from which the joint can still brake before its position limit at its
    acceleration limit: ``q̇ ≤ min(q̇_max, sqrt(2 q̈_max (q̄ − q)))`` and symmetrically below.
    """
    up = np.sqrt(2.0 * limits.acceleration * np.maximum(limits.position_upper - q, 0.0))
    lo = np.sqrt(2.0 * limits.acceleration * np.maximum(q - limits.position_lower, 0.0))
    return -np.minimum(limits.velocity, lo), np.minimum(limits.velocity, up)


@dataclass(frozen=True)
class VelocityLP:
    """Data of eq 9 (variables q̇, rad/s): ``min c·q̇`` s.t. ``J_B q̇ = 0``, ``lower ≤ q̇ ≤ upper``."""

    J_A: np.ndarray
    J_B: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


def velocity_lp_data(
    J_A: np.ndarray, J_B: np.ndarray, lower: np.ndarray, upper: np.ndarray
) -> VelocityLP:
    """Eq 9 data; ``lower/upper`` are joint velocity bounds (rad/s)."""
    return VelocityLP(J_A=J_A, J_B=J_B, lower=lower, upper=upper)


def _highs_velocity(lp: VelocityLP, sign: float) -> float:
    """One eq 9 LP by HiGHS: ``min sign·J_A q̇`` → the extreme ż (m/s)."""
    res = linprog(
        sign * lp.J_A,
        A_eq=lp.J_B,
        b_eq=np.zeros(lp.J_B.shape[0]),
        bounds=list(zip(lp.lower, lp.upper, strict=True)),
        method="highs",
    )
    if res.status != 0:
        raise SolverError(f"eq 9 velocity LP failed: {res.message}")
    return float(lp.J_A @ res.x)


def deformation_velocity_bounds(lp: VelocityLP) -> tuple[float, float]:
    """Eq 9 by HiGHS: ``(ż̲, ż̄)`` (m/s), the extreme end-effector speeds along ``d`` with zero
    velocity in the five other task directions and joint velocities within bounds."""
    return _highs_velocity(lp, 1.0), _highs_velocity(lp, -1.0)


def task_reduction(J_A: np.ndarray, J_B: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Solutions of ``J_A x = s``, ``J_B x = r`` (eq 2 split, ``J = [J_A; J_B]`` 6×n) in closed
    form: ``x = J⁺ [s; r] + N β`` with ``J⁺`` (n×6) the pseudo-inverse and ``N`` (n×(n−6)) an
    orthonormal basis of ``ker J``, both from one SVD. Returns ``(J⁺, N)``, or ``None`` when
    ``J`` is rank deficient (σ_min ≤ 1e-9 σ_max: a kinematic singularity, the callers then use
    the LP references)."""
    J = np.empty((6, J_A.size))
    J[0] = J_A
    J[1:] = J_B
    U, S, Vt = np.linalg.svd(J)
    if not (S[-1] > 1e-9 * S[0]):
        return None
    pinv = (Vt[:6].T / S) @ U.T
    return pinv, Vt[6:].T


def deformation_velocity_bounds_closed_form(
    J_A: np.ndarray,
    J_B: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    reduction: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[float, float] | None:
    """Eq 9 in closed form: ``(ż̲, ż̄)`` (m/s) without an LP solver.

    ``J_B q̇ = 0`` and ``J_A q̇ = ż`` give ``q̇ = c ż + N β`` (:func:`task_reduction`, ``c`` the
    first column of ``J⁺``), and eq 9 becomes: the range of ``ż`` such that some ``β`` satisfies
    ``lower ≤ c ż + N β ≤ upper`` (joint velocity bounds, rad/s), i.e. the projection of that
    polytope on ``ż``. For a 6-joint arm (no ``β``) it is the intersection of the intervals
    ``lower_i ≤ c_i ż ≤ upper_i``. For a 7-joint arm (``N`` = one vector ``m``) β is eliminated
    exactly (Fourier–Motzkin): joint i bounds β between ``L_i(ż) = α_i + γ_i ż`` and
    ``U_i(ż) = δ_i + γ_i ż`` (``γ_i = −c_i/m_i``), and a β exists iff ``L_i(ż) ≤ U_j(ż)`` for
    every pair (i, j): ``(γ_i − γ_j) ż ≤ δ_j − α_i``, one bound on ż per pair; joints with
    ``m_i = 0`` bound ż directly. ``0`` is feasible (``lower ≤ 0 ≤ upper``), so the range holds 0.
    Returns ``None`` at a singularity (the caller then uses the LP) or for more than one
    redundant joint.
    """
    red = reduction if reduction is not None else task_reduction(J_A, J_B)
    if red is None or red[1].shape[1] > 1:
        return None
    c = red[0][:, 0]
    if red[1].shape[1] == 1 and np.all(np.abs(red[1][:, 0]) > 1e-12):
        # Every joint moves with β (the usual case): pairs only.
        m = red[1][:, 0]
        pos = m > 0
        alpha = np.where(pos, lower, upper) / m  # β ≥ α_i + γ_i ż
        delta = np.where(pos, upper, lower) / m  # β ≤ δ_i + γ_i ż
        gamma = -c / m
        k = gamma[:, None] - gamma[None, :]  # pair (i, j): k ż ≤ δ_j − α_i
        bound = np.divide(delta[None, :] - alpha[:, None], k, where=k != 0.0, out=_nan_like(k))
        up_pairs, lo_pairs = bound[k > 0], bound[k < 0]
        if up_pairs.size == 0 or lo_pairs.size == 0:
            return None
        return float(lo_pairs.max()), float(up_pairs.min())
    if red[1].shape[1] == 1:
        m = red[1][:, 0]
        free = np.abs(m) > 1e-12
    else:
        m = np.zeros_like(c)
        free = np.zeros(c.size, dtype=bool)
    z_lo, z_hi = -np.inf, np.inf
    direct = ~free & (np.abs(c) > 0.0)
    if np.any(direct):
        cd, lo_d, up_d = c[direct], lower[direct], upper[direct]
        pos = cd > 0
        z_hi = float(np.min(np.where(pos, up_d, lo_d) / cd))
        z_lo = float(np.max(np.where(pos, lo_d, up_d) / cd))
    if np.any(free):
        mf, cf = m[free], c[free]
        pos = mf > 0
        alpha = np.where(pos, lower[free], upper[free]) / mf
        delta = np.where(pos, upper[free], lower[free]) / mf
        gamma = -cf / mf
        k = gamma[:, None] - gamma[None, :]
        bound = np.divide(delta[None, :] - alpha[:, None], k, where=k != 0.0, out=_nan_like(k))
        up_pairs, lo_pairs = bound[k > 0], bound[k < 0]
        if up_pairs.size:
            z_hi = min(z_hi, float(up_pairs.min()))
        if lo_pairs.size:
            z_lo = max(z_lo, float(lo_pairs.max()))
    if not (np.isfinite(z_lo) and np.isfinite(z_hi)):
        return None
    return z_lo, z_hi


def _nan_like(a: np.ndarray) -> np.ndarray:
    return np.full_like(a, np.nan)


@dataclass(frozen=True)
class VertexLP:
    """Data of eq 10 with variables ``x = [q̈ (rad/s²), z̈ (m/s²), f (N)]``.

    ``A_eq x = b_eq``: ``J_B q̈ = −J̇_B q̇`` and ``J_A q̈ − z̈ = −J̇_A q̇`` (the paper prints
    ``J q̇_cur`` on the right-hand side; the task acceleration is ``J q̈ + J̇ q̇``).
    ``lower ≤ A_in x ≤ upper``: ``q̲̈ ≤ q̈ ≤ q̄̈``; ``τ̲ − h ≤ M q̈ + J_Aᵀ f ≤ τ̄ − h``; ``0 ≤ f``.
    """

    A_eq: np.ndarray
    b_eq: np.ndarray
    A_in: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


def vertex_lp_data(
    J_A: np.ndarray,
    J_B: np.ndarray,
    drift_A: float,
    drift_B: np.ndarray,
    inertia: np.ndarray,
    nonlinear_effects: np.ndarray,
    limits: JointLimits,
) -> VertexLP:
    """Eq 10 data. ``drift_A = J̇_A q̇`` (m/s²), ``drift_B = J̇_B q̇`` (5,), ``inertia`` = M
    (kg·m²), ``nonlinear_effects`` = h (N·m, gravity + Coriolis at the current state)."""
    n = J_A.size
    A_eq = np.zeros((J_B.shape[0] + 1, n + 2))
    A_eq[:-1, :n] = J_B
    A_eq[-1, :n] = J_A
    A_eq[-1, n] = -1.0
    b_eq = np.concatenate([-drift_B, [-drift_A]])
    A_in = np.zeros((2 * n + 1, n + 2))
    A_in[:n, :n] = np.eye(n)
    A_in[n : 2 * n, :n] = inertia
    A_in[n : 2 * n, n + 1] = J_A
    A_in[2 * n, n + 1] = 1.0
    lower = np.concatenate([-limits.acceleration, -limits.torque - nonlinear_effects, [0.0]])
    upper = np.concatenate([limits.acceleration, limits.torque - nonlinear_effects, [np.inf]])
    return VertexLP(A_eq=A_eq, b_eq=b_eq, A_in=A_in, lower=lower, upper=upper)


def vertex_directions(n_directions: int, effective_mass: float) -> np.ndarray:
    """Weights ``(ω_z̈, ω_f)`` of eq 10 (to be *maximised*), one row per direction.

    Directions are equally spaced angles in the plane ``(z̈, f/Λ)`` (both m/s²; Λ in kg), which
    makes the polygon roughly isotropic, offset by half a step from the axes: the polytope has
    edges parallel to the axes (``f = 0``, joint-acceleration-limited ``z̈``), and an axis-aligned
    weight would make the LP optimum a whole edge (non-unique), which ADMM solves poorly.
    """
    if n_directions < 3:
        raise ConfigError("need at least 3 vertex directions for a polygon")
    theta = 2.0 * np.pi * (np.arange(n_directions) + 0.5) / n_directions
    return np.column_stack([np.cos(theta), np.sin(theta) / effective_mass])


def _highs_vertex(lp: VertexLP, weight: np.ndarray) -> np.ndarray:
    """One eq 10 LP by HiGHS: the ``(z̈, f)`` (m/s², N) maximising ``weight·(z̈, f)``."""
    n = lp.A_eq.shape[1] - 2
    A_ub = np.vstack([lp.A_in, -lp.A_in])
    b_ub = np.concatenate([lp.upper, -lp.lower])
    keep = np.isfinite(b_ub)
    c = np.zeros(n + 2)
    c[n:] = -np.asarray(weight, dtype=float)
    res = linprog(
        c,
        A_ub=A_ub[keep],
        b_ub=b_ub[keep],
        A_eq=lp.A_eq,
        b_eq=lp.b_eq,
        bounds=[(None, None)] * (n + 2),
        method="highs",
    )
    if res.status != 0:
        raise SolverError(f"eq 10 vertex LP failed: {res.message}")
    return res.x[n:].copy()


def acceleration_force_vertices(lp: VertexLP, weights: np.ndarray) -> np.ndarray:
    """Eq 10 by HiGHS: one vertex ``(z̈, f)`` (m/s², N) per weight row, maximising ``ω·(z̈, f)``."""
    return np.array([_highs_vertex(lp, w) for w in weights])


def halfplanes_from_vertices(
    vertices: np.ndarray, effective_mass: float
) -> tuple[np.ndarray, np.ndarray]:
    """Eq 11: half-plane form ``P [z̈; f] ≤ p`` of the convex hull of ``vertices`` (z̈ m/s², f N).

    The hull is computed (scipy/Qhull) in the scaled plane ``(z̈, f/Λ)``; each row of ``P`` is a
    unit normal there, so ``P`` has units [1, 1/kg] and ``p`` m/s². The hull of LP vertices is an
    inner approximation of the true polytope: constraints built from it are conservative.
    Raises :class:`SolverError` if the vertices do not span a polygon.
    """
    scaled = np.column_stack([vertices[:, 0], vertices[:, 1] / effective_mass])
    try:
        hull = ConvexHull(scaled)
    except (QhullError, ValueError) as exc:
        raise SolverError(f"eq 11: acceleration/force polytope is degenerate: {exc}") from exc
    eq = hull.equations
    P = np.column_stack([eq[:, 0], eq[:, 1] / effective_mass])
    return P, -eq[:, 2]


def halfplanes_from_support_points(
    vertices: np.ndarray, effective_mass: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """Eq 11 in closed form: ``P [z̈; f] ≤ p`` from the eq 10 support points in weight order.

    The eq 10 vertices of the weight directions of :func:`vertex_directions` (angles increasing,
    counter-clockwise in the scaled plane ``(z̈, f/Λ)``) are the support points of the polytope in
    those directions, hence its hull vertices in counter-clockwise order: repeated points and
    points on an edge between their neighbours are dropped and each remaining edge gives one
    half-plane (unit outward normal in the scaled plane, as :func:`halfplanes_from_vertices`).
    Returns ``None`` if the ordered points are not a convex counter-clockwise polygon of at least
    3 vertices (the caller then uses Qhull).
    """
    # Plain floats: a handful of points, where numpy's per-call cost would dominate.
    pts = [(z, f / effective_mass) for z, f in np.asarray(vertices, dtype=float).tolist()]
    scale = 1.0 + max(max(abs(x), abs(y)) for x, y in pts)
    tol = 1e-7 * scale  # well above the LP solvers' accuracy (~1e-9), in m/s²
    # Repeated support points (several directions on one vertex): keep one.
    pts = [p for k, p in enumerate(pts) if math.dist(p, pts[k - 1]) > tol]
    if len(pts) < 3:
        return None
    # Points on the chord of their neighbours are not hull vertices; a right turn beyond the
    # tolerance means the points are not a convex counter-clockwise polygon.
    hull = []
    m = len(pts)
    for k in range(m):
        (x0, y0), (x1, y1), (x2, y2) = pts[k - 1], pts[k], pts[(k + 1) % m]
        cross = (x1 - x0) * (y2 - y1) - (y1 - y0) * (x2 - x1)
        chord = math.hypot(x2 - x0, y2 - y0)
        if cross < -tol * chord:
            return None
        if cross > tol * chord:
            hull.append((x1, y1))
    if len(hull) < 3:
        return None
    m = len(hull)
    normal = np.empty((m, 2))
    offset = np.empty(m)
    for k in range(m):
        (x0, y0), (x1, y1) = hull[k], hull[(k + 1) % m]
        length = math.hypot(x1 - x0, y1 - y0)
        nx, ny = (y1 - y0) / length, (x0 - x1) / length
        normal[k] = nx, ny
        offset[k] = nx * x0 + ny * y0
    if np.any(np.array(pts) @ normal.T > offset + tol):
        return None
    P = np.column_stack([normal[:, 0], normal[:, 1] / effective_mass])
    return P, offset


@dataclass(frozen=True)
class ContactSpaceBounds:
    """Contact-space bounds at one robot state (Sec. III-B).

    Attributes:
        velocity_lower, velocity_upper: ż̲ ≤ ż ≤ ż̄ (m/s), eq 9.
        halfplane_normals: P (k×2, [1, 1/kg]) and halfplane_offsets: p (k,, m/s²) of eq 11.
        vertices: the eq 10 vertices (N×2: z̈ m/s², f N).
        effective_mass: Λ (kg) along the motion direction (footnote 1).
        direction: the unit motion direction (world frame).
    """

    velocity_lower: float
    velocity_upper: float
    halfplane_normals: np.ndarray
    halfplane_offsets: np.ndarray
    vertices: np.ndarray
    effective_mass: float
    direction: np.ndarray

    def acceleration_range(self, force: float = 0.0) -> tuple[float, float]:
        """Range of z̈ (m/s²) allowed by eq 11 at the pressing force ``force`` (N)."""
        a, b = self.halfplane_normals[:, 0], self.halfplane_normals[:, 1]
        rhs = self.halfplane_offsets - b * force
        with np.errstate(divide="ignore"):
            hi = np.min(np.where(a > 1e-12, rhs / np.where(a > 1e-12, a, 1.0), np.inf))
            lo = np.max(np.where(a < -1e-12, rhs / np.where(a < -1e-12, a, 1.0), -np.inf))
        return float(lo), float(hi)


class _SparsePattern:
    """A fixed CSC sparsity pattern with a map from a dense matrix to its data array."""

    def __init__(self, mask: np.ndarray) -> None:
        self.matrix = sp.csc_matrix(mask.astype(float))
        self.matrix.sort_indices()
        cols = np.repeat(np.arange(mask.shape[1]), np.diff(self.matrix.indptr))
        self.index = (self.matrix.indices.copy(), cols)

    def values(self, dense: np.ndarray) -> np.ndarray:
        return dense[self.index]


class ContactKinematics(TypedDict):
    """Pinocchio quantities of :meth:`ContactSpaceMapper.kinematics` at one (q, v)."""

    J_A: np.ndarray  # Jacobian row along the impact direction d (n entries)
    J_B: np.ndarray  # Jacobian rows of the five other task directions (5 × n)
    drift_A: float  # J̇q̇ along d, m/s²
    drift_B: np.ndarray  # J̇q̇ of the five other directions (m/s², rad/s²)
    M: np.ndarray  # joint-space mass matrix, kg·m²
    h: np.ndarray  # nonlinear effects, N·m
    effective_mass: float  # Λ along d, kg


class ContactSpaceMapper:
    """Hot-path mapping of joint limits to contact-space bounds (eq 9–11), built once.

    ``solver="daqp"`` (default): eq 9 in closed form
    (:func:`deformation_velocity_bounds_closed_form`); the eq 10 LPs in the reduced variables
    ``x = [z̈, β, f/Λ]`` (``q̈ = J⁺([z̈; 0] − J̇q̇) + N β``, :func:`task_reduction`), whose
    constraints are the same for every weight direction: one DAQP workspace is set up once,
    its rows updated in place each cycle, and the directions solved in angular order, each
    warm-started from the working set of the previous one (the last direction neighbours the
    first of the next cycle); eq 11 from the ordered support points
    (:func:`halfplanes_from_support_points`). At a kinematic singularity, or when DAQP fails, the
    HiGHS references are used instead (counted in :attr:`stats`).

    ``solver="osqp"``: every LP has its own OSQP instance (two for eq 9, one per weight
    direction for eq 10), set up once with a fixed sparsity pattern and updated in place each
    control cycle, so that each keeps its own warm start (its previous-cycle primal/dual
    solution) and step size ρ. OSQP solves the LPs with polishing, which returns the exact vertex
    when it succeeds; an LP whose OSQP solve or polish fails is re-solved by HiGHS (counted in
    :attr:`stats`), so a bound is never the output of an unconverged ADMM run.

    Pinocchio workspaces are preallocated.

    Args:
        robot: the robot model (contact frame = end-effector).
        limits: eq 1 joint limits.
        direction: unit motion direction, world frame.
        n_directions: number of eq 10 weight directions (vertices), ≥ 3 (the paper used 6).
        solver: ``"daqp"`` (closed forms + DAQP) or ``"osqp"`` (one OSQP instance per LP).
    """

    def __init__(
        self,
        robot: RobotModel,
        limits: JointLimits,
        direction: np.ndarray,
        n_directions: int = 8,
        solver: str = "daqp",
    ) -> None:
        if limits.velocity.size != robot.nv:
            raise ConfigError(f"limits are for {limits.velocity.size} joints, robot has {robot.nv}")
        if solver not in MAPPER_SOLVERS:
            raise ConfigError(f"solver must be one of {MAPPER_SOLVERS}, got {solver!r}")
        if solver == "daqp" and robot.nv not in (6, 7):
            raise ConfigError(
                f"the closed-form eq 9 handles 6- and 7-joint arms, {robot.name} has {robot.nv}: "
                "use solver='osqp'"
            )
        self.solver = solver
        self.robot = robot
        self.limits = limits
        self.n_directions = int(n_directions)
        vertex_directions(self.n_directions, 1.0)  # validates the count
        self._data = robot.create_data()
        self.set_direction(direction)
        n = robot.nv
        self._n = n
        self._zero_nv = np.zeros(n)
        theta = 2.0 * np.pi * (np.arange(self.n_directions) + 0.5) / self.n_directions
        self._weights = np.column_stack([np.cos(theta), np.sin(theta)])  # ÷ Λ in column 1
        # eq 9: variables q̇ (n); rows [J_B; I].
        vel_mask = np.vstack([np.ones((5, n)), np.eye(n)])
        self._vel_pattern = _SparsePattern(vel_mask)
        self._vel = [self._lp_solver(n, self._vel_pattern, 5 + n) for _ in range(2)]
        # eq 10: variables [q̈ (n), z̈, f]; rows [J_B 0 0; J_A −1 0; I 0 0; M 0 J_Aᵀ; 0 0 1].
        vmask = np.zeros((6 + 2 * n + 1, n + 2))
        vmask[:6, :n] = 1.0
        vmask[5, n] = 1.0
        vmask[6 : 6 + n, :n] = np.eye(n)
        vmask[6 + n : 6 + 2 * n, :n] = 1.0
        vmask[6 + n : 6 + 2 * n, n + 1] = 1.0
        vmask[6 + 2 * n, n + 1] = 1.0
        self._vtx_pattern = _SparsePattern(vmask)
        self._vtx = [
            self._lp_solver(n + 2, self._vtx_pattern, vmask.shape[0])
            for _ in range(self.n_directions)
        ]
        self._A_vel = np.zeros(vel_mask.shape)
        self._A_vel[5:] = np.eye(n)
        self._A_vtx = np.zeros(vmask.shape)
        self._vtx_cost = np.zeros(n + 2)
        self.stats = {"lp_solves": 0, "highs_fallbacks": 0, "qhull_fallbacks": 0}
        # DAQP eq 10 workspace: variables [z̈, β (n−6), f/Λ]; rows [q̈ box (n); torque (n); f ≥ 0].
        k = n - 6
        self._nx = 2 + k
        self._daqp_A = np.zeros((2 * n + 1, self._nx))
        self._daqp_A[2 * n, -1] = 1.0
        self._daqp_lo = np.zeros(2 * n + 1)
        self._daqp_up = np.zeros(2 * n + 1)
        self._daqp_up[2 * n] = DAQP_INF
        self._daqp_f = np.zeros(self._nx)
        self._daqp: daqp.Model | None = None

    @staticmethod
    def _lp_solver(n_var: int, pattern: _SparsePattern, n_rows: int) -> osqp.OSQP:
        solver = osqp.OSQP()
        solver.setup(
            sp.csc_matrix((n_var, n_var)),
            np.zeros(n_var),
            pattern.matrix,
            np.zeros(n_rows),
            np.zeros(n_rows),
            **_OSQP_LP_SETTINGS,
        )
        return solver

    def set_direction(self, direction: np.ndarray) -> None:
        """Change the unit motion direction (world frame); the solvers are kept."""
        self.direction = unit_direction(direction)
        self.basis = motion_basis(self.direction)
        self._basis_T = np.ascontiguousarray(self.basis.T)

    def kinematics(self, q: np.ndarray, v: np.ndarray) -> ContactKinematics:
        """Pinocchio quantities at (q rad, v rad/s): J_A, J_B, drifts J̇q̇ (m/s², rad/s²),
        M (kg·m²), h (N·m) and the effective mass Λ (kg)."""
        model, data, fid = self.robot.model, self._data, self.robot.contact_frame_id
        pin.forwardKinematics(model, data, q, v, self._zero_nv)
        pin.computeJointJacobians(model, data)  # from the placements just computed
        pin.updateFramePlacements(model, data)
        JO = self._basis_T @ pin.getFrameJacobian(model, data, fid, _LWA)  # eq 2 split
        drift = self._basis_T @ pin.getFrameClassicalAcceleration(model, data, fid, _LWA).vector
        M = mass_matrix(model, data, q)
        h = pin.nonLinearEffects(model, data, q, v).copy()
        Minv = pin.computeMinverse(model, data, q)
        return {
            "J_A": JO[0],
            "J_B": JO[1:],
            "drift_A": float(drift[0]),
            "drift_B": drift[1:],
            "M": M,
            "h": h,
            "effective_mass": effective_mass_from(JO[0], Minv),
        }

    def _osqp(self, solver: osqp.OSQP, cost: np.ndarray) -> np.ndarray | None:
        """Solve one LP; ``None`` if OSQP or its polish did not succeed."""
        self.stats["lp_solves"] += 1
        solver.update(q=cost)
        res = solver.solve(raise_error=False)
        if res.info.status_val != osqp.SolverStatus.OSQP_SOLVED or res.info.status_polish != 1:
            self.stats["highs_fallbacks"] += 1
            return None
        return res.x

    def velocity_bounds(
        self, J_A: np.ndarray, J_B: np.ndarray, q: np.ndarray
    ) -> tuple[float, float]:
        """Eq 9 at joint positions ``q`` (rad): ``(ż̲, ż̄)`` in m/s."""
        lower, upper = position_aware_velocity_limits(q, self.limits)
        self._A_vel[:5] = J_B
        Ax = self._vel_pattern.values(self._A_vel)
        lo = np.concatenate([np.zeros(5), lower])
        up = np.concatenate([np.zeros(5), upper])
        out = []
        for solver, sign in zip(self._vel, (1.0, -1.0), strict=True):
            solver.update(Ax=Ax, l=lo, u=up)
            x = self._osqp(solver, sign * J_A)
            if x is None:
                out.append(_highs_velocity(velocity_lp_data(J_A, J_B, lower, upper), sign))
            else:
                out.append(float(J_A @ x))
        return out[0], out[1]

    def vertices(self, lp: VertexLP, weights: np.ndarray) -> np.ndarray:
        """Eq 10: the vertices ``(z̈, f)`` (m/s², N), one per weight row (maximised)."""
        n = self._n
        self._A_vtx[:6] = lp.A_eq
        self._A_vtx[6:] = lp.A_in
        Ax = self._vtx_pattern.values(self._A_vtx)
        lo = np.concatenate([lp.b_eq, lp.lower])
        up = np.concatenate([lp.b_eq, lp.upper])
        out = np.empty((len(weights), 2))
        for k, (solver, w) in enumerate(zip(self._vtx, weights, strict=True)):
            solver.update(Ax=Ax, l=lo, u=up)
            self._vtx_cost[n:] = -w
            x = self._osqp(solver, self._vtx_cost)
            out[k] = _highs_vertex(lp, w) if x is None else x[n:]
        return out

    def _daqp_vertices(
        self,
        kin: ContactKinematics,
        reduction: tuple[np.ndarray, np.ndarray],
        weights: np.ndarray,
    ) -> np.ndarray | None:
        """Eq 10 by DAQP in the reduced variables (see the class docstring); ``None`` if a solve
        fails (the caller then uses HiGHS)."""
        n, lim = self._n, self.limits
        pinv, N = reduction
        lam = float(kin["effective_mass"])
        c = pinv[:, 0]
        drift = np.empty(6)
        drift[0] = kin["drift_A"]
        drift[1:] = kin["drift_B"]
        qdd0 = -(pinv @ drift)
        M = kin["M"]
        A, lo, up = self._daqp_A, self._daqp_lo, self._daqp_up
        A[:n, 0] = c
        A[:n, 1:-1] = N
        A[n : 2 * n, 0] = M @ c
        A[n : 2 * n, 1:-1] = M @ N
        A[n : 2 * n, -1] = lam * kin["J_A"]
        np.subtract(-lim.acceleration, qdd0, out=lo[:n])
        np.subtract(lim.acceleration, qdd0, out=up[:n])
        bias = kin["h"] + M @ qdd0
        np.subtract(-lim.torque, bias, out=lo[n : 2 * n])
        np.subtract(lim.torque, bias, out=up[n : 2 * n])
        # No row scaling here: DAQP scales the rows of A R⁻¹ to unit norm itself.
        An, lon, upn = A, lo, up
        f = self._daqp_f
        out = np.empty((len(weights), 2))
        for k, w in enumerate(weights):
            f[0] = -w[0]
            f[-1] = -w[1] * lam
            self.stats["lp_solves"] += 1
            if self._daqp is None:
                self._daqp = daqp.Model()
                self._daqp.settings = DAQP_LP_SETTINGS
                self._daqp.setup(np.zeros((self._nx, self._nx)), f, An, upn, lon)
            elif k == 0:
                self._daqp.update(f=f, A=An, bupper=upn, blower=lon)
            else:
                self._daqp.update(f=f)
            x, _, exitflag, _ = self._daqp.solve()
            if exitflag not in DAQP_SOLVED:
                self._daqp = None  # rebuild from scratch next time (no stale working set)
                self.stats["highs_fallbacks"] += 1
                return None
            out[k, 0] = x[0]
            out[k, 1] = x[-1] * lam
        return out

    def update(self, q: np.ndarray, v: np.ndarray) -> ContactSpaceBounds:
        """Contact-space bounds at joint positions ``q`` (rad) and velocities ``v`` (rad/s)."""
        n = self._n
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if q.shape != (n,) or v.shape != (n,) or not np.all(np.isfinite(q) & np.isfinite(v)):
            raise InputError(f"q and v must be finite vectors of size {n}")
        kin = self.kinematics(q, v)
        J_A, J_B = kin["J_A"], kin["J_B"]
        lam = float(kin["effective_mass"])
        weights = self._weights.copy()
        weights[:, 1] /= lam  # = vertex_directions(self.n_directions, lam)
        vertices: np.ndarray | None
        if self.solver == "osqp":
            zdot_lower, zdot_upper = self.velocity_bounds(J_A, J_B, q)
            lp = vertex_lp_data(
                J_A, J_B, kin["drift_A"], kin["drift_B"], kin["M"], kin["h"], self.limits
            )
            vertices = self.vertices(lp, weights)
            P, p = halfplanes_from_vertices(vertices, lam)
        else:
            lower, upper = position_aware_velocity_limits(q, self.limits)
            red = task_reduction(J_A, J_B)
            vel = None
            if red is not None:
                vel = deformation_velocity_bounds_closed_form(J_A, J_B, lower, upper, red)
            if vel is None:
                self.stats["highs_fallbacks"] += 1
                vel = deformation_velocity_bounds(velocity_lp_data(J_A, J_B, lower, upper))
            zdot_lower, zdot_upper = vel
            vertices = None if red is None else self._daqp_vertices(kin, red, weights)
            if vertices is None:
                lp = vertex_lp_data(
                    J_A, J_B, kin["drift_A"], kin["drift_B"], kin["M"], kin["h"], self.limits
                )
                vertices = acceleration_force_vertices(lp, weights)
            hp = halfplanes_from_support_points(vertices, lam)
            if hp is None:
                self.stats["qhull_fallbacks"] += 1
                hp = halfplanes_from_vertices(vertices, lam)
            P, p = hp
        return ContactSpaceBounds(
            velocity_lower=zdot_lower,
            velocity_upper=zdot_upper,
            halfplane_normals=P,
            halfplane_offsets=p,
            vertices=vertices,
            effective_mass=lam,
            direction=self.direction.copy(),
        )
