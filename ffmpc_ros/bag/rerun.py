"""Deterministic re-run: feed one node the inputs recorded in a bag, compare its outputs.

The node (``mpc``, ``pid``, ``joint_sensor`` or ``ft_sensor``) is built with the parameters it
ran with — recorded in the bag by the recorder — plus the caller's overrides (scenario names
such as ``mpc.weights.force_feedback.force_phase``, or the node's own parameter names). A feeder
node publishes, cycle by cycle, the recorded ``/clock`` and the recorded messages of every topic
the node subscribes to, exactly as recorded (CDR bytes), and waits until the node has taken each
one (accepted or rejected) before the next cycle: the lockstep of the graph, so the node sees
its inputs in the same order and at the same simulated times as in the recorded run. Its outputs
are compared field by field with the recorded ones.

In lockstep the nodes are deterministic: on the machine that recorded the bag, the same inputs
give bit-identical outputs, except the fields that carry wall time (:data:`WALL_TIME_FIELDS`: the
MPC's solve time), which are ignored. Another CPU, other BLAS kernels (``OPENBLAS_CORETYPE``) or
other library versions change the last bits, so outputs are judged with a stated tolerance
(:class:`RerunTolerance`: per field, max |Δ| ≤ absolute + relative · max |recorded|), and
bit-identity is demanded only when the bag's ``ffmpc_machine`` fingerprint equals this machine's
(:mod:`ffmpc_ros.bag.machine`). A changed parameter (a cost weight, a gain) shows as differences far
above the tolerance: this is how a controller change is regression-tested against a recorded run.

All topics of the re-run are remapped under a private hidden prefix, so a re-run never talks to a
live graph on the same ROS domain. A bag of a namespaced graph (``ffmpc run --namespace /arm1``)
is re-run in its namespace (:func:`bag_namespace`): the node's relative names resolve to the
recorded ``/arm1/...`` names, its ``/clock`` to the recorded ``/arm1/clock``.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
import rclpy
from ffmpc_msgs.msg import MpcCommand as MpcCommandMsg
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import Executor
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import Scenario
from ffmpc_ros import command_msg, layouts, topics
from ffmpc_ros.bag.errors import BagError
from ffmpc_ros.bag.machine import MACHINE_RECORD, same_machine
from ffmpc_ros.bag.reader import BagMessage, BagReader
from ffmpc_ros.bag.ros_types import message_class, qos_from_dicts
from ffmpc_ros.discovery import domain_id as _env_domain_id

if TYPE_CHECKING:
    from ffmpc_ros.base import GraphNode

#: Nodes that can be re-run from a bag.
RERUN_NODES = ("joint_sensor", "ft_sensor", "mpc", "pid")
#: Fields of typed messages that carry wall-clock time (never reproducible), by message class.
TYPED_WALL_TIME_FIELDS: dict[type, tuple[str, ...]] = {MpcCommandMsg: command_msg.WALL_TIME_FIELDS}
#: Layout fields that carry wall-clock time (never reproducible), by layout name.
WALL_TIME_FIELDS: dict[str, tuple[str, ...]] = {
    "plant_status": (
        "latency_mean",
        "latency_p50",
        "latency_p99",
        "latency_max",
        "wall_time",
        "latency_count",
        "deadline_misses",
    ),
}
#: Not outputs of a node's computation: logs, parameter events, the clock, and /diagnostics
#: (a status report on the wall clock, DIAGNOSTICS_PERIOD apart).
_IGNORED_TOPICS = ("/rosout", "/parameter_events", topics.CLOCK, topics.DIAGNOSTICS)
_LAYOUTS_BY_LABEL = {layout.label: layout for layout in layouts.LAYOUTS.values()}


class RerunError(BagError):
    """The re-run could not be carried out (missing inputs, a node that does not respond)."""


@dataclass(frozen=True)
class RerunTolerance:
    """How close a re-run output must be to the recorded one, field by field.

    A field (a named slice of a layout, or a message field) matches when
    ``max |re-run − recorded| ≤ absolute + relative · max |recorded|`` over its entries, in the
    field's own unit. The defaults sit far above round-off (1e-15 relative per operation; a whole
    MPC solve measured 1e-11 relative between two OpenBLAS kernel sets) and far below any change a
    parameter makes (a cost weight changed from 1 to 5 changes the torque by > 1e-3 N·m).
    """

    relative: float = 1e-6
    absolute: float = 1e-9

    def __post_init__(self) -> None:
        if not (self.relative >= 0.0 and self.absolute >= 0.0):
            raise ConfigError(f"tolerances must be >= 0, got {self}")

    def allows(self, recorded: object, difference: float) -> bool:
        """Whether ``difference`` (max |Δ| of one field) is within tolerance of ``recorded``."""
        if not math.isfinite(difference):
            return False
        if isinstance(recorded, np.ndarray) and recorded.size:
            finite = recorded[np.isfinite(recorded)]
            scale = float(np.max(np.abs(finite))) if finite.size else 0.0
        else:
            scale = 0.0
        return difference <= self.absolute + self.relative * scale


# -- comparison -------------------------------------------------------------------------------
def flatten_message(msg: Any) -> dict[str, Any]:
    """{field path: value} of a message: numbers and numeric arrays as float arrays, strings as
    str; a Float64MultiArray with a known ffmpc layout by its named fields."""
    label = None
    if hasattr(msg, "layout") and hasattr(msg, "data") and len(msg.layout.dim) == 1:
        label = msg.layout.dim[0].label
    if label in _LAYOUTS_BY_LABEL:
        layout = _LAYOUTS_BY_LABEL[label]
        data = np.asarray(msg.data, dtype=float)
        names = [f.name for f in layout.fields]
        nv = int(data[names.index("nv")]) if "nv" in names and data.size > 1 else 0
        nx = int(data[names.index("nx")]) if "nx" in names and data.size > 2 else 0
        if data.size == layout.length(nv, nx):
            return {
                f"{layout.name}.{name}": data[sl]
                for name, sl in layout.slices(nv, nx).items()
                if name not in WALL_TIME_FIELDS.get(layout.name, ())
            }
    out: dict[str, Any] = {}

    def walk(value: Any, prefix: str) -> None:
        if hasattr(value, "get_fields_and_field_types"):
            for name in value.get_fields_and_field_types():
                walk(getattr(value, name), f"{prefix}{name}.")
            return
        key = prefix[:-1]
        if isinstance(value, str | bytes):
            out[key] = value
        elif isinstance(value, bool | int | float):
            out[key] = np.array([float(value)])
        elif len(value) and hasattr(value[0], "get_fields_and_field_types"):
            for i, item in enumerate(value):
                walk(item, f"{key}[{i}].")
            out[f"{key}.len"] = np.array([float(len(value))])
        elif len(value) and isinstance(value[0], str):
            out[key] = tuple(value)
        else:
            out[key] = np.asarray(value, dtype=float).reshape(-1)

    walk(msg, "")
    for name in TYPED_WALL_TIME_FIELDS.get(type(msg), ()):
        del out[name]
    return out


def ignored_fields(msg: Any) -> tuple[str, ...]:
    """The wall-time fields :func:`flatten_message` leaves out of this message."""
    if type(msg) in TYPED_WALL_TIME_FIELDS:
        return TYPED_WALL_TIME_FIELDS[type(msg)]
    if hasattr(msg, "layout") and len(getattr(msg.layout, "dim", [])) == 1:
        layout = _LAYOUTS_BY_LABEL.get(msg.layout.dim[0].label)
        if layout is not None:
            return tuple(f"{layout.name}.{n}" for n in WALL_TIME_FIELDS.get(layout.name, ()))
    return ()


def _difference(a: object, b: object) -> float:
    """0 when equal (NaN equals NaN), else the largest |a − b| (inf for other shapes/strings)."""
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray):
        if a.shape != b.shape:
            return math.inf
        if np.array_equal(a, b, equal_nan=True):
            return 0.0
        diff = np.abs(a - b)
        diff[np.isnan(diff)] = math.inf
        return float(diff.max())
    return 0.0 if a == b else math.inf


def message_time(msg: Any) -> float | None:
    """The simulated time a message belongs to: its header stamp, a layout's ``t``, a Clock's
    time; None for messages without one."""
    stamp = None
    if hasattr(msg, "header"):
        stamp = msg.header.stamp
    elif hasattr(msg, "clock"):
        stamp = msg.clock
    if stamp is not None:
        return stamp.sec + stamp.nanosec * 1e-9
    if hasattr(msg, "layout") and len(msg.layout.dim) == 1 and len(msg.data):
        if msg.layout.dim[0].label in _LAYOUTS_BY_LABEL:
            return float(msg.data[0])
    return None


@dataclass
class TopicComparison:
    """Recorded vs re-run outputs of one topic (messages matched in order)."""

    topic: str
    recorded: int
    rerun: int
    identical: int  # matched messages equal in every compared field (bit for bit)
    within_tolerance: int = 0  # matched messages equal within the tolerance in every field
    max_difference: dict[str, float] = field(default_factory=dict)  # field: max |Δ| (> 0 only)
    first_difference: str | None = None
    ignored: tuple[str, ...] = ()

    @property
    def exact(self) -> bool:
        return self.recorded == self.rerun == self.identical

    @property
    def reproduced(self) -> bool:
        """Every recorded message re-run, each within the tolerance."""
        return self.recorded == self.rerun == self.within_tolerance

    def describe(self) -> str:
        verdict = (
            "IDENTICAL" if self.exact else "WITHIN TOLERANCE" if self.reproduced else "DIFFERENT"
        )
        lines = [
            f"  {self.topic}: {verdict} — {self.identical} of {self.recorded} recorded messages "
            f"reproduced exactly, {self.within_tolerance} within tolerance ({self.rerun} re-run)"
            + (f"; ignored (wall time): {', '.join(self.ignored)}" if self.ignored else "")
        ]
        for name, value in sorted(self.max_difference.items(), key=lambda kv: -kv[1])[:8]:
            lines.append(f"      max |Δ| {name}: {value:.6g}")
        if self.first_difference:
            lines.append(f"      first difference: {self.first_difference}")
        return "\n".join(lines)


@dataclass
class RerunReport:
    """Outcome of :func:`rerun_node`."""

    node: str
    bag: str
    overrides: dict[str, Any]
    inputs: dict[str, int]
    outputs: list[TopicComparison]
    cycles: int
    wall_time: float
    rejected: dict[str, int] = field(default_factory=dict)
    tolerance: RerunTolerance = field(default_factory=RerunTolerance)
    same_machine: bool = False  # the bag's fingerprint equals this machine's
    #: what the bag's summary says it holds, per input and output topic (messages)
    summary_counts: dict[str, int] = field(default_factory=dict)

    @property
    def compared(self) -> int:
        """Recorded output messages compared with the re-run's."""
        return sum(c.recorded for c in self.outputs)

    def shortfall(self) -> list[str]:
        """Topics fed or compared with fewer messages than the bag's summary holds
        (``topic: n of N``), or ``nothing compared``: a re-run that checked less than the
        recording is no pass."""
        out = []
        seen = {**self.inputs, **{c.topic: c.recorded for c in self.outputs}}
        for topic, total in sorted(self.summary_counts.items()):
            if seen.get(topic, 0) < total:
                out.append(f"{topic}: {seen.get(topic, 0)} of {total}")
        if self.compared == 0:
            out.append("nothing compared (no recorded output message)")
        return out

    @property
    def identical(self) -> bool:
        """Every output bit-identical to the recording, and something compared."""
        return all(c.exact for c in self.outputs) and not self.shortfall()

    @property
    def reproduced(self) -> bool:
        """Every output equal to the recording within the tolerance, and something compared."""
        return all(c.reproduced for c in self.outputs) and not self.shortfall()

    @property
    def ok(self) -> bool:
        """The re-run passes: bit-identical on the recording machine, within tolerance elsewhere."""
        return self.identical if self.same_machine else self.reproduced

    def comparison(self, topic: str) -> TopicComparison:
        for c in self.outputs:
            if c.topic == topic:
                return c
        raise KeyError(topic)

    def describe(self) -> str:
        head = (
            f"re-ran {self.node} on {self.bag}: {self.cycles} cycles, inputs "
            + ", ".join(f"{t} ({n})" for t, n in self.inputs.items())
            + f"; {self.wall_time:.2f} s wall"
        )
        if self.overrides:
            head += "\n  overrides: " + ", ".join(f"{k}={v!r}" for k, v in self.overrides.items())
        if self.rejected:
            head += f"\n  inputs rejected by the node: {self.rejected}"
        t = self.tolerance
        head += f"\n  tolerance per field: {t.absolute:g} + {t.relative:g}·max|recorded|; " + (
            "recorded on this machine: bit-identity required"
            if self.same_machine
            else "recorded on another machine (or stack): bit-identity not required"
        )
        head += (
            f"\n  compared {self.compared} recorded output messages on {len(self.outputs)} "
            f"topics, fed {sum(self.inputs.values())} recorded input messages"
        )
        short = self.shortfall()
        if short:
            verdict = "FAILED: the re-run checked less than the recording holds: " + "; ".join(
                short
            )
        elif self.identical:
            verdict = "outputs IDENTICAL to the recording"
        elif self.reproduced:
            verdict = "outputs equal to the recording WITHIN TOLERANCE" + (
                ", but not bit-identical on the recording machine" if self.same_machine else ""
            )
        else:
            verdict = "outputs DIFFER from the recording"
        return "\n".join([head, *(c.describe() for c in self.outputs), verdict])


def compare_outputs(
    topic: str, recorded: list, rerun: list, tolerance: RerunTolerance | None = None
) -> TopicComparison:
    """Field-by-field comparison of two message lists (deserialized), matched in order."""
    tolerance = tolerance or RerunTolerance()
    comparison = TopicComparison(topic, len(recorded), len(rerun), 0)
    first_outside: str | None = None
    first_inexact: str | None = None
    for i, (a, b) in enumerate(zip(recorded, rerun, strict=False)):
        fa, fb = flatten_message(a), flatten_message(b)
        if not comparison.ignored:
            comparison.ignored = ignored_fields(a)
        same = close = True
        worst: tuple[float, str] = (0.0, "")
        for name in sorted(set(fa) | set(fb)):
            d = _difference(fa.get(name), fb.get(name)) if name in fa and name in fb else math.inf
            if d > 0:
                same = False
                close = close and tolerance.allows(fa.get(name), d)
                comparison.max_difference[name] = max(comparison.max_difference.get(name, 0), d)
                worst = max(worst, (d, name))
        if same:
            comparison.identical += 1
        if close:
            comparison.within_tolerance += 1
        if not same and (first_inexact is None or (not close and first_outside is None)):
            t = message_time(a)
            when = f"message {i}" + (f" (t = {t:.6f} s)" if t is not None else "")
            shown = f"{when}: " + _show(worst[1], fa.get(worst[1]), fb.get(worst[1]))
            first_inexact = first_inexact or shown
            if not close:
                first_outside = shown
    # The first message outside the tolerance; else the first not bit-identical.
    comparison.first_difference = first_outside or first_inexact
    if len(recorded) != len(rerun) and comparison.first_difference is None:
        comparison.first_difference = f"{len(recorded)} recorded vs {len(rerun)} re-run messages"
    return comparison


def _show(name: str, recorded: object, rerun: object) -> str:
    """The largest difference of one field: element, both values, |Δ|."""
    if isinstance(recorded, np.ndarray) and isinstance(rerun, np.ndarray):
        if recorded.shape == rerun.shape and recorded.size:
            diff = np.abs(recorded - rerun)
            diff[np.isnan(diff)] = math.inf
            i = int(np.argmax(diff))
            element = f"{name}[{i}]" if recorded.size > 1 else name
            return (
                f"{element} recorded {float(recorded[i])!r}, re-run {float(rerun[i])!r} "
                f"(|Δ| {diff[i]:.3g})"
            )
        return f"{name} has {recorded.size} recorded values, {rerun.size} re-run"
    return f"{name} recorded {recorded!r}, re-run {rerun!r}"


# -- parameters -------------------------------------------------------------------------------
def bag_namespace(bag: BagReader) -> str:
    """The namespace of the graph a bag recorded: the one its ``ffmpc_run`` metadata names, or
    (another recorder's bag) the one its topic names show (``topics.namespace_of``)."""
    run = bag.metadata_named("ffmpc_run") or {}
    if run.get("namespace"):
        return topics.normalize_namespace(run["namespace"])
    return topics.namespace_of(bag.topics)


def node_parameters(bag: BagReader, node: str) -> dict[str, Any]:
    """The parameters ``node`` ran with, as recorded in the bag (the node of the bag's graph,
    :func:`bag_namespace`, when several namespaces hold one of that name)."""
    params = bag.parameters
    own = f"{bag_namespace(bag).rstrip('/')}/{node}"
    if own in params:
        return dict(params[own])
    for fqn, values in params.items():
        if fqn == node or fqn.rsplit("/", 1)[-1] == node:
            return dict(values)
    raise RerunError(
        f"the bag holds no parameters of node {node!r} (it has {sorted(params)}); record runs "
        "with `ffmpc run --record` or the recorder node"
    )


def apply_overrides(node: str, values: dict[str, Any], overrides: Mapping[str, Any]) -> None:
    """Set overrides given by the node's parameter names or by scenario names (``mpc.horizon``
    for the MPC node's ``horizon``); ConfigError for a parameter the node does not read. A number
    replacing a float parameter becomes a float."""
    from ffmpc_ros.params import NODE_SPECS, node_scenario_names, scenario_flat

    spec = NODE_SPECS[node]
    by_scenario = {
        scen: ros
        for ros, scen in node_scenario_names(spec, scenario_flat(Scenario(name="d"))).items()
    }
    for name, value in overrides.items():
        ros = name if name in values else by_scenario.get(name)
        if ros is None or ros not in values:
            raise ConfigError(f"node {node} has no parameter {name!r}")
        old = values[ros]
        if isinstance(old, float) and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        values[ros] = value


# -- the re-run -------------------------------------------------------------------------------
def _spin_until(executor: Executor, done: Callable[[], bool], timeout: float, what: str) -> None:
    end = time.monotonic() + timeout
    while not done():
        if time.monotonic() > end:
            raise RerunError(f"timed out after {timeout} s waiting for {what}")
        executor.spin_once(timeout_sec=0.002)


def rerun_node(
    path: str | os.PathLike,
    node: str = "mpc",
    overrides: Mapping[str, Any] | None = None,
    *,
    domain_id: int | None = None,
    timeout: float = 10.0,
    tolerance: RerunTolerance | None = None,
) -> RerunReport:
    """Re-run ``node`` on the inputs recorded in bag ``path`` (module docstring).

    Args:
        overrides: parameter changes ({name: value}, scenario or node names).
        timeout: wall seconds to wait for the node at any one step (RerunError beyond).
        tolerance: how close outputs must be off the recording machine (default
            :class:`RerunTolerance`).
    """
    from ffmpc_ros.graph_nodes import NODES, load_node_class
    from ffmpc_ros.params import parameter_overrides

    if node not in RERUN_NODES:
        raise ConfigError(f"cannot re-run {node!r}; nodes: {RERUN_NODES}")
    overrides = dict(overrides or {})
    start = time.perf_counter()
    with BagReader(path) as bag:
        values = node_parameters(bag, node)
        values.pop("use_sim_time", None)
        values.pop("autostart", None)  # recorded false under the bring-up: the re-run starts itself
        # the recorded graph's start barrier: the re-run node is alone, nothing to wait for
        values.pop("start_clock_subscribers", None)
        apply_overrides(node, values, overrides)
        prefix = f"/_ffmpc_rerun_{os.getpid()}"
        namespace = bag_namespace(bag)
        clock = topics.resolve(topics.CLOCK, namespace)
        references = (topics.resolve(t, namespace) for t, _, _ in topics.REFERENCE_TOPICS)
        graph = (t for t, _, _ in topics.resolved_topics(namespace))
        names = sorted({*bag.topics, *graph, *references})
        # /clock (the time source's) goes to the recorded clock; rules are not chained
        remaps = ["-r", f"{topics.CLOCK}:={prefix}{clock}"]
        if namespace != topics.ROOT_NAMESPACE:
            remaps += ["-r", f"__ns:={namespace}"]
        remaps += [a for t in names if t != topics.CLOCK for a in ("-r", f"{t}:={prefix}{t}")]
        values.update(_rerun_qos(bag, names, prefix))
        domain = _env_domain_id() if domain_id is None else domain_id
        context = Context()
        rclpy.init(args=[], context=context, domain_id=domain)
        executor = EventsExecutor(context=context)
        created: list[Node] = []
        try:
            try:
                target = load_node_class(NODES[node])(
                    context=context,
                    parameter_overrides=parameter_overrides(values),
                    node_name=f"_rerun_{node}",
                    cli_args=["--ros-args", *remaps],
                )
            except ParameterException as exc:
                raise ConfigError(f"{node} refuses its parameters: {exc}") from None
            created.append(target)
            feeder = Node(f"_rerun_feeder_{node}", context=context)
            created.append(feeder)
            for n in created:
                executor.add_node(n)
            report = _run(
                bag,
                node,
                target,
                feeder,
                executor,
                prefix,
                timeout,
                overrides,
                start,
                tolerance,
                clock,
            )
            report.same_machine = same_machine(bag.metadata_named(MACHINE_RECORD))
            return report
        finally:
            for n in created:
                executor.remove_node(n)
                n.destroy_node()
            executor.shutdown()
            rclpy.shutdown(context=context)


def _rerun_qos(bag: BagReader, names: Iterable[str], prefix: str) -> dict[str, str | int]:
    """QoS override parameters of the re-run node's remapped topics: its readers as reliable as
    the recording's publishers were (a reliable reader would not match a best-effort feeder),
    its writers reliable with the graph's history (the collectors must get every output)."""
    out: dict[str, str | int] = {}
    for t in names:
        profiles = bag.topics[t].qos_profiles if t in bag.topics else []
        reliable = bool(profiles) and all(p.get("reliability") == "reliable" for p in profiles)
        base = f"qos_overrides.{prefix}{t}"
        out[f"{base}.subscription.reliability"] = "reliable" if reliable else "best_effort"
        out[f"{base}.publisher.reliability"] = "reliable"
        out[f"{base}.publisher.depth"] = topics.PUBLISHER_DEPTH
    return out


def _strip(prefix: str, name: str) -> str:
    return name[len(prefix) :] if name.startswith(prefix) else name


def _type_name(cls: Any) -> str:
    """``pkg/msg/Type`` of an rclpy message class."""
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


def _check_types(
    bag: BagReader, node: str, target: GraphNode, prefix: str, names: list[str]
) -> None:
    """RerunError when a topic was recorded with another type than the node uses now (a bag
    from before ``mpc/command`` became ``ffmpc_msgs/msg/MpcCommand``: record it again)."""
    entities: list[Subscription | Publisher] = [*target.subscriptions, *target.publishers]
    ours = {_strip(prefix, e.topic_name): _type_name(e.msg_type) for e in entities}
    for t in names:
        if t in ours and bag.topics[t].type != ours[t]:
            raise RerunError(
                f"{t} was recorded as {bag.topics[t].type}; this {node} node uses {ours[t]} "
                f"(the bag predates that message: record it again with this version)"
            )


def _run(
    bag: BagReader,
    node: str,
    target: GraphNode,
    feeder: Node,
    executor: Executor,
    prefix: str,
    timeout: float,
    overrides: Mapping[str, Any],
    start: float,
    tolerance: RerunTolerance | None,
    clock: str,
) -> RerunReport:
    tolerance = tolerance or RerunTolerance()
    ignored = {*_IGNORED_TOPICS, clock}  # clock: the bag's (/arm1/clock under a namespace)
    inputs = sorted({_strip(prefix, s.topic_name) for s in target.subscriptions} - ignored)
    outputs = sorted({_strip(prefix, p.topic_name) for p in target.publishers} - ignored)
    # The MPC's reference inputs come from outside the graph: a bag without them had none.
    namespace = bag_namespace(bag)
    optional = {topics.resolve(name, namespace) for name, _, _ in topics.REFERENCE_TOPICS}
    inputs = [t for t in inputs if t in bag.topics or t not in optional]
    missing = [t for t in inputs if t not in bag.topics]
    if missing:
        raise RerunError(f"the bag lacks the inputs {missing} of {node}")
    outputs = [t for t in outputs if t in bag.topics]
    _check_types(bag, node, target, prefix, [*inputs, *outputs])
    step_ns = target.step_ns
    # Publishers of the recorded inputs and /clock, collectors of the outputs.
    pubs = {
        t: feeder.create_publisher(
            message_class(bag.topics[t].type),
            prefix + t,
            qos_from_dicts(bag.topics[t].qos_profiles),
        )
        for t in [*inputs, *([clock] if clock in bag.topics else [])]
    }
    collected: dict[str, list[bytes]] = {t: [] for t in outputs}
    for t in outputs:
        qos = qos_from_dicts(bag.topics[t].qos_profiles, depth=10000)
        # the re-run node has its default QoS (the graph's overrides name the graph's topics,
        # not the re-run's remapped ones): a volatile reader matches it whatever the bag's
        # durability, and nothing is lost, the inputs go out once it is matched
        qos.durability = DurabilityPolicy.VOLATILE
        feeder.create_subscription(
            message_class(bag.topics[t].type), prefix + t, collected[t].append, qos, raw=True
        )
    _spin_until(
        executor,
        lambda: (
            all(p.get_subscription_count() > 0 for p in pubs.values())
            and all(target.count_subscribers(prefix + t) > 0 for t in outputs)
        ),
        timeout,
        "the re-run node to match the feeder",
    )
    # Inputs by cycle, in recorded order.
    types = {t: message_class(bag.topics[t].type) for t in pubs}
    by_cycle: dict[int, list[tuple[str, int, bytes]]] = {}
    clock_of: dict[int, bytes] = {}
    last = 0
    count = dict.fromkeys(inputs, 0)
    for m in bag.messages(list(pubs)):
        msg = deserialize_message(m.data, types[m.topic])
        t_msg = message_time(msg)  # s
        k = last if t_msg is None else int(round(t_msg * 1e9 / step_ns))
        last = k
        if m.topic == clock:
            clock_of.setdefault(k, m.data)
            continue
        by_cycle.setdefault(k, []).append((m.topic, k, m.data))
        count[m.topic] += 1

    def rejected(topic: str) -> int:
        return sum(v for key, v in target.rejected.items() if key.startswith(topic + ":"))

    node_clock = target.get_clock()
    for k in sorted(by_cycle):
        if k in clock_of:
            pubs[clock].publish(clock_of[k])

            def clock_reached(k: int = k) -> bool:
                return node_clock.now().nanoseconds >= k * step_ns

            _spin_until(executor, clock_reached, timeout, f"the node's clock to reach cycle {k}")
        pending = []
        for topic, kk, data in by_cycle[k]:
            pending.append((topic, kk, rejected(topic)))
            pubs[topic].publish(data)

        def taken(pending: list[tuple[str, int, int]] = pending) -> bool:
            return all(
                target.gate.last_cycle(topic) >= kk or rejected(topic) > before
                for topic, kk, before in pending
            )

        _spin_until(executor, taken, timeout, f"{node} to take the inputs of cycle {k}")
    # Outputs: wait until they stop coming.
    expected = {t: bag.topics[t].count for t in outputs}
    quiet_since = time.monotonic()
    seen = -1
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        now_seen = sum(len(v) for v in collected.values())
        if now_seen != seen:
            seen, quiet_since = now_seen, time.monotonic()
        enough = all(len(collected[t]) >= expected[t] for t in outputs)
        if time.monotonic() - quiet_since > (0.05 if enough else 0.5):
            break
        executor.spin_once(timeout_sec=0.005)
    recorded: dict[str, list[BagMessage]] = {t: [] for t in outputs}
    for m in bag.messages(outputs) if outputs else ():
        recorded[m.topic].append(m)
    comparisons = []
    for t in outputs:
        cls = message_class(bag.topics[t].type)
        comparisons.append(
            compare_outputs(
                t,
                [deserialize_message(m.data, cls) for m in recorded[t]],
                [deserialize_message(d, cls) for d in collected[t]],
                tolerance,
            )
        )
    return RerunReport(
        node=node,
        bag=str(bag.path),
        overrides=dict(overrides),
        inputs=count,
        outputs=comparisons,
        cycles=len(by_cycle),
        wall_time=time.perf_counter() - start,
        rejected=dict(target.rejected),
        tolerance=tolerance,
        summary_counts={t: bag.topics[t].count for t in [*inputs, *outputs]},
    )
