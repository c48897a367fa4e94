"""Learning the material's stiffness and damping (Dehio & Kheddar 2020, Sec. V, eq 15–21).

Data: deformation states ``s_i = [z_i, ż_i]`` (m, m/s, along the unit motion direction in the
world frame, from forward kinematics) and the pressing force ``f_i`` (N, from the F/T sensor).
Model (eq 3): ``f = E s`` with ``E = [α, β]`` (N/m, N·s/m).

The batch estimate (eq 17, ridge-regularised) is ``Ê = F Sᵀ (S Sᵀ + λ I)⁻¹``; the recursive form
(eq 19–21) accumulates ``(S Sᵀ)`` and ``(F Sᵀ)`` from the initial values ``λ I`` and ``0`` and
solves the same 2×2 system, so both give the same estimate on the same data (up to rounding).

Confidence measure. Under the model ``f_i = E s_i + ε_i`` with independent noise of variance σ²,
the (unregularised) least-squares estimate has covariance ``σ² (S Sᵀ)⁻¹``. We estimate
``σ̂² = RSS / (K − 2)`` with the residual sum of squares ``RSS = Σ f² − 2 Ê (F Sᵀ)ᵀ + Ê (S Sᵀ) Êᵀ``
(all recursive sums, no data stored) and report the standard errors ``sqrt(diag(σ̂² (S Sᵀ + λI)⁻¹))``
(N/m, N·s/m). The ridge term λ biases the estimate by ``−λ Ê (S Sᵀ + λI)⁻¹``; keep λ small against
the data's ``S Sᵀ`` (the default 1e-9 m²… is negligible for any real excitation).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.plausibility import check_contact_parameters

__all__ = [
    "ContactEstimate",
    "ExplorationReference",
    "RecursiveContactLearner",
    "confident",
    "exploration_reference",
    "fit_stiffness_damping",
    "model_error",
    "predict_force",
    "stack_data",
]


def stack_data(
    deformation: np.ndarray, deformation_rate: np.ndarray, force: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Eq 15: ``S = [s_1 … s_K]`` (2×K; m, m/s) and ``F = [f_1 … f_K]`` (1×K; N)."""
    z = np.asarray(deformation, dtype=float).reshape(-1)
    zd = np.asarray(deformation_rate, dtype=float).reshape(-1)
    f = np.asarray(force, dtype=float).reshape(-1)
    if not (z.size == zd.size == f.size) or z.size == 0:
        raise InputError("deformation, deformation_rate and force need the same, non-zero length")
    if not (np.all(np.isfinite(z)) and np.all(np.isfinite(zd)) and np.all(np.isfinite(f))):
        raise InputError("learning data must be finite")
    return np.vstack([z, zd]), f[None, :]


def _regularization(value: float) -> float:
    value = float(value)
    if not np.isfinite(value) or value < 0:
        raise ConfigError(f"regularization must be finite and ≥ 0, got {value}")
    return value


def fit_stiffness_damping(S: np.ndarray, F: np.ndarray, regularization: float = 0.0) -> np.ndarray:
    """Eq 17: ``Ê = F Sᵀ (S Sᵀ + λ I)⁻¹`` → ``[α̂, β̂]`` (N/m, N·s/m).

    ``λ`` (``regularization``, in the units of ``S Sᵀ``) is the ridge term the paper mentions for
    numerical stability; ``λ = 0`` is the plain pseudo-inverse ``F S†`` for full-rank data.
    """
    lam = _regularization(regularization)
    G = S @ S.T + lam * np.eye(2)
    try:
        return np.linalg.solve(G, (F @ S.T).reshape(2))
    except np.linalg.LinAlgError as exc:
        raise InputError("eq 17: S Sᵀ is singular (no excitation); add data or regularise") from exc


def predict_force(E: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Eq 18: ``F̂ = Ê S`` (N) for states S (2×K)."""
    return np.asarray(E, dtype=float).reshape(1, 2) @ S


def model_error(E: np.ndarray, S: np.ndarray, F: np.ndarray) -> float:
    """Eq 16: ``e = (1/K) ‖Fᵀ − Sᵀ Êᵀ‖²`` (N²), the mean squared force residual."""
    r = F - predict_force(E, S)
    return float(np.sum(r * r) / S.shape[1])


@dataclass(frozen=True)
class ContactEstimate:
    """Stiffness/damping estimate with its confidence.

    Attributes:
        stiffness: α̂, N/m. damping: β̂, N·s/m.
        stiffness_std, damping_std: standard errors, N/m and N·s/m (NaN with fewer than 3 samples).
        noise_std: σ̂, N, the residual standard deviation of the force model.
        samples: K, number of data points.
        condition: condition number of ``S Sᵀ + λI`` (large = poorly excited, e.g. no velocity).
    """

    stiffness: float
    damping: float
    stiffness_std: float
    damping_std: float
    noise_std: float
    samples: int
    condition: float

    @property
    def material_matrix(self) -> np.ndarray:
        """``[α̂, β̂]`` as eq 3's 1×2 matrix."""
        return np.array([[self.stiffness, self.damping]])


def confident(estimate: ContactEstimate, min_samples: int, max_relative_std: float) -> bool:
    """True when an estimate may replace the prior contact model (MPC, impact planner): at least
    ``min_samples`` samples, both standard errors at most ``max_relative_std`` times their value,
    and α̂, β̂ inside the plausible ranges of ``ffmpc_core.plausibility`` (10–1e6 N/m,
    0–1e5 N·s/m) — a learned 1e-9 or 1e12 N/m is refused and the prior kept."""
    e = estimate
    values = (e.stiffness, e.damping, e.stiffness_std, e.damping_std)
    if not all(np.isfinite(values)) or e.samples < min_samples:
        return False
    try:
        check_contact_parameters(e.stiffness, e.damping)
    except InputError:
        return False
    return bool(
        e.stiffness_std <= max_relative_std * e.stiffness
        and e.damping_std <= max_relative_std * max(e.damping, 1e-9)
    )


class RecursiveContactLearner:
    """Eq 19–21: online stiffness/damping estimate, O(1) memory and time per sample.

    Args:
        regularization: λ, the initial ``(S Sᵀ)_0 = λ I`` (units of ``S Sᵀ``: m², m²/s, m²/s²);
            the paper's initialisation is λ = 0. With the same λ, :meth:`estimate` equals
            :func:`fit_stiffness_damping` on all samples seen.
    """

    def __init__(self, regularization: float = 1e-9) -> None:
        self.regularization = _regularization(regularization)
        self.SSt = np.zeros((2, 2))
        self.FSt = np.zeros(2)
        self.reset()

    def reset(self) -> None:
        """Forget all data: ``(S Sᵀ)_0 = λ I``, ``(F Sᵀ)_0 = 0`` (eq 19–20)."""
        self.SSt[:] = self.regularization * np.eye(2)
        self.FSt[:] = 0.0
        self._ff = 0.0  # Σ f², N²
        self._raw = np.zeros((2, 2))  # Σ s sᵀ without λ, for the residual
        self.samples = 0

    def update(self, deformation: float, deformation_rate: float, force: float) -> None:
        """Add one sample: z (m), ż (m/s), f (N) — eq 19 and eq 20."""
        z, zd, f = float(deformation), float(deformation_rate), float(force)
        if not (np.isfinite(z) and np.isfinite(zd) and np.isfinite(f)):
            raise InputError("learner sample must be finite")
        s0z, s01, s11 = z * z, z * zd, zd * zd
        self.SSt[0, 0] += s0z
        self.SSt[0, 1] += s01
        self.SSt[1, 0] += s01
        self.SSt[1, 1] += s11
        self._raw[0, 0] += s0z
        self._raw[0, 1] += s01
        self._raw[1, 0] += s01
        self._raw[1, 1] += s11
        self.FSt[0] += f * z
        self.FSt[1] += f * zd
        self._ff += f * f
        self.samples += 1

    def update_batch(
        self, deformation: np.ndarray, deformation_rate: np.ndarray, force: np.ndarray
    ) -> None:
        """Add many samples at once (same sums as repeated :meth:`update`)."""
        S, F = stack_data(deformation, deformation_rate, force)
        G = S @ S.T
        self.SSt += G
        self._raw += G
        self.FSt += (F @ S.T).reshape(2)
        self._ff += float(np.sum(F * F))
        self.samples += S.shape[1]

    def coefficients(self) -> np.ndarray:
        """Eq 21: ``Ê = (F Sᵀ)_i (S Sᵀ)_i⁻¹`` → ``[α̂, β̂]`` (N/m, N·s/m)."""
        try:
            return np.linalg.solve(self.SSt, self.FSt)
        except np.linalg.LinAlgError as exc:
            raise InputError("eq 21: (S Sᵀ) is singular: not enough excitation yet") from exc

    def confident_estimate(
        self, min_samples: int, max_relative_std: float
    ) -> ContactEstimate | None:
        """The estimate if it is :func:`confident` (it may replace the prior), else None.

        None too with fewer than ``min_samples`` samples (the estimate is not computed) or
        while ``(S Sᵀ)`` is singular. The one rule every user of the learner applies: the
        studies, the touch-first controller and the ROS nodes.
        """
        if self.samples < min_samples:
            return None
        try:
            est = self.estimate()
        except InputError:  # (S Sᵀ) still singular
            return None
        return est if confident(est, min_samples, max_relative_std) else None

    def estimate(self) -> ContactEstimate:
        """Eq 21 with the confidence measure of the module docstring."""
        E = self.coefficients()
        K = self.samples
        rss = max(self._ff - 2.0 * E @ self.FSt + E @ self._raw @ E, 0.0)
        if K > 2:
            sigma2 = rss / (K - 2)
            cov = sigma2 * np.linalg.inv(self.SSt)
            std = np.sqrt(np.maximum(np.diag(cov), 0.0))
        else:
            sigma2, std = float("nan"), np.full(2, np.nan)
        return ContactEstimate(
            stiffness=float(E[0]),
            damping=float(E[1]),
            stiffness_std=float(std[0]),
            damping_std=float(std[1]),
            noise_std=float(np.sqrt(sigma2)),
            samples=K,
            condition=float(np.linalg.cond(self.SSt)),
        )


@dataclass(frozen=True)
class ExplorationReference:
    """A reference deformation trajectory along the motion direction (Sec. VI, learning).

    Attributes:
        time: s. deformation: z_ref, m (negative = above the surface). deformation_rate: m/s.
        deformation_acceleration: m/s². phase: 0 = sinusoidal penetration, k ≥ 1 = k-th impact.
        impact_velocities: the planned pre-impact velocities, m/s.
    """

    time: np.ndarray
    deformation: np.ndarray
    deformation_rate: np.ndarray
    deformation_acceleration: np.ndarray
    phase: np.ndarray
    impact_velocities: np.ndarray


#: A piece of the excitation trajectory: τ (s, from its start) ↦ (z m, ż m/s, z̈ m/s²).
_Segment = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


def _smooth_move(z0: float, z1: float, duration: float) -> tuple[float, _Segment]:
    """Cosine blend from rest at z0 to rest at z1 in ``duration`` s: τ ↦ (m, m/s, m/s²)."""
    w = np.pi / duration

    def seg(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (
            z0 + (z1 - z0) * 0.5 * (1.0 - np.cos(w * tau)),
            (z1 - z0) * 0.5 * w * np.sin(w * tau),
            (z1 - z0) * 0.5 * w * w * np.cos(w * tau),
        )

    return duration, seg


def _constant_acceleration(
    z0: float, v0: float, a: float, duration: float
) -> tuple[float, _Segment]:
    """``z = z0 + v0 τ + a τ²/2`` for ``duration`` s: τ ↦ (m, m/s, m/s²)."""

    def seg(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return z0 + v0 * tau + 0.5 * a * tau * tau, v0 + a * tau, np.full(tau.shape, a)

    return duration, seg


def exploration_reference(
    max_penetration: float,
    dt: float = 1e-3,
    sine_amplitude: float | None = None,
    sine_frequency: float = 1.0,
    sine_cycles: int = 4,
    impact_velocities: np.ndarray | None = None,
    approach_height: float = 0.05,
    stop_depth: float | None = None,
    dwell: float = 0.3,
) -> ExplorationReference:
    """Exploration motion: a sinusoidal penetration then impacts (Sec. VI, "Learning Procedure").

    The reference starts at the surface (z = 0, at rest). Phase 0: ``z = A (1 − cos 2πνt)/2`` for
    ``sine_cycles`` periods (A = ``sine_amplitude``, default 0.6 z̄; ν = ``sine_frequency`` Hz).
    Then for each pre-impact velocity ``v`` (default five values, 0.15 … 0.35 m/s): a smooth
    retreat to ``−approach_height``, a constant acceleration ``v²/(2·approach_height)`` that reaches
    ``v`` at ``z = 0``, a constant deceleration that stops at ``stop_depth`` (default 0.6 z̄), a
    dwell of ``dwell`` s. The robot is meant to track it with a stiff position controller; the
    soft material, not this reference, decides the forces. All lengths in m, times in s.
    """
    zbar = float(max_penetration)
    if not (np.isfinite(zbar) and zbar > 0):
        raise ConfigError("max_penetration must be positive")
    A = 0.6 * zbar if sine_amplitude is None else float(sine_amplitude)
    depth = 0.6 * zbar if stop_depth is None else float(stop_depth)
    if not 0 < A <= zbar or not 0 < depth <= zbar:
        raise ConfigError("sine_amplitude and stop_depth must lie in (0, max_penetration]")
    v_imp = (
        np.linspace(0.15, 0.35, 5)
        if impact_velocities is None
        else np.asarray(impact_velocities, dtype=float)
    )
    if np.any(v_imp <= 0) or not np.all(np.isfinite(v_imp)):
        raise ConfigError("impact velocities must be positive")
    if not (dt > 0 and approach_height > 0 and sine_frequency > 0 and sine_cycles >= 1):
        raise ConfigError("dt, approach_height, sine_frequency must be > 0 and sine_cycles ≥ 1")
    w = 2.0 * np.pi * sine_frequency

    def sine(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return (
            0.5 * A * (1 - np.cos(w * tau)),
            0.5 * A * w * np.sin(w * tau),
            0.5 * A * w * w * np.cos(w * tau),
        )

    # (duration s, segment function, phase): the trajectory is continuous in z and ż.
    segments: list[tuple[float, _Segment, int]] = [(sine_cycles / sine_frequency, sine, 0)]
    for k, v in enumerate(v_imp, start=1):
        segments.append((*_smooth_move(0.0 if k == 1 else depth, -approach_height, 0.8), k))
        a_up = v * v / (2.0 * approach_height)
        segments.append((*_constant_acceleration(-approach_height, 0.0, a_up, v / a_up), k))
        a_dn = v * v / (2.0 * depth)
        segments.append((*_constant_acceleration(0.0, v, -a_dn, v / a_dn), k))
        segments.append((*_constant_acceleration(depth, 0.0, 0.0, dwell), k))
    segments.append((*_smooth_move(depth, 0.0, 0.8), len(v_imp)))
    starts = np.concatenate([[0.0], np.cumsum([s[0] for s in segments])])
    time = np.arange(int(np.floor(starts[-1] / dt)) + 1) * dt
    index = np.clip(np.searchsorted(starts, time, side="right") - 1, 0, len(segments) - 1)
    cat = [np.empty(time.size) for _ in range(3)] + [np.empty(time.size, dtype=int)]
    for i, (_, fn, phase) in enumerate(segments):
        sel = index == i
        z, zd, zdd = fn(time[sel] - starts[i])
        cat[0][sel], cat[1][sel], cat[2][sel], cat[3][sel] = z, zd, zdd, phase
    return ExplorationReference(
        time=time,
        deformation=cat[0],
        deformation_rate=cat[1],
        deformation_acceleration=cat[2],
        phase=cat[3],
        impact_velocities=v_imp,
    )
