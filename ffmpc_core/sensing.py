"""Sensing model of the simulation study (paper VI-B2, eq 30 and 32) and an exact delay line.

Delays are counted in cycles, i.e. calls of ``step``: a delay of k cycles returns, at call n, the
sample given at call n − k, exactly (k = 0 is no delay). Call the sensing model once per
simulation cycle to get the paper's δs = 1 simulation cycle.

Noise parameters are STANDARD DEVIATIONS: ν ~ N(0, σ²) with σ in the signal's unit (the paper
calls σ_q, σ_q̇ "variances" but writes ν_λ ~ N(0, σ_λ²); we read every σ as a standard
deviation). Every random number comes from the ``numpy.random.Generator`` handed in (the joint
sensor and the force sensor are separate devices, each with its own); the joint sensor draws in a
fixed order (q, then q̇) so the same seed gives the same streams.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ffmpc_core.config import ContactConfig
from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.plausibility import check_force, check_tare_offset


def delay_cycles(delay: float, cycle: float) -> int:
    """A delay in seconds as a whole number of cycles of ``cycle`` seconds (e.g. 5 ms at 1 kHz
    → 5); ConfigError if it is not a whole number (to 1e-9 relative)."""
    if not (math.isfinite(delay) and math.isfinite(cycle)) or delay < 0.0 or cycle <= 0.0:
        raise ConfigError(f"need delay >= 0 and cycle > 0, got {delay}, {cycle}")
    cycles = delay / cycle
    k = round(cycles)
    if abs(cycles - k) > 1e-9 * max(1.0, cycles):
        raise ConfigError(f"delay {delay} s is not a whole number of {cycle} s cycles")
    return int(k)


def _as_std(value: npt.ArrayLike, size: int, name: str) -> np.ndarray:
    try:
        arr = np.broadcast_to(np.asarray(value, dtype=float), (size,)).copy()
    except ValueError:
        raise ConfigError(
            f"{name} must be a scalar or have {size} entries, got {value!r}"
        ) from None
    if np.any(arr < 0.0) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite and >= 0, got {value!r}")
    return arr


class DelayLine:
    """Delays a fixed-shape signal by exactly ``delay`` cycles (calls of :meth:`step`).

    Until ``delay`` samples have been seen, the output is the initial value given to
    :meth:`reset` or, by default, the first sample (a sensor reads the initial state).
    The buffer is preallocated; :meth:`step` returns a fresh array.
    """

    def __init__(self, delay: int, shape: int | tuple[int, ...] = ()) -> None:
        if isinstance(delay, bool) or int(delay) != delay or delay < 0:
            raise ConfigError(f"delay must be a whole number of cycles >= 0, got {delay!r}")
        self.delay = int(delay)
        self.shape = (shape,) if isinstance(shape, int) else tuple(shape)
        self._buffer = np.zeros((self.delay + 1, *self.shape))
        self._oldest = 0
        self._primed = False

    def reset(self, initial: np.ndarray | float | None = None) -> None:
        """Forget the history; the first ``delay`` outputs will be ``initial`` (default: the
        first sample)."""
        self._oldest = 0
        self._primed = initial is not None
        if initial is not None:
            self._buffer[:] = self._check(initial, "initial")

    def _check(self, value: npt.ArrayLike, name: str) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != self.shape or not np.all(np.isfinite(arr)):
            raise InputError(f"{name} must be finite with shape {self.shape}, got {value!r}")
        return arr

    def step(self, sample: np.ndarray | float) -> np.ndarray:
        """Push ``sample`` and return the sample pushed ``delay`` calls ago."""
        sample = self._check(sample, "sample")
        if not self._primed:
            self._buffer[:] = sample
            self._primed = True
        # The slot written now is the one read: with delay + 1 slots, the slot after the newest
        # holds the sample written delay calls ago.
        newest = self._oldest
        self._buffer[newest] = sample
        self._oldest = (newest + 1) % (self.delay + 1)
        return self._buffer[self._oldest].copy()


def joint_state_measurement(
    q_delayed: np.ndarray,
    v_delayed: np.ndarray,
    position_noise_std: np.ndarray,
    velocity_noise_std: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """Eq 30: q̂(t) = q(t − δs) + ν_q, q̇̂(t) = q̇(t − δs) + ν_q̇.

    Args:
        q_delayed: q(t − δs), rad.  v_delayed: q̇(t − δs), rad/s.
        position_noise_std: σ_q, rad (per joint).  velocity_noise_std: σ_q̇, rad/s.
        rng: draws ν_q first, then ν_q̇.
    Returns: (q̂ in rad, q̇̂ in rad/s).
    """
    q_hat = q_delayed + position_noise_std * rng.standard_normal(q_delayed.shape)
    v_hat = v_delayed + velocity_noise_std * rng.standard_normal(v_delayed.shape)
    return q_hat, v_hat


def force_measurement(
    force_delayed: np.ndarray, force_noise_std: np.ndarray, rng: np.random.Generator
) -> np.ndarray:
    """Eq 32: λ̂(t) = λ(t − δs) + ν_λ, ν_λ ~ N(0, σ_λ²); N, in the frame λ is given in."""
    return force_delayed + force_noise_std * rng.standard_normal(force_delayed.shape)


def measured_force(wrench_world: np.ndarray, contact: ContactConfig) -> np.ndarray:
    """The MPC's force from the tool wrench (world axes): 1-D → the world-z component
    (LOCAL_WORLD_ALIGNED normal, config.py's convention), 3-D → the world force."""
    if contact.frame_type != "LOCAL_WORLD_ALIGNED":
        raise ConfigError("the study feeds world-aligned forces; use LOCAL_WORLD_ALIGNED")
    if contact.dimension == 1:
        return wrench_world[contact.normal_axis : contact.normal_axis + 1].copy()
    return wrench_world[:3].copy()


@dataclass(frozen=True)
class JointSensorConfig:
    """The joint sensor of eq 30 (paper VI-B2); the scenario's ``joint_sensor`` section is this
    class. The force sensor of eq 32 is :class:`ForceSensingModel` (its σ_λ: the ``ft_sensor``
    section).

    Attributes:
        delay_cycles: δs in cycles of :meth:`JointSensingModel.step` (paper: 1 simulation cycle).
        position_noise_std: σ_q, rad, every joint (paper: 1e-3).
        velocity_noise_std: σ_q̇, rad/s, every joint (paper: 1e-3).
    """

    delay_cycles: int = param(1, "cycles", (0, 1000), "sensing delay δs (eq 30)")
    position_noise_std: float = param(1e-3, "rad", (0.0, 1.0), "σ_q (eq 30)")
    velocity_noise_std: float = param(1e-3, "rad/s", (0.0, 10.0), "σ_q̇ (eq 30)")

    def __post_init__(self) -> None:
        if isinstance(self.delay_cycles, bool) or int(self.delay_cycles) != self.delay_cycles:
            raise ConfigError(f"delay_cycles must be an integer, got {self.delay_cycles!r}")
        if self.delay_cycles < 0:
            raise ConfigError("delay_cycles must be >= 0")
        for name in ("position_noise_std", "velocity_noise_std"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f"{name} must be finite and >= 0, got {getattr(self, name)!r}")


class JointSensingModel:
    """Delays and noises the true joint state (eq 30).

    ``step(q, v)`` is called once per cycle with the simulator's true values and returns the
    measurements (q̂, q̇̂); the noises are drawn from ``rng`` (ν_q, then ν_q̇).
    """

    def __init__(self, config: JointSensorConfig, nv: int, rng: np.random.Generator) -> None:
        if nv <= 0:
            raise ConfigError(f"need nv > 0, got {nv}")
        if not isinstance(rng, np.random.Generator):
            raise ConfigError("rng must be a numpy.random.Generator")
        self.config = config
        self.nv = nv
        self.rng = rng
        self.position_noise_std = _as_std(config.position_noise_std, nv, "position_noise_std")
        self.velocity_noise_std = _as_std(config.velocity_noise_std, nv, "velocity_noise_std")
        self._q = DelayLine(config.delay_cycles, nv)
        self._v = DelayLine(config.delay_cycles, nv)

    def reset(self) -> None:
        """Forget the history (the next sample fills the delay lines)."""
        self._q.reset()
        self._v.reset()

    def step(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Measurements (q̂ rad, q̇̂ rad/s) from the true (q, q̇) of this cycle."""
        q_d = self._q.step(q)
        v_d = self._v.step(v)
        return joint_state_measurement(
            q_d, v_d, self.position_noise_std, self.velocity_noise_std, self.rng
        )


class ForceSensingModel:
    """Eq 32 alone: the force/torque sensor's delay δs (cycles) and noise σ_λ (N).

    The joint and force sensors are separate devices (and separate ROS nodes), so each has its
    own generator; ``step(force)`` once per cycle returns λ̂.
    """

    def __init__(
        self, delay: int, force_noise_std: npt.ArrayLike, force_dim: int, rng: np.random.Generator
    ) -> None:
        if force_dim <= 0:
            raise ConfigError(f"force_dim must be > 0, got {force_dim}")
        if not isinstance(rng, np.random.Generator):
            raise ConfigError("rng must be a numpy.random.Generator")
        self.force_dim = force_dim
        self.rng = rng
        self.force_noise_std = _as_std(force_noise_std, force_dim, "force_noise_std")
        self._force = DelayLine(delay, force_dim)

    def reset(self) -> None:
        """Forget the delayed forces."""
        self._force.reset()

    def step(self, force: np.ndarray) -> np.ndarray:
        """λ̂ (N) from this cycle's true force λ (N), same frame."""
        return force_measurement(self._force.step(force), self.force_noise_std, self.rng)


class ForceTare:
    """The F/T sensor's tare: offset (N) = mean of the last ``samples`` plausible raw readings.

    ``add(raw)`` once per reading (readings that are non-finite or beyond
    ``plausibility.FORCE_MAX`` are not kept: a −1e9 N glitch must not become the offset);
    ``tare(in_contact)`` sets the offset, or raises InputError and keeps the previous one while
    in contact, before any reading, or when the mean exceeds ``plausibility.TARE_OFFSET_MAX``
    per axis (a loaded or broken sensor); ``offset`` is what the sensor subtracts.
    """

    def __init__(self, samples: int, force_dim: int) -> None:
        if isinstance(samples, bool) or int(samples) != samples or samples < 1:
            raise ConfigError(f"tare samples must be a whole number >= 1, got {samples!r}")
        if force_dim <= 0:
            raise ConfigError(f"force_dim must be > 0, got {force_dim}")
        self._recent: deque[np.ndarray] = deque(maxlen=int(samples))
        self.offset = np.zeros(force_dim)
        self.force_dim = force_dim
        self.rejected = 0

    @property
    def samples(self) -> int:
        """Readings currently kept for the next tare."""
        return len(self._recent)

    def add(self, raw: np.ndarray) -> bool:
        """Keep a raw reading (N) for the next tare; False (not kept) if it is implausible."""
        arr = np.asarray(raw, dtype=float)
        if arr.shape != (self.force_dim,):
            raise InputError(f"a reading must have {self.force_dim} entries, got {arr.shape}")
        try:
            check_force(arr, "F/T reading")
        except InputError:
            self.rejected += 1
            return False
        self._recent.append(arr.copy())
        return True

    def tare(self, in_contact: bool) -> np.ndarray:
        """Set and return the offset (N); InputError (offset unchanged) when refused."""
        if in_contact:
            raise InputError("tare refused: the sensor is in contact")
        if not self._recent:
            raise InputError("tare refused: no plausible measurement yet")
        offset = check_tare_offset(np.mean(np.array(self._recent), axis=0))
        self.offset = offset
        return offset.copy()


class ContactHysteresis:
    """Contact detection with hysteresis on a normal force (N): contact starts once the force
    exceeds ``on`` and ends once it falls below ``off`` (``off`` ≤ ``on``); between the two the
    state is kept, so noise around one threshold does not toggle it (the agimus deburring
    controller's contact detector uses two thresholds the same way)."""

    def __init__(self, on: float, off: float) -> None:
        if not (np.isfinite(on) and np.isfinite(off)) or off > on:
            raise ConfigError(
                f"contact thresholds need off <= on (N), got on {on!r}, off {off!r}: "
                "contact_off_force must not exceed contact_on_force"
            )
        self.on = float(on)
        self.off = float(off)
        self.in_contact = False

    def reset(self) -> None:
        """Out of contact (the state before any reading)."""
        self.in_contact = False

    def update(self, normal_force: float) -> bool:
        """The contact state after this normal force (N)."""
        if self.in_contact and normal_force < self.off:
            self.in_contact = False
        elif not self.in_contact and normal_force > self.on:
            self.in_contact = True
        return self.in_contact
