"""The robot's own reflexes: what its controller does when a measured value crosses a data-sheet
limit or when commands stop coming — stop the robot and abort the motion (pure: no simulator,
no ROS).

One model, :class:`RobotReflex`, and one wrapper, :class:`ReflexPlant`, that gives any
:class:`~ffmpc_core.plant.Plant` (PyBullet, MuJoCo, an OCP's own dynamics: any plant whose state
has ``q`` and ``v``) the reflexes. The ROS-free runner (:func:`ffmpc_core.runner.run_scenario`:
the polishing, impact and exploration experiments), the plant nodes (``ffmpc_ros.plant_node``,
``ffmpc_ros.dice_plant_node``) and the real-time loop (``ffmpc_ros.realtime``) all step their
plant through it.

What the robot's controller measures (each plant step of Δt, as its own 1 kHz loop would): the
joint positions q (rad) and velocities q̇ (rad/s) at the end of the step, the torque it was asked
to apply over the step τ_d (N·m, before its drives saturate it), and finite differences over the
step: q̈ = (q̇_k+1 − q̇_k)/Δt (rad/s²) and τ̇_d = (τ_d,k − τ_d,k−1)/Δt (N·m/s).

When a value "crosses" (the rules; :mod:`ffmpc_core.datasheet` says which kinds each robot stops
on in torque control, :attr:`DataSheet.stops`, and why):

==============  =========================================  ===================================
kind            crosses when                               iiwa 14 R820 / Panda
==============  =========================================  ===================================
position        q outside [q̲, q̄] (ratio |q − mid|/half)    stop / stop
velocity        |q̇| > 100 % of q̇_max                       stop / stop
acceleration    |q̈| > q̈_max                                no limit / reported
torque          |τ_d| > τ_max                              saturated by the drives (both)
torque_rate     |τ̇_d| > τ̇_max (from the second command)    no limit / reported
communication   no command for longer than the timeout     stop / stop (20 ms)
==============  =========================================  ===================================

"Reported": the largest ratio over the run and the first crossing (``crossings`` of
:meth:`RobotReflex.report`), no stop. q̈ from finite differences jumps at every contact onset
(a PyBullet contact changes q̇ within one step: hundreds of rad/s² at an impact), and Franka
checks q̈ only on the commanded trajectory of its motion generators, not on the measured state
in torque control. τ̇: why the Panda's necessary condition of the torque interface is reported
and not a stop is in :mod:`ffmpc_core.datasheet` (libfranka ≤ 0.9, the Panda's, rate-limits
the command to it by default, so a real Panda never stops on it; the simulation has no libfranka
between the controllers and the robot). Torques are saturated by the drives (the plant clips
them to τ_max), as the real drives' current limits do. No tolerance is added to any limit: the
data sheet's value is the threshold. A :class:`DataSheet` may list any of these kinds in
``stops`` (the tests drive every kind through a stop).

The stop (the drives' own, not our controllers'): from the step after the crossing on, every
command is ignored and each drive applies gravity compensation g_i(q) plus, with
m_i = 1/(M⁻¹(q))_ii the inertia joint i moves when the others are free (M the joint-space mass
matrix of the robot model, which the robot's controller knows):

* **brake** while any |q̇_i| > ``rest_speed``: −b·m_i·q̇_i (b = ``brake_rate``), saturated per
  joint to what τ_max,i leaves after gravity. Each term has the sign of −q̇_i, so with
  T = ½q̇ᵀMq̇, Ṫ = q̇ᵀ(τ − g) = −Σ q̇_i·sat(b·m_i·q̇_i) ≤ 0 whatever saturates: the kinetic energy
  only decreases (an external push stronger than the drives is not resisted). At the 1 ms step
  the unsaturated brake neither diverges nor overshoots in any posture: the eigenvalues of
  Δt·b·M⁻¹·diag(m) are positive and sum to Δt·b·n (trace: (M⁻¹)_ii·m_i = 1), 0.98 < 1 for
  b = 140 s⁻¹ and 7 joints. (Measured alternatives: the diagonal of M instead of m diverged
  within 30 ms on the Panda's impact start pose, where joints 1 and 3 are nearly aligned and
  M_11 is far above m_1; a brake −b·M·q̇ scaled as a whole to the limits stopped braking every
  joint when one saturated; under a 100 N push on the tool for 50 ms the iiwa's wrist reached
  10.5× its velocity limit with b = 30 s⁻¹, 4.6× with 100 s⁻¹, 3.4× with 140 s⁻¹ — the
  controllers, reflex off: 3.3×.)
* **hold** once at rest: the posture q_h is latched and each drive holds its joint,
  m_i(q_h)·(−ω²(q_i − q_h,i) − 2ω·q̇_i), ω = 2π·``hold_frequency`` (a critically damped
  position loop per axis, saturated the same way).

The run is marked aborted: :class:`ReflexEvent` says which limit, which joint, the value, the
limit, their ratio and when. With ``enabled=False`` nothing is stopped, but the
first crossing of a kind the robot would have stopped on is still recorded (``stopped``
False): a study that switches the reflex off sees the raw excess and what would have aborted.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

import numpy as np
import pinocchio as pin

from ffmpc_core.datasheet import DataSheet
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.plant import Plant
from ffmpc_core.robots import RobotModel, mass_matrix

__all__ = [
    "REFLEX_KINDS",
    "ReflexConfig",
    "ReflexEvent",
    "ReflexPlant",
    "RobotReflex",
    "reflex_plant",
]

#: Everything a reflex watches, in the order a crossing is looked for within one sample.
REFLEX_KINDS = ("position", "velocity", "acceleration", "torque", "torque_rate", "communication")
#: Tolerance on the communication timeout, s (steps are floats).
_TIME_EPS = 1e-9
#: Largest Δt·gain·n of the stop's per-axis loops (gain: the brake rate b, or 2ω of the hold's
#: damping): below 1, no mode of the unsaturated loop overshoots (module docstring).
_NO_OVERSHOOT = 0.98


@dataclass(frozen=True)
class ReflexConfig:
    """The reflex of one run.

    Attributes:
        enabled: stop the robot on a crossing (off: record only; the module docstring).
        command_timeout: s without a command before the communication reflex stops the robot
            (None: the data sheet's, :attr:`DataSheet.command_timeout`).
        brake_rate: b of the drives' brake, 1/s (140: a 7 ms time constant per axis while not
            saturated; Δt·b·n = 0.98 < 1 at 1 kHz and 7 joints, so no mode of the unsaturated
            brake can overshoot whatever the coupling; module docstring). A plant with a
            longer step gets b = 0.98/(Δt·n) (:attr:`RobotReflex.brake_rate`).
        hold_frequency: ω/2π of the drives' position hold once at rest, Hz (capped the same
            way: 2ω·Δt·n ≤ 0.98).
        rest_speed: largest |q̇_i| counted as rest, rad/s.
    """

    enabled: bool = True
    command_timeout: float | None = None
    brake_rate: float = 140.0
    hold_frequency: float = 5.0
    rest_speed: float = 0.01

    def __post_init__(self) -> None:
        if self.command_timeout is not None and not (
            math.isfinite(self.command_timeout) and self.command_timeout > 0.0
        ):
            raise ConfigError(f"command_timeout must be > 0 s, got {self.command_timeout}")
        for name in ("brake_rate", "hold_frequency", "rest_speed"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"reflex {name} must be > 0, got {value}")


@dataclass(frozen=True)
class ReflexEvent:
    """A crossing the robot stops on (the first of a run).

    Attributes:
        kind: one of :data:`REFLEX_KINDS`.
        joint: 0-based joint index (None: communication).
        joint_name: the joint's name (None: communication).
        value: the measured value (rad, rad/s, rad/s², N·m, N·m/s; s without a command).
        limit: the limit it crossed, same unit (position: the bound crossed).
        ratio: |value|/limit (position: |q − mid-range|/half range, 1 at a limit).
        t: simulated time of the sample that crossed, s.
        stopped: the robot stopped (False: the reflex was off; the crossing is only recorded).
    """

    kind: str
    joint: int | None
    joint_name: str | None
    value: float
    limit: float
    ratio: float
    t: float
    stopped: bool

    def describe(self) -> str:
        """One line: which reflex, which joint, value, limit, ratio, when and what followed."""
        units = {
            "position": "rad",
            "velocity": "rad/s",
            "acceleration": "rad/s²",
            "torque": "N·m",
            "torque_rate": "N·m/s",
        }
        if self.kind == "communication":
            what = f"no command for {self.value * 1e3:.0f} ms > {self.limit * 1e3:.0f} ms"
        else:
            unit = units[self.kind]
            what = (
                f"joint {self.joint_name} (#{(self.joint or 0) + 1}) {self.kind} "
                f"{self.value:.4g} {unit}, limit {self.limit:.4g} {unit} ({self.ratio:.3f}x)"
            )
        then = (
            "the robot braked to rest and held; the run is aborted"
            if self.stopped
            else "reflex off: the robot went on (it would have stopped here)"
        )
        return f"{self.kind} reflex at t = {self.t:.3f} s: {what}; {then}"

    def to_dict(self) -> dict[str, Any]:
        """The event as plain data (JSON summaries, tables)."""
        return {
            "kind": self.kind,
            "joint": self.joint,
            "joint_name": self.joint_name,
            "value": self.value,
            "limit": self.limit,
            "ratio": self.ratio,
            "t": self.t,
            "stopped": self.stopped,
            "message": self.describe(),
        }


class RobotReflex:
    """The reflex model of one robot (module docstring): :meth:`command` before each plant step
    (a command arrived or not), :meth:`observe` after it (the new state and the torque the
    drives were asked for), :meth:`stop_torque` while :attr:`stopped`.

    Args:
        robot: the robot model (its pinocchio model gives g(q) and M(q) for the stop).
        time_step: Δt of one plant step, s.
        config: the run's reflex settings.
        sheet: the limits (default: the robot's data sheet, :attr:`RobotModel.datasheet`).
    """

    def __init__(
        self,
        robot: RobotModel,
        time_step: float,
        config: ReflexConfig | None = None,
        sheet: DataSheet | None = None,
    ) -> None:
        if not (math.isfinite(time_step) and time_step > 0.0):
            raise ConfigError(f"the reflex's time step must be > 0 s, got {time_step}")
        self.robot = robot
        self.config = config if config is not None else ReflexConfig()
        self.sheet = sheet if sheet is not None else robot.datasheet
        self.dt = float(time_step)
        self.command_timeout = (
            self.sheet.command_timeout
            if self.config.command_timeout is None
            else self.config.command_timeout
        )
        self._data = robot.create_data()
        self._mid = 0.5 * (self.sheet.position_upper + self.sheet.position_lower)
        self._half = 0.5 * (self.sheet.position_upper - self.sheet.position_lower)
        # The stop's gains within the bound that keeps its unsaturated per-axis loops from
        # overshooting at this step, Δt·gain·n < 1 (module docstring): the configured ones at
        # 1 kHz, lower for a slower plant.
        bound = _NO_OVERSHOOT / (robot.nv * self.dt)
        self.brake_rate = min(self.config.brake_rate, bound)
        self._omega = min(2.0 * math.pi * self.config.hold_frequency, 0.5 * bound)
        self.reset(robot.q_nominal, np.zeros(robot.nv))

    # -- state ---------------------------------------------------------------------------------
    def reset(self, q: np.ndarray, v: np.ndarray) -> None:
        """A new run from (q rad, q̇ rad/s) at t = 0: nothing crossed, commands on time."""
        self.event: ReflexEvent | None = None
        self._v = np.array(v, dtype=float)
        self._demanded: np.ndarray | None = None
        self._gap = 0.0
        self._hold_q: np.ndarray | None = None
        self._hold_m = np.zeros(self.robot.nv)
        self.stop_cycles = 0
        nv = self.robot.nv
        self.max_ratio: dict[str, np.ndarray] = {
            kind: np.zeros(nv)
            for kind in REFLEX_KINDS[:-1]
            if kind == "position" or self.sheet.limit(kind) is not None
        }
        self.max_gap = 0.0  # longest time without a command, s
        #: the first crossing of each kind (stop or not): {kind: {"t", "joint", "ratio"}}
        self.crossings: dict[str, dict[str, Any]] = {}
        self._update("position", np.abs(np.asarray(q, dtype=float) - self._mid) / self._half)

    @property
    def stopped(self) -> bool:
        """The robot has stopped itself: commands are ignored for the rest of the run."""
        return self.event is not None and self.event.stopped

    # -- monitoring ----------------------------------------------------------------------------
    def command(self, fresh: bool, t: float) -> bool:
        """Before the step starting at t (s): did a command arrive for it? Returns whether the
        drives stop the robot over this step (a stop already on, or commands missing longer
        than :attr:`command_timeout`: the communication reflex, from this step on)."""
        if fresh:
            self._gap = 0.0
        else:
            self._gap += self.dt
            self.max_gap = max(self.max_gap, self._gap)
            if self._gap > self.command_timeout + _TIME_EPS:
                ratio = self._gap / self.command_timeout
                self.crossings.setdefault(
                    "communication", {"t": float(t), "joint": None, "ratio": float(ratio)}
                )
                if self.event is None:
                    self._trip("communication", None, self._gap, self.command_timeout, ratio, t)
        return self.stopped

    def observe(self, t: float, q: np.ndarray, v: np.ndarray, demanded: np.ndarray | None) -> None:
        """After a step: the state at t (s; q rad, q̇ rad/s) and the torque the drives were
        asked for over the step (N·m; None when the stop was on: no controller's command)."""
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
            raise InputError("the reflex observed a non-finite joint state")
        ratios: dict[str, np.ndarray] = {
            "position": np.abs(q - self._mid) / self._half,
            "velocity": np.abs(v) / self.sheet.velocity,
        }
        if self.sheet.acceleration is not None:
            ratios["acceleration"] = np.abs(v - self._v) / self.dt / self.sheet.acceleration
        if demanded is not None:
            tau = np.nan_to_num(np.asarray(demanded, dtype=float), nan=np.inf)
            ratios["torque"] = np.abs(tau) / self.sheet.torque
            if self.sheet.torque_rate is not None and self._demanded is not None:
                rate = np.abs(tau - self._demanded) / self.dt
                ratios["torque_rate"] = rate / self.sheet.torque_rate
            self._demanded = tau
        self._v = v
        for kind, ratio in ratios.items():
            self._update(kind, ratio)
            j = int(np.argmax(ratio))
            if ratio[j] > 1.0 and kind not in self.crossings:
                self.crossings[kind] = {"t": float(t), "joint": j, "ratio": float(ratio[j])}
        if self.event is None:
            self._check(t, q, v, ratios)

    def _update(self, kind: str, ratio: np.ndarray) -> None:
        self.max_ratio[kind] = np.maximum(self.max_ratio[kind], ratio)

    def _check(self, t: float, q: np.ndarray, v: np.ndarray, ratios: dict[str, np.ndarray]) -> None:
        """The first kind (in :data:`REFLEX_KINDS` order) the robot stops on whose ratio is
        above 1; its worst joint."""
        for kind in REFLEX_KINDS[:-1]:
            if kind not in self.sheet.stops or kind not in ratios:
                continue
            ratio = ratios[kind]
            j = int(np.argmax(ratio))
            if not ratio[j] > 1.0:
                continue
            if kind == "position":
                value = float(q[j])
                limit = float(
                    self.sheet.position_upper[j]
                    if q[j] > self._mid[j]
                    else self.sheet.position_lower[j]
                )
            else:
                limit = float(self.sheet.limit(kind)[j])  # type: ignore[index]
                value = float(ratio[j] * limit)
                if kind == "velocity":
                    value = float(v[j])
            self._trip(kind, j, value, limit, float(ratio[j]), t)
            return

    def _trip(
        self, kind: str, joint: int | None, value: float, limit: float, ratio: float, t: float
    ) -> None:
        name = None if joint is None else self.robot.joint_names[joint]
        self.event = ReflexEvent(
            kind, joint, name, value, limit, ratio, float(t), stopped=self.config.enabled
        )

    # -- the stop ------------------------------------------------------------------------------
    def stop_torque(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The drives' own torque over the next step, N·m, from the true q (rad) and q̇ (rad/s):
        brake, then hold (module docstring); within the torque limits."""
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        model, data = self.robot.model, self._data
        gravity = pin.computeGeneralizedGravity(model, data, q).copy()
        self.stop_cycles += 1
        if self._hold_q is None and np.max(np.abs(v)) <= self.config.rest_speed:
            self._hold_q, self._hold_m = q.copy(), self._axis_inertia(q)
        if self._hold_q is not None:
            w = self._omega
            drive = self._hold_m * (-w * w * (q - self._hold_q) - 2.0 * w * v)
        else:
            drive = -self.brake_rate * self._axis_inertia(q) * v
        limit = self.sheet.torque
        room = np.maximum(limit - np.abs(gravity), 0.0)
        return np.clip(gravity + np.clip(drive, -room, room), -limit, limit)

    def _axis_inertia(self, q: np.ndarray) -> np.ndarray:
        """Each joint's effective inertia with the others free, 1/(M⁻¹(q))_ii (kg·m²)."""
        mass = mass_matrix(self.robot.model, self._data, q)
        return 1.0 / np.diag(np.linalg.inv(mass))

    @property
    def hold_posture(self) -> np.ndarray | None:
        """The posture the drives hold, rad (None before the robot came to rest)."""
        return None if self._hold_q is None else self._hold_q.copy()

    def report(self) -> dict[str, Any]:
        """JSON-friendly: ``enabled``, ``aborted`` (the robot stopped itself), ``event`` (the
        first crossing of a kind it stops on, or None), ``max_ratio`` per kind and joint (the
        raw excess; ``communication``: the longest gap / the timeout), ``crossings`` (the first
        crossing of every kind, stop or not: t s, 0-based joint, ratio), ``stops`` (the kinds
        the robot stops on), ``stop_time_s`` (time under the robot's stop),
        ``command_timeout_s``."""
        ratios: dict[str, Any] = {k: [float(x) for x in v] for k, v in self.max_ratio.items()}
        ratios["communication"] = self.max_gap / self.command_timeout
        return {
            "enabled": self.config.enabled,
            "aborted": self.stopped,
            "event": None if self.event is None else self.event.to_dict(),
            "max_ratio": ratios,
            "crossings": {k: dict(v) for k, v in self.crossings.items()},
            "stops": sorted(self.sheet.stops) + ["communication"],
            "stop_time_s": self.stop_cycles * self.dt,
            "command_timeout_s": self.command_timeout,
        }


class _JointState(Protocol):
    """What the reflex reads of a plant's state: q (rad) and q̇ (rad/s)."""

    @property
    def q(self) -> np.ndarray: ...
    @property
    def v(self) -> np.ndarray: ...


StateT = TypeVar("StateT", bound=_JointState)


class ReflexPlant(Generic[StateT]):
    """Any :class:`~ffmpc_core.plant.Plant` with the robot's reflexes (a Plant itself).

    :meth:`step` asks :attr:`reflex` whether the robot is stopped; if so the drives' stop torque
    replaces the command, otherwise the command goes to the plant; then the reflex observes the
    new state and the torque asked for. ``step(command, fresh=False)``: no new command came for
    this step and the drives apply ``command``, the one held (real-time loops; after
    :attr:`RobotReflex.command_timeout` of that, the communication reflex stops the robot).
    :meth:`state` is the state after the last step (read once per step).

    Args:
        plant: the plant (already reset: its present state starts the reflex).
        reflex: the reflex model (its time step must be the plant's).
    """

    def __init__(self, plant: Plant[StateT], reflex: RobotReflex) -> None:
        if abs(reflex.dt - plant.dt) > _TIME_EPS:
            raise ConfigError(
                f"the reflex's time step {reflex.dt} s is not the plant's {plant.dt} s"
            )
        self.plant = plant
        self.reflex = reflex
        self.dt = plant.dt
        self._k = 0
        self._state = plant.state()
        reflex.reset(self._state.q, self._state.v)

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Reset the plant to (q rad, q̇ rad/s; rest by default) and the reflex with it."""
        self.plant.reset(q, v)
        self._k = 0
        self._state = self.plant.state()
        self.reflex.reset(self._state.q, self._state.v)

    def step(self, command: np.ndarray, /, *, fresh: bool = True) -> None:
        """One step of ``dt`` s under ``command`` (N·m; ``fresh``: it arrived for this step),
        or under the drives' stop torque once the reflex has stopped the robot."""
        t = self._k * self.dt
        s = self._state
        if self.reflex.command(fresh, t):
            applied: np.ndarray = self.reflex.stop_torque(s.q, s.v)
            demanded = None
        else:
            applied = demanded = np.asarray(command, dtype=float)
        self.plant.step(applied)
        self._k += 1
        self._state = self.plant.state()
        self.reflex.observe(self._k * self.dt, self._state.q, self._state.v, demanded)

    def state(self) -> StateT:
        """The state after the last step (the truth)."""
        return self._state

    @property
    def stopped(self) -> bool:
        """The robot has stopped itself (:attr:`RobotReflex.stopped`)."""
        return self.reflex.stopped


def reflex_plant(
    plant: Plant[StateT],
    robot: RobotModel,
    enabled: bool = True,
    config: ReflexConfig | None = None,
) -> ReflexPlant[StateT]:
    """``plant`` (reset) with ``robot``'s reflexes (its data sheet), on (``enabled``) or
    recording only; ``config`` for the other settings (its ``enabled`` is replaced)."""
    from dataclasses import replace

    base = config if config is not None else ReflexConfig()
    return ReflexPlant(plant, RobotReflex(robot, plant.dt, replace(base, enabled=enabled)))


def _conforms(plant: ReflexPlant[Any]) -> Plant[Any]:
    """Static check (mypy): a ReflexPlant is a :class:`~ffmpc_core.plant.Plant`."""
    return plant
