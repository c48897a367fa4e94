"""A node's ``/diagnostics`` report (``diagnostic_msgs/DiagnosticArray``, the topic
``diagnostic_aggregator`` and ``rqt_robot_monitor`` read), every :data:`DIAGNOSTICS_PERIOD` s of
wall time: one status named after the node, with the rate of each input it accepted over the
period (Hz, wall time), its rejections (total and in the period) and the node's own values (the
MPC's solve times, the PID's mode); level WARN when an input was rejected in the period, ERROR
for the node's own problems (the PID in its safe hold, a failed solve).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from ffmpc_ros import topics

#: Wall time between two /diagnostics reports of a node, s (1 Hz, as diagnostic_updater).
DIAGNOSTICS_PERIOD = 1.0
#: The standard diagnostics topic (absolute: the aggregator listens there).
DIAGNOSTICS_TOPIC = topics.DIAGNOSTICS


class NodeDiagnostics:
    """The diagnostics of one node (module docstring).

    Args:
        name: the status's name (the node's fully qualified name).
        accepted: accepted inputs per topic (read, never changed).
        rejected: rejections per kind (read, never changed).
        values: the node's own values over the last ``period`` wall s.
        problems: the node's faults now (each makes the report an ERROR).
        clock: wall time, s.
    """

    def __init__(
        self,
        name: str,
        accepted: Counter[str],
        rejected: Counter[str],
        values: Callable[[float], dict[str, str]],
        problems: Callable[[], list[str]],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.name = name
        self._accepted = accepted
        self._rejected = rejected
        self._values = values
        self._problems = problems
        self._clock = clock
        self._previous = (clock(), Counter[str](), 0)  # (wall s, accepted, rejected) last report

    def status(self) -> DiagnosticStatus:
        """The node's status since the previous report (module docstring); starts a new
        period."""
        now = self._clock()
        since, accepted, rejected = self._previous
        period = max(now - since, 1e-9)
        total = sum(self._rejected.values())
        self._previous = (now, Counter(self._accepted), total)
        values = {
            f"input_rate_hz {topic}": f"{(n - accepted[topic]) / period:.1f}"
            for topic, n in sorted(self._accepted.items())
        }
        values["rejected_total"] = str(total)
        values["rejected_in_period"] = str(total - rejected)
        values["period_s"] = f"{period:.3f}"
        values.update(self._values(period))
        problems = self._problems()
        if problems:
            level, message = DiagnosticStatus.ERROR, "; ".join(problems)
        elif total > rejected:
            kinds = ", ".join(sorted(self._rejected))
            level, message = DiagnosticStatus.WARN, f"{total - rejected} inputs rejected ({kinds})"
        else:
            level, message = DiagnosticStatus.OK, "ok"
        return DiagnosticStatus(
            level=level,
            name=self.name,
            message=message,
            hardware_id="ffmpc",
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )

    def publish_from(self, node: Node) -> None:
        """Publish :meth:`status` on ``node``'s /diagnostics every DIAGNOSTICS_PERIOD wall s
        (stamped with the node's clock)."""
        publisher = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)

        def publish() -> None:
            msg = DiagnosticArray()
            msg.header.stamp = node.get_clock().now().to_msg()
            msg.status = [self.status()]
            publisher.publish(msg)

        self._timer = node.create_timer(
            DIAGNOSTICS_PERIOD, publish, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
