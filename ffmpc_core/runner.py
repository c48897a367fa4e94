"""The one closed loop: a plant, the controllers and a scenario's measurement and log, on a clock.

Every simulated experiment of the project runs through :func:`run_scenario`: the polishing
study of the force-feedback paper (Fig. 2; :mod:`ffmpc_core.polishing_loop`), the MPC against its
own model (:func:`ffmpc_core.model_plant.run_model_closed_loop`), and the impact and
exploration experiments of the impact paper (``studies``). One cycle k of the clock does, in
this order:

1. ``state = plant.state()``: the true plant state at t_k (before any sensing model);
2. ``measurement = scenario.measure(k, t, state)``: what the controllers read (sensing models,
   delays, noise, injected faults);
3. the controllers in cascade: ``signal = controller.step(signal, t)``, the first one fed the
   measurement, each next one the output of the one before (as the ROS graph's nodes pass
   topics: MPC → torque loop);
4. ``joint_input = scenario.actuate(k, t, state, command)``: the scenario turns the last
   controller's command into the plant's joint input (an actuation model, eq 31, or the
   command's torque); None ends the run here, before the plant moves (an exploration that is
   done);
5. ``scenario.record(k, t, state, measurement, command, joint_input)`` logs the cycle;
6. ``plant.step(joint_input)``: the plant advances one step.

The loop reads no wall clock and draws no random number: a run is as deterministic as its
scenario's generators. Sensing and actuation belong to the scenario, not to the plant, because
the ROS graph runs them as nodes of their own (``joint_sensor``, ``ft_sensor``, ``pid``) around
the same plant.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from ffmpc_core.errors import ConfigError
from ffmpc_core.plant import Plant

__all__ = [
    "Controller",
    "LockstepClock",
    "LoopScenario",
    "PeriodicController",
    "run_cycle",
    "run_scenario",
]

StateT = TypeVar("StateT")
StateT_contra = TypeVar("StateT_contra", contravariant=True)
MeasT = TypeVar("MeasT")
CmdT_contra = TypeVar("CmdT_contra", contravariant=True)
InT_contra = TypeVar("InT_contra", contravariant=True)
OutT_co = TypeVar("OutT_co", covariant=True)


class Controller(Protocol[InT_contra, OutT_co]):
    """A controller object: ``reset()`` before a run, then one ``step`` per call of its loop."""

    def reset(self) -> None:
        """Forget every run-time state (warm starts, integrators, phases)."""
        ...

    def step(self, measurement: InT_contra, t: float, /) -> OutT_co:
        """The command for ``measurement`` at time ``t`` (s)."""
        ...


class LoopScenario(Protocol[StateT_contra, MeasT, CmdT_contra]):
    """What an experiment adds around the plant and its controllers (module docstring)."""

    def measure(self, k: int, t: float, state: StateT_contra, /) -> MeasT:
        """What the controllers read at cycle k (t s) from the true plant state."""
        ...

    def actuate(
        self, k: int, t: float, state: StateT_contra, command: CmdT_contra, /
    ) -> np.ndarray | None:
        """The plant's joint input for cycle k (N·m) from the last controller's command; None
        ends the run before the plant is stepped."""
        ...

    def record(
        self,
        k: int,
        t: float,
        state: StateT_contra,
        measurement: MeasT,
        command: CmdT_contra,
        joint_input: np.ndarray | None,
        /,
    ) -> None:
        """Log cycle k (``joint_input``: what :meth:`actuate` returned)."""
        ...


@dataclass(frozen=True)
class LockstepClock:
    """Simulated time: ``steps`` cycles of ``time_step`` s, cycle k at t = k·time_step."""

    time_step: float
    steps: int

    def __post_init__(self) -> None:
        if not (np.isfinite(self.time_step) and self.time_step > 0):
            raise ConfigError(f"the clock's time step must be positive, got {self.time_step} s")
        if self.steps < 0:
            raise ConfigError(f"the clock's number of steps must be >= 0, got {self.steps}")

    @classmethod
    def for_duration(cls, time_step: float, duration: float) -> LockstepClock:
        """The clock of ``duration`` s of simulated time (rounded to whole steps)."""
        return cls(time_step, int(round(duration / time_step)))

    def __iter__(self) -> Iterator[tuple[int, float]]:
        dt = self.time_step
        for k in range(self.steps):
            yield k, k * dt


class PeriodicController(Generic[InT_contra, OutT_co]):
    """A controller run every ``every``-th cycle of its loop, its command held in between
    (zero-order hold): the first call, cycle 0, always runs it."""

    def __init__(self, controller: Controller[InT_contra, OutT_co], every: int) -> None:
        if every < 1:
            raise ConfigError(f"a periodic controller runs every >= 1 cycles, got {every}")
        self.controller = controller
        self.every = every
        self._k = 0
        self._held: OutT_co | None = None

    def reset(self) -> None:
        """Reset the wrapped controller and the hold."""
        self.controller.reset()
        self._k = 0
        self._held = None

    def step(self, measurement: InT_contra, t: float, /) -> OutT_co:
        """Step the wrapped controller every ``every`` cycles; hold its output in between."""
        if self._k % self.every == 0 or self._held is None:
            self._held = self.controller.step(measurement, t)
        self._k += 1
        return self._held


def run_scenario(
    scenario: LoopScenario[StateT, Any, Any],
    plant: Plant[StateT],
    controllers: Sequence[Controller[Any, Any]],
    clock: LockstepClock,
) -> int:
    """Run the closed loop of the module docstring on ``clock``; the plant must be reset and the
    controllers ready. Returns the number of cycles whose input reached the plant (``clock.steps``
    unless the scenario stopped the run)."""
    if not controllers:
        raise ConfigError("a closed loop needs at least one controller")
    for k, t in clock:
        if run_cycle(scenario, plant, controllers, k, t) is None:
            return k
    return clock.steps


def run_cycle(
    scenario: LoopScenario[StateT, Any, Any],
    plant: Plant[StateT],
    controllers: Sequence[Controller[Any, Any]],
    k: int,
    t: float,
) -> np.ndarray | None:
    """Cycle k at t (s) of the closed loop (steps 1-6 of the module docstring): the plant's
    state, the scenario's measurement, the controllers in cascade, the actuation, the record and
    the plant's step. Returns the joint input (N·m) the plant was stepped with; None when the
    scenario ended the run (the plant was not stepped). :func:`run_scenario` runs it on the
    lockstep clock; the real-time loop (``ffmpc_ros.realtime``) on the wall clock."""
    state = plant.state()
    measurement = scenario.measure(k, t, state)
    command = measurement
    for controller in controllers:
        command = controller.step(command, t)
    joint_input = scenario.actuate(k, t, state, command)
    scenario.record(k, t, state, measurement, command, joint_input)
    if joint_input is not None:
        plant.step(joint_input)
    return joint_input
