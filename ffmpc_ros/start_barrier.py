"""The lockstep start barrier (``ffmpc_ros.topics.START_READY``) of one node, and a plant's
start rule.

A node of a lockstep graph subscribes ``lockstep/member`` as its last reader (its membership
marker), then checks :meth:`StartBarrier.writers_matched` every :data:`BARRIER_PERIOD` s of wall
time; once it holds, the node subscribes ``lockstep/ready`` (its token). The plant publishes
cycle 0 only once every member's token is there (:meth:`StartBarrier.handshake`): every writer of
the graph is then matched to every reader, so the reliable, volatile topics lose nothing from
cycle 0 on, with no replay. Outside a lockstep graph (``start_clock_subscribers`` 0: ``ros2 run``
of one node, a re-run from a bag) there is no barrier and no token.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import QoSCompatibility, qos_check_compatible
from std_msgs.msg import Empty

from ffmpc_ros import topics

#: Wall time between two checks of a node's side of the lockstep start barrier, s.
BARRIER_PERIOD = 0.01


def _ignore(msg: Empty) -> None:
    """The barrier's marker and token readers take nothing (nobody publishes them)."""


class StartBarrier:
    """One node's side of the lockstep start barrier (module docstring).

    Args:
        node: the node (its graph queries, its timers and readers).
        params: the node's parameters (``start_clock_subscribers``; a plant's
            ``start_subscribers``, ``start_nodes``, ``start_delay``).
        clock: wall time, s (the plant's ``start_delay``).
    """

    def __init__(
        self, node: Node, params: Mapping[str, Any], clock: Callable[[], float] = time.monotonic
    ) -> None:
        self._node = node
        self._params = params
        self._clock = clock
        clock_readers = int(params.get("start_clock_subscribers", 0))
        #: Members of the lockstep graph (``start_clock_subscribers`` counts two /clock readers
        #: per member: each node, the recorder); 0 outside a lockstep graph.
        self.members = clock_readers // topics.CLOCK_READERS_PER_NODE
        self.writers: list[Publisher] = []  # the writers the barrier waits for
        self.ready = False  # this node's lockstep/ready reader exists
        self._member_topic = node.resolve_topic_name(topics.START_MEMBER)
        self._ready_topic = node.resolve_topic_name(topics.START_READY)
        self._timer: Any = None
        self._holds_since: float | None = None  # wall s the plant's start rule holds since

    def add_writer(self, publisher: Publisher) -> None:
        """A writer of the node the barrier waits for (``topics.barrier_writer`` names them)."""
        self.writers.append(publisher)

    def join(self) -> None:
        """Subscribe the membership marker (``lockstep/member``): the node's last reader."""
        if self.members > 0:
            self._node.create_subscription(
                Empty,
                topics.START_MEMBER,
                _ignore,
                topics.start_ready_qos(),
                qos_overriding_options=None,
            )

    def arm(self) -> None:
        """Check :meth:`writers_matched` now and every :data:`BARRIER_PERIOD` wall s until it
        holds; then subscribe ``lockstep/ready`` (the node's token, counted by the plant)."""
        self._timer = self._node.create_timer(
            BARRIER_PERIOD, self._check, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self._check()

    def _check(self) -> None:
        if self.ready or not self.writers_matched():
            return
        self._timer.cancel()
        if self.members <= 0:
            self.ready = True  # no graph to wait for: no token either (ros2 run, re-runs)
            return
        self._node.create_subscription(
            Empty,
            topics.START_READY,
            _ignore,
            topics.start_ready_qos(),
            qos_overriding_options=None,
        )
        self.ready = True
        matched = sum(w.get_subscription_count() for w in self.writers)
        self._node.get_logger().info(
            f"start barrier passed: {len(self.writers)} writers matched to {matched} readers"
        )

    def writers_matched(self) -> bool:
        """This node's side of the barrier: it has discovered the membership marker of each of
        the graph's :attr:`members` (a member's marker is its last reader, and a participant
        announces its readers in the order it creates them, so every reader of the graph is
        then known here; readers of /clock outside the graph, a live view's or a ``ros2 topic
        echo``'s, do not count), and each of its :attr:`writers` has matched every reader
        discovered on its topic whose QoS is compatible with it. A reliable, volatile writer
        delivers every sample it sends after it matched a reader: once every node holds this,
        nothing sent from cycle 0 on is lost. True at once outside a lockstep graph."""
        if self.members <= 0:
            return True
        if self._node.count_subscribers(self._member_topic) < self.members:
            return False
        for writer in self.writers:
            readers = self._node.get_subscriptions_info_by_topic(writer.topic_name)
            compatible = sum(
                1
                for r in readers
                if qos_check_compatible(writer.qos_profile, r.qos_profile)[0]
                != QoSCompatibility.ERROR
            )
            if writer.get_subscription_count() < compatible:
                return False
        return True

    def handshake(
        self, active: bool, joints: Publisher, clock: Publisher, ready: bool = True
    ) -> bool:
        """A plant's start rule (lockstep graphs): True once the plant is ``active``
        (lifecycle: the bring-up activates the plant last), ``start_subscribers`` readers are
        matched to its joint-state writer ``joints`` and ``start_clock_subscribers`` to its
        /clock writer ``clock`` (a node's reliable /clock reader is its last data reader, so
        the count means every node has all its readers), ``start_nodes`` nodes (the plant
        included) passed the barrier, ``ready`` holds (the plant's own extra condition), and
        all of it has held for ``start_delay`` wall s. Call it from a timer until it is True."""
        holds = (
            ready
            and active
            and joints.get_subscription_count() >= int(self._params["start_subscribers"])
            and clock.get_subscription_count() >= int(self._params["start_clock_subscribers"])
            and self._node.count_subscribers(self._ready_topic) >= int(self._params["start_nodes"])
        )
        if not holds:
            self._holds_since = None
            return False
        if self._holds_since is None:
            self._holds_since = self._clock()
        return self._clock() - self._holds_since >= float(self._params["start_delay"])
