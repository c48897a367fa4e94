"""Real-time mode: the 1 kHz loop and the 500 Hz MPC on the wall clock, deadlines measured.

Execution model (chosen by measurement on the 2-core machine, see docs/explanation/ros.md, "Real
time"):

* **the loop process** composes the ``plant``, ``joint_sensor``, ``ft_sensor`` and ``pid`` ROS
  nodes in one process, as ROS 2 components with intra-process communication would be: four
  rclpy nodes with their own names, parameters and publishers, but the edges between them
  (plant → sensor models → torque loop → actuation → plant) are direct calls, not DDS: the
  core's cycle (``ffmpc_core.runner.run_cycle``) with the ROS-free run's objects
  (:mod:`ffmpc_ros.realtime_cycle`). One thread runs the loop on an absolute wall-clock
  schedule (cycle k is released at t0 + k·time_step; sleep to ~``SPIN_MARGIN`` before the
  release, then busy-wait: ``realtime_cycle.WallClock``), with no
  executor on the hot path: the MPC commands are taken straight from the subscription
  (``take_message``, ~2 µs when empty). The garbage collector is frozen and disabled for the run.
* **the MPC process** is the ordinary ``mpc`` node (``ffmpc_ros.mpc_node``) with
  ``lockstep: false``: it blocks on a wait set over its inputs (no executor), solves on the
  newest measurement of each MPC tick and publishes ``/mpc/command``; its constrained solve
  makes one SQP iteration per tick (its ``real_time_iterations``, the budget that keeps it
  inside the MPC period; ``mpc_ros_args`` of :func:`run_realtime` can set it).
* They talk over ROS topics: ``/joint_sensor/joint_states`` and ``/ft_sensor/wrench`` (loop →
  MPC, every cycle), ``/mpc/command`` (MPC → loop) and ``/clock``. The observer topics
  (``/plant/*``, ``/pid/*``) are published only while something subscribes to them.
* Optional scheduling: each process pinned to one core (``cpus``) and/or ``SCHED_FIFO`` at
  ``priority`` (root or CAP_SYS_NICE; the kernel's RT throttling still leaves 5 % to others).

Deadlines (every time below is wall time, measured with ``time.perf_counter``):

* **loop** — cycle k is released at r_k = t0 + k·Δt (Δt = ``plant.time_step``). Its deadline
  is met when, by r_{k+1}, it has run the sensor models on the state of t_k, published the
  measurement, taken the MPC commands that arrived, computed τ^m (hold/blend/track/fallback +
  PID), applied it through the actuation model and stepped the plant to t_{k+1}: the torque of
  cycle k is applied before the plant's step k+1 is due. A cycle that starts late but within
  its period runs at once. A cycle the loop reaches a whole period after its release is
  **missed**: the plant is physical and does not wait for its controller, so it steps on under
  the motor torque last sent (zero-order hold, as motor drivers do) while the sensor devices
  keep sampling; nothing is published or computed for it, and the loop resumes at the first
  release still ahead, on the same grid. Likewise a torque computed after its deadline reaches
  the plant only after the steps whose start it missed (they run under the held torque).
  (Running the missed cycles back to back instead, faster than real time, let the MPC fall
  behind the plant it controls: measured with an injected 30 ms stall of the loop, joint 5
  reached 4.96x its velocity limit; 8.6x after 100 ms.)
  The **cycle latency** is the time from r_k to the end of that work (so it includes the
  wake-up jitter; inf for a missed cycle).
* **MPC** — every ``mpc.period`` (a tick: cycles k with k % (period/Δt) = 0) the MPC must solve
  from the measurement of cycle k and its command must be in the loop when it takes commands
  in cycle k + period/Δt (just after publishing that cycle's measurement), i.e. within one MPC
  period. A tick that is never solved (the MPC was still busy) is a miss. The MPC latency
  reported is the wall time from publishing the measurement of a tick to the loop taking its
  command, so it is quantised by the 1 ms cycle.
* **Fixed latency (logical execution time).** A command solved from cycle k is applied at
  cycle k + period/Δt — not earlier even if it is in sooner — so its latency is fixed, as in
  lockstep. The scenario's δo (``pid.delay_cycles``) is the end-to-end delay of the
  lockstep model: here period/Δt cycles of it are real (the MPC's deadline) and the torque
  PID's delay line models the rest (δo − period, never negative; with δo < period the real
  delay is one period). A late command is applied when it arrives.
* **fallback time** — simulated time the loop spends in ``LowLevelMode.FALLBACK`` (its input
  older than ``pid.stale_timeout`` past its use at cycle k + period/Δt, as in lockstep: one
  missed solve is tolerated, :func:`real_time_pid_settings`), minus what falls inside a fault
  window (a list of (start, end) simulated seconds during which a fault is injected on purpose:
  the hook for fault injection, :func:`fallback_time`).

``ffmpc run --real-time`` exits non-zero when more than :data:`MAX_MISSED_FRACTION` of either
kind of deadline was missed or any fallback time falls outside the fault windows.

Injected stalls (``ffmpc run --real-time --fault loop-stall@T+D`` or ``mpc-stall@T+D``,
:class:`_StallSchedule`): the loop thread, or the whole MPC process (SIGSTOP), is frozen for D
wall seconds from the cycle at simulated time T, as a preempted process would be; the summary
lists them under ``faults`` and, as for the lockstep graph's faults, the verdict of such a run
is its safety (joint limits), its timing failures are reported.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import gc
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from ffmpc_msgs.msg import MpcCommand as MpcCommandMsg
from geometry_msgs.msg import WrenchStamped
from rclpy.context import Context
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import FfmpcError, InputError
from ffmpc_core.faults import REALTIME_KINDS, Fault, parse_fault, require_kinds
from ffmpc_core.lowlevel import (
    LowLevelCommand,
    LowLevelController,
    LowLevelMode,
    LowLevelOutput,
)
from ffmpc_core.metrics import PolishingMetrics, limit_ratios
from ffmpc_core.polishing import (
    PolishingLog,
    device_generator,
    force_pipeline,
    joint_sensing_model,
    lowlevel_controller,
    polishing_run_metrics,
    scenario_robot,
    steps_per_mpc_period,
)
from ffmpc_core.polishing_loop import (
    LowLevelStage,
    MpcDecision,
    PolishingLoop,
    PolishingReading,
)
from ffmpc_core.scenario import Scenario, flatten
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import (
    GraphNode,
    force_on_axes,
    joint_state_message,
    stamp_at,
    wrench_stamped,
)
from ffmpc_ros.command_msg import command_fields
from ffmpc_ros.params import parameter_overrides
from ffmpc_ros.realtime_cycle import (
    CycleTimes,
    MotorDrives,
    WallClock,
    WallClockCycles,
    initial_output,
)

#: A run fails when more than this fraction of the loop's or the MPC's deadlines was missed.
MAX_MISSED_FRACTION = 0.01
#: How often the loop re-checks who subscribes to its observer topics, cycles.
SUBSCRIBER_CHECK_EVERY = 100
#: SCHED_FIFO priority of both processes by default (where permitted; 0: normal scheduling).
DEFAULT_PRIORITY = 80
#: Wall time the loop process waits for the MPC to appear, s.
MPC_WAIT = 120.0

#: Environment variables set to 1 in both processes (unless set): BLAS and OpenMP thread pools
#: spin on the other core and steal it from the other process.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

FaultWindows = Sequence[tuple[float, float]]


class RealtimeError(FfmpcError):
    """The real-time run could not start or finish (a process died, a time limit passed)."""


# -- statistics ---------------------------------------------------------------------------------
def fallback_time(
    modes: np.ndarray, time_step: float, fault_windows: FaultWindows = ()
) -> tuple[float, float]:
    """(unexcused, excused) simulated seconds in FALLBACK: cycle k (t_k = k·time_step) counts
    time_step; it is excused when t_k lies in a fault window (:func:`in_fault_windows`)."""
    modes = np.asarray(modes)
    fallback = modes == int(LowLevelMode.FALLBACK)
    excused = in_fault_windows(modes.size, time_step, fault_windows)
    return (
        float(np.count_nonzero(fallback & ~excused)) * time_step,
        float(np.count_nonzero(fallback & excused)) * time_step,
    )


def in_fault_windows(cycles: int, time_step: float, fault_windows: FaultWindows) -> np.ndarray:
    """Per cycle k (t_k = k·time_step), whether t_k lies in a fault window [start, end] (s,
    both ends included); InputError for a window that is not finite or ends before it starts."""
    t = np.arange(cycles) * time_step
    inside = np.zeros(cycles, dtype=bool)
    for start, end in fault_windows:
        if not (math.isfinite(start) and math.isfinite(end)) or end < start:
            raise InputError(f"fault window ({start}, {end}) must be finite with end >= start")
        inside |= (t >= start - 1e-12) & (t <= end + 1e-12)
    return inside


def percentiles_ms(values: np.ndarray) -> dict[str, float | None]:
    """p50, p99 and max of durations in s, as ms (None when there are none)."""
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if values.size == 0:
        return {"p50_ms": None, "p99_ms": None, "max_ms": None}
    return {
        "p50_ms": float(np.percentile(values, 50) * 1e3),
        "p99_ms": float(np.percentile(values, 99) * 1e3),
        "max_ms": float(values.max() * 1e3),
    }


def timing_report(
    *,
    time_step: float,
    every: int,
    cycle_latency: np.ndarray,
    modes: np.ndarray,
    command_arrival: np.ndarray,
    command_latency: np.ndarray,
    solve_times: np.ndarray,
    fault_windows: FaultWindows = (),
) -> dict:
    """The deadline statistics of a run (see the module docstring for the definitions).

    Args:
        time_step: Δt, s. every: cycles per MPC period.
        cycle_latency: per cycle, wall time from its release to the end of its work, s.
        modes: per cycle, the LowLevelMode of the loop.
        command_arrival: per cycle k, the cycle at whose start the command solved from cycle k
            was taken (−1: none).
        command_latency: per cycle k, wall time from publishing the measurement of k to taking
            its command, s (nan: none).
        solve_times: the solve times the commands reported, s.
    """
    cycles = cycle_latency.size
    met = cycle_latency <= time_step
    loop_met = int(np.count_nonzero(met))
    # the machine's share: a fault injected on purpose (a loop stall) misses deadlines by design
    outside = ~in_fault_windows(cycles, time_step, fault_windows)
    ticks = np.arange(0, cycles, every)
    ticks = ticks[ticks + every < cycles]  # ticks whose deadline falls inside the run
    arrival = command_arrival[ticks]
    mpc_met = int(np.count_nonzero((arrival >= 0) & (arrival <= ticks + every)))
    unexcused, excused = fallback_time(modes, time_step, fault_windows)
    loop = {
        "cycles": cycles,
        "deadlines_met": loop_met,
        "deadline_met_fraction": loop_met / cycles if cycles else None,
        "deadline_met_fraction_outside_faults": (
            float(np.mean(met[outside])) if outside.any() else None
        ),
        **{f"latency_{k}": v for k, v in percentiles_ms(cycle_latency).items()},
    }
    mpc = {
        "ticks": int(ticks.size),
        "solved": int(np.count_nonzero(arrival >= 0)),
        "deadlines_met": mpc_met,
        "deadline_met_fraction": mpc_met / ticks.size if ticks.size else None,
        **{f"latency_{k}": v for k, v in percentiles_ms(command_latency[ticks]).items()},
        **{f"solve_{k}": v for k, v in percentiles_ms(solve_times).items()},
    }
    return {
        "deadline_met_fraction": {
            "mpc": mpc["deadline_met_fraction"],
            "loop": loop["deadline_met_fraction"],
        },
        "fallback_time_s": unexcused,
        "fallback_excused_s": excused,
        "fault_windows": [list(map(float, w)) for w in fault_windows],
        "latency_p50_ms": loop["latency_p50_ms"],
        "latency_p99_ms": loop["latency_p99_ms"],
        "latency_max_ms": loop["latency_max_ms"],
        "loop": loop,
        "mpc": mpc,
    }


def timing_failures(timing: dict, max_missed: float = MAX_MISSED_FRACTION) -> list[str]:
    """Why a run's timing fails (empty: it passes): a deadline fraction below 1 − max_missed
    (or unknown), or fallback time outside the fault windows."""
    out = []
    for kind, fraction in timing["deadline_met_fraction"].items():
        if fraction is None or fraction < 1.0 - max_missed:
            shown = "unknown" if fraction is None else f"{fraction:.4f}"
            out.append(f"{kind} deadlines met {shown} < {1.0 - max_missed:.2f}")
    if timing["fallback_time_s"] > 0.0:
        out.append(f"{timing['fallback_time_s']:.3f} s in fallback outside fault windows")
    return out


# -- injected stalls ----------------------------------------------------------------------------
class _StallSchedule:
    """The stalls a real-time run injects (``loop-stall``, ``mpc-stall``: ``ffmpc_core.faults``),
    driven by the loop thread: :meth:`inject` at every cycle that runs, :meth:`resume_due` at
    every release (missed cycles included).

    * ``loop-stall`` — the loop thread sleeps ``duration`` wall s in the first cycle at or after
      ``start`` that runs (after publishing that cycle's measurement, before its torque);
    * ``mpc-stall`` — SIGSTOP of the MPC process (``mpc_pid``) at that cycle, SIGCONT at the
      first release ``duration`` wall s later (and at the end of the run, whatever happens).
    """

    def __init__(self, stalls: Sequence[Fault], time_step: float, mpc_pid: int | None) -> None:
        self.time_step = time_step
        self.mpc_pid = mpc_pid
        self.pending = sorted(stalls, key=lambda f: f.start)
        if any(f.kind == "mpc-stall" for f in self.pending) and mpc_pid is None:
            raise RealtimeError("an mpc-stall needs the MPC's process id (--mpc-pid)")
        self.stopped: float | None = None  # perf_counter time to resume the MPC at, s
        self.records: list[dict] = []

    def inject(self, k: int) -> None:
        t = k * self.time_step
        while self.pending and self.pending[0].start <= t + 1e-9:
            fault = self.pending.pop(0)
            duration = float(fault.duration or 0.0)
            self.records.append({"fault": str(fault), "injected_at": t, "ended_at": t + duration})
            if fault.kind == "loop-stall":
                time.sleep(duration)
            elif self.stopped is None:
                assert self.mpc_pid is not None  # __init__ refuses an mpc-stall without it
                os.kill(self.mpc_pid, signal.SIGSTOP)
                self.stopped = time.perf_counter() + duration

    def resume_due(self) -> None:
        if self.stopped is not None and time.perf_counter() >= self.stopped:
            self.release()

    def release(self) -> None:
        """SIGCONT of a stopped MPC (also at the end of the run: never left stopped)."""
        if self.stopped is not None and self.mpc_pid is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.mpc_pid, signal.SIGCONT)
        self.stopped = None

    def report(self) -> list[dict]:
        """Per stall: the fault, the simulated s it began and ended at (wall s = plant s)."""
        return list(self.records)


# -- scheduling ---------------------------------------------------------------------------------
def set_timer_slack(ns: int = 1000) -> bool:
    """Linux: timer slack of this thread, ns (default 50 µs makes every sleep late)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return libc.prctl(29, ctypes.c_ulong(ns), 0, 0, 0) == 0  # PR_SET_TIMERSLACK
    except (OSError, AttributeError):
        return False


def apply_scheduling(pid: int, cpu: int | None, priority: int) -> list[str]:
    """Pin process ``pid`` (0: this one) to ``cpu`` and give it SCHED_FIFO ``priority`` (0:
    leave the normal policy). Returns warnings for what could not be applied."""
    warnings = []
    if cpu is not None:
        try:
            os.sched_setaffinity(pid, {cpu})
        except OSError as exc:
            warnings.append(f"cannot pin to CPU {cpu}: {exc}")
    if priority > 0:
        try:
            os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(priority))
        except (OSError, PermissionError) as exc:
            warnings.append(f"cannot use SCHED_FIFO {priority}: {exc}")
    return warnings


def raise_helper_threads() -> list[str]:
    """Under SCHED_FIFO: give every other thread of this process (the middleware's receive and
    event threads) one priority level above the calling thread. At equal priority they would
    run only while the loop thread sleeps, so a command that arrived in time could wait
    past the cycle that needs it. Returns warnings."""
    if os.sched_getscheduler(0) != os.SCHED_FIFO:
        return []
    me = threading.get_native_id()
    level = min(os.sched_getparam(0).sched_priority + 1, 99)
    warnings = []
    for tid in os.listdir("/proc/self/task"):
        if int(tid) == me:
            continue
        try:
            os.sched_setscheduler(int(tid), os.SCHED_FIFO, os.sched_param(level))
        except OSError as exc:  # the thread may have ended
            warnings.append(f"thread {tid}: {exc}")
    return warnings


def default_cpus() -> tuple[int, int] | None:
    """(loop CPU, MPC CPU): the first two CPUs this process may use (None with fewer)."""
    allowed = sorted(os.sched_getaffinity(0))
    return (allowed[0], allowed[1]) if len(allowed) >= 2 else None


def _die_with_parent() -> None:
    """In a child before exec: SIGINT when the parent dies (no orphan survives a killed run)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGINT, 0, 0, 0)  # PR_SET_PDEATHSIG


# -- the loop process ---------------------------------------------------------------------------
def real_time_pid_settings(scenario: Scenario) -> Scenario:
    """The scenario the real-time loop's torque PID runs: the lockstep model shifted by the fixed
    MPC latency of ``every`` = mpc.period/Δt cycles (a command solved at cycle k is applied at
    cycle k + every, see the module docstring).

    * ``pid.delay_cycles``: δo − every (never negative): those cycles of δo are real here, the
      delay line models the rest.
    * ``pid.stale_timeout``: + every·Δt. The command's age is counted from its stamp (cycle k),
      and it is never used before it is every·Δt old, so the timeout keeps its lockstep meaning
      (time past the command's use, s: one missed solve tolerated, two give the safe hold).
    """
    every = steps_per_mpc_period(scenario)
    return scenario.with_overrides(
        {
            "pid.delay_cycles": max(0, scenario.pid.delay_cycles - every),
            "pid.stale_timeout": scenario.pid.stale_timeout + every * scenario.plant.time_step,
        }
    )


def command_qos() -> QoSProfile:
    """/mpc/command in the loop process: reliable, every command kept until taken."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=topics.PUBLISHER_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


class CommandInbox:
    """The loop's side of ``/mpc/command`` (module docstring, "MPC" and "Fixed latency").

    :meth:`take` takes every command that arrived, each checked whole before it may claim the
    cycle of its stamp (fields and sizes, ``command_msg.command_fields``; a plausible torque,
    ``LowLevelController.check_command``; a stamp on the run's grid, not from the future and not
    taken yet: as the PID node, a rejected message is counted, logged in one line and changes
    nothing); :meth:`release` hands the low level, in order, the commands solved at least one
    MPC period (``every`` cycles) before the present cycle.

    Per cycle k it keeps ``arrival`` (the cycle at which the command solved from k was taken,
    −1: none), ``latency`` (wall s from :meth:`sent` of k to the take; nan: none) and the solve
    times the commands reported (``solve_times``, s).

    Args:
        take: the next message that arrived, None when there is none.
        lowlevel: the low-level controller the commands go to.
        cycle_of: the cycle of a stamp (None: off the grid).
        reject: called with (kind, message) for a rejected command.
        steps, every, time_step: the run's cycles, cycles per MPC period, Δt (s).
        topic: the command topic's resolved name (the rejection kinds are keyed by it).
    """

    def __init__(
        self,
        take: Callable[[], Any],
        lowlevel: LowLevelController,
        cycle_of: Callable[[TimeMsg], int | None],
        reject: Callable[[str, str], None],
        steps: int,
        every: int,
        time_step: float,
        topic: str,
    ) -> None:
        self._take = take
        self.lowlevel = lowlevel
        self.cycle_of = cycle_of
        self.reject = reject
        self.steps, self.every, self.time_step = steps, every, time_step
        self.topic = topic
        self.arrival = np.full(steps, -1, dtype=np.int64)
        self.latency = np.full(steps, np.nan)
        self.published = np.zeros(steps)
        self.solve_times: list[float] = []
        self._pending: dict[int, LowLevelCommand] = {}

    def sent(self, k: int) -> None:
        """The measurement of cycle k was published now."""
        self.published[k] = time.perf_counter()

    def take(self, k: int) -> None:
        """At cycle k: take every command that arrived; note the cycle at which each arrived."""
        now = time.perf_counter()
        robot = self.lowlevel.robot
        while (msg := self._take()) is not None:
            try:
                fields = command_fields(msg, robot.nv, robot.joint_names)
                if fields["nx"] != self.lowlevel.nx:
                    raise InputError(f"command for nx={fields['nx']}")
                command = self.lowlevel.check_command(
                    LowLevelCommand(fields["torque"], fields["state"], fields["feedback_gain"])
                )
            except InputError as exc:
                self.reject(f"{self.topic}:value", str(exc))
                continue
            kc = self.cycle_of(fields["stamp"])
            if kc is None or kc > k or kc < 0 or kc >= self.steps or self.arrival[kc] >= 0:
                self.reject(f"{self.topic}:stamp", f"command time {fields['t']} s")
                continue
            self.arrival[kc] = k
            self.latency[kc] = now - self.published[kc]
            self.solve_times.append(float(fields["solve_time"]))
            self._pending[kc] = command

    def release(self, k: int) -> None:
        """Hand the low level, in order, the commands solved at least ``every`` cycles before
        cycle k (each with the time of its measurement)."""
        for kc in sorted(c for c in self._pending if c + self.every <= k):
            command = self._pending.pop(kc)
            try:
                self.lowlevel.set_command(command, kc * self.time_step)
            except InputError as exc:
                self.reject(f"{self.topic}:value", str(exc))


class TopicMpc:
    """The MPC stage of the real-time loop, in the place of the runner's
    :class:`~ffmpc_core.polishing_loop.MpcStage` (PolishingReading → MpcDecision): the MPC
    solves in its own process. The stage publishes the reading as the sensors' messages, lets
    an injected stall freeze the loop there (:class:`_StallSchedule`), then takes the commands
    that arrived and hands the low level those due (:class:`CommandInbox`). It decides nothing
    itself: no command of its own, no hold (the low level's stale-command rule holds the robot
    when the MPC is late)."""

    def __init__(
        self,
        publish: Callable[[int, PolishingReading], None],
        inbox: CommandInbox,
        stalls: _StallSchedule,
        clock: WallClock,
    ) -> None:
        self.publish = publish
        self.inbox = inbox
        self.stalls = stalls
        self.clock = clock

    def reset(self) -> None:
        """Nothing to reset (the MPC process resets itself)."""

    def step(self, reading: PolishingReading, t: float, /) -> MpcDecision:
        """Publish the reading of the present cycle (t in s), take and release the commands."""
        k = self.clock.k
        self.publish(k, reading)
        self.inbox.sent(k)
        self.stalls.inject(k)  # (an injected stall freezes this process here)
        self.inbox.take(k)
        self.inbox.release(k)
        return MpcDecision(reading, None, False)


def _subscription_taker(sub: Any) -> Callable[[], Any]:
    """The next message of a subscription, taken without an executor (~2 µs when empty)."""

    def take() -> Any:
        with sub.handle:
            taken = sub.handle.take_message(sub.msg_type, sub.raw)
        return None if taken is None else taken[0]

    return take


class RealtimeLoop:
    """The plant, sensor and PID nodes composed in one process, run on the wall clock.

    The cycle is the core's (:mod:`ffmpc_ros.realtime_cycle`): the same
    :class:`~ffmpc_core.polishing_loop.PolishingLoop` (sensing, actuation, push, log) and
    :class:`~ffmpc_core.polishing_loop.LowLevelStage` as the ROS-free runner, the reflex plant,
    :func:`ffmpc_core.runner.run_cycle`; :class:`TopicMpc` in the MPC stage's place.

    Args:
        params: {node: {ROS name: value}} of ``plant``, ``joint_sensor``, ``ft_sensor``, ``pid``
            (``ffmpc_ros.graph_nodes.graph_parameters``; the plant's ``duration`` and
            ``start_delay`` are used).
        context: the rclpy context.
        stalls: ``loop-stall`` / ``mpc-stall`` faults to inject (:class:`_StallSchedule`).
        mpc_pid: the MPC process (for ``mpc-stall``).
    """

    def __init__(
        self,
        params: dict[str, dict],
        context: Context,
        stalls: Sequence[Fault] = (),
        mpc_pid: int | None = None,
    ) -> None:
        def node(name: str) -> GraphNode:
            return GraphNode(
                name, context=context, parameter_overrides=parameter_overrides(params[name])
            )

        self.context = context
        self.stalls = tuple(stalls)
        self.mpc_pid = mpc_pid
        self.nodes = {n: node(n) for n in ("plant", "joint_sensor", "ft_sensor", "pid")}
        plant_node = self.nodes["plant"]
        s = self.scenario = plant_node.scenario
        robot = self.robot = scenario_robot(s)  # carrying the tool (the cell's load data)
        self.joint_names = list(robot.joint_names)
        self.time_step = plant_node.time_step
        self.step_ns = plant_node.step_ns
        duration = float(plant_node.params["duration"])
        self.start_delay = float(plant_node.params["start_delay"])
        # torque loop (as PidNode), with the fixed MPC latency counted (real_time_pid_settings)
        ps = real_time_pid_settings(self.nodes["pid"].scenario)
        self.every = steps_per_mpc_period(ps)
        self.modelled_delay_cycles = ps.pid.delay_cycles
        self.stale_timeout = ps.pid.stale_timeout
        self.lowlevel = lowlevel_controller(ps, robot)
        self.loop = self._polishing_loop(duration)
        self._create_topics()
        self._active: dict[str, bool] = {}
        self.rejected: dict[str, int] = {}

    def _polishing_loop(self, duration: float) -> PolishingLoop:
        """The plant (as PlantNode), the sensor models (as JointSensorNode, FtSensorNode) and
        the core's polishing loop around them."""
        from sim_bridge.scenes import simulated_robot

        s, robot = self.scenario, self.robot
        self.sim = simulated_robot(
            s, robot, device_generator(s.seed, "draws"), device_generator(s.seed, "actuation")
        )
        self.task, self.plant = self.sim.task, self.sim.plant
        self.reflex_plant = self.sim.reflex_plant  # the robot's reflexes (module docstring)
        self.steps = int(round((duration or self.task.duration) / self.time_step))
        js = self.nodes["joint_sensor"].scenario
        ft = self.nodes["ft_sensor"].scenario
        contact = ft.mpc.contact
        self.force_axes = [contact.normal_axis] if contact.dimension == 1 else [0, 1, 2]
        return PolishingLoop(
            robot,
            contact,
            joint_sensing_model(js, robot.nv, device_generator(js.seed, "joint_sensor")),
            force_pipeline(  # eq 32, or the wrist sensor, calibrated now
                ft,
                robot,
                device_generator(ft.seed, "force_sensor"),
                device_generator(ft.seed, "ft_calibration"),
                time.time(),
            ),
            self.sim.actuation,
            PolishingLog(self.steps, robot, self.task),
            self.every,
            initial_torque=robot.gravity(robot.q_nominal),  # the motors hold the robot at start
            disturbance=self.sim.push_if_due,
        )

    def _create_topics(self) -> None:
        pn, jn, fn, cn = (self.nodes[n] for n in ("plant", "joint_sensor", "ft_sensor", "pid"))
        self.pub_clock = pn.create_publisher(ClockMsg, topics.CLOCK, topics.clock_qos())
        self.pub_plant_joints = pn.graph_publisher(JointState, topics.PLANT_JOINT_STATES)
        self.pub_plant_wrench = pn.graph_publisher(WrenchStamped, topics.PLANT_WRENCH)
        self.pub_truth = pn.graph_publisher(Float64MultiArray, topics.PLANT_TRUTH)
        self.pub_status = pn.graph_publisher(Float64MultiArray, topics.PLANT_STATUS)
        self.pub_joints = jn.graph_publisher(JointState, topics.SENSED_JOINT_STATES)
        self.pub_wrench = fn.graph_publisher(WrenchStamped, topics.SENSED_WRENCH)
        self.pub_motor = cn.graph_publisher(JointState, topics.MOTOR_TORQUE)
        self.pub_desired = cn.graph_publisher(JointState, topics.DESIRED_TORQUE)
        self.pub_pid_status = cn.graph_publisher(Float64MultiArray, topics.LOWLEVEL_STATUS)
        self.sub_command = cn.create_subscription(
            MpcCommandMsg, topics.MPC_COMMAND, lambda _msg: None, command_qos()
        )
        self._command_topic = cn.name_of(topics.MPC_COMMAND)  # /arm1/mpc/command, as keyed

    # -- helpers ---------------------------------------------------------------------------------
    def _refresh_subscribers(self) -> None:
        pubs = {
            "clock": self.pub_clock,
            "plant_joints": self.pub_plant_joints,
            "plant_wrench": self.pub_plant_wrench,
            "truth": self.pub_truth,
            "joints": self.pub_joints,
            "wrench": self.pub_wrench,
            "motor": self.pub_motor,
            "desired": self.pub_desired,
            "pid_status": self.pub_pid_status,
        }
        self._active = {name: pub.get_subscription_count() > 0 for name, pub in pubs.items()}

    def _reject(self, kind: str, message: str) -> None:
        self.rejected[kind] = self.rejected.get(kind, 0) + 1
        self.nodes["pid"].reject(kind, message)

    def wait_for_mpc(self, limit: float = MPC_WAIT) -> None:
        """Block until the MPC subscribes to the joint states and /clock (its time source: this
        loop's nodes read /clock too) and publishes commands, then ``start_delay`` more
        (discovery settles both ways)."""
        end = time.monotonic() + limit
        while (
            self.pub_joints.get_subscription_count() < 1
            or self.pub_clock.get_subscription_count()
            < topics.CLOCK_READERS_PER_NODE * (len(self.nodes) + 1)
            or self.sub_command.get_publisher_count() < 1
        ):
            if time.monotonic() > end:
                raise RealtimeError(f"no MPC node appeared within {limit} s")
            if not self.context.ok():
                raise KeyboardInterrupt
            time.sleep(0.01)
        time.sleep(self.start_delay)

    # -- the run ---------------------------------------------------------------------------------
    def cycles(self, stalls: _StallSchedule) -> tuple[WallClockCycles, CommandInbox]:
        """The run's closed loop on a new wall clock (:class:`WallClockCycles`) and its inbox
        of MPC commands."""
        clock = WallClock(self.time_step, self.steps)
        inbox = CommandInbox(
            _subscription_taker(self.sub_command),
            self.lowlevel,
            self.nodes["pid"].cycle_of,
            self._reject,
            self.steps,
            self.every,
            self.time_step,
            self._command_topic,
        )
        drives = MotorDrives(
            LowLevelStage(self.lowlevel),
            clock,
            initial_output(self.loop.tau_hat.copy()),
            self._reject,
        )
        mpc = TopicMpc(self._publish_measurement, inbox, stalls, clock)
        return WallClockCycles(self.loop, self.reflex_plant, mpc, drives), inbox

    def run(self) -> dict[str, Any]:
        """Run every cycle on the wall clock; returns the raw per-cycle records.

        A cycle whose release is a whole period past when the loop gets to it is **missed**:
        the physical plant does not wait for a late controller, so it steps on under the motor
        torque last sent (zero-order hold, as motor drivers do), the sensor devices keep
        sampling, and nothing is published or computed for that cycle. A torque computed past
        its deadline r_{k+1} missed the start of step k: that step and each later one whose
        start passed meanwhile run under the held torque, then it is delivered
        (:class:`~ffmpc_ros.realtime_cycle.MotorDrives`). A step without a new torque (missed,
        or late) tells the robot's communication reflex so (``fresh=False``). The loop resumes
        at the first release still ahead, on the same grid."""
        stalls = _StallSchedule(self.stalls, self.time_step, self.mpc_pid)
        cycles, inbox = self.cycles(stalls)
        clock, drives = cycles.clock, cycles.drives
        next_check = SUBSCRIBER_CHECK_EVERY

        def before(k: int) -> None:
            nonlocal next_check
            stalls.resume_due()
            if not clock.missed and k >= next_check:  # every 100 cycles run
                next_check = k + SUBSCRIBER_CHECK_EVERY
                if not self.context.ok():  # SIGINT (rclpy's handler shuts the context)
                    raise KeyboardInterrupt
                self._refresh_subscribers()

        gc.collect()
        gc.freeze()
        gc.disable()
        set_timer_slack()
        self._refresh_subscribers()  # (cycle 0 may be missed: the first check is not on it)
        try:
            times = cycles.run(before, lambda k: self._publish_observers(k, drives.computed))
        finally:
            stalls.release()
            gc.enable()
            gc.unfreeze()
        wall_time = time.perf_counter() - clock.t0
        return self._records(times, inbox, stalls, wall_time)

    def _records(
        self, times: CycleTimes, inbox: CommandInbox, stalls: _StallSchedule, wall_time: float
    ) -> dict[str, Any]:
        """The raw records of a run (:meth:`results` reads them). A guarded approach's
        contact was detected in the MPC process: its phases are read again from the logged
        measured force (:meth:`~ffmpc_core.polishing.PolishingLog.replay_contact`)."""
        contact_time = self.loop.log.replay_contact(self.every)
        log = self.loop.log.arrays
        pid_rejected = self.nodes["pid"].rejected
        return {
            "log": log,
            "contact_time": contact_time,
            "v": self.loop.trace_v,
            "mode": self.loop.trace_mode.astype(np.int8),
            "tau_motor": log["tau_motor"],
            "tau_measured": log["tau_measured"],
            "cycle_latency": times.latency,
            "missed": times.missed,
            "command_arrival": inbox.arrival,
            "command_latency": inbox.latency,
            "solve_times": np.array(inbox.solve_times),
            "wall_time": wall_time,
            "table_normal": self.plant.table_normal,
            "rejected": dict(self.rejected)
            | {k: v for k, v in pid_rejected.items() if k not in self.rejected},
            "stalls": stalls.report(),
        }

    def _publish_measurement(self, k: int, reading: PolishingReading) -> None:
        """The measurement of cycle k on the topics the MPC reads (and /clock: its time)."""
        act = self._active
        stamp = stamp_at(k, self.step_ns)
        if act["clock"]:
            self.pub_clock.publish(ClockMsg(clock=stamp))
        self.pub_joints.publish(
            joint_state_message(stamp, self.joint_names, reading.q, reading.v, reading.torque)
        )
        if act["wrench"]:
            full = force_on_axes(self.force_axes, reading.force)
            self.pub_wrench.publish(wrench_stamped(stamp, full))

    def _publish_observers(self, k: int, out: LowLevelOutput | None) -> None:
        """The topics no controller reads, only while someone subscribes: the plant's of cycle
        k+1 (the state after this step; effort: τ̂ applied over it) and the torque loop's
        output of cycle k (none when the low level refused the step)."""
        act = self._active
        stamp = stamp_at(k, self.step_ns)
        state, tau_hat = self.reflex_plant.state(), self.loop.tau_hat
        if act["plant_joints"] or act["plant_wrench"] or act["truth"]:
            nxt = stamp_at(k + 1, self.step_ns)
            if act["plant_joints"]:
                self.pub_plant_joints.publish(
                    joint_state_message(nxt, self.joint_names, state.q, state.v, tau_hat)
                )
            if act["plant_wrench"]:
                w = state.wrench_world
                self.pub_plant_wrench.publish(wrench_stamped(nxt, w[:3], w[3:]))
            if act["truth"]:
                self.pub_truth.publish(
                    layouts.PLANT_TRUTH.pack(
                        {
                            "t": (k + 1) * self.time_step,
                            "normal_force": state.normal_force,
                            "in_contact": float(state.in_contact),
                            "robot_collision": float(state.robot_collision),
                            "table_normal": self.plant.table_normal,
                            "contact_position": state.contact_frame_position,
                        }
                    )
                )
        if out is not None:
            self._publish_low_level(stamp, k, out)

    def _publish_low_level(self, stamp: TimeMsg, k: int, out: LowLevelOutput) -> None:
        act = self._active
        if act["motor"]:
            self.pub_motor.publish(
                joint_state_message(stamp, self.joint_names, None, None, out.motor_torque)
            )
        if act["desired"]:
            self.pub_desired.publish(
                joint_state_message(stamp, self.joint_names, None, None, out.desired_torque)
            )
        if act["pid_status"]:
            age = out.command_age if np.isfinite(out.command_age) else 1e9
            self.pub_pid_status.publish(
                layouts.LOWLEVEL_STATUS.pack(
                    {
                        "t": k * self.time_step,
                        "mode": float(out.mode),
                        "command_age": age,
                        "blend": out.blend,
                        "rejected": float(sum(self.rejected.values())),
                    }
                )
            )

    def publish_status(self, rec: dict, timing: dict) -> None:
        """The final /plant/status (latencies: cycle latency of the cycles that ran, s, all 0
        when none did; misses: loop deadlines, the missed cycles included). A missed cycle's
        latency is inf in the log, and a status with a non-finite value is refused by every
        reader of the layout."""
        lat = rec["cycle_latency"]
        lat = lat[np.isfinite(lat)]
        if lat.size == 0:
            lat = np.zeros(1)
        loop = timing["loop"]
        self.pub_status.publish(
            layouts.PLANT_STATUS.pack(
                {
                    "t": self.steps * self.time_step,
                    "steps": self.steps,
                    "done": 1.0,
                    "lockstep": 0.0,
                    "deadline_misses": loop["cycles"] - loop["deadlines_met"],
                    "latency_count": int(np.count_nonzero(np.isfinite(rec["cycle_latency"]))),
                    "latency_mean": float(lat.mean()),
                    "latency_p50": float(np.percentile(lat, 50)),
                    "latency_p99": float(np.percentile(lat, 99)),
                    "latency_max": float(lat.max()),
                    "wall_time": rec["wall_time"],
                    **layouts.reflex_status(self.reflex_plant.reflex),
                }
            )
        )

    def results(self, rec: dict, fault_windows: FaultWindows = ()) -> tuple[dict, dict]:
        """(summary, log arrays): the study metrics (same code as the runner) and the timing;
        the log has the runner's arrays plus, per cycle, ``mode`` (LowLevelMode),
        ``cycle_latency`` (s; inf for a missed cycle), ``command_arrival`` (the cycle at which the
        command solved from this cycle was taken, −1 for none), ``missed`` (the loop missed
        the cycle: the plant stepped under the held torque, :meth:`run`) and ``v`` (the true
        joint velocity, rad/s: where :meth:`safety`'s velocity ratios come from)."""
        true, measured = polishing_run_metrics(rec["log"], self.task, rec["table_normal"])
        timing = timing_report(
            time_step=self.time_step,
            every=self.every,
            cycle_latency=rec["cycle_latency"],
            modes=rec["mode"],
            command_arrival=rec["command_arrival"],
            command_latency=rec["command_latency"],
            solve_times=rec["solve_times"],
            fault_windows=fault_windows,
        )
        timing["mpc_fixed_latency_cycles"] = self.every
        timing["pid_delay_line_cycles"] = self.modelled_delay_cycles
        timing["pid_stale_timeout_s"] = self.stale_timeout
        timing["mode_cycles"] = {
            m.name.lower(): int(np.count_nonzero(rec["mode"] == int(m))) for m in LowLevelMode
        }
        timing["rejected"] = rec["rejected"]
        timing["loop"]["missed_cycles"] = int(np.count_nonzero(rec["missed"]))
        arrays = dict(rec["log"])
        for name in ("mode", "cycle_latency", "command_arrival", "missed", "v"):  # per cycle
            arrays[name] = rec[name]
        summary = {
            "formulation": self.scenario.mpc.ocp.formulation,
            "seed": self.scenario.seed,
            "cycles": self.steps,
            "metrics_true": true.to_dict(),
            "metrics_measured": measured.to_dict(),
            "contact_time_s": rec["contact_time"],  # the guarded approach's detection, s
            "wall_time_s": rec["wall_time"],
            "timing": timing,
            "safety": self.safety(rec) | ({"faults": rec["stalls"]} if rec["stalls"] else {}),
        }
        return summary, arrays

    def safety(self, rec: dict) -> dict:
        """The run's joint-limit ratios (as the lockstep graph's summary): per joint the largest
        |q̇|/velocity limit, |τ^m|/torque limit (the PID's motor torque) and |τ̂|/torque limit
        (the actuation output), the times of the largest (s), the time in the safe hold (s:
        hold and fallback cycles), the commands the velocity guard dropped (0 with it off), and
        the robot's reflexes: ``aborted`` (a reflex stopped the robot) and ``reflex``
        (:meth:`ffmpc_core.reflex.RobotReflex.report`)."""
        robot, dt = self.robot, self.time_step
        velocity, k_velocity = limit_ratios(rec["v"], robot.velocity_limit)
        torque, k_torque = limit_ratios(rec["tau_motor"], robot.torque_limit)
        applied, _ = limit_ratios(rec["tau_measured"], robot.torque_limit)
        hold = np.isin(rec["mode"], [int(LowLevelMode.HOLD), int(LowLevelMode.FALLBACK)])
        return {
            "max_velocity_ratio": [float(x) for x in velocity],
            "max_torque_ratio": [float(x) for x in torque],
            "max_applied_torque_ratio": [float(x) for x in applied],
            "max_velocity_ratio_at_s": None if k_velocity is None else k_velocity * dt,
            "max_torque_ratio_at_s": None if k_torque is None else k_torque * dt,
            "safe_hold_s": float(np.count_nonzero(hold) * dt),
            "velocity_guard_trips": self.lowlevel.velocity_guard_trips,
            "aborted": self.reflex_plant.stopped,
            "reflex": self.reflex_plant.reflex.report(),
        }

    def close(self) -> None:
        self.plant.close()
        for node in self.nodes.values():
            node.destroy_node()


def loop_main(argv: Sequence[str] | None = None) -> int:
    """The loop process: ``python -m ffmpc_ros.realtime --out PREFIX [--fault-window START END]...
    [--stall KIND@T+D]... [--mpc-pid PID] --ros-args --params-file FILE``. Writes PREFIX.json
    (summary) and PREFIX.npz (log)."""
    argv = list(sys.argv if argv is None else argv)
    parser = argparse.ArgumentParser(prog="ffmpc-realtime-loop", description=loop_main.__doc__)
    parser.add_argument("--out", required=True)
    parser.add_argument("--fault-window", nargs=2, type=float, action="append", default=[])
    parser.add_argument("--stall", action="append", default=[], help="loop-stall|mpc-stall@T+D")
    parser.add_argument("--mpc-pid", type=int, default=None)
    user = rclpy.utilities.remove_ros_args(argv)[1:]
    args = parser.parse_args(user)
    context = Context()
    rclpy.init(args=argv, context=context)
    # SIGINT (Ctrl-C, the bring-up's stop, the parent's death) and SIGTERM end the run at once
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    loop = None
    try:
        stalls = [parse_fault(text) for text in args.stall]
        require_kinds(stalls, REALTIME_KINDS, "the real-time loop")
        loop = RealtimeLoop(_params_from_args(argv), context, stalls, args.mpc_pid)
        loop.wait_for_mpc()
        raise_helper_threads()
        rec = loop.run()
        summary, log = loop.results(rec, [tuple(w) for w in args.fault_window])
        loop.publish_status(rec, summary["timing"])
        np.savez(args.out + ".npz", **log)
        with open(args.out + ".json", "w", encoding="utf-8") as fh:
            json.dump(summary, fh)
    except KeyboardInterrupt:
        return 130
    finally:
        if loop is not None:
            loop.close()
        with contextlib.suppress(Exception):
            rclpy.shutdown(context=context)
    return 0


def _params_from_args(argv: Sequence[str]) -> dict[str, dict]:
    """The node sections of the ``--params-file`` among ``argv`` (as the bring-up wrote it)."""
    import yaml

    path = argv[list(argv).index("--params-file") + 1]
    with open(path, encoding="utf-8") as fh:
        doc = yaml.safe_load(fh)
    out = {}
    for node in ("plant", "joint_sensor", "ft_sensor", "pid"):
        # keyed by the bare name, or by the fully qualified one under a namespace
        key = next(k for k in doc if k == node or k.rsplit("/", 1)[-1] == node)
        out[node] = flatten(doc[key]["ros__parameters"])
    return out


# -- the bring-up -------------------------------------------------------------------------------
@dataclass
class RealtimeRun:
    """What :func:`run_realtime` returns: the loop's summary and log, the processes' output."""

    summary: dict
    log: dict[str, np.ndarray] = field(repr=False)
    startup_time: float
    warnings: list[str]

    @property
    def metrics_true(self) -> PolishingMetrics:
        return PolishingMetrics(**self.summary["metrics_true"])

    @property
    def metrics_measured(self) -> PolishingMetrics:
        return PolishingMetrics(**self.summary["metrics_measured"])


def run_realtime(
    params: dict[str, dict],
    *,
    timeout: float = 600.0,
    domain: int = 0,
    quiet: bool = True,
    cpus: tuple[int, int] | None | str = "auto",
    priority: int = DEFAULT_PRIORITY,
    fault_windows: FaultWindows = (),
    stalls: Sequence[Fault] = (),
    namespace: str | None = None,
    mpc_ros_args: Sequence[str] = (),
) -> RealtimeRun:
    """Start the MPC process and the loop process, wait for the run, return its results.

    Args:
        params: ``graph_nodes.graph_parameters(scenario, lockstep=False, duration)``.
        cpus: (loop CPU, MPC CPU) to pin each process to ("auto": :func:`default_cpus`; None:
            let the kernel place them).
        priority: SCHED_FIFO priority of both processes (0: normal scheduling); where it is
            not permitted the run goes on with normal scheduling and a warning.
        fault_windows: (start, end) simulated s in which fallback is excused.
        stalls: ``loop-stall`` / ``mpc-stall`` faults the loop injects (their windows are the
            caller's to add to ``fault_windows``).
        namespace: ROS namespace of both processes' nodes (``topics.graph_ros_args``).
        mpc_ros_args: ROS arguments of the MPC process after the parameter file (``-p``
            ``NAME:=VALUE`` pairs, e.g. ``["-p", "real_time_iterations:=0"]``).
    """
    from ffmpc_ros.graph_nodes import NODES, write_params_file

    start = time.perf_counter()
    warnings: list[str] = []
    if cpus == "auto":
        cpus = default_cpus()
    elif isinstance(cpus, str):
        raise RealtimeError(f"cpus: 'auto', None or (loop CPU, MPC CPU), got {cpus!r}")
    with tempfile.TemporaryDirectory(prefix="ffmpc_rt_") as tmp:
        path = os.path.join(tmp, "graph_params.yaml")
        write_params_file({n: v for n, v in params.items() if n in NODES}, path, namespace)
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
        for name in THREAD_VARIABLES:  # one BLAS/OpenMP thread: no spinning helper threads
            env.setdefault(name, "1")
        # the publishing thread sends (no asynchronous sender thread to wait for)
        env.setdefault("RMW_FASTRTPS_PUBLICATION_MODE", "SYNCHRONOUS")
        out = os.path.join(tmp, "loop")
        ros = ["--ros-args", "--params-file", path, *topics.graph_ros_args(namespace)]
        faults = [a for w in fault_windows for a in ("--fault-window", str(w[0]), str(w[1]))]
        faults += [a for f in stalls for a in ("--stall", str(f))]
        commands = {
            "mpc": [sys.executable, "-m", "ffmpc_ros.mpc_node", *ros, *mpc_ros_args],
            "loop": [sys.executable, "-m", "ffmpc_ros.realtime", "--out", out, *faults, *ros],
        }
        children: dict[str, subprocess.Popen] = {}
        try:
            for name, cmd in commands.items():
                if name == "loop":  # (the MPC started first: the loop may stop it, mpc-stall)
                    cmd[-len(ros) : -len(ros)] = ["--mpc-pid", str(children["mpc"].pid)]
                log_file = open(os.path.join(tmp, f"{name}.log"), "w") if quiet else None  # noqa: SIM115
                child = subprocess.Popen(
                    cmd,
                    env=env,
                    stdout=log_file,
                    stderr=subprocess.STDOUT if quiet else None,
                    start_new_session=True,
                    preexec_fn=_die_with_parent,  # noqa: PLW1509  (the parent has no threads)
                )
                children[name] = child
                cpu = None if cpus is None else cpus[0 if name == "loop" else 1]
                warnings += apply_scheduling(child.pid, cpu, priority)
            end = start + timeout
            loop = children["loop"]
            while loop.poll() is None:
                if time.perf_counter() > end:
                    raise RealtimeError(f"the real-time run did not finish within {timeout} s")
                if children["mpc"].poll() is not None:
                    raise RealtimeError(
                        f"the MPC process exited with {children['mpc'].returncode}"
                        + _tail(tmp, "mpc", quiet)
                    )
                time.sleep(0.05)
            if loop.returncode != 0:
                raise RealtimeError(
                    f"the loop process exited with {loop.returncode}" + _tail(tmp, "loop", quiet)
                )
        finally:
            _stop(list(children.values()))
        with open(out + ".json", encoding="utf-8") as fh:
            summary = json.load(fh)
        with np.load(out + ".npz") as data:
            log = {k: data[k] for k in data.files}
    startup = time.perf_counter() - start - summary["wall_time_s"]
    return RealtimeRun(summary=summary, log=log, startup_time=startup, warnings=warnings)


def _tail(directory: str, name: str, quiet: bool) -> str:
    if not quiet:
        return ""
    try:
        with open(os.path.join(directory, f"{name}.log"), encoding="utf-8") as fh:
            return ":\n" + "".join(fh.readlines()[-15:])
    except OSError:
        return ""


def _stop(children: list[subprocess.Popen]) -> None:
    """SIGINT every child still running, then wait (SIGKILL after 5 s)."""
    for child in children:
        if child.poll() is None:
            child.send_signal(signal.SIGINT)
    deadline = time.monotonic() + 5.0
    for child in children:
        try:
            child.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


if __name__ == "__main__":
    raise SystemExit(loop_main())
