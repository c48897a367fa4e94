"""The recorder node: what was published equals what is read back, for every topic type of the
graph (bytes and decoded messages), with the publishers' QoS and type hashes and the parameters
of the publishing node; the start-up gate; and a recorder process killed with SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray, MultiArrayDimension, String

from ffmpc_ros import topics
from ffmpc_ros.bag.errors import BagExistsError
from ffmpc_ros.bag.reader import BagReader
from ffmpc_ros.bag.recorder import BagRecorder
from ffmpc_ros.bag.ros_types import message_class
from ffmpc_ros.command_msg import command_message

ROOT = Path(__file__).resolve().parents[1]


def _random_message(type_name: str, k: int, rng: np.random.Generator):
    """A message of one of the graph's types with random content, stamped with cycle k."""
    sec, nanosec = divmod(k * 1_000_000, 1_000_000_000)
    if type_name == "rosgraph_msgs/msg/Clock":
        msg = Clock()
        msg.clock.sec, msg.clock.nanosec = sec, nanosec
        return msg
    if type_name == "sensor_msgs/msg/JointState":
        msg = JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.name = [f"lbr_iiwa_joint_{i}" for i in range(1, 8)]
        msg.position, msg.velocity, msg.effort = (rng.normal(size=7).tolist() for _ in range(3))
        return msg
    if type_name == "geometry_msgs/msg/WrenchStamped":
        msg = WrenchStamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        msg.header.frame_id = topics.WRENCH_FRAME
        f, m = rng.normal(size=3) * 50, rng.normal(size=3)
        msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = map(float, f)
        msg.wrench.torque.x, msg.wrench.torque.y, msg.wrench.torque.z = map(float, m)
        return msg
    if type_name == "std_msgs/msg/Float64MultiArray":
        data = rng.normal(size=int(rng.integers(1, 130))).tolist()
        msg = Float64MultiArray(data=data)
        msg.layout.dim = [MultiArrayDimension(label="ffmpc/test/1", size=len(data))]
        return msg
    if type_name == "tf2_msgs/msg/TFMessage":
        from geometry_msgs.msg import TransformStamped
        from tf2_msgs.msg import TFMessage

        msg = TFMessage()
        for child in ("lbr_iiwa_link_1", "contact"):
            t = TransformStamped()
            t.header.stamp.sec, t.header.stamp.nanosec = sec, nanosec
            t.header.frame_id, t.child_frame_id = "world", child
            p, q = rng.normal(size=3), rng.normal(size=4)
            q /= np.linalg.norm(q)
            t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = map(
                float, p
            )
            r = t.transform.rotation
            r.x, r.y, r.z, r.w = map(float, q)
            msg.transforms.append(t)
        return msg
    if type_name == "ffmpc_msgs/msg/MpcCommand":
        solution = SimpleNamespace(
            torque=rng.normal(size=7),
            state=rng.normal(size=15),
            feedback_gain=rng.normal(size=(7, 15)),
            iterations=int(rng.integers(1, 9)),
            kkt=float(rng.random()),
            solve_time=float(rng.random()) * 1e-3,
            converged=bool(rng.integers(2)),
        )
        stamp = TimeMsg(sec=sec, nanosec=nanosec)
        names = [f"lbr_iiwa_joint_{i}" for i in range(1, 8)]
        return command_message(stamp, "force_feedback", names, k, solution)
    if type_name == "std_msgs/msg/Bool":
        return Bool(data=bool(rng.integers(2)))
    if type_name == "std_msgs/msg/String":
        return String(data=f"run {k}: λ = {rng.normal():.17g} N")
    raise AssertionError(type_name)


def test_what_is_published_is_what_is_read_back_for_every_topic_type(ros, tmp_path):
    rng = np.random.default_rng(3)
    source = ros.add(Node("bag_source", context=ros.context))
    declared = {"gain": 0.1 + 0.2, "cycles": 7, "axes": [0.5, -1.25], "name": "x", "on": True}
    for name, value in declared.items():
        source.declare_parameter(name, value)
    publishers = {
        topic: source.create_publisher(
            message_class(type_name),
            topic,
            topics.clock_qos() if topic == topics.CLOCK else topics.publisher_qos(),
        )
        for topic, type_name, _ in topics.resolved_topics()
    }
    probe = ros.probe("bag_probe")
    wire: dict[str, list[bytes]] = {t: [] for t in publishers}
    for topic, type_name, _ in topics.resolved_topics():
        probe.create_subscription(
            message_class(type_name),
            topic,
            wire[topic].append,
            topics.subscriber_qos(True) if topic != topics.CLOCK else 100,
            raw=True,
        )
    path = tmp_path / "all.mcap"
    recorder = ros.add(
        BagRecorder(
            path,
            context=ros.context,
            topics=list(publishers),
            parameters_of=["bag_source"],
            wait_for=list(publishers),
            gate_topic=topics.CLOCK,
            use_sim_time=False,
        )
    )
    assert ros.spin_until(
        lambda: (
            recorder.ready and all(p.get_subscription_count() == 2 for p in publishers.values())
        ),
        timeout=20,
    ), (recorder.received, recorder.parameters)
    sent: dict[str, list] = {t: [] for t in publishers}
    for k in range(25):
        for topic, type_name, _ in topics.resolved_topics():
            msg = _random_message(type_name, k, rng)
            publishers[topic].publish(msg)
            sent[topic].append(msg)
    assert ros.spin_until(
        lambda: all(len(wire[t]) == 25 and recorder.received[t] == 25 for t in publishers),
        timeout=20,
    ), (recorder.received, {t: len(w) for t, w in wire.items()})
    infos = {t: source.get_publishers_info_by_topic(t)[0] for t in publishers}
    recorder.close()
    with BagReader(path) as bag:
        assert set(bag.topics) == set(publishers)
        for topic, type_name, _ in topics.resolved_topics():
            info = bag.topics[topic]
            assert info.type == type_name and info.count == 25
            assert info.type_hash == str(infos[topic].topic_type_hash)
            assert [q["durability"] for q in info.qos_profiles] == ["volatile"]
            assert [q["reliability"] for q in info.qos_profiles] == ["reliable"]
            recorded = [m.data for m in bag.messages([topic])]
            assert recorded == wire[topic], topic  # the bytes on the wire
            cls = message_class(type_name)
            assert [deserialize_message(d, cls) for d in recorded] == sent[topic], topic
        params = bag.parameters["/bag_source"]
        assert {k: params[k] for k in declared} == declared
        assert params["use_sim_time"] is False
    # Another tool decodes the same values.
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        wrenches = [
            reader.deserialize(raw, c.msgtype).wrench.force.z
            for c, _, raw in reader.messages()
            if c.topic == topics.resolve(topics.PLANT_WRENCH)
        ]
    assert wrenches == [m.wrench.force.z for m in sent[topics.resolve(topics.PLANT_WRENCH)]]


def test_the_gate_opens_once_the_graph_is_seen(ros, tmp_path):
    recorder = ros.add(
        BagRecorder(
            tmp_path / "gate.mcap",
            context=ros.context,
            topics=["/a"],
            wait_for=["/a"],
            gate_topic="/gate",
            parameters_of=["late_node"],
            use_sim_time=False,
        )
    )
    probe = ros.probe("gate_probe")
    gate_pub = probe.create_publisher(Bool, "/gate", 10)
    ros.spin_for(0.3)
    assert not recorder.ready and gate_pub.get_subscription_count() == 0
    probe.create_publisher(Bool, "/a", 10)
    ros.spin_for(0.3)
    assert not recorder.ready  # /a is seen, but late_node's parameters are not in
    late = ros.add(Node("late_node", context=ros.context))
    late.declare_parameter("k", 2)
    assert ros.spin_until(lambda: gate_pub.get_subscription_count() == 1, timeout=10)
    assert recorder.ready and recorder.parameters["/late_node"]["k"] == 2
    recorder.close()


def test_a_recorder_refuses_an_existing_bag(ros, tmp_path):
    path = tmp_path / "old.mcap"
    path.write_bytes(b"yesterday")
    with pytest.raises(BagExistsError):
        BagRecorder(path, context=ros.context)
    assert path.read_bytes() == b"yesterday"


def test_a_recorder_killed_with_sigkill_leaves_a_readable_bag(ros, tmp_path):
    path = tmp_path / "killed.mcap"
    env = dict(os.environ)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ffmpc_ros.cli",
            "bag",
            "record",
            str(path),
            "--topics",
            "/killed/js",
            "--wall-clock",
            "--flush-interval",
            "0.1",
        ],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        node = ros.probe("killed_source")
        pub = node.create_publisher(JointState, "/killed/js", topics.publisher_qos())
        assert ros.spin_until(lambda: pub.get_subscription_count() > 0, timeout=30)
        rng = np.random.default_rng(4)
        start = time.monotonic()
        k = 0
        while time.monotonic() - start < 1.5:
            pub.publish(_random_message("sensor_msgs/msg/JointState", k, rng))
            k += 1
            ros.spin_for(0.004)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    with BagReader(path) as bag:
        report = bag.recovery
        assert not report.complete
        stamps = [
            deserialize_message(m.data, JointState).header.stamp.nanosec // 1_000_000
            for m in bag.messages()
        ]
    assert report.messages == len(stamps) > 0 and report.chunks >= 1
    assert stamps == list(range(len(stamps)))  # a gap-free prefix of what was published
    assert len(stamps) <= k
