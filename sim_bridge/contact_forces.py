"""Soft contact forces of the MuJoCo plant, in the units and conventions of the PyBullet plant.

The scenario gives a contact by a stiffness K (N/m), a damping B (N·s/m) and a Coulomb friction
coefficient μ; the PyBullet plant hands them to Bullet (:mod:`sim_bridge.plant`). MuJoCo has no
contact with those units: its soft constraints (``solref``/``solimp``) set a reference
ACCELERATION, and the force they give per metre of penetration scales with the effective mass
at the contact (a diagonal approximation of it that changed between MuJoCo versions). So the
MuJoCo plant takes only the geometry from MuJoCo's collision detection and applies the
contact's forces itself, with the functions here:

* the normal force is the spring–damper of the scenario, :func:`normal_force`,
  ``λ = max(0, K·δ + B·δ̇)`` (δ penetration, m; δ̇ its rate, m/s), evaluated at the start of
  the step (explicit; the plant shortens its step when K or B would make that unstable);
* friction is Coulomb's with the maximal-dissipation principle at the end of the step
  (backward Euler in the tangential velocity, as Bullet and MuJoCo treat friction):
  :func:`coulomb_friction` finds the tangential forces f (N) that minimise
  ``½·h·fᵀ·A·f + fᵀ·u`` under ``|f_i| ≤ μ_i·λ_i`` (A: the tangential inverse inertia of the
  contacts, 1/kg; u: their predicted slip velocity without friction, m/s; h: the step, s).
  A contact sticks when the force that stops its slip within the step fits in its disc, and
  otherwise slides with ``|f| = μ·λ`` against the slip at the end of the step. One contact is
  solved exactly; several by block Gauss–Seidel over the contacts (at most 100 sweeps).

Two bodies' parameters combine as Bullet combines them (:func:`combine_materials`), so the same
configuration gives the same contact in both plants.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

__all__ = [
    "BULLET_DEFAULT_MATERIAL",
    "ContactMaterial",
    "combine_materials",
    "coulomb_friction",
    "friction_disc",
    "normal_force",
]


@dataclass(frozen=True)
class ContactMaterial:
    """The contact parameters of one body's surface.

    Attributes:
        stiffness: N/m (``math.inf``: rigid).
        damping: N·s/m.
        friction: Coulomb coefficient.
    """

    stiffness: float
    damping: float
    friction: float


#: A surface whose parameters were never set: Bullet makes it rigid, with damping 0.1 N·s/m and
#: friction 0.5 (the PyBullet plant's robot links other than the tool).
BULLET_DEFAULT_MATERIAL = ContactMaterial(stiffness=math.inf, damping=0.1, friction=0.5)


def combine_materials(a: ContactMaterial, b: ContactMaterial) -> ContactMaterial:
    """The contact between two surfaces, combined as Bullet does: stiffness in series
    (``1/k = 1/k_a + 1/k_b``), damping summed, friction multiplied."""
    compliance = 1.0 / a.stiffness + 1.0 / b.stiffness
    stiffness = math.inf if compliance == 0.0 else 1.0 / compliance
    return ContactMaterial(stiffness, a.damping + b.damping, a.friction * b.friction)


def normal_force(
    stiffness: float, damping: float, penetration: float, penetration_rate: float
) -> float:
    """Spring–damper normal force ``max(0, K·δ + B·δ̇)``, N (K in N/m, B in N·s/m, δ in m,
    δ̇ in m/s); a contact never pulls."""
    return max(0.0, stiffness * penetration + damping * penetration_rate)


def friction_disc(
    inverse_inertia: np.ndarray, slip: np.ndarray, bound: float, step: float
) -> np.ndarray:
    """Coulomb friction of one contact at the end of a step: the force f (N, 2 tangential
    components) minimising ``½·h·fᵀ·A·f + fᵀ·u`` with ``|f| ≤ bound``.

    ``inverse_inertia`` A (2×2, 1/kg, symmetric positive definite), ``slip`` u (m/s, the
    tangential velocity at the end of the step without this force), ``bound`` μ·λ (N), ``step``
    h (s). Inside the disc the contact sticks (``u + h·A·f = 0``); on it, f opposes the final
    slip (``f = −2ν·(u + h·A·f)``), found as the root of ``|(h·A + ν·I)⁻¹·u| = bound``.
    """
    if bound <= 0.0 or not (slip[0] or slip[1]):
        return np.zeros(2)
    (a, b), (_, c) = step * inverse_inertia
    u0, u1 = float(slip[0]), float(slip[1])
    det = a * c - b * b
    if det > 1e-12 * (a * a + c * c):  # invertible: can the contact stick?
        stick = np.array([(b * u1 - c * u0) / det, (b * u0 - a * u1) / det])
        if math.hypot(stick[0], stick[1]) <= bound:
            return stick
    # h·A = Q·diag(e)·Qᵀ in closed form, w = Qᵀ·u
    mean, half_gap = 0.5 * (a + c), math.hypot(0.5 * (a - c), b)
    e0, e1 = max(mean - half_gap, 0.0), mean + half_gap
    angle = 0.5 * math.atan2(2.0 * b, a - c)  # Q's columns: (cos, sin) ↦ e1, (−sin, cos) ↦ e0
    cos, sin = math.cos(angle), math.sin(angle)
    w1, w0 = cos * u0 + sin * u1, -sin * u0 + cos * u1

    def excess(nu: float) -> float:
        return math.hypot(w0 / (e0 + nu), w1 / (e1 + nu)) - bound

    upper = math.hypot(u0, u1) / bound  # |f(ν)| < |u|/ν = bound there
    lower = 0.0 if e0 > 0.0 else 1e-15 * upper  # a direction no force can move
    nu = lower
    if excess(lower) > 0.0:
        nu = brentq(excess, lower, upper, xtol=1e-14 * upper, rtol=1e-12)
    f0, f1 = -w0 / (e0 + nu), -w1 / (e1 + nu)
    return np.array([cos * f1 - sin * f0, sin * f1 + cos * f0])


def coulomb_friction(
    inverse_inertia: np.ndarray,
    slip: np.ndarray,
    bounds: np.ndarray,
    step: float,
    max_sweeps: int = 100,
    tolerance: float = 1e-8,
) -> tuple[np.ndarray, bool]:
    """Coulomb friction of n contacts at the end of a step (module docstring), N.

    Args:
        inverse_inertia: A, 2n×2n, 1/kg: tangential velocity change per unit tangential impulse,
            contact i in rows/columns 2i, 2i+1 (symmetric positive semi-definite).
        slip: u, 2n, m/s: the tangential velocities at the end of the step without friction.
        bounds: μ_i·λ_i, n, N.
        step: h, s.
        max_sweeps, tolerance: block Gauss–Seidel stops when no force changed by more than
            ``tolerance`` × the largest bound (N) in a sweep, or after ``max_sweeps`` sweeps.

    Returns:
        f, 2n, N, in the same layout as ``slip``, and whether the sweeps converged. Every sweep
        lowers the dissipation objective and keeps each force in its disc, so forces that did
        not converge (many contacts on one body, e.g. a link lying in the table) are still
        admissible Coulomb forces, only not the optimum.
    """
    n = len(bounds)
    if n == 1:
        return friction_disc(inverse_inertia, slip, float(bounds[0]), step), True
    forces = np.zeros(2 * n)
    if n == 0:
        return forces, True
    scale = float(np.max(bounds))
    if scale <= 0.0:
        return forces, True
    for _ in range(max_sweeps):
        largest_change = 0.0
        for i in range(n):
            rows = slice(2 * i, 2 * i + 2)
            block = inverse_inertia[rows, rows]
            others = slip[rows] + step * (inverse_inertia[rows] @ forces - block @ forces[rows])
            new = friction_disc(block, others, float(bounds[i]), step)
            largest_change = max(largest_change, float(np.abs(new - forces[rows]).max()))
            forces[rows] = new
        if largest_change <= tolerance * scale:
            return forces, True
    return forces, False
