"""The real-time loop's cycle: the core's closed loop on the wall clock (no ROS here).

A real-time run composes the same core objects as the ROS-free runner
(``studies.polishing.run_polishing``) and runs each cycle with the same function,
:func:`ffmpc_core.runner.run_cycle`:

* :class:`~ffmpc_core.polishing_loop.PolishingLoop` — sensing (eq 30, 32), actuation (eq 31),
  the external push and the run's log;
* an MPC stage in the place of :class:`~ffmpc_core.polishing_loop.MpcStage` (in a real-time
  run the MPC solves in its own process: ``ffmpc_ros.realtime.TopicMpc``);
* :class:`~ffmpc_core.polishing_loop.LowLevelStage` — hold / blend / track / fallback and the
  torque PID (eq 33), the PID node's class;
* the plant with the robot's reflexes (:class:`~ffmpc_core.reflex.ReflexPlant`).

What differs from lockstep is the clock (:class:`WallClock`: a cycle is released at a wall
time and may be reached too late) and the motor drives between the torque loop and the plant
(:class:`MotorDrives`: the zero-order hold of a torque that missed its deadline or of a
missed cycle). :class:`WallClockCycles` runs them: an on-time cycle runs the stages; a missed
cycle runs none (the plant steps under the held motor torque, the sensor devices sample, the
cycle is logged).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.lowlevel import LowLevelMode, LowLevelOutput
from ffmpc_core.polishing_loop import (
    LowLevelStage,
    MpcDecision,
    PolishingLoop,
    PolishingPlantState,
    PolishingReading,
)
from ffmpc_core.reflex import ReflexPlant
from ffmpc_core.runner import Controller, run_cycle

__all__ = ["CycleTimes", "MotorDrives", "WallClock", "WallClockCycles", "sleep_until"]

#: The loop sleeps until this long before a release, then busy-waits, s.
SPIN_MARGIN = 2.0e-4
#: Wall time from the start of a run to the release of its first cycle, s.
START_LEAD = 0.01


def sleep_until(deadline: float) -> None:
    """Sleep until ``SPIN_MARGIN`` before ``deadline`` (perf_counter s), then busy-wait."""
    remaining = deadline - time.perf_counter()
    if remaining > SPIN_MARGIN:
        time.sleep(remaining - SPIN_MARGIN)
    while time.perf_counter() < deadline:
        pass


class WallClock:
    """The real-time loop's clock: ``steps`` cycles of ``time_step`` s, cycle k released at the
    wall time r_k = t0 + k·time_step (t0: ``START_LEAD`` after the iteration starts).

    Iterating waits for each release in turn and yields (k, t_k = k·time_step), every cycle,
    on the same grid; :attr:`missed` tells whether the loop reached cycle k a whole period
    after its release (its deadline r_{k+1} had passed: nothing can be computed for it in time).

    Args:
        time_step: Δt, s.
        steps: number of cycles.
        now: the wall clock, s (``time.perf_counter``; a test passes a scripted one).
        wait: waits until a wall time, s (None: :func:`sleep_until`).
    """

    def __init__(
        self,
        time_step: float,
        steps: int,
        now: Callable[[], float] = time.perf_counter,
        wait: Callable[[float], None] | None = None,
    ) -> None:
        if not (math.isfinite(time_step) and time_step > 0.0) or steps < 0:
            raise ConfigError(f"a wall clock needs Δt > 0 s, steps >= 0; got {time_step}, {steps}")
        self.time_step = time_step
        self.steps = steps
        self.now = now
        self.wait = wait
        self.t0 = math.nan
        self.k = -1
        self.missed = False

    def __iter__(self) -> Iterator[tuple[int, float]]:
        wait = self.wait or sleep_until
        dt = self.time_step
        self.t0 = self.now() + START_LEAD
        for k in range(self.steps):
            release = self.t0 + k * dt
            wait(release)
            self.k = k
            self.missed = self.now() - release >= dt
            yield k, k * dt

    def elapsed(self) -> float:
        """Wall time since the present cycle's release, s."""
        return self.now() - (self.t0 + self.k * self.time_step)

    def periods_late(self) -> int:
        """Whole periods the present cycle's work is past its deadline: 0 within the period
        (before r_{k+1}), L when r_{k+L} has passed but not r_{k+L+1}."""
        return int(self.elapsed() / self.time_step)


class MotorDrives:
    """The motor drives between the torque loop and the plant (zero-order hold, as motor
    drivers do), a controller stage after :class:`~ffmpc_core.polishing_loop.LowLevelStage`.

    A torque computed within its cycle's period reaches the plant at once. One computed L
    periods past its deadline missed the start of the steps k, …, k+L−1: they run under the
    torque held, and it is delivered for step k+L. A missed cycle (:meth:`hold`) runs under the
    torque held. A step the low level refuses (InputError: one line through ``reject``) leaves
    the torque held.

    The output is what the plant is given (``motor_torque``: the applied τ^m, N·m; the desired
    torque and mode of the low level's newest output); :attr:`computed` is this cycle's own
    output (None: missed or refused) and :attr:`fresh` is False on a missed cycle and on a
    cycle whose torque was late (no new torque reached the plant in time: the robot's
    communication watchdog counts, ``ReflexPlant.step``).

    Args:
        lowlevel: the low-level stage. clock: the wall clock.
        initial: the output before the first cycle (the motors hold the robot: τ^m = g(q0)).
        reject: called with (kind, message) for a refused step.
    """

    def __init__(
        self,
        lowlevel: LowLevelStage,
        clock: WallClock,
        initial: LowLevelOutput,
        reject: Callable[[str, str], None],
    ) -> None:
        self.lowlevel = lowlevel
        self.clock = clock
        self.reject = reject
        self.last = initial  # the output the plant was given last
        self.held = initial.motor_torque  # the torque the drives hold, N·m
        self._due: tuple[int, np.ndarray] | None = None  # (cycle, τ^m) of a late delivery
        self.computed: LowLevelOutput | None = None
        self.fresh = True

    def reset(self) -> None:
        """Reset the low-level stage (the drives keep the torque they hold)."""
        self.lowlevel.reset()

    def arrive(self, k: int) -> None:
        """At the start of cycle k: deliver the torque due by now."""
        if self._due is not None and k >= self._due[0]:
            self.held, self._due = self._due[1], None

    def step(self, decision: MpcDecision, t: float, /) -> LowLevelOutput:
        """An on-time cycle (t in s): the low level's output, applied if in time."""
        k = self.clock.k
        try:
            self.computed = self.lowlevel.step(decision, t)
        except InputError as exc:
            self.reject("step", f"cycle {k}: {exc}")
            self.computed = None
        out = self.computed
        if out is None:  # refused: the torque held, the newest desired torque and mode
            out = replace(self.last, motor_torque=self.held)
        late = self.clock.periods_late()
        self.fresh = late == 0
        self._due = (k + max(late, 1), out.motor_torque)
        if late:
            out = replace(out, motor_torque=self.held)
        self.last = out
        return out

    def hold(self, reading: PolishingReading, t: float, /) -> LowLevelOutput:
        """A missed cycle (t in s): the torque held, with the newest output's desired torque
        and mode."""
        self.computed = None
        self.fresh = False  # no new command: the communication reflex counts
        self.last = replace(self.last, motor_torque=self.held)
        return self.last


class _HeldStage:
    """The stages of a missed cycle: the drives' hold alone."""

    def __init__(self, drives: MotorDrives) -> None:
        self.drives = drives

    def reset(self) -> None:
        """Nothing to reset (the drives' state belongs to the run)."""

    def step(self, reading: PolishingReading, t: float, /) -> LowLevelOutput:
        return self.drives.hold(reading, t)


class _DrivenPlant:
    """The reflex plant stepped with the drives' ``fresh`` flag (a core Plant)."""

    def __init__(self, plant: ReflexPlant[Any], drives: MotorDrives) -> None:
        self.plant = plant
        self.drives = drives
        self.dt = plant.dt

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        self.plant.reset(q, v)

    def step(self, command: np.ndarray, /) -> None:
        self.plant.step(command, fresh=self.drives.fresh)

    def state(self) -> Any:
        return self.plant.state()


class _LoggedAfterRun:
    """The polishing loop as a core scenario whose log is written after the run (off the hot
    path, as a lockstep run's log is, row by row in cycle order with the loop's own
    ``record``): :meth:`record` keeps the cycle's arguments (fresh objects every cycle: the
    plant's state, the reading, the drives' output, the actuation's τ̂), :meth:`flush` logs
    them."""

    def __init__(self, loop: PolishingLoop) -> None:
        self.loop = loop
        self.rows: list[tuple] = []

    def measure(self, k: int, t: float, state: PolishingPlantState, /) -> PolishingReading:
        return self.loop.measure(k, t, state)

    def actuate(
        self, k: int, t: float, state: PolishingPlantState, command: LowLevelOutput, /
    ) -> np.ndarray:
        return self.loop.actuate(k, t, state, command)

    def record(self, *row: Any) -> None:
        self.rows.append(row)

    def flush(self) -> None:
        """Log the cycles kept by :meth:`record`, in order."""
        for row in self.rows:
            self.loop.record(*row)
        self.rows.clear()


@dataclass(frozen=True)
class CycleTimes:
    """Per cycle of a run: ``latency`` (wall s from the release to the end of the plant's step;
    inf for a missed cycle) and ``missed`` (the loop missed the cycle)."""

    latency: np.ndarray
    missed: np.ndarray


def _nothing(k: int, /) -> None:
    return None


class WallClockCycles:
    """The closed loop of a real-time run (module docstring) on a :class:`WallClock`.

    Args:
        loop: the polishing loop (sensing, actuation, push, log).
        plant: the plant with the robot's reflexes (reset).
        mpc: the MPC stage (PolishingReading → MpcDecision at time t).
        drives: the motor drives around the low-level stage.
        clock: the wall clock (``drives.clock``).
    """

    def __init__(
        self,
        loop: PolishingLoop,
        plant: ReflexPlant[Any],
        mpc: Controller[PolishingReading, MpcDecision],
        drives: MotorDrives,
    ) -> None:
        self.loop = loop
        self.clock = drives.clock
        self.drives = drives
        self.scenario = _LoggedAfterRun(loop)
        self.plant = _DrivenPlant(plant, drives)
        self.stages: list[Controller[Any, Any]] = [mpc, drives]
        self.held: list[Controller[Any, Any]] = [_HeldStage(drives)]

    def run(
        self,
        before: Callable[[int], None] = _nothing,
        after: Callable[[int], None] = _nothing,
    ) -> CycleTimes:
        """Every cycle of the clock through :func:`ffmpc_core.runner.run_cycle`: the stages on
        time, the held torque when missed; the loop's log is written after the last cycle.
        ``before(k)`` runs at every release, ``after(k)`` after each on-time cycle's plant step
        (off the deadline: the observer topics)."""
        n = self.clock.steps
        latency, missed = np.zeros(n), np.zeros(n, dtype=bool)
        for k, t in self.clock:
            before(k)
            self.drives.arrive(k)
            missed[k] = self.clock.missed
            run_cycle(self.scenario, self.plant, self.held if missed[k] else self.stages, k, t)
            latency[k] = math.inf if missed[k] else self.clock.elapsed()
            if not missed[k]:
                after(k)
        self.scenario.flush()
        return CycleTimes(latency, missed)


def initial_output(torque: np.ndarray) -> LowLevelOutput:
    """The drives' output before the first cycle: ``torque`` (N·m) held, no desired torque, the
    safe hold."""
    return LowLevelOutput(torque, np.zeros_like(torque), LowLevelMode.HOLD, math.inf, 0.0)
