"""The state-publisher node (robot_state_publisher's job with pinocchio): /tf from the measured
joint states equals pinocchio's frame placements, /tf_static holds the fixed joints, and
robot_description and /tf_static are latched; bad joint states publish nothing. Also the
generated tf2_msgs: its type hashes are ROS 2 Jazzy's."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pinocchio as pin
from ros_helpers import joint_state, overrides
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from tf2_msgs.msg import TFMessage

from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.robot_tree import CONTACT_WORLD_ALIGNED, WORLD_FRAME
from ffmpc_ros.state_publisher_node import StatePublisherNode

#: tf2_msgs' RIHS01 type hashes in ROS 2 Jazzy (``ros2 topic info -v /tf`` on a Jazzy install
#: prints the first; both are the rosidl golden values of geometry2 0.36.x).
JAZZY_HASHES = {
    "msg/TFMessage": "RIHS01_e369d0f05a23ae52508854b66f6aa0437f3449d652e8cbf22d5abe85d020f087",
    "msg/TF2Error": "RIHS01_db2485e7d6a0ec75bf087e058ee45df682acc3a621ca7780503d10aac141809a",
}


def _node(ros, robot: str = "iiwa", **graph) -> StatePublisherNode:
    scenario = load_scenario("polishing", {"robot": robot})
    return ros.add(
        StatePublisherNode(
            context=ros.context,
            parameter_overrides=overrides("state_publisher", scenario, **graph),
        )
    )


def _latched_reader(ros, topic: str, msg_type) -> list:
    out: list = []
    ros.probe(f"late_{topic.strip('/')}").create_subscription(
        msg_type, topic, out.append, topics.latched_qos()
    )
    return out


def _tf_reader(ros) -> list:
    out: list = []
    ros.probe("tf_reader").create_subscription(
        TFMessage, topics.TF, out.append, topics.subscriber_qos(True, topics.TF)
    )
    return out


def _joints_pub(ros):
    return ros.probe("joints").create_publisher(
        JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos(topics.SENSED_JOINT_STATES)
    )


def _placements(msg: TFMessage) -> dict[tuple[str, str], pin.SE3]:
    out = {}
    for t in msg.transforms:
        p, r = t.transform.translation, t.transform.rotation
        rotation = pin.Quaternion(r.w, r.x, r.y, r.z).toRotationMatrix()
        out[(t.header.frame_id, t.child_frame_id)] = pin.SE3(rotation, np.array([p.x, p.y, p.z]))
    return out


def test_generated_tf2_msgs_has_jazzy_type_hashes():
    share = Path(sys.prefix) / "share" / "tf2_msgs"
    for name, expected in JAZZY_HASHES.items():
        found = json.loads((share / f"{name}.json").read_text())["type_hashes"][0]["hash_string"]
        assert found == expected, name
    from tf2_msgs.action import LookupTransform  # the whole package, the action too
    from tf2_msgs.srv import FrameGraph

    assert LookupTransform.Goal().target_frame == "" and FrameGraph.Response().frame_yaml == ""


def test_tf_equals_pinocchio_frame_placements(ros):
    node = _node(ros)
    tf, static = _tf_reader(ros), _latched_reader(ros, topics.TF_STATIC, TFMessage)
    pub = _joints_pub(ros)
    q = np.array([math.pi / 2, 0.3, -0.2, -1.1, 0.4, 0.9, -0.5])
    zero = np.zeros(7)
    assert ros.spin_until(lambda: pub.get_subscription_count() == 1 and len(static) == 1)
    pub.publish(joint_state(node, 0, q, zero, zero))
    assert ros.spin_until(lambda: len(tf) == 1)
    msg = tf[0]
    assert all((t.header.stamp.sec, t.header.stamp.nanosec) == (0, 0) for t in msg.transforms)
    moving = _placements(msg)
    edges = {**_placements(static[0]), **moving}
    # hand-checked from the URDF: lbr_iiwa_joint_1 at xyz 0 0 0.1575, axis z, q1 = 90°
    j1 = moving[("lbr_iiwa_link_0", "lbr_iiwa_link_1")]
    np.testing.assert_allclose(j1.translation, [0.0, 0.0, 0.1575], atol=1e-12)
    np.testing.assert_allclose(pin.Quaternion(j1.rotation).coeffs(), [0, 0, 0.5**0.5, 0.5**0.5])
    # the chain world → ... → contact equals pinocchio's placement of the contact frame
    model, data = node.robot.model, node.robot.create_data()
    pin.framesForwardKinematics(model, data, q)
    parents = {child: parent for parent, child in edges}
    frame, chain = "contact", pin.SE3.Identity()
    while frame != WORLD_FRAME:
        chain = edges[(parents[frame], frame)] * chain
        frame = parents[frame]
    contact = data.oMf[node.robot.contact_frame_id]
    np.testing.assert_allclose(chain.homogeneous, contact.homogeneous, atol=1e-12)
    # every link of the URDF is in the tree, each with one parent
    links = {f.name for f in model.frames if f.type == pin.FrameType.BODY}
    assert links | {"contact", CONTACT_WORLD_ALIGNED} == set(parents)
    aligned = moving[(WORLD_FRAME, CONTACT_WORLD_ALIGNED)]
    np.testing.assert_allclose(aligned.rotation, np.eye(3))
    np.testing.assert_allclose(aligned.translation, contact.translation, atol=1e-12)
    assert node.rejected.total() == 0


def test_static_tree_and_description_are_latched(ros):
    node = _node(ros, "panda", frame_prefix="arm1/")
    ros.spin_for(0.3)  # activated and published before anyone listens
    description = _latched_reader(ros, topics.ROBOT_DESCRIPTION, String)
    static = _latched_reader(ros, topics.TF_STATIC, TFMessage)
    assert ros.spin_until(lambda: description and static)
    assert len(description) == 1 and description[0].data.lstrip().startswith("<?xml")
    assert '<robot name="panda"' in description[0].data and 'filename="file:///' in (
        description[0].data
    )
    fixed = _placements(static[0])
    assert set(fixed) == {
        ("arm1/world", "arm1/panda_link0"),
        ("arm1/panda_link7", "arm1/panda_link8"),
        ("arm1/panda_link8", "arm1/panda_hand"),
        ("arm1/panda_hand", "arm1/panda_leftfinger"),
        ("arm1/panda_hand", "arm1/panda_rightfinger"),
        ("arm1/panda_hand", "arm1/panda_hand_tcp"),
        ("arm1/panda_link8", "arm1/contact"),
    }
    # hand-checked from the URDF: panda_joint8 xyz 0 0 0.107; panda_hand_joint rpy 0 0 -π/4
    np.testing.assert_allclose(
        fixed[("arm1/panda_link7", "arm1/panda_link8")].translation, [0, 0, 0.107], atol=1e-12
    )
    hand = fixed[("arm1/panda_link8", "arm1/panda_hand")]
    np.testing.assert_allclose(hand.rotation, pin.utils.rpyToMatrix(0, 0, -math.pi / 4), atol=1e-12)
    # the moving edges are the seven joints and the wrench frame
    tf, pub = _tf_reader(ros), _joints_pub(ros)
    zero = np.zeros(7)
    assert ros.spin_until(lambda: pub.get_subscription_count() == 1)
    pub.publish(joint_state(node, 0, node.robot.q_nominal, zero, zero))
    assert ros.spin_until(lambda: len(tf) == 1)
    assert len(tf[0].transforms) == 8 and not set(_placements(tf[0])) & set(fixed)


def test_publish_frequency_in_simulated_time(ros):
    node = _node(ros, publish_frequency=200.0)  # every 5 ms of stamps
    tf, pub = _tf_reader(ros), _joints_pub(ros)
    zero = np.zeros(7)
    assert ros.spin_until(lambda: pub.get_subscription_count() == 1)
    for k in range(1, 13):
        if k != 5:  # cycle 5 missing: the next joint state after the grid point takes its place
            pub.publish(joint_state(node, k, zero, zero, zero))
    assert ros.spin_until(lambda: len(tf) == 3)
    ros.spin_for(0.2)
    cycles = [node.cycle_of(m.transforms[0].header.stamp) for m in tf]
    assert cycles == [1, 6, 10] and node.published == 3


def test_bad_joint_states_are_rejected_and_publish_nothing(ros):
    node = _node(ros)
    tf, pub = _tf_reader(ros), _joints_pub(ros)
    zero = np.zeros(7)
    names = list(node.joint_names)
    assert ros.spin_until(lambda: pub.get_subscription_count() == 1)
    bad = [
        joint_state(node, 0, [np.nan] + [0.0] * 6, zero, zero),
        joint_state(node, 0, [np.inf] + [0.0] * 6, zero, zero),
        joint_state(node, 0, zero, zero, zero, names[:6] + ["elbow"]),  # unknown name
        joint_state(node, 0, zero[:6], zero[:6], zero[:6], names[:6]),  # a joint missing
    ]
    for msg in bad:
        pub.publish(msg)
    topic = topics.resolve(topics.SENSED_JOINT_STATES)
    assert ros.spin_until(lambda: node.rejected[f"{topic}:value"] == len(bad))
    ros.spin_for(0.2)
    assert tf == [] and node.published == 0
    assert node.log_lines[f"{topic}:value"] == 1  # one line for the four
    pub.publish(joint_state(node, 0, zero, zero, zero))  # a good one still goes through
    assert ros.spin_until(lambda: len(tf) == 1)
