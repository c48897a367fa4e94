"""A node's second, RELIABLE reader of the plant's ``/clock``.

rclpy's time source reads /clock BEST_EFFORT: a sample reaches a reader only once the reader has
matched the plant's writer too, so a node whose side of the match came late judged its first
inputs by a clock still at 0 and rejected them as from the future (lockstep never publishes that
cycle's /clock again). A RELIABLE reader gets what the writer sent since the writer matched it
(resent until acknowledged); it feeds the node's clock through a second ``TimeSource`` (public
rclpy API). The reader is a node's last data reader (:meth:`ffmpc_ros.base.GraphNode.join_graph`):
the plant waits for every node's two /clock readers (``start_clock_subscribers``), so it starts
only once every node has all its readers.
"""

from __future__ import annotations

from rclpy.clock import ROSClock
from rclpy.node import Node
from rclpy.time_source import TimeSource
from rosgraph_msgs.msg import Clock as ClockMsg

from ffmpc_ros import topics


class ReliableClock:
    """Feeds ``node``'s clock from a reliable /clock reader (module docstring)."""

    def __init__(self, node: Node) -> None:
        self._node = node
        self._time = TimeSource()
        self._time.ros_time_is_active = True
        clock = node.get_clock()
        assert isinstance(clock, ROSClock)  # a node's clock is always a ROSClock (rclpy Node)
        self._time.attach_clock(clock)
        self.received = False  # the reader got a /clock sample (the clock moved off 0)

    def subscribe(self) -> None:
        """Create the reader (call it after the node's data readers: module docstring)."""
        self._node.create_subscription(
            ClockMsg, topics.CLOCK, self.on_clock, topics.clock_reader_qos()
        )

    def on_clock(self, msg: ClockMsg) -> None:
        """A /clock sample: the node's clock moves to it."""
        self.received = True
        self._time.clock_callback(msg)
