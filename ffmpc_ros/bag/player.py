"""The player: republish a bag's messages with their original timing.

Message i is published ``(log_time_i − log_time_0) / rate`` wall seconds after the start, as the
recorded CDR bytes (no decoding), on its topic or the topic it is remapped to, with a QoS that
matches the recorded publishers' (reliable / transient-local when they all were). The recorded
``/clock`` is replayed like any topic, so nodes with ``use_sim_time`` follow the bag's time; with
``clock_rate`` the player publishes ``/clock`` itself from the bag time at that rate instead
(for bags without one). A bag of a graph under a namespace replays on its recorded names
(``/arm1/plant/joint_states``, clock ``/arm1/clock``): nodes started with ``-r __ns:=/arm1 -r
/clock:=clock`` read it.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import rclpy
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg

from ffmpc_ros.bag.errors import BagError
from ffmpc_ros.bag.reader import BagMessage, BagReader
from ffmpc_ros.bag.ros_types import is_installed, message_class, qos_from_dicts
from ffmpc_ros.discovery import domain_id as _env_domain_id

CLOCK = "/clock"


def parse_remaps(items: Iterable[str]) -> dict[str, str]:
    """``FROM:=TO`` pairs (ROS remapping syntax) as {from: to}."""
    out = {}
    for item in items:
        source, sep, target = item.partition(":=")
        if not sep or not source.startswith("/") or not target.startswith("/"):
            raise BagError(f"remap {item!r}: expected /from/topic:=/to/topic")
        out[source] = target
    return out


@dataclass
class PlayReport:
    """What a playback published."""

    published: dict[str, int] = field(default_factory=dict)  # by recorded topic
    wall_time: float = 0.0  # s, from the first to the last message
    bag_time: float = 0.0  # s of bag time played
    max_lateness: float = 0.0  # s, worst delay of a message after its due time
    mean_lateness: float = 0.0
    skipped: list[str] = field(default_factory=list)  # topics whose type rclpy lacks here

    def describe(self) -> str:
        total = sum(self.published.values())
        skipped = (
            f"; not played (type not installed): {', '.join(self.skipped)}" if self.skipped else ""
        )
        return (
            f"published {total} messages on {len(self.published)} topics: {self.bag_time:.3f} s "
            f"of bag time in {self.wall_time:.3f} s wall; lateness mean "
            f"{1e3 * self.mean_lateness:.2f} ms, max {1e3 * self.max_lateness:.2f} ms{skipped}"
        )


class BagPlayer:
    """Publishes a bag from ``node`` (module docstring); drive it with :meth:`publish_due`.

    Args:
        node: the node that owns the publishers.
        bag: an open bag.
        rate: playback speed factor (2: twice as fast).
        topics: recorded topics to play (None: all).
        remap: {recorded topic: published topic}.
        clock_rate: publish ``/clock`` from the bag time at this rate (Hz) instead of replaying
            the recorded one (None: replay it).
    """

    def __init__(
        self,
        node: Node,
        bag: BagReader,
        *,
        rate: float = 1.0,
        topics: Iterable[str] | None = None,
        remap: Mapping[str, str] | None = None,
        clock_rate: float | None = None,
    ) -> None:
        if not rate > 0:
            raise BagError(f"rate must be > 0, got {rate}")
        if clock_rate is not None and not clock_rate > 0:
            raise BagError(f"clock_rate must be > 0 Hz, got {clock_rate}")
        # every topic whose type rclpy has (a --view bag's /tf has none here), or those asked
        self.skipped = (
            []
            if topics is not None
            else [t for t, info in bag.topics.items() if not is_installed(info.type)]
        )
        selected = (
            [t for t in bag.topics if t not in self.skipped] if topics is None else list(topics)
        )
        missing = sorted(set(selected) - set(bag.topics))
        if missing:
            raise BagError(f"not in the bag: {missing}; it has {sorted(bag.topics)}")
        from ffmpc_ros import topics as graph_topics
        from ffmpc_ros.bag.rerun import bag_namespace

        # the graph's clock: /clock, or /arm1/clock in a bag of a graph under /arm1
        self.clock_topic = graph_topics.resolve(CLOCK, bag_namespace(bag))
        if clock_rate is not None and self.clock_topic in selected:
            selected.remove(self.clock_topic)  # the player drives the clock itself
        self.remap = dict(remap or {})
        unknown = sorted(set(self.remap) - set(bag.topics))
        if unknown:
            raise BagError(f"remapped topics not in the bag: {unknown}")
        self.node = node
        self.bag = bag
        self.rate = rate
        self.clock_rate = clock_rate
        self.publishers = {}
        for topic in selected:
            info = bag.topics[topic]
            self.publishers[topic] = node.create_publisher(
                message_class(info.type),
                self.remap.get(topic, topic),
                qos_from_dicts(info.qos_profiles),
            )
        self.clock_publisher = None
        if clock_rate is not None:
            self.clock_publisher = node.create_publisher(
                ClockMsg, self.remap.get(self.clock_topic, self.clock_topic), 10
            )
        self.report = PlayReport(published={t: 0 for t in selected}, skipped=self.skipped)
        self._messages = bag.messages(selected) if selected else iter(())
        self._next: BagMessage | None = next(self._messages, None)
        self._t0 = bag.start_time or 0
        self._start: float | None = None
        self._next_clock = 0.0  # bag seconds
        self._late_sum = 0.0
        self._count = 0

    @property
    def done(self) -> bool:
        return self._next is None

    def start(self, now: float | None = None) -> None:
        """Start the playback clock (wall time ``now``, default time.perf_counter())."""
        self._start = time.perf_counter() if now is None else now

    def _started(self) -> float:
        """The wall time playback started at (BagError before :meth:`start`)."""
        if self._start is None:
            raise BagError("playback has not started: call start() or publish_due() first")
        return self._start

    def due_at(self, message: BagMessage) -> float:
        """Wall time at which a message is due."""
        return self._started() + (message.log_time - self._t0) * 1e-9 / self.rate

    def time_to_next(self, now: float | None = None) -> float | None:
        """Wall seconds until the next message is due (None when done)."""
        if self._next is None:
            return None
        now = time.perf_counter() if now is None else now
        return self.due_at(self._next) - now

    def publish_due(self, now: float | None = None) -> int:
        """Publish every message due by ``now`` (and /clock ticks); returns how many."""
        if self._start is None:
            self.start(now)
        now = time.perf_counter() if now is None else now
        start = self._started()
        bag_now = (now - start) * self.rate
        if self.clock_publisher is not None and self.clock_rate is not None and not self.done:
            while self._next_clock <= bag_now:
                ns = self._t0 + int(round(self._next_clock * 1e9))
                msg = ClockMsg()
                msg.clock.sec, msg.clock.nanosec = divmod(ns, 1_000_000_000)
                self.clock_publisher.publish(msg)
                self._next_clock += 1.0 / self.clock_rate
        count = 0
        while self._next is not None:
            due = self.due_at(self._next)
            if due > now:
                break
            message = self._next
            self.publishers[message.topic].publish(message.data)
            self.report.published[message.topic] += 1
            late = time.perf_counter() - due
            self._late_sum += late
            self._count += 1
            self.report.max_lateness = max(self.report.max_lateness, late)
            self.report.bag_time = (message.log_time - self._t0) * 1e-9
            count += 1
            self._next = next(self._messages, None)
            now = max(now, time.perf_counter())
        if count:
            self.report.wall_time = now - start
            self.report.mean_lateness = self._late_sum / self._count
        return count


def play_bag(
    path: str | os.PathLike,
    *,
    rate: float = 1.0,
    topics: Iterable[str] | None = None,
    remap: Mapping[str, str] | None = None,
    clock_rate: float | None = None,
    delay: float = 0.5,
    domain_id: int | None = None,
) -> PlayReport:
    """Play a bag on its own node and executor until its last message (Ctrl-C stops it).

    Args:
        delay: wall seconds between creating the publishers and the first message (discovery).
    """
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor

    domain = _env_domain_id() if domain_id is None else domain_id
    context = Context()
    rclpy.init(args=[], context=context, domain_id=domain)
    executor = EventsExecutor(context=context)
    node = Node("ffmpc_player", context=context)
    executor.add_node(node)
    try:
        with BagReader(path) as bag:
            player = BagPlayer(
                node, bag, rate=rate, topics=topics, remap=remap, clock_rate=clock_rate
            )
            end = time.perf_counter() + delay
            while time.perf_counter() < end:
                executor.spin_once(timeout_sec=0.01)
            player.start()
            try:
                while not player.done:
                    player.publish_due()
                    wait = player.time_to_next()
                    if wait is not None and wait > 0:
                        executor.spin_once(timeout_sec=min(wait, 0.05))
            except KeyboardInterrupt:
                pass
            return player.report
    finally:
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()
        rclpy.shutdown(context=context)
