"""Deformation dynamics of a soft contact (Dehio & Kheddar 2020, Sec. III-A, eq 3–8, appendix A).

Conventions (used by the whole :mod:`ffmpc_core.impact` package):

* The **motion direction** ``d`` is a unit vector in the world frame along which the end-effector
  (the robot's ``contact`` frame) moves and presses; it is the paper's ``o1``.
* The **deformation** ``z`` (m) is the displacement of the contact point along ``d`` from the point
  where the soft material was first touched; ``z > 0`` is a penetration. ``ż`` (m/s) is its rate.
  The state is ``s = [z, ż]``.
* The **contact force** ``f`` (N) is the force the robot exerts on the material along ``d`` (the
  material pushes back on the robot with ``-f·d``); it is positive while pressing:
  ``f = α z + β ż`` with stiffness ``α`` (N/m) and damping ``β`` (N·s/m), both positive.
* The control input ``u`` (m/s²) is the end-effector acceleration the robot's actuation would
  produce along ``d`` without contact: ``Λ z̈ = Λ u − f``.

Sign note. The paper prints ``A_c = [[0, I], [Λ⁻¹α, Λ⁻¹β]]`` (eq 5) together with
``f = αz + βż`` and forces ``0 ≤ f`` (eq 10). Read literally with positive ``α, β`` that system is
unstable (the material would pull the robot in); it is the physical model only if ``f`` is the
force *on the robot* along ``d`` (``α, β < 0``). We keep positive stiffness/damping, ``f ≥ 0``
while pressing, and the physically consistent ``A_c = [[0, 1], [−α/Λ, −β/Λ]]``; the joint-space
counterpart is ``τ = M q̈ + h + J_Aᵀ f`` (see :mod:`ffmpc_core.impact.limits`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from scipy.linalg import expm

from ffmpc_core.errors import ConfigError, InputError, ModelError
from ffmpc_core.robots import RobotModel

__all__ = [
    "DOWN",
    "DeformationDynamics",
    "SoftMaterial",
    "acceleration_map",
    "continuous_deformation_dynamics",
    "deformation_dynamics",
    "deformation_force",
    "discretize_deformation_dynamics",
    "discretize_deformation_closed_form",
    "effective_mass",
    "effective_mass_from",
    "material_matrix",
    "measured_deformation",
    "one_step_impact_force",
    "predicted_force_increase",
    "simulate_deformation",
    "unit_direction",
]

#: The default motion direction d (world frame): straight down.
DOWN = np.array([0.0, 0.0, -1.0])


def _positive(value: float, name: str, allow_zero: bool = False) -> float:
    value = float(value)
    ok = value >= 0.0 if allow_zero else value > 0.0
    if not np.isfinite(value) or not ok:
        sign = "non-negative" if allow_zero else "positive"
        raise ConfigError(f"{name} must be finite and {sign}, got {value}")
    return value


def unit_direction(direction: np.ndarray) -> np.ndarray:
    """Validate a motion direction: a 3-vector in the world frame, returned normalised.

    Raises :class:`InputError` for a wrong size, NaN/Inf, or a norm far from 1 (|‖d‖ − 1| > 1e-6):
    a direction that is not unit is treated as a bug, not silently rescaled.
    """
    d = np.asarray(direction, dtype=float).reshape(-1)
    if d.shape != (3,) or not np.all(np.isfinite(d)):
        raise InputError(f"motion direction must be a finite 3-vector, got {direction!r}")
    norm = float(np.linalg.norm(d))
    if abs(norm - 1.0) > 1e-6:
        raise InputError(f"motion direction must be a unit vector (world frame), norm={norm}")
    return d / norm


@dataclass(frozen=True)
class SoftMaterial:
    """Linear visco-elastic material along the motion direction (eq 3).

    Attributes:
        stiffness: α, N/m (> 0).
        damping: β, N·s/m (≥ 0).
        max_penetration: z̄, m (> 0): the end of the elastic domain; the planner keeps
            ``0 ≤ z ≤ z̄`` (Sec. III-B, "elastic domain constraint").
    """

    stiffness: float
    damping: float
    max_penetration: float

    def __post_init__(self) -> None:
        _positive(self.stiffness, "stiffness")
        _positive(self.damping, "damping", allow_zero=True)
        _positive(self.max_penetration, "max_penetration")


def measured_deformation(
    position: np.ndarray, surface: np.ndarray, direction: np.ndarray = DOWN
) -> float:
    """Sec. III-A: deformation ``z = dᵀ (p − p_s)`` (m) of the contact-frame position ``p``
    relative to the initial contact position ``p_s`` along the unit motion direction ``d``
    (world frame); z > 0 inside the material."""
    return float(np.asarray(direction) @ (np.asarray(position) - np.asarray(surface)))


def deformation_force(
    stiffness: float, damping: float, deformation: np.ndarray, deformation_rate: np.ndarray
) -> np.ndarray:
    """Eq 3: contact force ``f = α z + β ż`` (N) along the motion direction.

    Args:
        stiffness: α, N/m. damping: β, N·s/m.
        deformation: z, m (scalar or array). deformation_rate: ż, m/s (same shape).
    """
    return stiffness * np.asarray(deformation, dtype=float) + damping * np.asarray(
        deformation_rate, dtype=float
    )


def one_step_impact_force(
    stiffness: float, damping: float, speed: float, dt: float, factor: float = 1.0
) -> float:
    """Eq 3 after one step Δt in contact from the surface: ``κ (β + α Δt) max(ż, 0)`` (N).

    A contact that starts at ``z = 0`` with rate ``ż`` has, one explicit step later,
    ``z = ż Δt`` and so ``f = α ż Δt + β ż``: the force an impact during the next control step
    adds, which the joint-limit guard reserves before the contact is seen. α N/m, β N·s/m,
    ż m/s along the motion direction (only approaching counts), Δt s; ``factor`` κ scales it
    (the measured first-contact force over this one, see ``touch_first``).
    """
    return factor * max(speed, 0.0) * (damping + stiffness * dt)


def predicted_force_increase(
    stiffness: float,
    damping: float,
    deformation: float,
    deformation_rate: float,
    force: float,
    dt: float,
) -> float:
    """Eq 3 one step ahead: how much the pressing force may grow during the next step (N),
    ``max(α (z + ż Δt) + β ż − f, 0)`` if the tool is inside the material at the end of the
    step (``z + ż Δt > 0``), else 0. α N/m, β N·s/m, z m, ż m/s, f N (the force compensated
    now), Δt s. It is the force the task-space law cannot compensate in time, handed to the
    joint-limit guard as ``impact_force``."""
    z_next = deformation + deformation_rate * dt
    if z_next <= 0.0:
        return 0.0
    return max(stiffness * z_next + damping * deformation_rate - force, 0.0)


def material_matrix(stiffness: float, damping: float) -> np.ndarray:
    """Eq 3: ``E = [α, β]`` (1×2; N/m, N·s/m) so that ``f = E s``."""
    return np.array([[float(stiffness), float(damping)]])


def continuous_deformation_dynamics(
    stiffness: float, damping: float, effective_mass: float
) -> tuple[np.ndarray, np.ndarray]:
    """Eq 4–5: ``ṡ = A_c s + B_c u`` for ``s = [z, ż]`` (m, m/s) and ``u`` (m/s²).

    ``A_c = [[0, 1], [−α/Λ, −β/Λ]]`` and ``B_c = [0, 1]ᵀ`` with the effective mass ``Λ`` (kg) along
    the motion direction (see the module docstring for the sign). Returns ``(A_c, B_c)``.
    """
    _positive(stiffness, "stiffness")
    _positive(damping, "damping", allow_zero=True)
    lam = _positive(effective_mass, "effective_mass")
    A_c = np.array([[0.0, 1.0], [-stiffness / lam, -damping / lam]])
    B_c = np.array([[0.0], [1.0]])
    return A_c, B_c


def discretize_deformation_dynamics(
    A_c: np.ndarray, B_c: np.ndarray, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Eq 6–7: zero-order-hold discretisation by the matrix exponential.

    ``[[A_d, B_d], [0, I]] = expm(Δt [[A_c, B_c], [0, 0]])`` with Δt in s; returns ``(A_d, B_d)``
    so that ``s_{i+1} = A_d s_i + B_d u_i`` when ``u`` is held constant over the step.
    """
    dt = _positive(dt, "dt")
    n, m = B_c.shape
    if A_c.shape != (n, n):
        raise ConfigError(f"A_c must be {n}×{n}, got {A_c.shape}")
    aug = np.zeros((n + m, n + m))
    aug[:n, :n] = A_c
    aug[:n, n:] = B_c
    phi = expm(dt * aug)
    return phi[:n, :n].copy(), phi[:n, n:].copy()


def _sinhc(x2: float) -> tuple[float, float]:
    """``(cosh(x), sinh(x)/x)`` for ``x = sqrt(x2)``, ``x2`` real of any sign (x imaginary when
    ``x2 < 0``: then ``(cos|x|, sin|x|/|x|)``); a Taylor series near 0 avoids the 0/0."""
    if abs(x2) < 1e-6:
        return 1.0 + x2 / 2.0 + x2 * x2 / 24.0, 1.0 + x2 / 6.0 + x2 * x2 / 120.0
    if x2 > 0.0:
        x = math.sqrt(x2)
        return math.cosh(x), math.sinh(x) / x
    x = math.sqrt(-x2)
    return math.cos(x), math.sin(x) / x


def discretize_deformation_closed_form(
    stiffness: float, damping: float, effective_mass: float, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Eq 6–7 in closed form: the zero-order-hold ``(A_d, B_d)`` of eq 5 without ``expm``.

    With ``a = α/Λ``, ``b = β/Λ`` (1/s², 1/s), ``A_c = [[0, 1], [−a, −b]]`` has the eigenvalues
    ``μ ± σ``, ``μ = −b/2``, ``σ² = b²/4 − a``; by Cayley–Hamilton
    ``A_d = e^{μΔt} (cosh(σΔt) I + Δt·sinh(σΔt)/(σΔt) (A_c − μ I))`` (σ imaginary: cos and sin;
    σ → 0: the series), and, ``A_c`` being invertible (``a > 0``),
    ``B_d = ∫₀^Δt e^{A_c τ} dτ B_c = A_c⁻¹ (A_d − I) e2``. Same result as
    :func:`discretize_deformation_dynamics` (the reference, tested to ~1e-12 relative) at a
    fraction of its cost. Inputs are validated as in :func:`continuous_deformation_dynamics`.
    """
    _positive(stiffness, "stiffness")
    _positive(damping, "damping", allow_zero=True)
    lam = _positive(effective_mass, "effective_mass")
    dt = _positive(dt, "dt")
    a, b = stiffness / lam, damping / lam
    mu = -0.5 * b
    ch, shc = _sinhc((0.25 * b * b - a) * dt * dt)
    e = math.exp(mu * dt)
    s = e * shc * dt  # e^{μΔt} sinh(σΔt)/σ
    c = e * ch
    a11 = c - mu * s
    a12 = s
    a21 = -a * s
    a22 = c + (-b - mu) * s
    # A_c⁻¹ = [[−b/a, −1/a], [1, 0]]; (A_d − I) e2 = [a12, a22 − 1].
    b1 = (-b * a12 - (a22 - 1.0)) / a
    b2 = a12
    return np.array([[a11, a12], [a21, a22]]), np.array([[b1], [b2]])


def acceleration_map(A_d: np.ndarray, B_d: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Eq 8 / appendix A: ``z̈_i = C s_i + D u_i`` (m/s²), the mean acceleration over step i.

    ``C = [d21/Δt, (d22 − 1)/Δt]`` (1/s², 1/s) and ``D = e2/Δt`` (dimensionless), from
    ``ż_{i+1} = d21 z_i + d22 ż_i + e2 u_i``. Returns ``(C, D)`` as 1×2 and 1×1 arrays.
    """
    dt = _positive(dt, "dt")
    C = np.array([[A_d[1, 0] / dt, (A_d[1, 1] - 1.0) / dt]])
    D = np.array([[B_d[1, 0] / dt]])
    return C, D


@dataclass(frozen=True)
class DeformationDynamics:
    """The discrete deformation model of eq 3–8 for one material and one effective mass.

    Attributes:
        stiffness: α, N/m. damping: β, N·s/m. effective_mass: Λ, kg. dt: Δt, s.
        A_c, B_c: eq 5. A_d, B_d: eq 7. C, D: eq 8. E: eq 3.
    """

    stiffness: float
    damping: float
    effective_mass: float
    dt: float
    A_c: np.ndarray
    B_c: np.ndarray
    A_d: np.ndarray
    B_d: np.ndarray
    C: np.ndarray
    D: np.ndarray
    E: np.ndarray


def deformation_dynamics(
    stiffness: float, damping: float, effective_mass: float, dt: float
) -> DeformationDynamics:
    """Build eq 3–8 at once: α (N/m), β (N·s/m), Λ (kg), Δt (s); eq 6–7 in closed form
    (:func:`discretize_deformation_closed_form`)."""
    A_c, B_c = continuous_deformation_dynamics(stiffness, damping, effective_mass)
    A_d, B_d = discretize_deformation_closed_form(stiffness, damping, effective_mass, dt)
    C, D = acceleration_map(A_d, B_d, dt)
    return DeformationDynamics(
        stiffness=float(stiffness),
        damping=float(damping),
        effective_mass=float(effective_mass),
        dt=float(dt),
        A_c=A_c,
        B_c=B_c,
        A_d=A_d,
        B_d=B_d,
        C=C,
        D=D,
        E=material_matrix(stiffness, damping),
    )


def simulate_deformation(
    dynamics: DeformationDynamics, s1: np.ndarray, inputs: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Feed-forward simulation of eq 6 with eq 3 and eq 8 (the paper's preview, Sec. IV-A).

    Args:
        s1: initial state ``[z_1, ż_1]`` (m, m/s).
        inputs: ``u_1 … u_h`` (m/s²).

    Returns:
        ``states`` (h+1)×2 = s_1 … s_{h+1}; ``accelerations`` (h,) = z̈_1 … z̈_h (m/s², eq 8);
        ``forces`` (h+1,) = f_1 … f_{h+1} (N, eq 3).
    """
    u = np.asarray(inputs, dtype=float).reshape(-1)
    s = np.asarray(s1, dtype=float).reshape(2)
    if not (np.all(np.isfinite(u)) and np.all(np.isfinite(s))):
        raise InputError("simulate_deformation: non-finite state or input")
    states = np.empty((u.size + 1, 2))
    states[0] = s
    for i, ui in enumerate(u):
        states[i + 1] = dynamics.A_d @ states[i] + dynamics.B_d[:, 0] * ui
    accelerations = states[:-1] @ dynamics.C[0] + dynamics.D[0, 0] * u
    forces = states @ dynamics.E[0]
    return states, accelerations, forces


def effective_mass_from(jacobian_row: np.ndarray, inverse_inertia: np.ndarray) -> float:
    """Footnote 1: ``Λ = (J_A M⁻¹ J_Aᵀ)⁻¹`` (kg) for a 1×n task Jacobian ``J_A`` (m/rad).

    Raises :class:`ModelError` if ``J_A M⁻¹ J_Aᵀ`` is not positive (singular direction).
    """
    j = np.asarray(jacobian_row, dtype=float).reshape(-1)
    inv = float(j @ inverse_inertia @ j)
    if not np.isfinite(inv) or inv <= 1e-12:
        raise ModelError(f"effective mass undefined: J M⁻¹ Jᵀ = {inv} (singular direction)")
    return 1.0 / inv


def effective_mass(
    robot: RobotModel, q: np.ndarray, direction: np.ndarray, data: pin.Data | None = None
) -> float:
    """Footnote 1 / eq 2: effective mass (kg) of the contact frame along ``direction``.

    ``J_A = dᵀ J_lin`` where ``J_lin`` (3×n, m/rad) is the linear part of the contact frame's
    Jacobian in pinocchio's ``LOCAL_WORLD_ALIGNED`` frame and ``d`` the unit motion direction in
    the world frame; ``M`` is the joint-space inertia at ``q`` (rad).
    """
    d = unit_direction(direction)
    q = np.asarray(q, dtype=float)
    if q.shape != (robot.nq,) or not np.all(np.isfinite(q)):
        raise InputError(f"q must be a finite vector of size {robot.nq}")
    data = data if data is not None else robot.create_data()
    pin.computeJointJacobians(robot.model, data, q)
    pin.updateFramePlacements(robot.model, data)
    J = pin.getFrameJacobian(
        robot.model, data, robot.contact_frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    )
    Minv = pin.computeMinverse(robot.model, data, q)
    return effective_mass_from(d @ J[:3], Minv)
