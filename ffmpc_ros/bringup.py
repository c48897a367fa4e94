"""Bring-up of the node graph: every node as its own process, or all in one process.

``run_graph(scenario)`` starts the plant, joint-sensor, F/T-sensor, MPC and PID nodes and the
metrics node, runs the scenario and returns the metrics (computed by the metrics node with the
runner's code). Multi-process (the default): each node is a child process started as
``python -m <module> --ros-args --params-file <generated file>``; the metrics node runs in this
process. Single-process: all nodes in this process on one ``EventsExecutor``.

The generated parameter file is the scenario itself (``scenario_parameters``) spread over the
node sections with the other-section values each node declares (``ffmpc_ros.params``), plus
``lockstep`` and ``duration``. Every process gets the caller's environment: set
``ROS_DOMAIN_ID`` (and ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``) to isolate a run.
"""

from __future__ import annotations

import importlib
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import rclpy
import yaml
from rclpy.context import Context
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_core.lowlevel import LowLevelMode
from ffmpc_core.metrics import PolishingMetrics
from ffmpc_core.scenario import Scenario
from ffmpc_ros import layouts, topics
from ffmpc_ros.params import node_parameter_values, parameter_overrides

#: node name → "module:class"; the module's ``main`` is the executable.
NODES: dict[str, str] = {
    "plant": "sim_bridge.node:PlantNode",
    "joint_sensor": "ffmpc_ros.joint_sensor_node:JointSensorNode",
    "ft_sensor": "ffmpc_ros.ft_sensor_node:FtSensorNode",
    "mpc": "ffmpc_ros.mpc_node:MpcNode",
    "pid": "ffmpc_ros.pid_node:PidNode",
}
METRICS_NODE = "ffmpc_ros.metrics_node:MetricsNode"


class GraphError(FfmpcError):
    """The graph did not finish (a node died, or the wall-time limit passed)."""


@dataclass
class GraphResult:
    """Outcome of a graph run: the metrics (true and measured force), the log, timing."""

    formulation: str
    seed: int
    single_process: bool
    lockstep: bool
    metrics_true: PolishingMetrics
    metrics_measured: PolishingMetrics
    log: dict[str, np.ndarray] = field(repr=False)
    sim_time: float = 0.0
    wall_time: float = 0.0  # from the first plant step to the last recorded cycle, s
    startup_time: float = 0.0  # from the call to the first plant step, s
    plant_status: dict | None = None
    bag: dict | None = None  # with ``record``: path and messages recorded per topic
    timing: dict | None = None  # deadlines met, fallback time, latencies (module docstring)
    warnings: list[str] = field(default_factory=list)

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
            "formulation": self.formulation,
            "seed": self.seed,
            "single_process": self.single_process,
            "lockstep": self.lockstep,
            "metrics_true": self.metrics_true.to_dict(),
            "metrics_measured": self.metrics_measured.to_dict(),
            "sim_time_s": self.sim_time,
            "wall_time_s": self.wall_time,
            "real_time_factor": self.real_time_factor,
            "plant_status": self.plant_status,
            **{key: timing.get(key) for key in TIMING_KEYS},
            "timing": timing,
            **({"bag": self.bag} if self.bag is not None else {}),
        }


#: Timing statistics copied to the top level of a run's summary (``ffmpc run --json``).
TIMING_KEYS = (
    "deadline_met_fraction",
    "fallback_time_s",
    "latency_p50_ms",
    "latency_p99_ms",
    "latency_max_ms",
)


def _load(path: str):
    module, _, cls = path.partition(":")
    return getattr(importlib.import_module(module), cls)


def graph_parameters(scenario: Scenario, lockstep: bool, duration: float) -> dict[str, dict]:
    """{node: {ROS name: value}} of every node of the graph, metrics node included."""
    graph = {
        "lockstep": lockstep,
        "duration": float(duration),
        "start_delay": 0.5,  # wall s after the subscribers appear: discovery settles
        "start_subscribers": 2,  # the joint-sensor and metrics nodes
        "wait_for_metrics": True,  # the metrics node has matched every topic it records
    }
    names = [*NODES, "metrics"]
    return {n: node_parameter_values(n, scenario, **graph) for n in names}


def _nested(flat: dict) -> dict:
    out: dict = {}
    for key, value in flat.items():
        parts = key.split(".")
        d = out
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = value
    return out


def write_params_file(params: dict[str, dict], path: str) -> None:
    """A ROS 2 parameter file with one section per node."""
    doc = {node: {"ros__parameters": _nested(values)} for node, values in params.items()}
    with open(path, "w", encoding="utf-8") as fh:
        yaml.safe_dump(doc, fh, sort_keys=False)


class _StatusProbe:
    """Keeps the newest /plant/status."""

    def __init__(self, node: Node) -> None:
        self.status: dict | None = None
        node.create_subscription(
            Float64MultiArray, topics.PLANT_STATUS, self._on, topics.subscriber_qos(False)
        )

    def _on(self, msg: Float64MultiArray) -> None:
        self.status = layouts.PLANT_STATUS.unpack(msg)


class _PidStatusProbe:
    """Lockstep: the torque loop's mode and command age of every cycle (``/pid/status``)."""

    def __init__(self, node: Node, steps: int, time_step: float) -> None:
        self.time_step = time_step
        self.mode = np.full(steps, -1, dtype=np.int8)
        self.command_age = np.full(steps, np.nan)
        node.create_subscription(
            Float64MultiArray, topics.LOWLEVEL_STATUS, self._on, topics.subscriber_qos(True)
        )

    def _on(self, msg: Float64MultiArray) -> None:
        try:
            status = layouts.LOWLEVEL_STATUS.unpack(msg)
        except FfmpcError:
            return
        k = int(round(status["t"] / self.time_step))
        if 0 <= k < self.mode.size:
            self.mode[k] = int(status["mode"])
            self.command_age[k] = status["command_age"]

    @property
    def complete(self) -> bool:
        return bool(np.all(self.mode >= 0))

    def timing(self, every: int, plant_status: dict, fault_windows) -> dict:
        """Lockstep timing (simulated-time deadlines, see the module docstring)."""
        from ffmpc_ros.realtime import fallback_time

        steps = self.mode.size
        ticks = np.arange(0, steps, every)
        heard = self.mode[ticks] >= 0
        on_time = heard & (np.abs(self.command_age[ticks]) < 0.5 * self.time_step)
        misses = int(plant_status.get("deadline_misses", steps)) if plant_status else steps
        known = np.where(self.mode >= 0, self.mode, int(LowLevelMode.HOLD))  # unheard: no fallback
        unexcused, excused = fallback_time(known, self.time_step, fault_windows)
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
            "fallback_excused_s": excused,
            "fault_windows": [list(map(float, w)) for w in fault_windows],
            "latency_p50_ms": lat["p50"],
            "latency_p99_ms": lat["p99"],
            "latency_max_ms": lat["max"],
            "status_cycles": int(np.count_nonzero(self.mode >= 0)),
            "unobserved_ticks": int(ticks.size - heard_ticks),
            "mode_cycles": {
                m.name.lower(): int(np.count_nonzero(self.mode == int(m))) for m in LowLevelMode
            },
            "definition": "lockstep: simulated-time deadlines (ffmpc_ros.bringup)",
        }


def run_graph(
    scenario: Scenario,
    *,
    duration: float | None = None,
    single_process: bool = False,
    lockstep: bool = True,
    timeout: float = 600.0,
    domain_id: int | None = None,
    quiet: bool = True,
    record: str | os.PathLike | None = None,
    fault_windows: Sequence[tuple[float, float]] = (),
    cpus: tuple[int, int] | None | str = "auto",
    priority: int | None = None,
) -> GraphResult:
    """Run ``scenario`` on the node graph and return the metrics node's result.

    Args:
        duration: simulated time, s (None: the task's duration).
        single_process: all nodes in this process on one executor.
        lockstep: lockstep (True) or real-time (False) plant.
        timeout: wall-time limit, s (GraphError beyond).
        domain_id: ROS domain of this run (default: ROS_DOMAIN_ID or 0).
        quiet: multi-process: send the children's output to a log file instead of the terminal.
        record: record the run into this MCAP bag (must not exist): every topic and every
            node's parameters; the plant then also waits for the recorder to see the graph.
        fault_windows: (start, end) simulated s of injected faults: fallback inside them is
            excused (the hook for fault injection).
        cpus: real time: (loop CPU, MPC CPU) to pin the two processes to ("auto": the first
            two CPUs; None: no pinning).
        priority: real time: SCHED_FIFO priority of both processes (None:
            ``realtime.DEFAULT_PRIORITY``; 0: normal scheduling).
    """
    start = time.perf_counter()
    domain = int(os.environ.get("ROS_DOMAIN_ID", "0")) if domain_id is None else domain_id
    metrics_cls = _load(METRICS_NODE)
    # Task duration from the metrics node's own view of the scenario when not given.
    if duration is None:
        from ffmpc_core.robots import load_robot
        from ffmpc_core.study import build_task

        duration = build_task(scenario, load_robot(scenario.robot)).duration
    params = graph_parameters(scenario, lockstep, duration)
    if not lockstep:
        if single_process or record is not None:
            raise ConfigError(
                "real time runs the loop nodes and the MPC node as two processes (one "
                "interpreter each, see ffmpc_ros.realtime); --single-process and --record are "
                "lockstep options"
            )
        return _run_real_time(
            scenario, params, timeout, domain, quiet, fault_windows, cpus, priority
        )
    from ffmpc_core.study import steps_per_mpc_period

    if record is not None:  # the recorder is one more subscriber the plant waits for
        params["plant"]["start_subscribers"] += 1
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    executor = EventsExecutor(context=context)
    nodes: list[Node] = []
    children: list[subprocess.Popen] = []
    recorder = None
    tmp = tempfile.TemporaryDirectory(prefix="ffmpc_graph_")
    try:
        metrics = metrics_cls(
            context=context, parameter_overrides=parameter_overrides(params["metrics"])
        )
        probe_node = Node("ffmpc_bringup", context=context)
        probe = _StatusProbe(probe_node)
        pid_probe = _PidStatusProbe(probe_node, metrics.steps, metrics.time_step)
        nodes += [metrics, probe_node]
        if record is not None:
            from ffmpc_ros.bag.recorder import graph_recorder

            recorder = graph_recorder(record, context=context, scenario=scenario, run=params)
            nodes.append(recorder)
        if single_process:
            for name, path in NODES.items():
                nodes.append(
                    _load(path)(
                        context=context, parameter_overrides=parameter_overrides(params[name])
                    )
                )
        else:
            children = _spawn(params, tmp.name, domain, quiet)
        for node in nodes:
            executor.add_node(node)
        end = start + timeout
        while not metrics.finished():
            if time.perf_counter() > end:
                raise GraphError(
                    f"the graph did not finish within {timeout} s: {metrics.recorded} of "
                    f"{metrics.steps} cycles recorded, partial rows {len(metrics._rows)}, "
                    f"plant status {probe.status}"
                )
            for child in children:
                if child.poll() is not None:
                    raise GraphError(f"{child.args[2]} exited with {child.returncode}")
            executor.spin_once(timeout_sec=0.05)
        done = time.perf_counter()
        # The final plant status (latencies, deadline misses) follows the last state.
        while (
            (probe.status is None or not probe.status["done"])
            or not (recorder is None or recorder.complete)
            or not pid_probe.complete
        ):
            if time.perf_counter() > done + 2.0:
                break
            executor.spin_once(timeout_sec=0.05)
    finally:
        _stop(children)
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
        executor.shutdown()
        rclpy.shutdown(context=context)
        tmp.cleanup()
    status = probe.status or {}
    stepping = status.get("wall_time", 0.0)
    true, measured = metrics.metrics
    return GraphResult(
        formulation=scenario.mpc.formulation,
        seed=scenario.seed,
        single_process=single_process,
        lockstep=lockstep,
        metrics_true=true,
        metrics_measured=measured,
        log=metrics.log.arrays,
        sim_time=metrics.steps * metrics.time_step,
        wall_time=stepping,
        startup_time=(done - start) - stepping,
        plant_status=status or None,
        bag=None if recorder is None else {"path": str(record), "received": recorder.received},
        timing=pid_probe.timing(steps_per_mpc_period(scenario), status, fault_windows),
    )


def _run_real_time(
    scenario: Scenario, params, timeout, domain, quiet, fault_windows, cpus, priority
) -> GraphResult:
    """Real time (``ffmpc_ros.realtime``): the loop process and the MPC process."""
    from ffmpc_ros.realtime import DEFAULT_PRIORITY, run_realtime

    run = run_realtime(
        params,
        timeout=timeout,
        domain=domain,
        quiet=quiet,
        cpus=cpus,
        priority=DEFAULT_PRIORITY if priority is None else priority,
        fault_windows=fault_windows,
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
        formulation=scenario.mpc.formulation,
        seed=scenario.seed,
        single_process=False,
        lockstep=False,
        metrics_true=run.metrics_true,
        metrics_measured=run.metrics_measured,
        log=run.log,
        sim_time=s["cycles"] * scenario.plant.time_step,
        wall_time=s["wall_time_s"],
        startup_time=run.startup_time,
        plant_status=status,
        timing=timing,
        warnings=run.warnings,
    )


def _spawn(params: dict, directory: str, domain: int, quiet: bool) -> list[subprocess.Popen]:
    path = os.path.join(directory, "graph_params.yaml")
    write_params_file({n: v for n, v in params.items() if n in NODES}, path)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    children = []
    for name, target in NODES.items():
        module = target.partition(":")[0]
        out = open(os.path.join(directory, f"{name}.log"), "w") if quiet else None  # noqa: SIM115
        children.append(
            subprocess.Popen(
                [sys.executable, "-m", module, "--ros-args", "--params-file", path],
                env=env,
                stdout=out,
                stderr=subprocess.STDOUT if quiet else None,
                start_new_session=True,
            )
        )
    return children


def _stop(children: list[subprocess.Popen]) -> None:
    """SIGINT every child, then wait (SIGKILL after 5 s)."""
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
