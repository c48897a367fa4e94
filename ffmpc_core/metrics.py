"""Performance metrics of the polishing task (paper VI-C, eq 34–35, Tables II–IV).

All functions take sampled signals (one row per control/simulation cycle) and their sample
times ``t`` (s), and evaluate them over the window ``start <= t <= end`` (s; None = unbounded);
the paper evaluates them over the circle phase.

Which signal each metric uses (the caller chooses TRUE or MEASURED signals; the study computes
both: the plant's true normal force along the tilted table normal, and the measured λ̂):

* E_P — tangential position MAE, mm: mean over the window of ‖(I − n nᵀ)(p − p̄)‖, p the contact
  frame position, p̄ its reference, n the TRUE table normal: the error in the table plane.
* E_λ — normal force MAE, N: mean of |λ − λ̄|.
* λmax — eq 34: max of |λ| over the window (the largest normal force, N). The paper's text
  calls it "the maximum normal force error magnitude" but eq 34 writes max ‖λ̂(t)‖ and
  Tables II–III report values (59–211 N) that are forces; we follow eq 34.
* t_break — eq 35: percentage of cycles in the window with λ ≤ γ (γ = 1e-3 N).
* E_τ — torque tracking MAE, N·m: mean over cycles AND joints of |τ^d − τ̂| (desired torque of
  the MPC vs measured joint torque, Table IV).

Experiment 3.3 (pushes): :func:`push_phase_windows` gives the DURING and AFTER windows of each
push, :func:`push_phase_metrics` E_λ (N), E_P (mm) and the largest |λ| (N) over one of them.

Eq 34–35 then take the max over the randomised runs; :func:`summarize` does that aggregation
(mean ± std of the MAEs, max of λmax and t_break, as in Tables II–III).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np
import numpy.typing as npt

from ffmpc_core.errors import InputError

#: γ of eq 35, N: a cycle with a normal force at or below it has no contact.
CONTACT_BREAK_THRESHOLD = 1e-3


def window_mask(t: np.ndarray, start: float | None = None, end: float | None = None) -> np.ndarray:
    """Boolean mask of the samples with ``start <= t <= end`` (s); InputError if empty."""
    t = np.asarray(t, dtype=float)
    if t.ndim != 1 or t.size == 0 or not np.all(np.isfinite(t)):
        raise InputError("t must be a non-empty 1-D array of finite times")
    mask = np.ones(t.size, dtype=bool)
    if start is not None:
        mask &= t >= start
    if end is not None:
        mask &= t <= end
    if not mask.any():
        raise InputError(f"no sample in the window [{start}, {end}] s")
    return mask


def _signal(value: npt.ArrayLike, shape: tuple[int | None, ...], name: str) -> np.ndarray:
    """A finite float array of the given shape (None: any size along that axis)."""
    arr = np.asarray(value, dtype=float)
    ok = arr.ndim == len(shape) and all(
        s is None or s == n for s, n in zip(shape, arr.shape, strict=True)
    )
    if not ok or not np.all(np.isfinite(arr)):
        raise InputError(f"{name} must be finite with shape {shape}, got {arr.shape}")
    return arr


def tangential_position_mae(
    t: np.ndarray,
    position: np.ndarray,
    reference: np.ndarray,
    table_normal: np.ndarray,
    start: float | None = None,
    end: float | None = None,
) -> float:
    """E_P (VI-C): mean of ‖(I − n nᵀ)(p − p̄)‖ over the window, in m.

    Args: position p and reference p̄ (N×3, m, world frame), table_normal n (3, world).
    """
    mask = window_mask(t, start, end)
    n = mask.size
    p = _signal(position, (n, 3), "position")
    ref = _signal(reference, (n, 3), "reference")
    normal = np.asarray(table_normal, dtype=float)
    if normal.shape != (3,) or not np.isclose(np.linalg.norm(normal), 1.0, atol=1e-9):
        raise InputError(f"table_normal must be a unit 3-vector, got {table_normal!r}")
    error = (p - ref)[mask]
    tangential = error - np.outer(error @ normal, normal)
    return float(np.mean(np.linalg.norm(tangential, axis=1)))


def normal_force_mae(
    t: np.ndarray,
    normal_force: np.ndarray,
    reference: np.ndarray | float,
    start: float | None = None,
    end: float | None = None,
) -> float:
    """E_λ (VI-C): mean of |λ − λ̄| over the window, N (λ̄ a scalar or one per sample)."""
    mask = window_mask(t, start, end)
    force = _signal(normal_force, (mask.size,), "normal_force")
    ref = np.asarray(reference, dtype=float)
    ref = _signal(ref, () if ref.ndim == 0 else force.shape, "reference")
    return float(np.mean(np.abs(force - ref)[mask]))


def max_normal_force(
    t: np.ndarray,
    normal_force: np.ndarray,
    start: float | None = None,
    end: float | None = None,
) -> float:
    """λmax (eq 34) of one run: max of |λ| over the window, N."""
    mask = window_mask(t, start, end)
    force = _signal(normal_force, (mask.size,), "normal_force")
    return float(np.max(np.abs(force[mask])))


def contact_break_percent(
    t: np.ndarray,
    normal_force: np.ndarray,
    start: float | None = None,
    end: float | None = None,
    threshold: float = CONTACT_BREAK_THRESHOLD,
) -> float:
    """t_break (eq 35) of one run: % of cycles in the window with λ ≤ γ (γ = ``threshold``, N)."""
    mask = window_mask(t, start, end)
    force = _signal(normal_force, (mask.size,), "normal_force")
    return float(100.0 * np.mean(force[mask] <= threshold))


def torque_tracking_mae(
    t: np.ndarray,
    desired_torque: np.ndarray,
    measured_torque: np.ndarray,
    start: float | None = None,
    end: float | None = None,
) -> float:
    """E_τ (Table IV): mean over the window's cycles and the joints of |τ^d − τ̂|, N·m."""
    mask = window_mask(t, start, end)
    desired = _signal(desired_torque, (mask.size, None), "desired_torque")
    measured = _signal(measured_torque, desired.shape, "measured_torque")
    return float(np.mean(np.abs(desired - measured)[mask]))


@dataclass(frozen=True)
class PolishingMetrics:
    """The metrics of one run (see the module docstring for the signals)."""

    position_mae_mm: float  # E_P, mm
    force_mae: float  # E_λ, N
    max_force: float  # λmax, N
    contact_break_percent: float  # t_break, %
    torque_mae: float | None = None  # E_τ, N·m (None when the torques were not given)

    def to_dict(self) -> dict[str, float | None]:
        """The metrics by field name (JSON-ready; None where a metric is undefined)."""
        return asdict(self)


def polishing_metrics(
    t: np.ndarray,
    position: np.ndarray,
    position_reference: np.ndarray,
    table_normal: np.ndarray,
    normal_force: np.ndarray,
    force_reference: np.ndarray | float,
    desired_torque: np.ndarray | None = None,
    measured_torque: np.ndarray | None = None,
    start: float | None = None,
    end: float | None = None,
    threshold: float = CONTACT_BREAK_THRESHOLD,
) -> PolishingMetrics:
    """All metrics of one run over the window ``[start, end]`` (s)."""
    torque = None
    if (desired_torque is None) != (measured_torque is None):
        raise InputError("give both desired_torque and measured_torque, or neither")
    if desired_torque is not None and measured_torque is not None:
        torque = torque_tracking_mae(t, desired_torque, measured_torque, start, end)
    return PolishingMetrics(
        position_mae_mm=1e3
        * tangential_position_mae(t, position, position_reference, table_normal, start, end),
        force_mae=normal_force_mae(t, normal_force, force_reference, start, end),
        max_force=max_normal_force(t, normal_force, start, end),
        contact_break_percent=contact_break_percent(t, normal_force, start, end, threshold),
        torque_mae=torque,
    )


#: Length of the AFTER window of a push (Experiment 3.3), s: the recovery is measured over the
#: ``PUSH_RECOVERY_WINDOW`` s that follow the end of the push (cut at the next push and at the end
#: of the evaluation window).
PUSH_RECOVERY_WINDOW = 0.5


@dataclass(frozen=True)
class PushPhaseMetrics:
    """Tracking over one phase of an external push (Experiment 3.3): DURING the push or AFTER it.

    ``start``/``end`` (s) bound the phase, half-open ``start <= t < end``; ``samples`` is how many
    cycles it holds. With no sample (the run ended before the phase) the metrics are None.
    """

    start: float  # s
    end: float  # s
    samples: int
    force_mae: float | None  # E_λ over the phase, N
    position_mae_mm: float | None  # E_P over the phase (tangential, as E_P), mm
    max_force: float | None  # max |λ| over the phase, N

    def to_dict(self) -> dict[str, float | int | None]:
        """The metrics by field name (JSON-ready; None where a window is empty)."""
        return asdict(self)


def push_phase_windows(
    pushes: Sequence[tuple[float, float]],
    recovery: float = PUSH_RECOVERY_WINDOW,
    end: float | None = None,
) -> list[dict[str, tuple[float, float]]]:
    """The DURING and AFTER windows (s, half-open) of each push, in time order.

    Args:
        pushes: (start s, duration s) of each push; the force acts on ``start <= t < start +
            duration`` (the plant applies it on those cycles).
        recovery: length of the AFTER window, s; it is cut at the next push's start and at
            ``end`` (s, the end of the evaluation window; None: not cut).
    Returns: one ``{"during": (t0, t1), "after": (t1, t2)}`` per push.
    """
    ordered = sorted((float(a), float(d)) for a, d in pushes)
    if any(not (np.isfinite(a) and np.isfinite(d) and d >= 0.0) for a, d in ordered):
        raise InputError(f"pushes must be (finite start s, duration s >= 0), got {pushes!r}")
    if not (np.isfinite(recovery) and recovery >= 0.0):
        raise InputError(f"recovery must be a finite duration >= 0 s, got {recovery!r}")
    out = []
    for i, (start, duration) in enumerate(ordered):
        stop = start + duration
        after = stop + recovery
        if i + 1 < len(ordered):
            after = min(after, ordered[i + 1][0])
        if end is not None:
            after = min(after, end)
        out.append({"during": (start, stop), "after": (stop, max(stop, after))})
    return out


def push_phase_metrics(
    t: np.ndarray,
    position: np.ndarray,
    position_reference: np.ndarray,
    table_normal: np.ndarray,
    normal_force: np.ndarray,
    force_reference: np.ndarray | float,
    window: tuple[float, float],
) -> PushPhaseMetrics:
    """E_λ (N), E_P (mm) and max |λ| (N) over one phase ``window[0] <= t < window[1]`` (s); the
    signals as :func:`polishing_metrics` (p, p̄ N×3 m world frame, n the TRUE table normal),
    computed by the same functions (:func:`normal_force_mae`, :func:`tangential_position_mae`,
    :func:`max_normal_force`) over ``[start, last]`` with ``last`` the float just below the
    phase's end: ``t <= last`` exactly when ``t < end``."""
    start, end = float(window[0]), float(window[1])
    last = float(np.nextafter(end, -np.inf))
    t = np.asarray(t, dtype=float)
    window_mask(t)  # the checks of t, whatever the phase
    samples = int(np.count_nonzero((t >= start) & (t <= last)))
    if samples == 0:  # the run ended before this phase: the signals are still checked
        n = t.size
        _signal(position, (n, 3), "position")
        _signal(position_reference, (n, 3), "position_reference")
        _signal(normal_force, (n,), "normal_force")
        return PushPhaseMetrics(start, end, 0, None, None, None)
    return PushPhaseMetrics(
        start=start,
        end=end,
        samples=samples,
        force_mae=normal_force_mae(t, normal_force, force_reference, start, last),
        position_mae_mm=1e3
        * tangential_position_mae(t, position, position_reference, table_normal, start, last),
        max_force=max_normal_force(t, normal_force, start, last),
    )


def summarize(runs: Sequence[PolishingMetrics]) -> dict[str, float | None]:
    """Aggregate runs as Tables II–III: mean and std of E_P, E_λ, E_τ; max of λmax (eq 34) and
    of t_break (eq 35) over the runs."""
    if len(runs) == 0:
        raise InputError("no run to summarize")
    out: dict[str, float | None] = {}
    for name in ("position_mae_mm", "force_mae", "torque_mae"):
        values = [getattr(r, name) for r in runs]
        if any(v is None for v in values):
            out[f"{name}_mean"] = out[f"{name}_std"] = None
            continue
        out[f"{name}_mean"] = float(np.mean(values))
        out[f"{name}_std"] = float(np.std(values))
    out["max_force"] = float(max(r.max_force for r in runs))
    out["contact_break_percent"] = float(max(r.contact_break_percent for r in runs))
    return out


def limit_ratios(values: npt.ArrayLike, limit: npt.ArrayLike) -> tuple[np.ndarray, int | None]:
    """Per joint, the largest |value|/limit over a run (one row per cycle; a NaN counts as a
    broken limit, inf), and the cycle of the overall largest (None for an empty run). For joint
    velocities (rad/s against the velocity limits) and torques (N·m against the torque limits):
    a ratio above 1 is a broken limit."""
    limit = np.asarray(limit, dtype=float)
    rows = np.asarray(values, dtype=float).reshape(-1, limit.size)
    if rows.shape[0] == 0:
        return np.zeros(limit.size), None
    ratio = np.nan_to_num(np.abs(rows) / limit, nan=np.inf)
    return ratio.max(axis=0), int(np.argmax(ratio.max(axis=1)))
