"""Low-level joint torque PID with feed-forward (paper VI-B2, eq 33, Fig. 2).

    τ^m(t) = τ^d(t − δo) − K_P·e(t) − K_I·∫₀ᵗ e(s) ds − K_D·de/dt,  e = τ̂ − τ^d(· − δo)

τ^d is the MPC's desired torque, δo the delay of the OCP resolution (5 ms: 5 cycles at 1 kHz,
10 at 2 kHz; see :func:`ffmpc_core.sensing.delay_cycles`), τ̂ the measured joint torque (the
output of the actuation model, eq 31) and τ^m the motor torque sent to the actuation model.

Readings of the paper's equation:

* (33c) integrates over time: the integral state is Σ e·Δt (N·m·s), and anti-windup clamps
  the integral term to ``|K_I·∫e| ≤ integral_limit`` (N·m) per joint.
* (33d) reads ``−K_D·τ̂(t)``, which is not a derivative term; we use ``−K_D·dτ̂/dt`` by a
  backward difference of the measured torque (0 at the first call). τ^d is piecewise
  constant, so this equals the derivative of the error between MPC updates without the kick
  a jump of τ^d would give.
* ``enabled=False`` is the paper's "without PID" study: τ^m(t) = τ^d(t − δo), no feedback.
* Plausibility (``ffmpc_core.plausibility``): with ``torque_limit`` given, a finite measured
  torque beyond ``MEASURED_TORQUE_FACTOR`` × the limit (a torque spike, a broken sensor) is
  rejected: that cycle has no P or D feedback, the integral keeps its value (one absurd sample
  must not pin it at its anti-windup bound) and ``rejected`` counts it. A non-finite one is an
  InputError, with the state untouched.

Default gains (``TorquePidGains.default``): K_P = 0.1, K_I = 20 s⁻¹, K_D = 0. On the torque
loop alone (actuation delay δs = 1 cycle: e_{k+1} = −a·K_P·e_k − a·K_I·Δt·Σe + d) any
a·K_P < 1 is stable and K_P = 0.5, K_I = 100 s⁻¹ settles in ~15 ms; but in the robot the
measured torque τ̂ carries the joint friction (eq 31), so the PID also feeds back joint velocity
and cancels the friction's damping: on the iiwa's light wrist (link-7 inertia ~1e-3 kg·m²)
those gains made joint 7 oscillate at ~270 Hz (E_τ 12–16 N·m, 36 N·m on joint 7). K_P = 0.1,
K_I = 20 s⁻¹ keep the wrist quiet and track torque best in the polishing task (E_τ 2–3.6 N·m,
measured on seeds 0 and 11 with all three MPCs) — the paper's criterion for its gains. K_D = 0
because τ̂ carries the torque noise (σ_τ ≈ 1 N·m) and a difference quotient at 1 kHz
multiplies it by ~1400 s⁻¹. The integral limit defaults to 30 % of the torque limit, enough to
cancel a 20 % gain error plus the 2 N·m offset.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.plausibility import MEASURED_TORQUE_FACTOR
from ffmpc_core.sensing import DelayLine


@dataclass(frozen=True)
class PidConfig:
    """The torque PID (eq 33) as the scenario states it, and the low-level loop around it
    (:class:`ffmpc_core.lowlevel.LowLevelController`: safe hold, blend, limits). The scenario's
    ``pid`` section is this class.

    The gains are the same for every joint; :meth:`TorquePidGains.from_config` makes them
    per-joint arrays and the anti-windup bound N·m from the robot's torque limits.
    """

    enabled: bool = param(True, "", None, "torque PID on (off: τ^m = τ^d(t − δo))")
    kp: float = param(0.1, "", (0.0, 100.0), "K_P (eq 33)")
    # 1/s; see the module docstring for why these gains
    ki: float = param(20.0, "1/s", (0.0, 1e5), "K_I (eq 33)")
    kd: float = param(0.0, "s", (0.0, 100.0), "K_D (eq 33)")
    integral_fraction: float = param(
        0.3, "", (0.0, 1.0), "anti-windup bound on K_I·∫e / torque limit"
    )
    delay_cycles: int = param(5, "cycles", (0, 1000), "δo (eq 33)")  # δo = 5 ms at 1 kHz
    # The low-level loop around the PID (ffmpc_core.lowlevel.LowLevelConfig holds this class
    # and reads these; its docstring says what each does). Inactive while the MPC is on time.
    # s without a new MPC command → safe hold (2 MPC periods)
    stale_timeout: float = param(
        0.004, "s", (1e-5, 10.0), "MPC command age that triggers the safe hold"
    )
    # s, hold → MPC torque blend (minimum jerk)
    blend_duration: float = param(0.1, "s", (0.0, 10.0), "hold → MPC blend")
    # Hz, natural frequency of the safe hold PD (full mass matrix)
    hold_frequency: float = param(4.0, "Hz", (0.0, 100.0), "natural frequency of the hold PD")
    hold_damping_ratio: float = param(1.0, "", (0.0, 10.0), "damping ratio of the hold PD")
    # Fraction of the data-sheet torque limits τ^d and τ^m are saturated to (live on the pid node).
    torque_limit_fraction: float = param(
        1.0,
        "",
        (0.01, 1.0),
        "fraction of the robot's data-sheet torque limits the low level saturates τ^d and τ^m to "
        "(never above the data sheet)",
    )
    # Fraction of the velocity limits above which a measured joint speed engages the safe hold
    # (ffmpc_core.lowlevel; 0: off, the paper's scheme).
    velocity_guard: float = param(
        0.0,
        "",
        (0.0, 1.0),
        "fraction of the velocity limits above which a measured joint speed engages the safe "
        "hold (0: off)",
    )

    def __post_init__(self) -> None:
        if isinstance(self.delay_cycles, bool) or int(self.delay_cycles) != self.delay_cycles:
            raise ConfigError(f"delay_cycles must be an integer, got {self.delay_cycles!r}")
        if self.delay_cycles < 0:
            raise ConfigError(f"delay_cycles must be >= 0, got {self.delay_cycles}")
        gains = (self.kp, self.ki, self.kd, self.integral_fraction)
        if not all(math.isfinite(g) and g >= 0.0 for g in gains):
            raise ConfigError(f"kp, ki, kd, integral_fraction must be finite and >= 0: {gains}")
        times = (self.stale_timeout, self.blend_duration, self.hold_frequency)
        if not all(math.isfinite(v) for v in times):
            raise ConfigError("stale_timeout, blend_duration, hold_frequency: finite")
        if self.blend_duration < 0 or self.hold_frequency < 0 or self.hold_damping_ratio < 0:
            raise ConfigError("blend_duration, hold_frequency, hold_damping_ratio must be >= 0")
        if not 0.0 < self.torque_limit_fraction <= 1.0:
            raise ConfigError(
                f"torque_limit_fraction must lie in (0, 1] (never above the data sheet), got "
                f"{self.torque_limit_fraction}"
            )
        if not 0.0 <= self.velocity_guard <= 1.0:
            raise ConfigError(
                f"velocity_guard must lie in [0, 1] (0: off), got {self.velocity_guard}"
            )


def _per_joint(value: npt.ArrayLike, nv: int, name: str) -> np.ndarray:
    try:
        arr = np.broadcast_to(np.asarray(value, dtype=float), (nv,)).copy()
    except ValueError:
        raise ConfigError(f"{name} must be a scalar or have {nv} entries, got {value!r}") from None
    if np.any(arr < 0.0) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite and >= 0, got {arr}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class TorquePidGains:
    """Per-joint gains of eq 33 (arrays of size nv).

    Attributes:
        kp: K_P, dimensionless.  ki: K_I, 1/s.  kd: K_D, s.
        integral_limit: bound on |K_I·∫e ds| per joint, N·m (anti-windup).
    """

    kp: np.ndarray
    ki: np.ndarray
    kd: np.ndarray
    integral_limit: np.ndarray

    def __post_init__(self) -> None:
        nv = int(np.size(self.kp))
        if nv == 0 or np.ndim(self.kp) != 1:
            raise ConfigError("kp must be a non-empty 1-D array (one entry per joint)")
        for name in ("kp", "ki", "kd", "integral_limit"):
            object.__setattr__(self, name, _per_joint(getattr(self, name), nv, name))

    @property
    def nv(self) -> int:
        """Number of joints the gains are for."""
        return int(self.kp.size)

    @classmethod
    def from_config(cls, config: PidConfig, torque_limit: np.ndarray) -> TorquePidGains:
        """The gains of ``config`` for a robot whose joints' torque limits are
        ``torque_limit`` (N·m): the same K_P, K_I, K_D per joint, integral limit =
        ``integral_fraction`` × torque limit."""
        return cls.default(torque_limit, config.kp, config.ki, config.kd, config.integral_fraction)

    @classmethod
    def default(
        cls,
        torque_limit: np.ndarray,
        kp: float = 0.1,
        ki: float = 20.0,
        kd: float = 0.0,
        integral_fraction: float = 0.3,
    ) -> TorquePidGains:
        """The gains of the module docstring; integral limit = fraction × torque limit (N·m)."""
        limit = np.asarray(torque_limit, dtype=float)
        if limit.ndim != 1 or limit.size == 0 or np.any(limit <= 0.0):
            raise ConfigError(f"torque_limit must be positive per joint, got {torque_limit!r}")
        nv = limit.size
        return cls(
            kp=np.full(nv, kp),
            ki=np.full(nv, ki),
            kd=np.full(nv, kd),
            integral_limit=integral_fraction * limit,
        )


class TorquePid:
    """Eq 33 as a controller: ``reset()``, ``step(τ̂, τ^d, t) -> τ^m``, once per cycle.

    Args:
        gains: per-joint gains.
        dt: the cycle, s (the first call integrates over dt; later calls over the actual Δt).
        delay_cycles: δo in cycles (5 at 1 kHz for the paper's 5 ms).
        enabled: False → τ^m = τ^d(t − δo) (the paper's "without PID").
        torque_limit: the joints' torque limits, N·m; measured torques beyond
            ``MEASURED_TORQUE_FACTOR`` × these are rejected (None: only non-finite ones are).
    """

    def __init__(
        self,
        gains: TorquePidGains,
        dt: float,
        delay_cycles: int = 5,
        enabled: bool = True,
        torque_limit: np.ndarray | None = None,
    ) -> None:
        if not (math.isfinite(dt) and dt > 0.0):
            raise ConfigError(f"dt must be > 0, got {dt}")
        if torque_limit is None:
            self._plausible_max = np.full(gains.nv, np.inf)
        else:
            limit = np.asarray(torque_limit, dtype=float)
            if limit.shape != (gains.nv,) or not np.all(limit > 0.0):
                raise ConfigError(f"torque_limit must be {gains.nv} positive values")
            self._plausible_max = MEASURED_TORQUE_FACTOR * limit
        self.rejected = 0
        self.gains = gains
        self.dt = float(dt)
        self.enabled = bool(enabled)
        nv = gains.nv
        self._desired = DelayLine(delay_cycles, nv)
        self._integral = np.zeros(nv)
        self._integral_bound = self._bound(gains)
        self._previous_measured = np.zeros(nv)
        self._t_previous: float | None = None

    @classmethod
    def from_config(cls, config: PidConfig, dt: float, torque_limit: np.ndarray) -> TorquePid:
        """Eq 33 as ``config`` states it (gains, δo, on/off) on a robot with these joint torque
        limits (N·m; they scale the anti-windup bound and the plausibility check); ``dt``: the
        cycle, s."""
        return cls(
            TorquePidGains.from_config(config, torque_limit),
            dt,
            delay_cycles=config.delay_cycles,
            enabled=config.enabled,
            torque_limit=torque_limit,
        )

    @staticmethod
    def _bound(gains: TorquePidGains) -> np.ndarray:
        """Anti-windup bound on the integral state ∫e ds (N·m·s); inf where K_I = 0."""
        with np.errstate(divide="ignore"):
            return np.where(
                gains.ki > 0.0,
                gains.integral_limit / np.where(gains.ki > 0.0, gains.ki, 1.0),
                np.inf,
            )

    def set_gains(
        self,
        kp: npt.ArrayLike | None = None,
        ki: npt.ArrayLike | None = None,
        kd: npt.ArrayLike | None = None,
    ) -> None:
        """Change K_P, K_I and/or K_D (scalar or per joint; None keeps one) from the next
        :meth:`step` on, as eq 33 reads: the state (∫e, the previous τ̂, the δo line) is kept, so
        a new K_I scales the integral term K_I·∫e at once; ∫e is clamped to the new anti-windup
        bound ``integral_limit / K_I``. ConfigError (nothing changed) for a value that is not
        finite and >= 0."""
        g = self.gains
        gains = TorquePidGains(
            kp=g.kp if kp is None else _per_joint(kp, g.nv, "kp"),
            ki=g.ki if ki is None else _per_joint(ki, g.nv, "ki"),
            kd=g.kd if kd is None else _per_joint(kd, g.nv, "kd"),
            integral_limit=g.integral_limit,
        )
        self.gains = gains
        self._integral_bound = self._bound(gains)
        np.clip(self._integral, -self._integral_bound, self._integral_bound, out=self._integral)

    @property
    def delay_cycles(self) -> int:
        """δo of eq 33 in control cycles: how late the desired torque reaches the PID."""
        return self._desired.delay

    @property
    def integral(self) -> np.ndarray:
        """The integral state ∫(τ̂ − τ^d(· − δo)) ds, N·m·s (a copy)."""
        return self._integral.copy()

    def reset(self) -> None:
        """Zero the integral, forget the derivative and the δo history."""
        self._desired.reset()
        self._integral[:] = 0.0
        self._t_previous = None

    def _check(self, value: npt.ArrayLike, name: str) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (self.gains.nv,) or not np.all(np.isfinite(arr)):
            raise InputError(f"{name} must be {self.gains.nv} finite numbers, got {value!r}")
        return arr

    def step(
        self,
        measured_torque: np.ndarray,
        desired_torque: np.ndarray,
        t: float,
        undelayed: np.ndarray | None = None,
        weight: float = 1.0,
    ) -> np.ndarray:
        """Motor torque τ^m(t), N·m, from τ̂(t) (N·m), this cycle's τ^d (N·m) and t (s).

        With ``undelayed`` (N·m) the reference of eq 33 is ``weight·τ^d(t − δo) + (1 − weight)·
        undelayed``: the low level's safe hold (weight 0) and its blend to the MPC torque reach
        the motors without the δo delay line, while τ^d keeps filling it and the integral runs
        on, so the PID takes over without a jump.
        """
        measured = self._check(measured_torque, "measured_torque")
        desired = self._check(desired_torque, "desired_torque")
        if not math.isfinite(t) or (self._t_previous is not None and t <= self._t_previous):
            raise InputError(f"t must be finite and increasing, got {t} after {self._t_previous}")
        delayed = self._desired.step(desired)
        if undelayed is not None:
            if not 0.0 <= weight <= 1.0:
                raise InputError(f"weight must lie in [0, 1], got {weight}")
            delayed = weight * delayed + (1.0 - weight) * self._check(undelayed, "undelayed")
        first = self._t_previous is None
        h = self.dt if self._t_previous is None else t - self._t_previous
        self._t_previous = float(t)
        g = self.gains
        if np.any(np.abs(measured) > self._plausible_max):
            # Implausible sample: no P/D feedback this cycle, the integral is kept.
            self.rejected += 1
            return delayed if not self.enabled else delayed - g.ki * self._integral
        derivative = np.zeros_like(measured) if first else (measured - self._previous_measured) / h
        self._previous_measured[:] = measured
        if not self.enabled:
            return delayed
        error = measured - delayed
        self._integral = np.clip(
            self._integral + error * h, -self._integral_bound, self._integral_bound
        )
        return delayed - g.kp * error - g.ki * self._integral - g.kd * derivative
