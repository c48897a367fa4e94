"""ros2_control's terms: the plant driven through a forward_command_controller-style effort command
topic (bad sizes rejected with one log line), the LFC-law node (the agimus
linear_feedback_controller's law from Control messages), and the whole graph in which the MPC
publishes Control and the LFC-law node drives the plant through the effort topic, against the
normal graph's metrics."""

from __future__ import annotations

import numpy as np
import pytest
from ffmpc_ros.node_table import node_table
from linear_feedback_controller_msgs.msg import Control, Sensor
from ros_helpers import joint_state, overrides, recorder
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import ConfigError
from ffmpc_core.linear_feedback import LinearFeedbackCommand, linear_feedback_torque
from ffmpc_core.lowlevel import LowLevelMode
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import layouts, lfc_msgs, topics
from ffmpc_ros.lfc_node import LfcNode
from ffmpc_ros.plant_node import PlantNode

ROS2_CONTROL = topics.ROS2_CONTROL_INTERFACES


def _efforts(data) -> Float64MultiArray:
    msg = Float64MultiArray()
    msg.data = [float(x) for x in data]
    return msg


def test_plant_is_driven_through_the_effort_command_topic(ros):
    """One effort per joint, robot order, no stamp: each valid command steps the plant one
    cycle; a command of another size, a NaN or an absurd torque is rejected (one throttled log
    line per kind, counted) and the plant does not step; joint_states mirrors the plant's."""
    scenario = load_scenario("polishing")
    node = ros.add(
        PlantNode(
            context=ros.context,
            parameter_overrides=overrides("plant", scenario, interfaces=ROS2_CONTROL),
        )
    )
    probe = ros.probe()
    pub = probe.create_publisher(
        Float64MultiArray, topics.EFFORT_COMMANDS, topics.publisher_qos(topics.EFFORT_COMMANDS)
    )
    states = recorder(probe, JointState, topics.PLANT_JOINT_STATES)
    mirrored = recorder(probe, JointState, topics.JOINT_STATES)
    # the ffmpc input is not read in this mode
    old = probe.create_publisher(JointState, topics.MOTOR_TORQUE, topics.publisher_qos())
    assert ros.spin_until(lambda: len(states) == 1 and len(mirrored) == 1)
    gravity = node.robot.gravity(node.robot.q_nominal)
    kind = f"/{topics.EFFORT_COMMANDS}:value"
    for bad in (gravity[:6], np.append(gravity, 0.0), [float("nan")] * 7, gravity + 1e6):
        pub.publish(_efforts(bad))
    old.publish(joint_state(node, 0, [], [], gravity))
    assert ros.spin_until(lambda: node.rejected[kind] == 4)
    ros.spin_for(0.3)
    assert len(states) == 1 and node.k == 0  # nothing stepped
    assert node.log_lines[kind] == 1  # one line for the four (throttled)
    for k in range(3):
        pub.publish(_efforts(gravity))
        assert ros.spin_until(lambda k=k: len(states) == k + 2 and len(mirrored) == k + 2)
    assert node.k == 3 and node.accepted[f"/{topics.EFFORT_COMMANDS}"] == 3
    for a, b in zip(states, mirrored, strict=True):
        assert a.header.stamp == b.header.stamp and list(a.name) == list(b.name)
        assert list(a.position) == list(b.position) and list(a.effort) == list(b.effort)


def _lfc(ros, scenario=None, **graph):
    scenario = scenario or load_scenario("polishing", {"mpc.formulation": "classical"})
    node = ros.add(
        LfcNode(context=ros.context, parameter_overrides=overrides("lfc", scenario, **graph))
    )
    probe = ros.probe()
    joints = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    controls = probe.create_publisher(
        Control, topics.LFC_CONTROL, topics.publisher_qos(topics.LFC_CONTROL)
    )
    return node, probe, joints, controls


def test_lfc_node_applies_the_law_of_each_control_and_holds_without_one(ros):
    node, probe, joints, controls = _lfc(ros)
    sensors = recorder(probe, Sensor, topics.LFC_SENSOR)
    efforts = recorder(probe, Float64MultiArray, topics.EFFORT_COMMANDS)
    records = recorder(probe, JointState, topics.LFC_EFFORT)
    status = recorder(probe, Float64MultiArray, topics.LFC_STATUS)
    robot, names = node.robot, node.joint_names
    rng = np.random.default_rng(4)
    q0 = robot.q_nominal.copy()
    ros.set_clock(node, 0)
    sol = type("S", (), {})()
    sol.torque = robot.gravity(q0) + rng.normal(0.0, 1.0, 7)
    sol.state = np.concatenate((q0, np.zeros(7)))
    sol.feedback_gain = -np.hstack(
        (np.diag(rng.uniform(50, 100, 7)), np.diag(rng.uniform(5, 10, 7)))
    )
    q = q0 + rng.normal(0.0, 0.01, 7)
    v = rng.normal(0.0, 0.05, 7)
    joints.publish(joint_state(node, 0, q, v, sol.torque))
    # the Sensor goes out at once; the effort of a tick waits for its Control (lockstep)
    assert ros.spin_until(lambda: len(sensors) == 1)
    ros.spin_for(0.2)
    assert efforts == []
    np.testing.assert_array_equal(sensors[0].joint_state.position, q)
    assert sensors[0].header.stamp == node.stamp_of(0)
    control = lfc_msgs.control_message(node.stamp_of(0), "classical", names, sol)
    controls.publish(control)
    assert ros.spin_until(lambda: len(efforts) == 1 and len(records) == 1 and len(status) == 1)
    fields = lfc_msgs.control_fields(control, names)
    cmd = LinearFeedbackCommand(fields["feedforward"], fields["feedback_gain"], q0, np.zeros(7))
    expected = np.clip(
        linear_feedback_torque(robot.model, cmd, q, v), -robot.torque_limit, robot.torque_limit
    )
    np.testing.assert_allclose(efforts[0].data, expected, rtol=1e-12)
    np.testing.assert_array_equal(records[0].effort, efforts[0].data)
    assert layouts.LOWLEVEL_STATUS.unpack(status[0])["mode"] == LowLevelMode.TRACK
    # cycle 1 is no tick: the same control applies; a Control for other joints is rejected
    bad = lfc_msgs.control_message(node.stamp_of(2), "classical", names[::-1], sol)
    controls.publish(bad)
    assert ros.spin_until(lambda: node.rejected[f"/{topics.LFC_CONTROL}:value"] == 1)
    ros.set_clock(node, 1)
    joints.publish(joint_state(node, 1, q, v, sol.torque))
    assert ros.spin_until(lambda: len(efforts) == 2 and len(status) == 2)
    # the rejected control dropped the current one: the safe hold from that cycle on
    assert layouts.LOWLEVEL_STATUS.unpack(status[1])["mode"] == LowLevelMode.FALLBACK


def test_lfc_needs_ros2_control_interfaces():
    with pytest.raises(ConfigError, match="ros2_control"):
        node_table("ffmpc", "lfc")
    assert "lfc" in node_table(ROS2_CONTROL, "lfc") and "pid" not in node_table(ROS2_CONTROL, "lfc")
    with pytest.raises(ConfigError, match="low_level"):
        node_table(ROS2_CONTROL, "torque_pid")
