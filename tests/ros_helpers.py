"""Helpers of the ROS node tests: a private rclpy context, an EventsExecutor driven with
``spin_once(timeout_sec=…)``, and probe nodes that publish and record."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from types import SimpleNamespace

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.experimental import EventsExecutor
from rclpy.node import Node

from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.params import node_parameter_values, parameter_overrides


class RosHarness:
    """One context + one executor; ``add`` nodes, ``spin_until`` a condition."""

    def __init__(self) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
        self.executor = EventsExecutor(context=self.context)
        self.nodes: list[Node] = []

    def add(self, node: Node) -> Node:
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def probe(self, name: str = "probe") -> Node:
        return self.add(Node(name, context=self.context))

    def spin_until(self, done: Callable[[], bool], timeout: float = 10.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if done():
                return True
            self.executor.spin_once(timeout_sec=0.01)
        return done()

    def set_clock(self, node, k: int, timeout: float = 5.0) -> None:
        """Publish /clock = t_k (node's time step) and spin until ``node``'s clock shows it: the
        nodes judge stamps against their clock (stale, or from the future)."""
        from rosgraph_msgs.msg import Clock

        if not hasattr(self, "_clock_pub"):
            self._clock_pub = self.probe("_clock_driver").create_publisher(Clock, topics.CLOCK, 10)
        self._clock_pub.publish(Clock(clock=node.grid.stamp_of(k)))
        target = k * node.step_ns
        assert self.spin_until(lambda: node.get_clock().now().nanoseconds >= target, timeout), (
            f"{node.get_name()} did not see /clock = cycle {k}"
        )

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def close(self) -> None:
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown()
        rclpy.shutdown(context=self.context)


def overrides(node: str, scenario=None, **graph):
    """Parameter overrides that make ``node`` run the polishing scenario (or ``scenario``)."""
    scenario = scenario or load_scenario("polishing")
    return parameter_overrides(node_parameter_values(node, scenario, **graph))


def recorder(probe: Node, msg_type, topic: str, lockstep: bool = True) -> list:
    """Subscribe ``probe`` to ``topic`` and return the list the messages go to."""
    out: list = []
    probe.create_subscription(msg_type, topic, out.append, topics.subscriber_qos(lockstep, topic))
    return out


def joint_state(node, k: int, q, v, effort, names=None):
    """A JointState stamped with cycle k of ``node``'s time step."""
    from sensor_msgs.msg import JointState

    msg = JointState()
    msg.header.stamp = node.grid.stamp_of(k)
    msg.name = list(names if names is not None else node.joint_names)
    msg.position = [float(x) for x in q]
    msg.velocity = [float(x) for x in v]
    msg.effort = [float(x) for x in effort]
    return msg


def wrench(node, k: int, force, torque=(0.0, 0.0, 0.0), frame=topics.WRENCH_FRAME):
    """A WrenchStamped stamped with cycle k, in ``frame``."""
    from geometry_msgs.msg import WrenchStamped

    msg = WrenchStamped()
    msg.header.stamp = node.grid.stamp_of(k)
    msg.header.frame_id = frame
    msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = map(float, force)
    msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = map(float, torque)
    return msg


def publish_clock(pub, node, k: int) -> None:
    """Publish /clock = t_k."""
    from rosgraph_msgs.msg import Clock

    pub.publish(Clock(clock=node.grid.stamp_of(k)))


def mpc_command(k: int, torque, nx: int = 14, gain=None, nv: int = 7, state=None, names=()):
    """An ``mpc/command`` (ffmpc_msgs/MpcCommand) solved at cycle k (stamp k ms): torque (N·m),
    the state it was solved from (zeros by default, nx entries: the formulation follows from
    nx, 2nv classical, 3nv torque feedback, else force feedback), the feedback gain (zeros by
    default) and the joint names (none by default: the receiver's order)."""
    from builtin_interfaces.msg import Time

    from ffmpc_ros.command_msg import command_message

    formulation = {2 * nv: "classical", 3 * nv: "torque_feedback"}.get(nx, "force_feedback")
    solution = SimpleNamespace(
        torque=np.asarray(torque, dtype=float),
        state=np.zeros(nx) if state is None else state,
        feedback_gain=np.zeros((nv, nx)) if gain is None else gain,
        iterations=1,
        kkt=0.0,
        solve_time=0.0,
        converged=True,
    )
    stamp = Time(sec=k // 1000, nanosec=(k % 1000) * 1_000_000)
    return command_message(stamp, formulation, list(names), k // 2, solution)


def assert_same_run(graph, runner) -> None:
    """A graph run (``run_graph``'s GraphResult) equals the ROS-free runner's run of the same
    scenario and seed: every logged signal bit for bit, and both metric sets."""
    assert set(graph.log) == set(runner.log)
    for name, values in runner.log.items():
        # (rejections say why a run diverged, e.g. a PID that went on without a late command)
        rejected = graph.safety["rejected_messages"]
        np.testing.assert_array_equal(graph.log[name], values, err_msg=f"{name}; {rejected}")
    assert graph.metrics_true == runner.metrics_true
    assert graph.metrics_measured == runner.metrics_measured
