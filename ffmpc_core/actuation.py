"""Actuation model of the simulation study (paper VI-B2, eq 31, Fig. 2).

    τ̂(t) = a·τ^m(t − δs) + b − μs·tanh(q̇(t)/v_s) − μv·q̇(t) + ν_τ

τ^m is the motor torque commanded by the low-level controller (the torque PID, or the MPC's
τ^d delayed by δo without PID). Reading of Fig. 2: the actuation block "simulates the combined
effects of motor inertia, transmission, torque sensing"; its output τ̂ is BOTH the joint torque
applied to the rigid-body simulator AND the measured joint torque fed back to the torque PID and
to the torque-feedback MPC. The noise ν_τ is therefore a real torque disturbance, not only a
sensor error.

Friction. The paper writes ``sign(q̂)`` and ``μv·q̂`` — a typo for the joint velocity: static
(Coulomb) friction opposes the motion. The sign is smoothed by tanh(q̇/v_s) as the paper does;
use the TRUE joint velocity of the simulator (friction acts on the real motion).

Choice of v_s = 1 rad/s. The friction torque is integrated explicitly by the simulator, so its
slope at rest, μs/v_s + μv, acts as a damping that is stable only if
(μs/v_s + μv)·dt / I < 2 for the lightest joint inertia I. The iiwa's wrist (joint 7) has
I ≈ 1e-3 kg·m²: at 1 kHz this needs v_s > 0.67 rad/s; with v_s = 0.1 rad/s the velocity of
joint 7 flips sign every step with an amplitude of ~0.7 rad/s (measured, tests/test_plant.py).
1 rad/s is the smallest round value stable at 1 kHz for both robots (the Panda alone would
accept 0.1 rad/s). The price: below ~1 rad/s the "static" friction grows gradually
(tanh(0.3) = 0.29 of μs at 0.3 rad/s) instead of jumping to μs.

Noise σ_τ. The paper says "a small percentage of the joint torque limits"; the authors' code
(force_feedback_mpc, demos/polishing) uses 0.01–0.03 N·m. ``ActuationConfig.noise_fraction``
(``plant.actuation_noise_fraction``) is 1e-4 of the limits by default (0.004–0.032 N·m on the
iiwa), the authors' order of magnitude (README "Simulation settings": on seeds 100–104 it and
1 % of the limits gave the same task errors within 0.1 N).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
import numpy.typing as npt

from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.sensing import DelayLine

#: Span of the per-run draw of the gain a of eq 31's affine bias (paper VI-C: uniform per joint).
GAIN_RANGE = (0.8, 1.2)
#: Span of the per-run draw of the offset b of eq 31's affine bias, N·m (paper VI-C: uniform per
#: joint).
OFFSET_RANGE = (-2.0, 2.0)


def joint_friction(
    joint_velocity: np.ndarray,
    static_friction: np.ndarray,
    viscous_friction: np.ndarray,
    friction_velocity: np.ndarray,
) -> np.ndarray:
    """Friction torque in eq 31: μs·tanh(q̇/v_s) + μv·q̇, N·m (subtracted from the torque).

    Args: q̇ in rad/s, μs in N·m, μv in N·m·s/rad, v_s in rad/s (all per joint).
    """
    return static_friction * np.tanh(joint_velocity / friction_velocity) + (
        viscous_friction * joint_velocity
    )


def actuation_torque(
    motor_torque_delayed: np.ndarray,
    joint_velocity: np.ndarray,
    gain: np.ndarray,
    offset: np.ndarray,
    static_friction: np.ndarray,
    viscous_friction: np.ndarray,
    friction_velocity: np.ndarray,
    noise: np.ndarray,
) -> np.ndarray:
    """Eq 31: τ̂ = a·τ^m(t − δs) + b − μs·tanh(q̇/v_s) − μv·q̇ + ν_τ, N·m per joint.

    Args:
        motor_torque_delayed: τ^m(t − δs), N·m.  joint_velocity: q̇(t), rad/s.
        gain: a (dimensionless).  offset: b, N·m.  noise: ν_τ, N·m (already drawn).
        static_friction, viscous_friction, friction_velocity: see :func:`joint_friction`.
    """
    friction = joint_friction(joint_velocity, static_friction, viscous_friction, friction_velocity)
    return gain * motor_torque_delayed + offset - friction + noise


def _broadcast(value: npt.ArrayLike, nv: int, name: str) -> np.ndarray:
    try:
        arr = np.broadcast_to(np.asarray(value, dtype=float), (nv,)).copy()
    except ValueError:
        raise ConfigError(f"{name} must be a scalar or have {nv} entries, got {value!r}") from None
    if not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be finite, got {arr}")
    return arr


def _per_joint(value: npt.ArrayLike, nv: int, name: str, positive: bool = False) -> np.ndarray:
    arr = _broadcast(value, nv, name)
    if np.any(arr <= 0.0) if positive else np.any(arr < 0.0):
        raise ConfigError(f"{name} must be {'> 0' if positive else '>= 0'}, got {arr}")
    return arr


@dataclass(frozen=True)
class ActuationConfig:
    """Eq 31 as a scenario states it, the same for every joint (the ``plant`` section's
    ``actuation`` part: ``plant.actuation_random_bias``, ``plant.actuation_delay_cycles``,
    ``plant.actuation_noise_fraction``, ``plant.static_friction``, ``plant.viscous_friction``,
    ``plant.friction_velocity``). A run's :class:`ActuationParams` are made from it by
    :meth:`ActuationParams.from_config` with the bias drawn by :meth:`draw_bias` and σ_τ
    scaled by the robot's torque limits."""

    random_bias: bool = param(True, "", None, "draw the actuation bias (a, b) per seed (eq 31)")
    delay_cycles: int = param(1, "cycles", (0, 1000), "actuation delay δs (eq 31)")
    # the authors' σ_τ (README "Simulation settings")
    noise_fraction: float = param(1e-4, "", (0.0, 0.99), "σ_τ / torque limit (eq 31)")
    static_friction: float = param(1.0, "N·m", (0.0, 100.0), "μs (eq 31)")
    viscous_friction: float = param(0.5, "N·m·s/rad", (0.0, 100.0), "μv (eq 31)")
    friction_velocity: float = param(1.0, "rad/s", (1e-6, 100.0), "v_s of the tanh friction")

    def __post_init__(self) -> None:
        if isinstance(self.delay_cycles, bool) or int(self.delay_cycles) != self.delay_cycles:
            raise ConfigError(f"delay_cycles must be an integer, got {self.delay_cycles!r}")
        if self.delay_cycles < 0:
            raise ConfigError("delay_cycles must be >= 0")
        if not 0.0 <= self.noise_fraction < 1.0:
            raise ConfigError(f"noise_fraction must lie in [0, 1), got {self.noise_fraction}")

    def draw_bias(self, rng: np.random.Generator, nv: int) -> tuple[np.ndarray, np.ndarray]:
        """The bias (a, b N·m) of one run, per joint: with ``random_bias``, drawn from ``rng``
        uniformly in :data:`GAIN_RANGE` × :data:`OFFSET_RANGE` (all gains, then all offsets);
        without, (1, 0) and nothing drawn."""
        if not self.random_bias:
            return np.ones(nv), np.zeros(nv)
        return draw_bias(rng, nv, GAIN_RANGE, OFFSET_RANGE)


def draw_bias(
    rng: np.random.Generator,
    nv: int,
    gain_range: tuple[float, float],
    offset_range: tuple[float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) per joint drawn uniformly from ``gain_range × offset_range`` (b in N·m): all
    gains, then all offsets."""
    if not isinstance(rng, np.random.Generator):
        raise ConfigError("rng must be a numpy.random.Generator")
    (a_lo, a_hi), (b_lo, b_hi) = gain_range, offset_range
    if not (0.0 < a_lo <= a_hi and b_lo <= b_hi):
        raise ConfigError(f"bad ranges {gain_range}, {offset_range}")
    return rng.uniform(a_lo, a_hi, nv), rng.uniform(b_lo, b_hi, nv)


@dataclass(frozen=True, eq=False)
class ActuationParams:
    """Parameters of eq 31, one entry per joint (scalars broadcast).

    Attributes:
        gain: a of the affine bias (paper: uniform in [0.8, 1.2]).
        offset: b of the affine bias, N·m (paper: uniform in [−2, 2]).
        torque_noise_std: σ_τ, N·m (standard deviation; see the module docstring).
        delay_cycles: δs in cycles of :meth:`ActuationModel.step` (paper: 1 simulation cycle).
        static_friction: μs, N·m (paper: 1).
        viscous_friction: μv, N·m·s/rad (paper: 0.5).
        friction_velocity: v_s of the tanh smoothing, rad/s (see the module docstring).
    """

    gain: np.ndarray
    offset: np.ndarray
    torque_noise_std: np.ndarray
    delay_cycles: int = 1
    static_friction: np.ndarray | float = 1.0
    viscous_friction: np.ndarray | float = 0.5
    friction_velocity: np.ndarray | float = 1.0
    nv: int = field(init=False)

    def __post_init__(self) -> None:
        nv = int(np.size(self.gain))
        if nv == 0 or np.ndim(self.gain) != 1:
            raise ConfigError("gain must be a non-empty 1-D array (one entry per joint)")
        if isinstance(self.delay_cycles, bool) or int(self.delay_cycles) != self.delay_cycles:
            raise ConfigError(f"delay_cycles must be an integer, got {self.delay_cycles!r}")
        if self.delay_cycles < 0:
            raise ConfigError("delay_cycles must be >= 0")
        object.__setattr__(self, "nv", nv)
        gain = _per_joint(self.gain, nv, "gain", positive=True)
        offset = _broadcast(self.offset, nv, "offset")
        for name, value in (
            ("gain", gain),
            ("offset", offset),
            ("torque_noise_std", _per_joint(self.torque_noise_std, nv, "torque_noise_std")),
            ("static_friction", _per_joint(self.static_friction, nv, "static_friction")),
            ("viscous_friction", _per_joint(self.viscous_friction, nv, "viscous_friction")),
            (
                "friction_velocity",
                _per_joint(self.friction_velocity, nv, "friction_velocity", positive=True),
            ),
        ):
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @classmethod
    def from_config(
        cls,
        config: ActuationConfig,
        torque_limit: np.ndarray,
        gain: np.ndarray,
        offset: np.ndarray,
    ) -> ActuationParams:
        """The per-joint parameters of ``config`` for one run: the bias (a, b N·m) drawn for
        it (:meth:`ActuationConfig.draw_bias`) and σ_τ = ``noise_fraction`` × the robot's
        ``torque_limit`` (N·m)."""
        limit = _per_joint(torque_limit, np.size(torque_limit), "torque_limit", positive=True)
        return cls(
            gain=gain,
            offset=offset,
            torque_noise_std=config.noise_fraction * limit,
            delay_cycles=config.delay_cycles,
            static_friction=config.static_friction,
            viscous_friction=config.viscous_friction,
            friction_velocity=config.friction_velocity,
        )

    @classmethod
    def ideal(cls, nv: int, delay_cycles: int = 0) -> ActuationParams:
        """A perfect actuator: a = 1, b = 0, no friction, no noise."""
        return cls(
            gain=np.ones(nv),
            offset=np.zeros(nv),
            torque_noise_std=np.zeros(nv),
            delay_cycles=delay_cycles,
            static_friction=0.0,
            viscous_friction=0.0,
        )


class ActuationModel:
    """Eq 31 with its delay line; ``step(τ^m, q̇) -> τ̂`` once per cycle.

    Until δs motor torques have been seen, the delayed motor torque is the first one (the motor
    was already producing it), so a robot started at rest with its gravity torque does not drop.
    """

    def __init__(self, params: ActuationParams, rng: np.random.Generator) -> None:
        if not isinstance(rng, np.random.Generator):
            raise ConfigError("rng must be a numpy.random.Generator")
        self.params = params
        self.rng = rng
        self._motor = DelayLine(params.delay_cycles, params.nv)

    @property
    def nv(self) -> int:
        """Number of actuated joints."""
        return self.params.nv

    def reset(self) -> None:
        """Forget the motor torque history."""
        self._motor.reset()

    def step(self, motor_torque: np.ndarray, joint_velocity: np.ndarray) -> np.ndarray:
        """τ̂(t) in N·m from τ^m(t) (N·m, this cycle's command) and the true q̇(t) (rad/s)."""
        v = np.asarray(joint_velocity, dtype=float)
        if v.shape != (self.nv,) or not np.all(np.isfinite(v)):
            raise InputError(f"joint_velocity must be {self.nv} finite numbers, got {v!r}")
        p = self.params
        delayed = self._motor.step(motor_torque)
        noise = p.torque_noise_std * self.rng.standard_normal(self.nv)
        return actuation_torque(
            delayed,
            v,
            p.gain,
            p.offset,
            # __post_init__ stored each of the three as a read-only per-joint array
            cast(np.ndarray, p.static_friction),
            cast(np.ndarray, p.viscous_friction),
            cast(np.ndarray, p.friction_velocity),
            noise,
        )
