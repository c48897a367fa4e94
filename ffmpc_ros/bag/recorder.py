"""The recorder node: raw subscriptions into a :class:`~ffmpc_ros.bag.writer.BagWriter`.

It records every topic of the graph (or a chosen set) as it is discovered, from raw (CDR)
subscriptions whose QoS matches the publishers' (reliable and transient-local when all of them
are, like rosbag2), with each channel's offered QoS and type hash. It records ``/clock`` like any
topic, and asks every node for its parameters (``list_parameters`` / ``get_parameters``
services) and stores them as metadata, so a bag describes its own run. Log times are the
recorder's clock at reception: simulated time when the graph runs on ``/clock``
(``use_sim_time``, the default), as ``ros2 bag record --use-sim-time`` does.

Start-up gate. A run must not start before the recorder sees it: with ``gate_topic`` the
recorder subscribes to that topic only once every topic of ``wait_for`` has a matched publisher
and the parameters of every node of ``parameters_of`` are in. ``ffmpc run --record`` gates on
``/plant/joint_states`` and the plant waits for one more subscriber of it, so nothing of the run
is missed (:func:`graph_recorder`).

Namespace. With ``namespace`` (a graph run under ``/arm1``) the recorder records only the topics
inside it (``/arm1/...``, its clock ``/arm1/clock`` included) and the domain-wide ``/diagnostics``
and ``/rosout``, and asks only the nodes inside it for their parameters: a second graph on the
same domain stays out of the bag. The bag's topic names are the fully qualified ones, and the
``ffmpc_run`` metadata record names the namespace (``ffmpc bag`` resolves the graph's names
with it).
"""

from __future__ import annotations

import json
import os
import signal
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import IO, TYPE_CHECKING, Any

import rclpy
from rcl_interfaces.srv import GetParameters, ListParameters
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.task import Future
from rclpy.topic_endpoint_info import TopicEndpointInfo

from ffmpc_ros.bag.ros_types import offered_profiles, subscribe_raw
from ffmpc_ros.bag.writer import BagWriter
from ffmpc_ros.discovery import domain_id as _env_domain_id
from ffmpc_ros.graph_nodes import SERVICE_RETRY

if TYPE_CHECKING:
    from ffmpc_core.scenario import Scenario

#: Topics not recorded unless asked for by name.
DEFAULT_EXCLUDE = ("/parameter_events",)
#: Absolute topics a namespaced recorder records beside its namespace's (shared by every graph
#: on the domain; each status or log line names its node).
DOMAIN_TOPICS = ("/diagnostics", "/rosout")
#: History kept by every recording subscription, messages.
RECORD_DEPTH = 1000
#: Wall seconds between two looks at the graph once the gate is open.
LATE_DISCOVERY_PERIOD = 0.5


def _fqn(name: str, namespace: str) -> str:
    return f"{namespace.rstrip('/')}/{name}"


class _ParameterFetch:
    """list_parameters then get_parameters of one node, polled from a timer (the recorder's) or
    a loop (the bring-up's); an unanswered request is sent again after
    :data:`~ffmpc_ros.graph_nodes.SERVICE_RETRY`.

    A parameter declared with a type but no value (e.g. the impact planner's
    ``acceleration_limit`` under a plain ``ros2 run``) makes rclpy's get_parameters answer
    with NO value at all for the whole request (``ParameterUninitializedException`` empties the
    response). The fetch then asks for each name alone: a name answered with no value is
    recorded as unset (None, JSON null in the bag), the others with their values."""

    def __init__(self, node: Node, fqn: str) -> None:
        self.fqn = fqn
        self.list_client = node.create_client(ListParameters, f"{fqn}/list_parameters")
        self.get_client = node.create_client(GetParameters, f"{fqn}/get_parameters")
        self.future: Future | None = None
        self._asked = 0.0  # monotonic s of the pending request
        self.names: list[str] | None = None
        self.values: dict[str, Any] | None = None
        self._asking: list[str] = []  # the names of the pending get_parameters request
        self._one_by_one: list[str] | None = None  # names still to ask alone (fallback)
        self._got: dict[str, Any] = {}

    def poll(self) -> bool:
        """Advance one step if possible; True once the values are in."""
        if self.values is not None:
            return True
        if self.future is not None and not self.future.done():
            if time.monotonic() - self._asked > SERVICE_RETRY:
                self.future = None  # lost: ask again below, on this poll or a later one
            else:
                return False
        if self.names is None:
            if self.future is None:
                if self.list_client.service_is_ready():
                    self.future = self.list_client.call_async(ListParameters.Request())
                    self._asked = time.monotonic()
                return False
            self.names = sorted(self.future.result().result.names)
            self.future = None
        if self.future is None:
            names = self.names if self._one_by_one is None else self._one_by_one[:1]
            if not names:
                return self._finish()
            if self.get_client.service_is_ready():
                self._asking = list(names)
                self.future = self.get_client.call_async(GetParameters.Request(names=names))
                self._asked = time.monotonic()
            return False
        answer = list(self.future.result().values)
        self.future = None
        if len(answer) != len(self._asking):
            if len(self._asking) > 1:  # an unset parameter emptied the answer: ask one by one
                self._one_by_one = list(self._asking)
                return self.poll()
            self._got[self._asking[0]] = None  # declared, no value
        else:
            for name, value in zip(self._asking, answer, strict=True):
                v = parameter_value_to_python(value)
                self._got[name] = (
                    list(v) if not isinstance(v, str | bytes) and hasattr(v, "__len__") else v
                )
        if self._one_by_one is not None:
            self._one_by_one = self._one_by_one[len(self._asking) :]
            return self.poll()
        return self._finish()

    def _finish(self) -> bool:
        assert self.names is not None
        self.values = {n: self._got.get(n) for n in self.names}
        return True


class BagRecorder(Node):
    """Records topics and parameters into a bag (module docstring).

    Args:
        target: bag path (must not exist) or binary file object.
        topics: topics to record (None: every topic discovered, less ``exclude``).
        exclude: topics never recorded when recording everything.
        wait_for: topics that must have a matched publisher before the gate opens.
        gate_topic: topic subscribed only once the gate opens (None: no gate).
        parameters_of: node names whose parameters must be in before the gate opens; every
            other node discovered is asked too (None: every node, nothing waited for).
        use_sim_time: log times on ``/clock`` (simulated) rather than the system clock.
        metadata: extra metadata records {name: {key: value}} written at once.
        writer_options: keyword arguments of :class:`BagWriter` (``chunk_size``,
            ``compression``, ``flush_interval``, ``fsync``).
        discovery_period: wall seconds between two looks at the graph.
        final_topic: the run is over once a message of this topic is recorded and nothing came
            for ``settle`` wall seconds (:attr:`complete`).
        namespace: record only this namespace's topics (and :data:`DOMAIN_TOPICS`) and nodes
            (None or ``/``: everything on the domain).
        lockstep_member: the recorder of a lockstep graph: once its gate opens (every reader
            exists), it subscribes the start barrier's membership marker, so that the graph's
            writers match its readers before the first sample (ffmpc_ros.topics.START_MEMBER).
    """

    def __init__(
        self,
        target: str | os.PathLike | IO[bytes],
        *,
        context: Context | None = None,
        node_name: str = "ffmpc_recorder",
        topics: Iterable[str] | None = None,
        exclude: Iterable[str] = DEFAULT_EXCLUDE,
        wait_for: Iterable[str] = (),
        gate_topic: str | None = None,
        parameters_of: Iterable[str] | None = None,
        use_sim_time: bool = True,
        metadata: Mapping[str, Mapping[str, str]] | None = None,
        writer_options: Mapping[str, Any] | None = None,
        discovery_period: float = 0.05,
        final_topic: str | None = None,
        settle: float = 0.2,
        namespace: str | None = None,
        lockstep_member: bool = False,
    ) -> None:
        super().__init__(
            node_name,
            context=context,
            parameter_overrides=[Parameter("use_sim_time", value=use_sim_time)],
        )
        self.writer = BagWriter(target, **dict(writer_options or {}))
        ns = (namespace or "/").rstrip("/")
        self._inside = None if not ns else ns + "/"  # prefix of the recorded names
        self.topics = set(topics) if topics is not None else None
        self.exclude = set(exclude)
        self.wait_for = set(wait_for) - {gate_topic}
        self.gate_topic = gate_topic
        self.parameters_of = list(parameters_of) if parameters_of is not None else []
        self.received: dict[str, int] = {}
        self._recording_subs: dict[str, Any] = {}
        self._channels: dict[str, int] = {}
        self._fetches: dict[str, _ParameterFetch] = {}
        self.parameters: dict[str, dict[str, Any]] = {}
        self.gate_open = gate_topic is None
        self.lockstep_member = lockstep_member
        self.final_topic = final_topic
        self.settle = settle
        self.last_message_at = time.monotonic()
        self.closed = False
        self._created = time.time()
        for name, data in (metadata or {}).items():
            self.writer.add_metadata(name, data)
        self._timer = self.create_timer(
            discovery_period, self.discover, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self.discover()

    # -- discovery ---------------------------------------------------------------------------
    def _wanted(self, topic: str) -> bool:
        if topic == self.gate_topic and not self.gate_open:
            return False
        if self._inside is not None and not (
            topic.startswith(self._inside) or topic in DOMAIN_TOPICS
        ):
            return False
        if self.topics is not None:
            return topic in self.topics or topic == self.gate_topic
        return topic not in self.exclude

    def discover(self) -> None:
        """Subscribe to new topics, ask new nodes for their parameters, open the gate."""
        if self.closed:
            return
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recording_subs or not self._wanted(topic):
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # the publishers' QoS decides ours: wait for one
            self._subscribe(topic, publishers[0].topic_type or types[0], publishers)
        me = self.get_fully_qualified_name()
        for name, namespace in self.get_node_names_and_namespaces():
            fqn = _fqn(name, namespace)
            if fqn == me or name.startswith("_") or fqn in self._fetches:
                continue
            if self._inside is not None and not fqn.startswith(self._inside):
                continue  # another graph's node
            self._fetches[fqn] = _ParameterFetch(self, fqn)
        for fqn, fetch in self._fetches.items():
            if fqn not in self.parameters and fetch.poll() and fetch.values is not None:
                self.parameters[fqn] = fetch.values
                self.writer.add_parameters(fqn, fetch.values)
        if not self.gate_open and self._ready():
            self.gate_open = True
            # The run starts now: look at the graph less often, off its hot path.
            self._timer.cancel()
            self._timer = self.create_timer(
                LATE_DISCOVERY_PERIOD, self.discover, clock=Clock(clock_type=ClockType.STEADY_TIME)
            )
            self.discover()
            if self.lockstep_member:
                # every reader of the recorder exists: its membership marker of the graph's start
                # barrier, last (ffmpc_ros.topics.START_MEMBER)
                from std_msgs.msg import Empty

                from ffmpc_ros import topics as graph_topics

                self.create_subscription(
                    Empty,
                    graph_topics.START_MEMBER,
                    lambda msg: None,
                    graph_topics.start_ready_qos(),
                )

    def _ready(self) -> bool:
        for topic in self.wait_for:
            sub = self._recording_subs.get(topic)
            if sub is None or sub.get_publisher_count() == 0:
                return False
        recorded = {fqn.rsplit("/", 1)[-1] for fqn in self.parameters} | set(self.parameters)
        return all(node in recorded for node in self.parameters_of)

    def _subscribe(self, topic: str, type_name: str, publishers: list[TopicEndpointInfo]) -> None:
        profiles = offered_profiles(publishers)
        channel = self.writer.add_topic(
            topic,
            type_name,
            qos_profiles=profiles,
            type_hash=str(publishers[0].topic_type_hash),
        )
        self._channels[topic] = channel
        self.received[topic] = 0
        clock = self.get_clock()
        writer = self.writer
        received = self.received

        def on_message(data: bytes) -> None:
            now = clock.now().nanoseconds
            writer.write(channel, data, now)
            received[topic] += 1
            self.last_message_at = time.monotonic()

        self._recording_subs[topic] = subscribe_raw(
            self, topic, type_name, profiles, on_message, RECORD_DEPTH
        )

    @property
    def complete(self) -> bool:
        """``final_topic`` recorded and nothing received for ``settle`` s (True without one)."""
        if self.final_topic is None:
            return True
        if not self.received.get(self.final_topic):
            return False
        return time.monotonic() - self.last_message_at >= self.settle

    @property
    def ready(self) -> bool:
        """The gate is open (always, without a gate topic)."""
        return self.gate_open

    # -- end ---------------------------------------------------------------------------------
    def close(self) -> None:
        """Stop recording and close the bag (summary, footer). Idempotent."""
        if self.closed:
            return
        self.closed = True
        self._timer.cancel()
        for sub in self._recording_subs.values():
            self.destroy_subscription(sub)
        self.writer.add_metadata(
            "ffmpc_recorder",
            {
                "node": self.get_fully_qualified_name(),
                "received": json.dumps(self.received),
                "parameters_of": json.dumps(sorted(self.parameters)),
                "started_unix_s": f"{self._created:.3f}",
                "stopped_unix_s": f"{time.time():.3f}",
            },
        )
        self.writer.close()

    def destroy_node(self) -> None:
        self.close()
        super().destroy_node()


def graph_recorder_metadata(
    scenario: Scenario | None = None,
    run: Mapping[str, Mapping[str, Any]] | None = None,
    namespace: str = "/",
) -> dict[str, dict[str, str]]:
    """Metadata records of ``ffmpc run --record`` (see :func:`graph_recorder`), JSON-able."""
    import yaml

    from ffmpc_core.scenario import scenario_parameters
    from ffmpc_ros.bag.machine import MACHINE_RECORD, machine_fingerprint
    from ffmpc_ros.graph_nodes import nested_parameters

    info: dict[str, str] = {"namespace": namespace}
    if scenario is not None:
        sections = scenario_parameters(scenario)
        info["scenario_name"] = scenario.name
        info["scenario"] = yaml.safe_dump(
            {sec: {"ros__parameters": nested_parameters(v)} for sec, v in sections.items()},
            sort_keys=False,
        )
    if run is not None:
        info["params_file"] = yaml.safe_dump(
            {node: {"ros__parameters": nested_parameters(v)} for node, v in run.items()},
            sort_keys=False,
        )
    records = {MACHINE_RECORD: machine_fingerprint()}
    records["ffmpc_run"] = info
    return records


def _graph_recorder_options(
    namespace: str | None = None, view_robot: str | None = None
) -> dict[str, Any]:
    """The graph recorder's topics, fully qualified under ``namespace`` (``/arm1/clock``); with
    ``view_robot`` (``--view``) the live view's topics too. ``/tf``, ``/tf_static`` and
    ``robot_description`` are the state publisher's, in every graph (``topics.TOPICS``)."""
    from ffmpc_ros import topics
    from ffmpc_ros.graph_nodes import NODES

    def name(topic: str) -> str:
        return topics.resolve(topic, namespace)

    extra = [name(t) for t, _, _ in topics.VIEW_TOPICS] if view_robot else []
    return {
        "wait_for": [t for t, _, _ in topics.resolved_topics(namespace)] + extra,
        "gate_topic": name(topics.PLANT_JOINT_STATES),
        "parameters_of": [*NODES, "metrics"],
        "final_topic": name(topics.METRICS_SUMMARY),
        "namespace": topics.normalize_namespace(namespace),
        "lockstep_member": True,
    }


def graph_recorder(
    target: str | os.PathLike,
    *,
    context: Context | None = None,
    scenario: Scenario | None = None,
    run: Mapping[str, Mapping[str, Any]] | None = None,
    view: str | None = None,
    namespace: str | None = None,
) -> BagRecorder:
    """The recorder of ``ffmpc run --record``: every topic, gated on ``/plant/joint_states``
    until every topic of the contract (``ffmpc_ros.topics.TOPICS``) has a publisher and the six
    nodes' parameters are in; :attr:`BagRecorder.complete` once the metrics summary is in.
    Metadata ``ffmpc_run`` holds the scenario file and the generated parameter file of the run
    (``run``: {node: {name: value}}); ``ffmpc_machine`` the recording machine's fingerprint
    (:func:`ffmpc_ros.bag.machine.machine_fingerprint`). ``namespace``: the graph's (the
    recorder node itself takes its context's, see ``ffmpc_ros.bringup``). With ``view``
    (``--view``: the robot's name) the gate also waits for the live view's topics
    (``ffmpc_ros.topics.VIEW_TOPICS``)."""
    from ffmpc_ros.topics import normalize_namespace

    return BagRecorder(
        target,
        context=context,
        metadata=graph_recorder_metadata(scenario, run, normalize_namespace(namespace)),
        **_graph_recorder_options(namespace, view),
    )


def graph_recorder_process(config_path: str) -> int:
    """The graph recorder in its own process (``ffmpc run --record``, multi-process).

    ``config_path``: JSON {"target": bag path, "domain": ROS domain, "metadata": records,
    "counts": path of the JSON written at the end, optionally "options": the BagRecorder
    keyword arguments (default: the polishing graph's)}. Records until the run is complete
    (:attr:`BagRecorder.complete`) or SIGINT/SIGTERM — including the SIGTERM the kernel sends
    when the bring-up dies (PR_SET_PDEATHSIG, set by the bring-up) — then closes the bag
    (summary, footer: readable without recovery) and writes {"received", "complete",
    "signal"} to ``counts``."""
    from ffmpc_ros.child_process import child_ros_process

    with child_ros_process(config_path) as child:
        config, executor, stopping = child.config, child.executor, child.stopping
        # "options": the BagRecorder options of another graph (the impact graph's); default
        # the polishing graph's
        options = config.get("options") or _graph_recorder_options(
            config.get("namespace"), config.get("view")
        )
        recorder = BagRecorder(
            config["target"], context=child.context, metadata=config["metadata"], **options
        )
        executor.add_node(recorder)
        try:
            while not stopping and not recorder.complete:
                executor.spin_once(timeout_sec=0.05)
        finally:
            complete = recorder.complete
            recorder.close()
            with open(config["counts"], "w", encoding="utf-8") as fh:
                json.dump(
                    {
                        "received": recorder.received,
                        "complete": complete,
                        "signal": stopping[0] if stopping else None,
                    },
                    fh,
                )
            executor.remove_node(recorder)
            recorder.destroy_node()
    return 0


def record_bag(
    target: str | os.PathLike,
    *,
    topics: Sequence[str] | None = None,
    duration: float | None = None,
    domain_id: int | None = None,
    use_sim_time: bool = True,
    writer_options: Mapping[str, Any] | None = None,
    stop: Callable[[], bool] | None = None,
) -> BagRecorder:
    """Record a live graph until Ctrl-C/SIGTERM, ``duration`` wall seconds or ``stop()`` returns
    True; returns the (closed) recorder with its counts."""
    from rclpy.experimental import EventsExecutor

    domain = _env_domain_id() if domain_id is None else domain_id
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    executor = EventsExecutor(context=context)
    recorder = BagRecorder(
        target,
        context=context,
        topics=topics,
        use_sim_time=use_sim_time,
        writer_options=writer_options,
    )
    executor.add_node(recorder)
    end = None if duration is None else time.monotonic() + duration
    stopping = []
    previous = signal.signal(signal.SIGTERM, lambda *_: stopping.append(True))
    try:
        while not stopping and (end is None or time.monotonic() < end):
            if stop is not None and stop():
                break
            executor.spin_once(timeout_sec=0.05)
    except KeyboardInterrupt:
        pass
    finally:
        signal.signal(signal.SIGTERM, previous)
        recorder.close()
        executor.remove_node(recorder)
        recorder.destroy_node()
        executor.shutdown()
        rclpy.shutdown(context=context)
    return recorder


if __name__ == "__main__":
    import sys

    raise SystemExit(graph_recorder_process(sys.argv[1]))
