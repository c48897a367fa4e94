"""What the impact and exploration runs are scored by: joint-limit violations, time to a steady
force, a run's metrics from its log, the touch-first run's touch metrics, the exploration's
checkpoints and the bound on their bias from the surface error.

Pure functions of logged arrays (no simulator, no ROS): the ROS-free runs
(:mod:`studies.impact_study`, :mod:`studies.exploration`) and the impact graph
(:mod:`ffmpc_ros.impact_graph`) summarise with the same code. Units: s, N, m, rad, rad/s,
N·m; ``t`` and ``force`` of a log are per control step.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ffmpc_core.errors import InputError
from ffmpc_core.impact.learner import ContactEstimate
from ffmpc_core.impact.limits import JointLimits
from ffmpc_core.impact.scenario import ImpactStudyConfig, Material


@dataclass(frozen=True)
class LimitViolations:
    """Samples (control steps) at which a joint exceeded a data-sheet limit (eq 1b–1e).

    Attributes:
        position: q outside [q̲, q̄]. velocity: |q̇| > q̇_max.
        acceleration: |q̈| > q̈_max with q̈ = (q̇[k+1] − q̇[k]) / Δt from the simulated q̇.
        torque: |τ| ≥ τ_max for the torque the controller sent (the plant would saturate it).
        max_ratio: largest |value| / limit of each kind (position: |q − mid-range| / half range,
            1 at a limit).
    """

    position: int
    velocity: int
    acceleration: int
    torque: int
    max_ratio: dict[str, float]

    @property
    def total(self) -> int:
        """Control steps beyond a limit, all kinds together (q, q̇, q̈ and τ)."""
        return self.position + self.velocity + self.acceleration + self.torque


def count_limit_violations(
    q: np.ndarray, v: np.ndarray, tau: np.ndarray, dt: float, limits: JointLimits
) -> LimitViolations:
    """Count the samples of a run (rows: steps) that break the limits; see LimitViolations."""
    mid = 0.5 * (limits.position_upper + limits.position_lower)
    half = 0.5 * (limits.position_upper - limits.position_lower)
    p_ratio = np.abs(q - mid) / half
    qdd = np.diff(v, axis=0) / dt
    v_ratio = np.abs(v) / limits.velocity
    a_ratio = np.abs(qdd) / limits.acceleration
    t_ratio = np.abs(tau) / limits.torque
    return LimitViolations(
        position=int(np.count_nonzero(np.any(p_ratio > 1.0, axis=1))),
        velocity=int(np.count_nonzero(np.any(v_ratio > 1.0, axis=1))),
        acceleration=int(np.count_nonzero(np.any(a_ratio > 1.0, axis=1))),
        torque=int(np.count_nonzero(np.any(t_ratio >= 1.0 - 1e-9, axis=1))),
        max_ratio={
            "position": float(p_ratio.max()) if p_ratio.size else 0.0,
            "velocity": float(v_ratio.max()) if v_ratio.size else 0.0,
            "acceleration": float(a_ratio.max()) if a_ratio.size else 0.0,
            "torque": float(t_ratio.max()) if t_ratio.size else 0.0,
        },
    )


def time_to_steady_force(
    t: np.ndarray, force: np.ndarray, target: float, band: float, hold: float, start: float
) -> float:
    """First time ≥ ``start`` (s) from which ``|f − target| ≤ band·target`` holds for ``hold`` s;
    NaN if never (within the data). ``t`` s, ``force`` N."""
    inside = np.abs(force - target) <= band * target
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    need = int(round(hold / dt))
    k0 = int(np.searchsorted(t, start))
    run = 0
    for k in range(k0, t.size):
        run = run + 1 if inside[k] else 0
        if run > need:
            return float(t[k - need])
    return float("nan")


def run_metrics(
    cfg: ImpactStudyConfig,
    log: dict[str, np.ndarray],
    qs: np.ndarray,
    vs: np.ndarray,
    taus: np.ndarray,
    limits: JointLimits,
    contact_time: float | None,
    touch_speed: float,
) -> dict[str, Any]:
    """A run's metrics from its log (``t`` s, ``force`` N, ``penetration`` m per step), the
    joint positions and velocities of steps 0..K (rad, rad/s), the torques sent at steps
    0..K−1 (N·m), the data-sheet limits, the contact time (s, None: never) and the speed along
    d at the last force-free sample before it (m/s): ``pre_impact_velocity``,
    ``contact_time``, ``steady_time``, ``peak_force``, ``peak_penetration``, ``final_force``,
    ``final_force_error``, ``violations`` (see
    :class:`studies.impact_study.ImpactRun`). The ROS-free run and the
    impact graph both summarise with it."""
    t_log, force = log["t"], log["force"]
    nan = float("nan")
    contact = nan if contact_time is None else float(contact_time)
    steady = (
        nan
        if contact_time is None
        else time_to_steady_force(
            t_log, force, cfg.target_force, cfg.steady_band, cfg.steady_hold, contact
        )
    )
    tail = t_log >= t_log[-1] - 0.2
    return dict(
        pre_impact_velocity=float(touch_speed) if contact_time is not None else nan,
        contact_time=contact,
        steady_time=steady,
        peak_force=float(force.max()),
        peak_penetration=float(log["penetration"].max()),
        final_force=float(force[tail].mean()),
        final_force_error=float(np.abs(force[tail] - cfg.target_force).max()),
        violations=count_limit_violations(qs, vs, taus, cfg.time_step, limits),
    )


def touch_metrics(
    log: dict[str, np.ndarray],
    touch_time: float | None,
    touch_velocity: float | None,
    decision_time: float | None,
) -> dict[str, float]:
    """The touch-first run's touch metrics (:class:`studies.impact_study.ImpactRun`) from the
    log (``t`` s, ``force`` N, ``penetration`` m) and the touch-first controller's touch time
    (s), touch velocity (m/s) and decision time (s) (None: never). The ROS-free run and the
    impact graph both summarise with it. Without a touch (strike-first) only the decision
    time is set."""
    nan = float("nan")
    t_log = log["t"]
    t_touch = nan if touch_time is None else float(touch_time)
    t_decide = nan if decision_time is None else float(decision_time)
    touched = np.isfinite(t_touch) and np.isfinite(t_decide)
    window = (t_log >= t_touch) & (t_log <= t_decide) if touched else None
    return dict(
        touch_time=t_touch,
        touch_velocity=nan if touch_velocity is None else float(touch_velocity),
        touch_peak_force=nan if window is None else float(log["force"][window].max()),
        touch_peak_penetration=(nan if window is None else float(log["penetration"][window].max())),
        decision_time=t_decide,
    )


def surface_offset_bias(
    stiffness: float, second_moment: np.ndarray, first_moment: np.ndarray, offset: float
) -> np.ndarray:
    """Effect on eq 17/21's ``Ê = [α̂, β̂]`` of a constant error ``ε`` (m) in the measured
    deformation (``z_measured = z_true + ε``, e.g. the surface found one step late):

        f = α z_true + β ż = α z_measured + β ż − α ε   ⇒   Ê − E = −α ε (S Sᵀ)⁻¹ Σ s

    Args:
        stiffness: α, N/m (the estimate is fine: the bias is a small correction).
        second_moment: ``S Sᵀ`` (2×2; m², m²/s, m²/s²) of the samples fed.
        first_moment: ``Σ s = [Σ z, Σ ż]`` (m, m/s).
        offset: ε, m.
    Returns: ``[Δα, Δβ]`` (N/m, N·s/m).
    """
    G = np.asarray(second_moment, dtype=float)
    m = np.asarray(first_moment, dtype=float)
    if G.shape != (2, 2) or m.shape != (2,):
        raise InputError("second_moment must be 2×2 and first_moment 2 numbers")
    return -float(stiffness) * float(offset) * np.linalg.solve(G, m)


@dataclass(frozen=True)
class Checkpoint:
    """The learner's state at one point of the exploration.

    Attributes:
        label: "sinusoid" or "impact k".
        time: s. estimate: the learner fed without the contact-onset samples.
        z_bias_bound: ``|Δα|, |Δβ|`` bound (N/m, N·s/m) from the surface error (see
            :func:`surface_offset_bias` with ε = ``approach_speed·Δt``).
        with_onset: the estimate of the learner fed every in-contact sample, onsets included.
        pre_impact_velocity: speed along d at the last force-free sample before the impact,
            m/s (NaN for the sinusoid). peak_penetration: largest z of the phase, m.
    """

    label: str
    time: float
    estimate: ContactEstimate
    z_bias_bound: tuple[float, float]
    with_onset: ContactEstimate
    pre_impact_velocity: float
    peak_penetration: float

    def relative_errors(self, material: Material) -> tuple[float, float]:
        """``(α̂/α − 1, β̂/β − 1)`` (NaN for β when β = 0)."""
        e = self.estimate
        rd = e.damping / material.damping - 1.0 if material.damping > 0 else float("nan")
        return e.stiffness / material.stiffness - 1.0, rd

    def interval(self, sigmas: float = 2.0) -> tuple[float, float]:
        """Half-widths of the confidence intervals (N/m, N·s/m): ``sigmas`` standard errors
        (the learner's, statistical) plus the surface-error bound."""
        e = self.estimate
        return (
            sigmas * e.stiffness_std + self.z_bias_bound[0],
            sigmas * e.damping_std + self.z_bias_bound[1],
        )

    def covers(self, material: Material, sigmas: float = 2.0) -> bool:
        """Whether the interval of :meth:`interval` contains the truth (both parameters)."""
        wa, wb = self.interval(sigmas)
        e = self.estimate
        return (
            abs(e.stiffness - material.stiffness) <= wa and abs(e.damping - material.damping) <= wb
        )
