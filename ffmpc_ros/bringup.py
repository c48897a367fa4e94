"""Bring-up of the node graph: every node as its own process, or all in one process.

``run_graph(scenario)`` starts the plant, joint-sensor, F/T-sensor, MPC and PID nodes and the
metrics node, runs the scenario and returns the metrics (computed by the metrics node with the
runner's code). Multi-process (the default): each node is a child process started as
``python -m <module> --ros-args --params-file <scenario file> --params-file <generated file>``;
the metrics node runs in this process. Single-process: all nodes in this process on one
``EventsExecutor``.

The scenario file (``Scenario.source``, copied as it is) gives each node its own section and
``/**``; the generated parameter file after it gives the rest of each node's parameters
(``ffmpc_ros.graph_nodes.write_graph_params``): the other-section values it declares
(``ffmpc_ros.params``), the values the run changed, ``lockstep``, ``duration`` and the other
graph parameters. A scenario built in code has no file: the generated file then holds every
value. Every process gets the caller's environment: set
``ROS_DOMAIN_ID`` (and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) to isolate a run.

Namespace (``namespace="/arm1"``, ``ffmpc run --namespace /arm1``): every node of the graph —
the children, the in-process nodes, the bring-up's own probe, the metrics node and the
recorder — runs under it with ``-r __ns:=/arm1 -r /clock:=clock``
(:func:`ffmpc_ros.topics.graph_ros_args`): the graph's relative names resolve to
``/arm1/plant/joint_states``, ... and its clock to ``/arm1/clock``, so two graphs run side by side
on one ROS domain. The generated parameter file keys each node by its fully qualified name.

Safety of the run itself (lockstep):

* Foreign publishers: before starting anything, the bring-up looks for publishers on the graph's
  topics (:data:`ffmpc_ros.topics.TOPICS`) for :data:`FOREIGN_DISCOVERY_WAIT` wall s; any is
  foreign (another graph on the domain, leftovers of a killed run) and the run is refused with
  their node names, unless ``allow_foreign``.
* Shared parameters: once the nodes are up and before the plant may start (the metrics node,
  whose readiness the plant waits for, is only created after this check), every node's
  parameters are read (the recorder's ``list_parameters``/``get_parameters`` fetch) and a
  parameter declared by several nodes with different values stops the run, naming both nodes
  and both values.
* Children: one process group of their own (Ctrl-C in a terminal reaches only the bring-up,
  which stops them); each is started through a launcher that sets PR_SET_PDEATHSIG (SIGKILL for
  the nodes, SIGTERM for the recorder, which then finalises the bag) and exits if the bring-up
  is already gone, so killing the bring-up, even with SIGKILL, leaves no process behind. A node
  that dies takes the run down with its name, exit status and the last lines of its log.
* Progress watchdog: no new plant cycle for ``stall_timeout`` wall s (``start_timeout`` before
  the first one) stops the run with what each stage last did.
* Recording (``record``): the recorder runs in its own child process
  (``ffmpc_ros.bag.recorder.graph_recorder_process``) and closes the bag on SIGINT/SIGTERM or
  once the run is complete.
* Live view (``view``: a port): the view node (``ffmpc_ros.view``, a Foxglove WebSocket server
  on ``view_host:view``) runs in its own child process; a busy port is refused before anything
  starts, the plant waits for the view's subscription to ``/plant/joint_states``, and with
  ``record`` the recorder also waits for ``/robot_description``, ``/view/markers`` and
  ``/mpc/prediction`` so the bag holds them from the first cycle. Lockstep only.
* Faults (``faults``): injected by the bring-up at the simulated time it sees
  (``ffmpc_ros.fault_injector``); the summary gains ``max_velocity_ratio`` and
  ``max_torque_ratio`` (per joint, max over the run of |q̇|/limit with the plant's true q̇ from
  ``/plant/joint_states``, and |τ^m|/limit with the motor torque commanded on
  ``/pid/motor_torque``), ``max_applied_torque_ratio`` (the torque the simulated actuation of
  eq 31 applies, gain error and friction included), ``safe_hold_s``, ``faults`` and
  ``rejected_messages`` (per node, per kind).
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import rclpy
from rclpy.client import Client
from rclpy.context import Context
from rclpy.executors import Executor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_core.faults import Fault, faults_from
from ffmpc_core.lowlevel import LowLevelMode
from ffmpc_core.metrics import PolishingMetrics
from ffmpc_core.robots import RobotModel, load_robot
from ffmpc_core.scenario import Scenario
from ffmpc_ros import layouts, topics
from ffmpc_ros.discovery import domain_id as _env_domain_id
from ffmpc_ros.graph_nodes import (
    METRICS_NODE,
    NODES,
    SERVICE_RETRY,
    graph_parameters,
    load_node_class,
    node_table,
    split_parameter_args,
    write_graph_params,
)
from ffmpc_ros.node_results import read_node_results
from ffmpc_ros.params import parameter_overrides

if TYPE_CHECKING:
    from ffmpc_ros.base import GraphNode

#: Wall s the bring-up listens for foreign publishers on the graph's topics before starting.
FOREIGN_DISCOVERY_WAIT = 2.0
#: s of discovery given, after a node refused a bring-up transition, to show that another graph's
#: node of the same name answered (only on that failure path, so a long wait costs a working
#: start nothing; 2 s missed it on a loaded 2-core machine, the refusal then read as the node's own)
CLASH_DISCOVERY_WAIT = 10.0
#: At most this many wall s, from the first foreign node seen, to gather the others' names.
FOREIGN_GATHER_MAX = 6.0
#: Default wall s without a new plant cycle before a lockstep run is stopped.
STALL_TIMEOUT = 30.0
#: Default wall s from the start to the first plant cycle (imports, MPC warm-up, discovery).
START_TIMEOUT = 180.0
#: Lines of a dead node's log shown in the error.
LOG_TAIL = 8
#: Simulated s after an injected fault during which fallback and missed MPC deadlines are
#: excused too (the nodes catch up with the messages queued while one was stopped).
FAULT_RECOVERY = 0.05
#: Wall s after the plant's last state before a run with faults fills the missing measurements.
FILL_GRACE = 2.0
#: The launcher of every child: die with the bring-up (PR_SET_PDEATHSIG), refuse to start if it
#: is already gone, then run the module as ``python -m`` would. argv: marker, signal, module, args.
_LAUNCHER = (
    "import ctypes, os, runpy, sys\n"
    "marker, sig, module = sys.argv[1:4]\n"
    "ctypes.CDLL(None, use_errno=True).prctl(1, int(sig), 0, 0, 0)\n"
    "if os.getppid() != int(marker.rpartition('=')[2]): sys.exit(1)\n"
    "sys.argv = [module, *sys.argv[4:]]\n"
    "runpy.run_module(module, run_name='__main__', alter_sys=True)\n"
)


class GraphError(FfmpcError):
    """The graph did not finish (a node died, or the wall-time limit passed)."""


class RunInterrupted(BaseException):  # noqa: N818  (like KeyboardInterrupt)
    """SIGINT/SIGTERM asked the run to stop (raised from the run's loop, never from a
    callback: see :func:`request_stop`)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


_STOP: list[int] = []


def request_stop(signum: int) -> None:
    """Signal handler side: ask the running graph to stop; the loop raises RunInterrupted."""
    _STOP.append(signum)


def _check_stop() -> None:
    if _STOP:
        raise RunInterrupted(_STOP[0])


def child_marker(parent_pid: int | None = None) -> str:
    """The argument in the command line of every child of the bring-up ``parent_pid``."""
    return f"--ffmpc-bringup={os.getpid() if parent_pid is None else parent_pid}"


@dataclass
class GraphResult:
    """Outcome of a graph run: the metrics (true and measured force), the log, timing."""

    formulation: str
    seed: int
    single_process: bool
    lockstep: bool
    namespace: str
    metrics_true: PolishingMetrics
    metrics_measured: PolishingMetrics
    log: dict[str, np.ndarray] = field(repr=False)
    sim_time: float = 0.0
    wall_time: float = 0.0  # from the first plant step to the last recorded cycle, s
    startup_time: float = 0.0  # from the call to the first plant step, s
    plant_status: dict | None = None
    bag: dict | None = None  # with ``record``: path and messages recorded per topic
    view: dict | None = None  # with ``view``: address and messages forwarded per topic
    timing: dict | None = None  # deadlines met, fallback time, latencies (module docstring)
    warnings: list[str] = field(default_factory=list)
    safety: dict | None = None  # ratios, safe_hold_s; lockstep also faults, rejected_messages
    plant_engine: str = "pybullet"  # the plant's simulator (plant.engine)

    @property
    def real_time_factor(self) -> float:
        """Simulated time / wall time of the stepping (> 1: faster than real time)."""
        return self.sim_time / self.wall_time if self.wall_time > 0 else float("inf")

    def timing_failures(self, max_missed: float | None = None) -> list[str]:
        """Why this run's timing fails (empty: it passes), ``ffmpc_ros.realtime``'s rule."""
        from ffmpc_ros.realtime import MAX_MISSED_FRACTION, timing_failures

        if self.timing is None:
            return ["no timing statistics"]
        limit = MAX_MISSED_FRACTION if max_missed is None else max_missed
        return timing_failures(self.timing, limit)

    def summary(self) -> dict:
        timing = self.timing or {}
        return {
            "mode": "lockstep" if self.lockstep else "real_time",
            "plant_engine": self.plant_engine,
            "formulation": self.formulation,
            "seed": self.seed,
            "single_process": self.single_process,
            "lockstep": self.lockstep,
            "namespace": self.namespace,
            "metrics_true": self.metrics_true.to_dict(),
            "metrics_measured": self.metrics_measured.to_dict(),
            "sim_time_s": self.sim_time,
            "wall_time_s": self.wall_time,
            "real_time_factor": self.real_time_factor,
            "plant_status": self.plant_status,
            **{key: timing.get(key) for key in TIMING_KEYS},
            "timing": timing,
            **({"bag": self.bag} if self.bag is not None else {}),
            **({"view": self.view} if self.view is not None else {}),
            **(self.safety or {}),
        }

    @property
    def aborted(self) -> bool:
        """A reflex of the robot stopped it (``ffmpc_core.reflex``): the run was aborted."""
        return bool((self.safety or {}).get("aborted", False))

    @property
    def reflex_event(self) -> dict | None:
        """The reflex's event of the run (``ReflexEvent.to_dict``), None without a crossing."""
        reflex = (self.safety or {}).get("reflex") or {}
        event: dict | None = reflex.get("event")
        return event

    def limit_failures(self) -> list[str]:
        """Joint velocity or torque limits broken (ratio > 1), one line per joint."""
        out = []
        for key, what in (("max_velocity_ratio", "velocity"), ("max_torque_ratio", "torque")):
            for j, ratio in enumerate((self.safety or {}).get(key) or []):
                if ratio is None or not ratio <= 1.0:
                    out.append(f"joint {j + 1} {what} limit broken: max |{what}|/limit = {ratio}")
        return out


def reflex_summary(status: Mapping[str, float] | None, joint_names: Sequence[str]) -> dict:
    """``aborted`` and ``reflex`` (enabled, aborted, the event: ``ReflexEvent.to_dict``) of a
    lockstep graph run, from the plant's newest ``/plant/status`` (``layouts.reflex_status``);
    an empty dict without a status."""
    if not status or "reflex_kind" not in status:
        return {}
    event = layouts.reflex_event_from_status(dict(status), list(joint_names))
    aborted = bool(status["reflex_stopped"])
    return {
        "aborted": aborted,
        "reflex": {
            "enabled": bool(status["reflex_enabled"]),
            "aborted": aborted,
            "event": None if event is None else event.to_dict(),
        },
    }


#: Timing statistics copied to the top level of a run's summary (``ffmpc run --json``).
TIMING_KEYS = (
    "deadline_met_fraction",
    "fallback_time_s",
    "latency_p50_ms",
    "latency_p99_ms",
    "latency_max_ms",
)


def graph_context(namespace: str, domain: int) -> tuple[Context, Executor]:
    """A bring-up's own rclpy context (in the graph's namespace, on its clock; no signal
    handlers: the bring-up stops the run itself) and its executor."""
    context = Context()
    rclpy.init(
        args=["ffmpc", "--ros-args", *topics.graph_ros_args(namespace)],
        context=context,
        domain_id=domain,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    return context, EventsExecutor(context=context)


def print_logs(logs: Mapping[str, str]) -> None:
    """Each child's log file on stderr (``quiet=False``)."""
    for name, path in logs.items():
        with contextlib.suppress(OSError), open(path, encoding="utf-8") as fh:
            sys.stderr.write(f"--- {name} ({path}) ---\n{fh.read()}")


class ProgressWatch:
    """The lockstep watchdog: GraphError when no new plant cycle came for ``stall_timeout``
    wall s (``start_timeout`` from ``start``, a ``time.perf_counter()``, before the first one).

    Attributes: last_cycle, last_progress (wall s of the newest new cycle), first_step (wall s
    of the first cycle seen, None before)."""

    def __init__(self, start: float, stall_timeout: float, start_timeout: float) -> None:
        self.start, self.stall_timeout, self.start_timeout = start, stall_timeout, start_timeout
        self.last_cycle = -1
        self.last_progress = time.perf_counter()
        self.first_step: float | None = None

    def check(self, cycle: int, now: float, progress: Callable[[], str]) -> None:
        """The newest plant cycle seen at wall time ``now``; ``progress()``: what each stage
        last did, for the error."""
        if cycle > self.last_cycle:
            if self.first_step is None and cycle >= 0:
                self.first_step = now
            self.last_cycle, self.last_progress = cycle, now
            return
        started = self.last_cycle >= 0
        limit = self.stall_timeout if started else self.start_timeout
        since = now - (self.last_progress if started else self.start)
        if since > limit:
            what = "no simulated progress" if started else "the run did not start"
            raise GraphError(f"{what} for {since:.1f} s (wall; limit {limit:g} s): {progress()}")


class _StatusProbe:
    """Keeps the newest /plant/status; from ``/plant/joint_states`` (true q̇ and the torque
    applied): the newest cycle and the max over the run of |q̇|/limit and |τ|/limit per joint."""

    def __init__(
        self,
        node: Node,
        robot: RobotModel | None = None,
        time_step: float = 1e-3,
        on_cycle: Callable[[int], None] | None = None,
        motor_topic: str = topics.MOTOR_TORQUE,
    ) -> None:
        self.status: dict | None = None
        self.cycle = -1
        self.time_step = time_step
        self.on_cycle = on_cycle
        node.create_subscription(
            Float64MultiArray,
            topics.PLANT_STATUS,
            self._on,
            topics.subscriber_qos(False, topics.PLANT_STATUS),
        )
        if robot is not None:  # the limit ratios (the joint subscriptions below need a robot)
            self.velocity_limit, self.torque_limit = robot.velocity_limit, robot.torque_limit
            self.max_velocity_ratio = np.zeros(robot.nv)
            self.max_torque_ratio = np.zeros(robot.nv)  # the commanded motor torque τ^m
            self.max_applied_torque_ratio = np.zeros(robot.nv)  # τ̂ of eq 31 (actuation errors)
            self.worst_velocity_t: float | None = None  # s, when the overall max occurred
            self.worst_torque_t: float | None = None
            node.create_subscription(
                JointState,
                topics.PLANT_JOINT_STATES,
                self._on_joints,
                topics.graph_qos(topics.PLANT_JOINT_STATES, "subscription"),
            )
            node.create_subscription(
                JointState,
                motor_topic,  # the low level's τ^m (pid/motor_torque, or lfc/effort)
                self._on_motor,
                topics.graph_qos(motor_topic, "subscription"),
            )

    def _on(self, msg: Float64MultiArray) -> None:
        self.status = layouts.PLANT_STATUS.unpack(msg)

    def _on_motor(self, msg: JointState) -> None:
        """|τ^m|/limit of the motor torque the PID commands (what the controllers answer for)."""
        tau = np.abs(np.asarray(msg.effort, dtype=float)) / self.torque_limit
        if tau.shape == self.max_torque_ratio.shape:
            tau = np.nan_to_num(tau, nan=np.inf)
            if tau.max() > self.max_torque_ratio.max():
                stamp = msg.header.stamp
                self.worst_torque_t = (stamp.sec * 1_000_000_000 + stamp.nanosec) * 1e-9
            self.max_torque_ratio = np.maximum(self.max_torque_ratio, tau)

    def _on_joints(self, msg: JointState) -> None:
        ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        k = int(round(ns * 1e-9 / self.time_step))
        v = np.abs(np.asarray(msg.velocity, dtype=float)) / self.velocity_limit
        tau = np.abs(np.asarray(msg.effort, dtype=float)) / self.torque_limit
        if v.shape == self.max_velocity_ratio.shape and tau.shape == v.shape:
            # a NaN state counts as a broken limit (inf)
            v, tau = np.nan_to_num(v, nan=np.inf), np.nan_to_num(tau, nan=np.inf)
            if v.max() > self.max_velocity_ratio.max():
                self.worst_velocity_t = k * self.time_step
            self.max_velocity_ratio = np.maximum(self.max_velocity_ratio, v)
            self.max_applied_torque_ratio = np.maximum(self.max_applied_torque_ratio, tau)
        if k > self.cycle:
            self.cycle = k
            if self.on_cycle is not None:
                self.on_cycle(k)


class _PidStatusProbe:
    """Lockstep: the torque loop's mode and command age of every cycle (``/pid/status``)."""

    def __init__(
        self, node: Node, steps: int, time_step: float, topic: str = topics.LOWLEVEL_STATUS
    ) -> None:
        self.time_step = time_step
        self.mode = np.full(steps, -1, dtype=np.int8)
        self.command_age = np.full(steps, np.nan)
        self.last_cycle = -1
        node.create_subscription(
            Float64MultiArray,
            topic,  # the low level's status (pid/status, or lfc/status: same layout)
            self._on,
            topics.graph_qos(topic, "subscription"),
        )

    def _on(self, msg: Float64MultiArray) -> None:
        try:
            status = layouts.LOWLEVEL_STATUS.unpack(msg)
        except FfmpcError:
            return
        k = int(round(status["t"] / self.time_step))
        self.last_cycle = max(self.last_cycle, k)
        if 0 <= k < self.mode.size:
            self.mode[k] = int(status["mode"])
            self.command_age[k] = status["command_age"]

    @property
    def complete(self) -> bool:
        return bool(np.all(self.mode >= 0))

    def timing(
        self, every: int, plant_status: dict | None, fault_windows: Sequence[tuple[float, float]]
    ) -> dict[str, Any]:
        """Lockstep timing (simulated-time deadlines, see the module docstring)."""
        from ffmpc_ros.realtime import fallback_time

        steps = self.mode.size
        ticks = np.arange(0, steps, every)
        # MPC deadlines inside a fault window are not counted
        t_ticks = ticks * self.time_step
        excused = np.zeros(ticks.size, dtype=bool)
        for start, end in fault_windows:
            excused |= (t_ticks >= start) & (t_ticks < end)
        ticks = ticks[~excused]
        heard = self.mode[ticks] >= 0
        on_time = heard & (np.abs(self.command_age[ticks]) < 0.5 * self.time_step)
        misses = int(plant_status.get("deadline_misses", steps)) if plant_status else steps
        known = np.where(self.mode >= 0, self.mode, int(LowLevelMode.HOLD))  # unheard: no fallback
        unexcused, excused_time = fallback_time(known, self.time_step, fault_windows)
        lat = {
            name: (plant_status[f"latency_{name}"] * 1e3 if plant_status else None)
            for name in ("p50", "p99", "max")
        }
        heard_ticks = int(np.count_nonzero(heard))
        return {
            "deadline_met_fraction": {  # over the ticks whose status arrived
                "mpc": float(np.count_nonzero(on_time)) / heard_ticks if heard_ticks else None,
                "loop": 1.0 - misses / steps,
            },
            "fallback_time_s": unexcused,
            "fallback_excused_s": excused_time,
            "fault_windows": [list(map(float, w)) for w in fault_windows],
            "latency_p50_ms": lat["p50"],
            "latency_p99_ms": lat["p99"],
            "latency_max_ms": lat["max"],
            "status_cycles": int(np.count_nonzero(self.mode >= 0)),
            "excused_mpc_ticks": int(np.count_nonzero(excused)),
            "unobserved_ticks": int(ticks.size - heard_ticks),
            "mode_cycles": {
                m.name.lower(): int(np.count_nonzero(self.mode == int(m))) for m in LowLevelMode
            },
            "definition": "lockstep: simulated-time deadlines (ffmpc_ros.bringup)",
        }


@dataclass(frozen=True)
class GraphOptions:
    """How :func:`run_graph` runs a scenario; the defaults are ``ffmpc run``'s.

    What runs:
        duration: simulated time, s (None: the task's duration).
        single_process: all nodes in this process on one executor.
        lockstep: lockstep (True) or real-time (False) plant.
        namespace: ROS namespace of the whole graph (module docstring; None: the root).
        interfaces: the topics between the MPC, the low level and the plant: ``"ffmpc"``
            (its own) or ``"ros2_control"`` (linear_feedback_controller_msgs Control/Sensor,
            the effort command topic; ``ffmpc_ros.topics.ROS2_CONTROL_TOPICS``). Lockstep
            only, without record, view or faults (ConfigError).
        low_level: the low-level node: ``"pid"`` (ffmpc's torque PID) or ``"lfc"`` (the
            linear_feedback_controller's law, ``ffmpc_ros.lfc_node``; ros2_control only).
        node_ros_args: multi-process: extra ROS arguments per node, after the parameter files
            (e.g. ``{"pid": ["-p", "kp:=0.2"]}``: a ``-p`` value goes into the node's section
            of the run's file, ``graph_nodes.split_parameter_args``); one that sets a scenario
            value other nodes take too is refused (:func:`check_unshared`). Real time: the
            ``mpc`` node's only (the MPC process; the loop process composes the other nodes
            from the file).

    Where, and for how long:
        domain_id: ROS domain of this run (default: ROS_DOMAIN_ID or 0).
        allow_foreign: start even if other publishers are on the graph's topics.
        timeout: wall-time limit, s (GraphError beyond).
        stall_timeout: lockstep: wall s without a new plant cycle before GraphError.
        start_timeout: lockstep: wall s from the call to the first plant cycle.
        quiet: multi-process: the children's output stays in their log files (otherwise each
            log is printed to stderr once the run ends).

    Faults:
        faults: faults to inject (``Fault`` or ``KIND[:NODE]@T[+DURATION]``;
            ``ffmpc_ros.fault_injector``); ConfigError for a kind the mode cannot inject.
        fault_windows: (start, end) simulated s of external faults: fallback inside them is
            excused (every ``faults`` entry adds its own window).

    Outputs:
        record: record the run into this MCAP bag (must not exist): every topic and every
            node's parameters; the plant then also waits for the recorder to see the graph.
        view: serve the live view (Foxglove WebSocket) on this port of ``view_host`` (None:
            no view); ViewError when the port is busy.
        view_host: the live view's address.
        view_wait: the run starts only once a Foxglove client subscribes to
            ``/plant/joint_states`` (``start_timeout`` still applies).

    Real time:
        cpus: (loop CPU, MPC CPU) to pin the two processes to ("auto": the first two CPUs;
            None: no pinning).
        priority: SCHED_FIFO priority of both processes (None: ``realtime.DEFAULT_PRIORITY``;
            0: normal scheduling).
    """

    duration: float | None = None
    single_process: bool = False
    lockstep: bool = True
    namespace: str | None = None
    interfaces: str = topics.FFMPC_INTERFACES
    low_level: str = "pid"
    node_ros_args: Mapping[str, Sequence[str]] | None = None
    domain_id: int | None = None
    allow_foreign: bool = False
    timeout: float = 600.0
    stall_timeout: float = STALL_TIMEOUT
    start_timeout: float = START_TIMEOUT
    quiet: bool = True
    faults: Sequence[Fault | str] = ()
    fault_windows: Sequence[tuple[float, float]] = ()
    record: str | os.PathLike | None = None
    view: int | None = None
    view_host: str = "127.0.0.1"
    view_wait: bool = False
    cpus: tuple[int, int] | None | str = "auto"
    priority: int | None = None


@dataclass
class GraphPlan:
    """What a run will start, checked before anything starts (:func:`plan_graph`)."""

    scenario: Scenario
    options: GraphOptions
    domain: int  # the ROS domain
    namespace: str  # normalised ("/" for the root)
    faults: tuple[Fault, ...]
    table: dict[str, str]  # node name → "module:class" (the metrics node apart)
    duration: float  # simulated s
    params: dict[str, dict[str, Any]]  # node → its parameters
    windows: list[tuple[float, float]]  # simulated s where fallback is excused


def plan_graph(scenario: Scenario, options: GraphOptions) -> GraphPlan:
    """Check ``options`` against each other and the mode (ConfigError, BagExistsError,
    ViewError: nothing has started) and work out every node's parameters."""
    from ffmpc_ros.fault_injector import FAULT_LOCKSTEP_TIMEOUT, PROCESS_KINDS, check_supported

    o = options
    faults = faults_from(o.faults)
    check_supported(faults, o.single_process, o.lockstep)
    table = node_table(o.interfaces, o.low_level)
    _check_options(o, table, faults)
    namespace = topics.normalize_namespace(o.namespace)
    duration = o.duration
    if duration is None:  # the task's, as the metrics node sees the scenario
        from ffmpc_core.polishing import build_task

        duration = build_task(scenario, load_robot(scenario.robot)).duration
    params = graph_parameters(scenario, o.lockstep, duration, namespace, o.interfaces, o.low_level)
    windows = [(float(start), float(end)) for start, end in o.fault_windows]
    # an injected fault's effects outlast it a little (queued messages): FAULT_RECOVERY
    windows += [(f.start, min(f.end + FAULT_RECOVERY, float(duration))) for f in faults]
    if o.lockstep:
        if any(f.kind in PROCESS_KINDS for f in faults):
            params[o.low_level]["lockstep_timeout"] = FAULT_LOCKSTEP_TIMEOUT
        # the bring-up's probe (_StatusProbe) reads the joint states too, and subscribes before
        # the metrics node exists, whose readiness the plant waits for: without counting it, the
        # plant could start with the probe in the recorder's place, before the recorder's gate
        # opened (a bag then lacked /plant/joint_states and the MPC's parameters, seen once in
        # four runs); the recorder and the view are more subscribers the plant waits for
        params["plant"]["start_subscribers"] += 1 + (o.record is not None) + (o.view is not None)
        # and it reads /clock twice: the topic it records and its time source (simulated log
        # times); every node's side of the start barrier counts them (its writers wait for the
        # recorder's readers too: ffmpc_ros.start_barrier.StartBarrier.writers_matched)
        for values in params.values():
            values["start_clock_subscribers"] += 2 * (o.record is not None)
    domain = _env_domain_id() if o.domain_id is None else o.domain_id
    return GraphPlan(scenario, o, domain, namespace, faults, table, duration, params, windows)


def _check_options(o: GraphOptions, table: Mapping[str, str], faults: Sequence[Fault]) -> None:
    """ConfigError for options that do not go together (BagExistsError, ViewError: the bag
    exists, the view's port is busy)."""
    if o.interfaces != topics.FFMPC_INTERFACES and (
        not o.lockstep or o.record is not None or o.view is not None or faults
    ):
        raise ConfigError(
            "interfaces='ros2_control' runs the lockstep graph only (no real time, record, "
            "view or faults yet)"
        )
    if o.node_ros_args and (
        o.single_process or (not o.lockstep and set(o.node_ros_args) - {"mpc"})
    ):
        raise ConfigError(
            "per-node ROS arguments need the multi-process graph (real time: the mpc node's only)"
        )
    unknown = sorted(set(o.node_ros_args or {}) - set(table))
    if unknown:
        raise ConfigError(
            f"per-node ROS arguments for unknown nodes {unknown}; nodes: {list(table)}"
        )
    check_unshared(o.node_ros_args or {}, [*table, "metrics"])
    for args in (o.node_ros_args or {}).values():
        split_parameter_args(args)  # ConfigError for a malformed -p
    if not o.lockstep:
        if o.single_process or o.record is not None or o.view is not None:
            raise ConfigError(
                "real time runs the loop nodes and the MPC node as two processes (one "
                "interpreter each, see ffmpc_ros.realtime); --single-process, --record and "
                "--view are lockstep options"
            )
        return
    if o.record is not None and os.path.exists(o.record):
        from ffmpc_ros.bag.errors import BagExistsError

        raise BagExistsError(f"{o.record} exists; a bag is never overwritten")
    if o.view is not None:
        from ffmpc_ros.view import check_port_free

        check_port_free(o.view_host, o.view)


def run_graph(scenario: Scenario, options: GraphOptions | None = None) -> GraphResult:
    """Run ``scenario`` on the node graph and return the metrics node's result.

    The steps (each its own function or :class:`GraphSession` method): :func:`plan_graph`
    (check, parameters), :meth:`GraphSession.spawn` (processes or in-process nodes, the view,
    the recorder), :meth:`GraphSession.bring_up` (configure, then activate, the plant last),
    :meth:`GraphSession.watch` (fault injector, probes, the metrics node), :meth:`GraphSession.run`,
    :meth:`GraphSession.stop` (whatever happened) and :meth:`GraphSession.collect`."""
    options = GraphOptions() if options is None else options
    start = time.perf_counter()
    plan = plan_graph(scenario, options)
    if not options.lockstep:
        return _run_real_time(plan)
    session = GraphSession(plan, start)
    try:
        session.spawn()
        session.bring_up()
        session.watch()
        session.run()
    finally:
        outputs = session.stop()
        failure = sys.exc_info()[1]
        if isinstance(failure, GraphError) and outputs.view is not None and failure.args:
            # a run that waited for a Foxglove client: say what the view still waited for
            failure.args = (f"{failure.args[0]}; the view: {outputs.view.get('started')}",)
    return session.collect(outputs)


@dataclass
class GraphOutputs:
    """What a stopped graph leaves: rejections per node process, the view's report, the bag's
    (``stop``)."""

    rejected: dict[str, dict] = field(default_factory=dict)
    view: dict | None = None
    bag: dict[str, Any] | None = None


class NodeSession:
    """What every lockstep run of node processes shares (:class:`GraphSession` of the polishing
    graph, ``ffmpc_ros.impact_graph.ImpactSession``): the bring-up's own ROS context in the
    graph's namespace and domain, its probe node, the child processes and their logs in a
    temporary directory.

    Its steps: :meth:`open_probe`, :meth:`spawn_nodes` and :meth:`spawn_recorder`,
    :meth:`bring_up_nodes`, then always :meth:`release` (and ``tmp.cleanup()`` once what the
    children left there is read)."""

    def __init__(self, namespace: str, domain: int, start: float, prefix: str) -> None:
        self.namespace, self.domain = namespace, domain
        self.start = start  # wall s (perf_counter) the run was asked for
        # every node of this context (probe, metrics, single-process nodes, recorder) in the
        # graph's namespace, on the graph's clock
        self.context, self.executor = graph_context(namespace, domain)
        self.nodes: list[Node] = []  # destroyed by release
        self.children: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, str] = {}
        self.tmp = tempfile.TemporaryDirectory(prefix=prefix)
        self.probe_node: Node | None = None
        self.counts_path: str | None = None  # the recorder process's report

    def _add(self, node: Node) -> None:
        self.nodes.append(node)
        self.executor.add_node(node)

    def open_probe(self, allow_foreign: bool) -> Node:
        """The bring-up's own node ``ffmpc_bringup``; GraphError when other nodes already
        publish on the graph's topics (:func:`_refuse_foreign`), unless ``allow_foreign``."""
        self.probe_node = Node("ffmpc_bringup", context=self.context)
        self._add(self.probe_node)
        if not allow_foreign:
            _refuse_foreign(self.probe_node, self.domain, self.namespace)
        return self.probe_node

    def spawn_nodes(
        self,
        params: dict[str, dict[str, Any]],
        table: Mapping[str, str],
        node_ros_args: Mapping[str, Sequence[str]] | None = None,
        scenario_file: str = "",
    ) -> None:
        """One child process per node of ``table`` (name → "module:class"), given the
        ``scenario_file`` (if any) and its parameters of ``params`` (:func:`_spawn`)."""
        children, logs = _spawn(
            params,
            self.tmp.name,
            self.domain,
            node_ros_args or {},
            self.namespace,
            table,
            scenario_file,
        )
        self.children.update(children)
        self.logs.update(logs)

    def spawn_recorder(self, record: str | os.PathLike, config: Mapping[str, Any]) -> None:
        """The recorder's own process (``ffmpc_ros.bag.recorder.graph_recorder_process``)
        recording into ``record``, with the graph's ``config`` entries (its metadata, ...)."""
        self.counts_path = os.path.join(self.tmp.name, "recorder_counts.json")
        full = {
            "target": os.fspath(record),
            "domain": self.domain,
            "ros_args": topics.graph_ros_args(self.namespace),
            "namespace": self.namespace,
            **config,
            "counts": self.counts_path,
        }
        self.children["recorder"], self.logs["recorder"] = _spawn_child(
            "recorder", "ffmpc_ros.bag.recorder", full, self.tmp.name, self.domain
        )

    def bring_up_nodes(self, names: Sequence[str], start_timeout: float, plant: str) -> None:
        """Configure, then activate, the child nodes ``names``, ``plant`` last
        (:func:`_bring_up`), by ``start_timeout`` wall s after the start."""
        assert self.probe_node is not None  # (open_probe)
        deadline = self.start + start_timeout
        _bring_up(self.probe_node, self.executor, names, self.children, self.logs, deadline, plant)

    def turn(
        self,
        watch: ProgressWatch,
        cycle: int,
        now: float,
        progress: Callable[[], str],
        killed: Iterable[str] = (),
    ) -> None:
        """One turn of a run's loop at wall time ``now`` with the plant at ``cycle``: GraphError
        for a dead child (but the ``killed`` ones) or a stall (``watch``; ``progress()`` says what
        each stage last did), then 50 ms of spinning; RunInterrupted on a stop request."""
        _check_children(self.children, self.logs, set(killed))
        watch.check(cycle, now, progress)
        self.executor.spin_once(timeout_sec=0.05)
        _check_stop()

    def release(self, quiet: bool) -> dict[str, dict]:
        """Stop the children, destroy the nodes, the executor and the context; the rejections
        the node processes wrote (:func:`rejected_from_results`). ``quiet=False``: every log
        printed to stderr."""
        _stop(self.children)
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown()
        rclpy.shutdown(context=self.context)
        rejected = rejected_from_results(self.tmp.name, self.logs)
        if not quiet:
            print_logs(self.logs)
        return rejected

    def bag_report(self, record: str | os.PathLike | None) -> dict[str, Any] | None:
        """The bag's path and the recorder process's counts (None without ``record``)."""
        if record is None:
            return None
        bag: dict[str, Any] = {"path": str(record)}
        if self.counts_path is not None:
            bag.update(_read_json(self.counts_path) or {})
        return bag


class GraphSession(NodeSession):
    """One lockstep run of a :class:`GraphPlan`: its ROS context, nodes, processes, probes.

    Call :meth:`spawn`, :meth:`bring_up`, :meth:`watch`, :meth:`run`, then always :meth:`stop`
    (it releases everything), then :meth:`collect`."""

    def __init__(self, plan: GraphPlan, start: float) -> None:
        super().__init__(plan.namespace, plan.domain, start, "ffmpc_graph_")
        self.plan = plan
        self.robot = load_robot(plan.scenario.robot)
        self.graph_nodes: list[GraphNode] = []  # single process: the graph's nodes
        self.view_node: Any = None
        self.view_counts: str | None = None
        self.injector: Any = None
        self.recorder: Any = None
        self.metrics: Any = None  # the metrics node (watch)
        self.probe: _StatusProbe  # the plant's (watch)
        self.pid_probe: _PidStatusProbe  # the low level's (watch)
        self.done = start  # wall s the metrics node finished

    def spawn(self) -> None:
        """The bring-up's probe node (and the foreign-publisher check), then the graph's nodes:
        in this process, or one child process each (with the view and the recorder)."""
        plan, o = self.plan, self.plan.options
        self.open_probe(o.allow_foreign)
        if o.single_process:
            for name, path in plan.table.items():
                overrides = parameter_overrides(plan.params[name])
                node = load_node_class(path)(context=self.context, parameter_overrides=overrides)
                self.graph_nodes.append(node)
                self._add(node)
            if o.view is not None:
                from ffmpc_ros.view import ViewNode

                self.view_node = ViewNode(
                    plan.scenario.robot,
                    host=o.view_host,
                    port=o.view,
                    context=self.context,
                    wait_for_client=o.view_wait,
                )
                self._add(self.view_node)
            return
        directory = self.tmp.name
        self.spawn_nodes(plan.params, plan.table, o.node_ros_args, plan.scenario.source)
        if o.view is not None:
            self.view_counts = os.path.join(directory, "view_counts.json")
            self.children["view"], self.logs["view"] = _spawn_view(
                plan.scenario.robot,
                o.view_host,
                o.view,
                directory,
                plan.domain,
                self.view_counts,
                o.view_wait,
                plan.namespace,
            )
        if o.record is not None:
            from ffmpc_ros.bag.recorder import graph_recorder_metadata

            metadata = graph_recorder_metadata(plan.scenario, plan.params, plan.namespace)
            # with the view, the recorder also writes /tf
            view = plan.scenario.robot if o.view is not None else None
            self.spawn_recorder(o.record, {"metadata": metadata, "view": view})

    def bring_up(self) -> None:
        """Configure, then activate, every child node, the plant last (:func:`_bring_up`); the
        in-process nodes started themselves."""
        if self.children:
            self.bring_up_nodes(list(self.plan.table), self.plan.options.start_timeout, "plant")

    def watch(self) -> None:
        """What the bring-up watches the run with: the fault injector, the plant and low-level
        probes, then the metrics node (the plant starts once it is ready: only now, after the
        checks) and the in-process recorder."""
        from ffmpc_ros.fault_injector import FaultInjector

        plan, o, probe_node = self.plan, self.plan.options, self.probe_node
        assert probe_node is not None
        time_step = plan.scenario.plant.time_step
        if plan.faults:
            self.injector = FaultInjector(probe_node, plan.faults, self.children, time_step)
            if self.injector.wants_sensors:
                _subscribe_injector(probe_node, self.injector)
        _, motor_topic, status_topic = topics.low_level_topics(o.low_level)
        on_cycle = None if self.injector is None else self.injector.on_cycle
        self.probe = _StatusProbe(probe_node, self.robot, time_step, on_cycle, motor_topic)
        self.metrics = load_node_class(METRICS_NODE)(
            context=self.context, parameter_overrides=parameter_overrides(plan.params["metrics"])
        )
        self.pid_probe = _PidStatusProbe(
            probe_node, self.metrics.steps, self.metrics.time_step, status_topic
        )
        self._add(self.metrics)
        if o.record is not None and o.single_process:
            from ffmpc_ros.bag.recorder import graph_recorder

            self.recorder = graph_recorder(
                o.record,
                context=self.context,
                scenario=plan.scenario,
                run=plan.params,
                namespace=plan.namespace,
                view=None if o.view is None else plan.scenario.robot,
            )
            self._add(self.recorder)

    def run(self) -> None:
        """Spin until the metrics node has every cycle (GraphError past the timeout, on a stall
        or a dead child), then until the plant's final status, the recorder and the low level's
        last status are in (at most 2 s more)."""
        o, metrics, probe = self.plan.options, self.metrics, self.probe
        end = self.start + o.timeout
        watch = ProgressWatch(self.start, o.stall_timeout, o.start_timeout)
        killed = set() if self.injector is None else self.injector.killed
        while not metrics.finished():
            now = time.perf_counter()
            if now > end:
                raise GraphError(
                    f"the graph did not finish within {o.timeout} s: {metrics.recorded} of "
                    f"{metrics.steps} cycles recorded; {self._progress()}"
                )
            if self.plan.faults and probe.cycle >= metrics.steps and metrics.metrics is None:
                # A stopped sensor loses measurements the metrics node waits for: once the
                # plant is done, fill them with the previous value (the real-time rule,
                # counted in metrics_filled) rather than wait forever.
                if now - watch.last_progress > FILL_GRACE:
                    metrics.finish_now()
            self.turn(watch, probe.cycle, now, self._progress, killed)
        self.done = time.perf_counter()
        # The final plant status (latencies, deadline misses) follows the last state.
        while (
            (probe.status is None or not probe.status["done"])
            or not (self.recorder is None or self.recorder.complete)
            or not self.pid_probe.complete
        ):
            if time.perf_counter() > self.done + 2.0:
                break
            self.executor.spin_once(timeout_sec=0.05)
            _check_stop()
        if "recorder" in self.children:  # it closes the bag once the metrics summary is in
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.children["recorder"].wait(timeout=10.0)

    def _progress(self) -> str:
        return _progress(self.probe, self.pid_probe, self.children)

    def stop(self) -> GraphOutputs:
        """Release the injected faults, stop the children, destroy the nodes and the context;
        what the run left (rejections, the view's report, the bag's counts)."""
        if self.injector is not None:
            self.injector.release()
        outputs = GraphOutputs({n.get_name(): dict(n.rejected) for n in self.graph_nodes})
        outputs.rejected.update(self.release(self.plan.options.quiet))
        if self.view_node is not None:
            outputs.view = self.view_node.report()
        elif self.view_counts is not None:
            outputs.view = _read_json(self.view_counts)
        record = self.plan.options.record
        if self.recorder is not None:  # in process
            outputs.bag = {"path": str(record), "received": self.recorder.received}
        else:
            outputs.bag = self.bag_report(record)
        self.tmp.cleanup()
        return outputs

    def collect(self, outputs: GraphOutputs) -> GraphResult:
        """The run's result: the metrics node's metrics and log, the probes' safety figures and
        timing, the rejections of every node."""
        from ffmpc_core.polishing import steps_per_mpc_period

        plan, metrics, probe, pid_probe = self.plan, self.metrics, self.probe, self.pid_probe
        scenario, time_step = plan.scenario, plan.scenario.plant.time_step
        rejected = {**outputs.rejected, "metrics": dict(metrics.rejected)}
        status = probe.status or {}
        stepping = status.get("wall_time", 0.0)
        true, measured = metrics.metrics
        hold = np.isin(pid_probe.mode, [int(LowLevelMode.HOLD), int(LowLevelMode.FALLBACK)])
        safety = {
            "max_velocity_ratio": [float(x) for x in probe.max_velocity_ratio],
            "max_torque_ratio": [float(x) for x in probe.max_torque_ratio],
            "max_applied_torque_ratio": [float(x) for x in probe.max_applied_torque_ratio],
            "max_velocity_ratio_at_s": probe.worst_velocity_t,
            "max_torque_ratio_at_s": probe.worst_torque_t,
            "safe_hold_s": float(np.count_nonzero(hold) * time_step),
            "metrics_filled": int(metrics.filled),
            # the guarded approach (ffmpc_core.tasks.GuardedTask): detection time, s, or None
            "contact_time_s": metrics.contact_time,
            "contact_missed": metrics.contact_missed,
            "faults": [] if self.injector is None else self.injector.report(),
            "rejected_messages": {name: rejected.get(name) for name in [*plan.table, "metrics"]},
            **reflex_summary(status, self.robot.joint_names),
        }
        return GraphResult(
            plant_engine=scenario.plant.engine,
            formulation=scenario.mpc.ocp.formulation,
            seed=scenario.seed,
            single_process=plan.options.single_process,
            lockstep=True,
            namespace=plan.namespace,
            metrics_true=true,
            metrics_measured=measured,
            log=metrics.log.arrays,
            sim_time=metrics.steps * metrics.time_step,
            wall_time=stepping,
            startup_time=(self.done - self.start) - stepping,
            plant_status=status or None,
            bag=outputs.bag,
            view=outputs.view,
            timing=pid_probe.timing(steps_per_mpc_period(scenario), status, plan.windows),
            safety=safety,
        )


def _read_json(path: str) -> dict | None:
    """The JSON object of ``path``, None when the file is not there (its writer died)."""
    if not os.path.exists(path):
        return None
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def _subscribe_injector(node: Node, injector: Any) -> None:
    """The fault injector's readers of the sensed joint states and wrench (on ``node``)."""
    from geometry_msgs.msg import WrenchStamped

    node.create_subscription(
        JointState,
        topics.SENSED_JOINT_STATES,
        injector.on_sensed_joints,
        topics.graph_qos(topics.SENSED_JOINT_STATES, "subscription"),
    )
    node.create_subscription(
        WrenchStamped,
        topics.SENSED_WRENCH,
        injector.on_sensed_wrench,
        topics.graph_qos(topics.SENSED_WRENCH, "subscription"),
    )


def _run_real_time(plan: GraphPlan) -> GraphResult:
    """Real time (``ffmpc_ros.realtime``): the loop process and the MPC process."""
    from ffmpc_ros.realtime import DEFAULT_PRIORITY, run_realtime

    o, scenario = plan.options, plan.scenario
    run = run_realtime(
        plan.params,
        timeout=o.timeout,
        domain=plan.domain,
        quiet=o.quiet,
        cpus=o.cpus,
        priority=DEFAULT_PRIORITY if o.priority is None else o.priority,
        fault_windows=plan.windows,
        stalls=plan.faults,
        namespace=plan.namespace,
        mpc_ros_args=(o.node_ros_args or {}).get("mpc", ()),
    )
    s, timing = run.summary, run.summary["timing"]
    loop = timing["loop"]
    status = {
        "done": 1.0,
        "steps": s["cycles"],
        "lockstep": 0.0,
        "deadline_misses": loop["cycles"] - loop["deadlines_met"],
        "wall_time": s["wall_time_s"],
    }
    return GraphResult(
        plant_engine=scenario.plant.engine,
        formulation=scenario.mpc.ocp.formulation,
        seed=scenario.seed,
        single_process=False,
        lockstep=False,
        namespace=plan.namespace,
        metrics_true=run.metrics_true,
        metrics_measured=run.metrics_measured,
        log=run.log,
        sim_time=s["cycles"] * scenario.plant.time_step,
        wall_time=s["wall_time_s"],
        startup_time=run.startup_time,
        plant_status=status,
        timing=timing,
        warnings=run.warnings,
        safety=s["safety"],
    )


def _launch(marker: str, deathsig: int, module: str, args: Sequence[str]) -> list[str]:
    """The command line of a child (``_LAUNCHER``): the module dies with the bring-up."""
    return [sys.executable, "-c", _LAUNCHER, marker, str(int(deathsig)), module, *args]


def _spawn(
    params: dict,
    directory: str,
    domain: int,
    node_ros_args: Mapping[str, Sequence[str]],
    namespace: str = topics.ROOT_NAMESPACE,
    nodes: Mapping[str, str] = NODES,
    scenario_file: str = "",
) -> tuple[dict[str, subprocess.Popen], dict[str, str]]:
    """Start every node of ``nodes`` (name → "module:class"; default the polishing graph's
    NODES) as a child in one new process group, given the ``scenario_file`` (if any) and the
    run's parameter file (``graph_nodes.write_graph_params``); output to log files."""
    extra = {n: split_parameter_args(node_ros_args.get(n, ())) for n in nodes}
    node_params = {n: {**v, **extra[n][0]} for n, v in params.items() if n in nodes}
    files = write_graph_params(node_params, directory, namespace, scenario_file)
    graph_args = topics.graph_ros_args(namespace)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    children: dict[str, subprocess.Popen] = {}
    logs: dict[str, str] = {}
    marker = child_marker()
    group = 0
    for name, target in nodes.items():
        module = target.partition(":")[0]
        logs[name] = os.path.join(directory, f"{name}.log")
        with open(logs[name], "w", encoding="utf-8") as out:
            args = ["--ros-args", *files, *graph_args, *extra[name][1]]
            args += ["-p", "autostart:=false"]  # the bring-up drives the lifecycle (run_graph)
            args += ["-p", f"results_file:={results_path(directory, name)}"]
            children[name] = subprocess.Popen(  # type: ignore[call-overload]
                # (process_group needs Python 3.11, the ROS wheels' Python; mypy checks 3.10)
                _launch(marker, signal.SIGKILL, module, args),
                env=env,
                stdout=out,
                stderr=subprocess.STDOUT,
                process_group=group,
            )
        group = group or children[name].pid
    return children, logs


def _spawn_view(
    robot: str,
    host: str,
    port: int,
    directory: str,
    domain: int,
    counts: str,
    wait_for_client: bool = False,
    namespace: str = topics.ROOT_NAMESPACE,
) -> tuple[subprocess.Popen, str]:
    """The view node's own process (``ffmpc_ros.view.view_process``), in the nodes' group and
    the graph's namespace."""
    config = {
        "robot": robot,
        "host": host,
        "port": port,
        "domain": domain,
        "counts": counts,
        "wait_for_client": wait_for_client,
        "ros_args": topics.graph_ros_args(namespace),
    }
    return _spawn_child("view", "ffmpc_ros.view", config, directory, domain)


def _spawn_child(
    name: str, module: str, config: dict, directory: str, domain: int
) -> tuple[subprocess.Popen, str]:
    """``python -m module DIRECTORY/NAME.json`` (``config`` written there) in the nodes' process
    group and ROS domain, its output in DIRECTORY/NAME.log; (process, log path)."""
    path = os.path.join(directory, f"{name}.json")
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(config, fh)
    log = os.path.join(directory, f"{name}.log")
    with open(log, "w", encoding="utf-8") as out:
        child = subprocess.Popen(  # type: ignore[call-overload]  # (process_group: 3.11)
            _launch(child_marker(), signal.SIGTERM, module, [path]),
            env=dict(os.environ, ROS_DOMAIN_ID=str(domain)),
            stdout=out,
            stderr=subprocess.STDOUT,
            process_group=0,
        )
    return child, log


def _stop(children: Mapping[str, subprocess.Popen]) -> None:
    """SIGINT every child, then wait (SIGKILL after 5 s)."""
    for child in children.values():
        if child.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(child.pid, signal.SIGCONT)  # a stopped child cannot handle SIGINT
                child.send_signal(signal.SIGINT)
    deadline = time.monotonic() + 5.0
    for child in children.values():
        try:
            child.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def _tail(path: str | None, lines: int = LOG_TAIL) -> str:
    if path is None:
        return ""
    try:
        with open(path, encoding="utf-8", errors="replace") as fh:
            return "".join(fh.readlines()[-lines:])
    except OSError:
        return ""


def _exit_status(code: int) -> str:
    if code < 0:
        with contextlib.suppress(ValueError):
            return f"killed by {signal.Signals(-code).name}"
        return f"killed by signal {-code}"
    return f"exit status {code}"


def _check_children(
    children: Mapping[str, subprocess.Popen], logs: Mapping[str, str], killed: set[str]
) -> None:
    """GraphError naming a child that died (other than one a node-kill fault killed)."""
    for name, child in children.items():
        if name in killed or child.poll() is None:
            continue
        if name == "recorder" and child.returncode == 0:
            continue  # it stops by itself once the run is complete
        tail = _tail(logs.get(name)).rstrip()
        raise GraphError(
            f"node {name} (pid {child.pid}) died unexpectedly: {_exit_status(child.returncode)}; "
            f"last lines of its output:\n{tail}"
        )


def _process_state(child: subprocess.Popen) -> str:
    try:
        with open(f"/proc/{child.pid}/stat", encoding="utf-8") as fh:
            state = fh.read().rpartition(")")[2].split()[0]
    except OSError:
        return "gone"
    return {"T": "stopped", "Z": "exited", "R": "running", "S": "waiting"}.get(state, state)


def _progress(
    probe: _StatusProbe, pid_probe: _PidStatusProbe, children: Mapping[str, subprocess.Popen]
) -> str:
    """What each stage last did, and who the plant waits for (stall and timeout messages)."""
    k, j = probe.cycle, pid_probe.last_cycle
    if k < 0:
        who = "the plant has published no state (it waits for its subscribers and the metrics node)"
    elif j < k:
        who = (
            f"the plant waits for the PID's torque of cycle {k}; the PID waits for the joint "
            f"sensor's measurement or the MPC's command of cycle {k}"
        )
    else:
        who = f"the PID stepped cycle {j}: the plant has not stepped past cycle {k}"
    states = ", ".join(f"{n} {_process_state(c)}" for n, c in children.items())
    return (
        f"plant at cycle {k} (t = {max(k, 0) * probe.time_step:.3f} s), PID last stepped cycle "
        f"{j}; {who}" + (f"; processes: {states}" if states else "")
    )


def _refuse_foreign(
    node: Node,
    domain: int,
    namespace: str = topics.ROOT_NAMESPACE,
    wait: float = FOREIGN_DISCOVERY_WAIT,
) -> None:
    """GraphError naming the publishers already on the graph's topics and the nodes already
    using the graph's node names in its namespace (module docstring); a graph in another
    namespace is no conflict (its names resolve elsewhere, its clock is its own)."""
    names = [t for t, _, _ in topics.resolved_topics(namespace)]
    ours = {*NODES, "lfc", "metrics", "ffmpc_recorder", "ffmpc_bringup", "view"}
    me = node.get_fully_qualified_name()
    deadline = time.monotonic() + wait
    first_seen: float | None = None
    last_change = 0.0  # wall s of the last change of ``found`` (set with first_seen)
    previous: dict[str, set[str]] = {}
    while True:
        found: dict[str, set[str]] = {}
        for topic in names:
            for info in node.get_publishers_info_by_topic(topic):
                fqn = f"{info.node_namespace.rstrip('/')}/{info.node_name}"
                found.setdefault(fqn, set()).add(topic)
        for name, node_namespace in node.get_node_names_and_namespaces():
            fqn = f"{node_namespace.rstrip('/')}/{name}"
            if name in ours and namespace == node_namespace and fqn != me:
                found.setdefault(fqn, set())
        now = time.monotonic()
        if found and first_seen is None:
            first_seen = now
        if found != previous:
            last_change, previous = now, found
        unnamed = any("_UNKNOWN_" in n for n in found)
        if first_seen is not None:  # gather the others until the list settles (and their names)
            settled = now > last_change + (2.0 if unnamed else 1.0)
            if settled or now > first_seen + FOREIGN_GATHER_MAX:
                break
        elif now > deadline:
            break
        time.sleep(0.05)
    if found:
        raise _foreign_error(domain, namespace, found)


def _foreign_error(domain: int, namespace: str, found: Mapping[str, set[str]]) -> GraphError:
    """The refusal of a graph that found foreign nodes: {node: the graph's topics it publishes
    (empty: it uses one of the graph's node names)}."""
    listed = "; ".join(
        f"{n} on {', '.join(sorted(t))}" if t else f"{n} (node name of this graph)"
        for n, t in sorted(found.items())
    )
    return GraphError(
        f"foreign nodes on this graph's topics (ROS_DOMAIN_ID {domain}"
        + ("" if namespace == topics.ROOT_NAMESPACE else f", namespace {namespace}")
        + f"): {listed}. Another graph (or the leftovers of a killed run) is on this "
        "domain: stop it or use another ROS_DOMAIN_ID or --namespace "
        "(--allow-foreign-publishers starts anyway)"
    )


def _node_name_clashes(
    node: Node, names: Sequence[str], wait: float = FOREIGN_DISCOVERY_WAIT
) -> dict[str, set[str]]:
    """The graph's node names that more than one node uses in ``node``'s namespace (this graph's
    and another's), as :func:`_foreign_error` lists them; discovery is given up to ``wait``
    wall s to show a clash."""
    namespace = node.get_namespace()
    deadline = time.monotonic() + wait
    while True:
        fqns = [
            f"{ns.rstrip('/')}/{name}"
            for name, ns in node.get_node_names_and_namespaces()
            if name in names and ns == namespace
        ]
        clashes: dict[str, set[str]] = {
            fqn: set() for fqn in sorted(set(fqns)) if fqns.count(fqn) > 1
        }
        if clashes or time.monotonic() > deadline:
            return clashes
        time.sleep(0.05)


#: Lifecycle transitions of the bring-up, in order (lifecycle_msgs/msg/Transition labels).
BRING_UP_TRANSITIONS = ("configure", "activate")
#: The state each transition of the bring-up leads to.
GOAL_STATES = {"configure": "inactive", "activate": "active"}


def _call(
    executor: Executor,
    client: Client,
    request: Any,
    deadline: float,
    what: str,
    children: Mapping[str, subprocess.Popen] | None = None,
    logs: Mapping[str, str] | None = None,
) -> tuple[Any, bool]:
    """(response, resent) of one service call, spinning ``executor``; the request is sent again
    when unanswered after SERVICE_RETRY (a lost response). GraphError past ``deadline``."""
    future, sent, resent = None, 0.0, False
    while future is None or not future.done():
        if children is not None:
            _check_children(children, logs or {}, set())
        now = time.perf_counter()
        if now > deadline:
            raise GraphError(f"{what} did not answer in time: the run did not start")
        if future is not None and now - sent > SERVICE_RETRY:
            future, resent = None, True  # the response was lost: ask again
        if future is None and client.service_is_ready():
            future, sent = client.call_async(request), now
        executor.spin_once(timeout_sec=0.05)
        _check_stop()
    return future.result(), resent


def _bring_up(
    node: Node,
    executor: Executor,
    names: Sequence[str],
    children: Mapping[str, subprocess.Popen],
    logs: Mapping[str, str],
    deadline: float,
    plant: str = "plant",
) -> None:
    """Configure every node of ``names``, then activate them, the node ``plant`` last (its
    first cycle waits for its own activation: every reader is active by then), through their
    ``<node>/change_state`` services; one log line per node and transition. GraphError when a
    transition fails (the node's log says why) or the deadline passes."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState

    prefix = node.get_namespace().rstrip("/")
    order = [n for n in names if n != plant] + [n for n in names if n == plant]
    clients = {n: node.create_client(ChangeState, f"{prefix}/{n}/change_state") for n in order}
    try:
        for label in BRING_UP_TRANSITIONS:
            for name in order if label == "activate" else names:
                client = clients[name]
                request = ChangeState.Request(transition=Transition(label=label))
                asked = time.perf_counter()
                what = f"{name} ({label})"
                response, resent = _call(executor, client, request, deadline, what, children, logs)
                done = response.success
                if not done and resent:  # a resent transition the node had made is refused
                    get = node.create_client(GetState, f"{prefix}/{name}/get_state")
                    try:
                        state, _ = _call(executor, get, GetState.Request(), deadline, what)
                    finally:
                        node.destroy_client(get)
                    done = state.current_state.label == GOAL_STATES[label]
                if not done:
                    # another graph's node of the same name may have answered: the foreign
                    # check before the start found nothing when discovery was slower than
                    # FOREIGN_DISCOVERY_WAIT (a fresh clone on a slow machine: the running
                    # graph's plant, already active, refused this graph's configure)
                    clashes = _node_name_clashes(node, names, wait=CLASH_DISCOVERY_WAIT)
                    if clashes:
                        domain = node.context.get_domain_id()
                        raise _foreign_error(domain, node.get_namespace(), clashes)
                    raise GraphError(
                        f"{name} refused the {label} transition (its log says why): the run "
                        "did not start"
                    )
                node.get_logger().debug(
                    f"{name}: {label} in {1e3 * (time.perf_counter() - asked):.0f} ms"
                )
    finally:
        for client in clients.values():
            node.destroy_client(client)


def check_unshared(node_ros_args: Mapping[str, Sequence[str]], nodes: Sequence[str]) -> None:
    """ConfigError for a per-node ``-p NAME:=VALUE`` (``--node-param``) that sets a scenario
    value other nodes of the graph (``nodes``) take too: each node gets its slice of the one
    scenario, so a value given to one of them alone would make them disagree; it belongs in
    ``--set`` (:func:`ffmpc_ros.params.sharing_nodes`)."""
    from ffmpc_ros.params import sharing_nodes

    for node, args in node_ros_args.items():
        for flag, assignment in zip(args[:-1], args[1:], strict=True):
            if flag != "-p":
                continue
            name = assignment.partition(":=")[0]
            scenario_name, others = sharing_nodes(node, name, nodes)
            if others:
                raise ConfigError(
                    f"{node}:{name}: the scenario value {scenario_name}, which "
                    f"{', '.join(others)} also take; give it to every node with --set "
                    f"{scenario_name}=VALUE (the run was not started)"
                )


def results_path(directory: str, node: str) -> str:
    """The results file of node process ``node`` in the run's ``directory``
    (:mod:`ffmpc_ros.node_results`)."""
    return os.path.join(directory, f"{node}.results.json")


def rejected_from_results(directory: str, names: Iterable[str]) -> dict[str, dict]:
    """{node: {kind: count}} of the node processes ``names`` that wrote their results file
    (the others, e.g. a killed node, the view or the recorder, wrote none)."""
    out = {}
    for name in names:
        results = read_node_results(results_path(directory, name))
        if results is not None:
            out[name] = results[1]
    return out
