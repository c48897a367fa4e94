"""The state-publisher node: robot_state_publisher's job, with pinocchio's forward kinematics.

Publishes, as robot_state_publisher does:

* ``robot_description`` (std_msgs/String, RELIABLE + TRANSIENT_LOCAL, depth 1; relative, like
  robot_state_publisher's): the URDF of the scenario's robot, its mesh paths made absolute
  ``file://`` URIs (``ffmpc_ros.robot_tree.description_with_absolute_meshes``); once, on
  activation;
* ``/tf_static`` (tf2_msgs/TFMessage, RELIABLE + TRANSIENT_LOCAL, depth 1: tf2's static
  broadcaster profile): every fixed edge of the tree (``ffmpc_ros.robot_tree``), once, on
  activation, stamped with the node's clock then;
* ``/tf`` (tf2_msgs/TFMessage): every moving edge from the measured joint states
  (``joint_sensor/joint_states``), stamped with the joint state's stamp, at most
  ``publish_frequency`` Hz of simulated time: the first accepted joint state stamped at or after
  each point of the grid k / publish_frequency (deterministic in lockstep).

``/tf`` and ``/tf_static`` are absolute names, as tf2 wants them. A namespaced graph remaps them
to its own ``<ns>/tf`` and ``<ns>/tf_static`` (``ffmpc_ros.topics.graph_ros_args``: ``-r
/tf:=tf -r /tf_static:=tf_static``, the rule Nav2 uses for several robots), so two robots'
frames never mix; ``frame_prefix`` (robot_state_publisher's parameter) prefixes every frame id
for a user who wants them in one tree instead.

A joint state with a bad stamp, non-finite positions or wrong joint names is rejected with one
throttled log line (``GraphNode.reject``) and nothing is published from it. The node only reads
the graph: the lockstep loop does not wait for it.
"""

from __future__ import annotations

from typing import Any

import pinocchio as pin
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import TransformStamped
from rclpy.lifecycle import LifecycleState, TransitionCallbackReturn
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from ffmpc_core.robots import load_robot
from ffmpc_ros import topics
from ffmpc_ros.base import GraphNode, run_node
from ffmpc_ros.message_parsing import joint_fields
from ffmpc_ros.robot_tree import (
    Edge,
    description_with_absolute_meshes,
    edge_placements,
    robot_edges,
)
from ffmpc_ros.time_grid import stamp_ns


class StatePublisherNode(GraphNode):
    """robot_description, /tf_static and /tf of the scenario's robot (module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("state_publisher", join=False, **kwargs)
        self.robot = load_robot(self.scenario.robot)
        self.joint_names = list(self.robot.joint_names)
        self.data = self.robot.create_data()
        self.prefix = str(self.params["frame_prefix"])
        self.period_ns = max(1, int(round(1e9 / float(self.params["publish_frequency"]))))
        edges = robot_edges(self.robot)
        self.static_edges = [e for e in edges if e.static]
        self.moving_edges = [e for e in edges if not e.static]
        self.description = description_with_absolute_meshes(self.robot.urdf_path)
        self.pub_description = self.create_publisher(
            String, topics.ROBOT_DESCRIPTION, topics.publisher_qos(topics.ROBOT_DESCRIPTION)
        )
        self.pub_static = self.create_publisher(
            TFMessage, topics.TF_STATIC, topics.publisher_qos(topics.TF_STATIC)
        )
        self.pub_tf = self.create_publisher(TFMessage, topics.TF, topics.publisher_qos(topics.TF))
        self.create_subscription(
            JointState,
            topics.SENSED_JOINT_STATES,
            self.on_joint_state,
            topics.subscriber_qos(True, topics.SENSED_JOINT_STATES),
        )
        self._next_ns: int | None = None  # the next grid point of /tf, ns
        self._latched_sent = False
        self.published = 0  # /tf messages
        self.join_graph()

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        result = super().on_activate(state)
        if not self._latched_sent:
            self._latched_sent = True
            self.pub_description.publish(String(data=self.description))
            q = pin.neutral(self.robot.model)  # static edges do not depend on q
            placements = edge_placements(self.robot, self.data, q, self.static_edges)
            stamp = self.get_clock().now().to_msg()
            self.pub_static.publish(self.message(stamp, self.static_edges, placements))
        return result

    def on_joint_state(self, msg: JointState) -> None:
        ns = stamp_ns(msg.header.stamp)
        if ns is not None and self._next_ns is not None and ns < self._next_ns:
            return  # between two points of the /tf grid: nothing to publish
        got = self.gate.receive(
            topics.SENSED_JOINT_STATES, msg, joint_fields(self.joint_names, "position")
        )
        if got is None:
            return
        _, (q,) = got
        assert ns is not None  # receive accepted the stamp
        self._next_ns = (ns // self.period_ns + 1) * self.period_ns
        placements = edge_placements(self.robot, self.data, q, self.moving_edges)
        self.pub_tf.publish(self.message(msg.header.stamp, self.moving_edges, placements))
        self.published += 1

    def message(self, stamp: TimeMsg, edges: list[Edge], placements: list[pin.SE3]) -> TFMessage:
        """One TFMessage of ``edges`` at ``placements``, every transform stamped ``stamp``."""
        out = TFMessage()
        for edge, placement in zip(edges, placements, strict=True):
            t = TransformStamped()
            t.header.stamp = stamp
            t.header.frame_id = self.prefix + edge.parent
            t.child_frame_id = self.prefix + edge.child
            p = placement.translation
            x, y, z, w = pin.Quaternion(placement.rotation).coeffs()
            tr = t.transform
            tr.translation.x, tr.translation.y, tr.translation.z = (float(v) for v in p)
            tr.rotation.x, tr.rotation.y, tr.rotation.z, tr.rotation.w = (
                float(x),
                float(y),
                float(z),
                float(w),
            )
            out.transforms.append(t)
        return out


def main(argv: list[str] | None = None) -> int:
    return run_node(StatePublisherNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
