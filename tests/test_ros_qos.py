"""QoS as ROS 2 users expect (ffmpc_ros.topics) and stamps off the cycle grid (ffmpc_ros.base):
a plain rclpy driver publishing SensorDataQoS with its own stamps feeds the MPC, every profile
is overridable with ROS 2's ``qos_overrides`` parameters, and the rule that maps a stamp to a
cycle."""

from __future__ import annotations

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from ffmpc_msgs.msg import MpcCommand
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from ros_helpers import overrides, recorder
from sensor_msgs.msg import JointState

from ffmpc_core.errors import ConfigError
from ffmpc_core.mpc import ModelPredictiveController, MpcMeasurement
from ffmpc_core.polishing import build_task, mpc_config
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.command_msg import command_fields
from ffmpc_ros.input_gate import MAX_FUTURE_STAMP
from ffmpc_ros.joint_sensor_node import JointSensorNode
from ffmpc_ros.mpc_node import MpcNode
from ffmpc_ros.time_grid import GRID_TOLERANCE_NS, cycle_at, stamp_ns

STEP_NS = 1_000_000  # 1 ms cycles
OFFSET_NS = 370_000  # a driver's clock 0.37 ms after the cycle


# -- the stamp rule (base.py) --------------------------------------------------------------------
def test_a_stamp_belongs_to_the_newest_cycle_at_or_before_it():
    assert cycle_at(7 * STEP_NS, STEP_NS) == 7
    assert cycle_at(7 * STEP_NS + OFFSET_NS, STEP_NS) == 7
    assert cycle_at(8 * STEP_NS - GRID_TOLERANCE_NS - 1, STEP_NS) == 7
    # a clock rounded to the grid: just before t_8 is cycle 8, just after t_7 is still 7
    assert cycle_at(8 * STEP_NS - GRID_TOLERANCE_NS, STEP_NS) == 8
    assert cycle_at(7 * STEP_NS - 1, STEP_NS) == 7
    assert cycle_at(0, STEP_NS) == 0 and cycle_at(OFFSET_NS, STEP_NS) == 0


def test_a_stamp_that_is_no_time_has_no_cycle():
    assert stamp_ns(Time(sec=2, nanosec=5)) == 2_000_000_005
    assert stamp_ns(Time(sec=-1, nanosec=0)) is None
    assert stamp_ns(Time(sec=0, nanosec=1_000_000_000)) is None


def test_an_off_grid_stamp_is_judged_by_itself_not_by_its_cycle(ros):
    """Future and stale are measured from the stamp: 10.37 ms ahead is from the future although
    its cycle is exactly 10 ms ahead; 49.63 ms old is fresh, 50.37 ms old is stale."""
    node = ros.add(
        JointSensorNode(context=ros.context, parameter_overrides=overrides("joint_sensor"))
    )
    topic = topics.PLANT_JOINT_STATES
    ros.set_clock(node, 1000)  # 1 s
    assert not node.gate.check_cycle(topic, 1010, 1010 * STEP_NS + OFFSET_NS)
    assert node.rejected[f"/{topic}:future"] == 1
    assert 1010 * STEP_NS - 1000 * STEP_NS <= MAX_FUTURE_STAMP * 1e9  # by its cycle: in time
    assert not node.gate.check_cycle(topic, 949, 949 * STEP_NS + 630_000)  # 50.37 ms old
    assert node.rejected[f"/{topic}:stale"] == 1
    assert node.gate.check_cycle(topic, 950, 950 * STEP_NS + OFFSET_NS)  # 49.63 ms old


# -- a driver's sensor data ------------------------------------------------------------------------
def _stamp(k: int) -> Time:
    return Time(sec=0, nanosec=k * STEP_NS + OFFSET_NS)


def test_a_plain_rclpy_driver_with_sensor_data_qos_and_its_own_stamps_feeds_the_mpc(ros, robot):
    """No ffmpc code on the driver's side: ``SensorDataQoS`` publishers (best effort,
    volatile) of JointState and WrenchStamped, stamped t_k + 0.37 ms. The MPC node, with its
    default QoS, matches them and solves each tick from them: the commands are stamped t_k and
    equal the ROS-free MPC's on the same measurements at t_k."""
    scenario = load_scenario("polishing")
    node = ros.add(MpcNode(context=ros.context, parameter_overrides=overrides("mpc", scenario)))
    driver = ros.add(Node("driver", context=ros.context))
    pub_j = driver.create_publisher(
        JointState, "/joint_sensor/joint_states", qos_profile_sensor_data
    )
    pub_w = driver.create_publisher(WrenchStamped, "/ft_sensor/wrench", qos_profile_sensor_data)
    commands = recorder(ros.probe(), MpcCommand, topics.MPC_COMMAND)
    assert ros.spin_until(
        lambda: pub_j.get_subscription_count() >= 1 and pub_w.get_subscription_count() >= 1
    ), "the MPC's subscriptions did not match the driver's best-effort publishers"
    rng = np.random.default_rng(3)
    q = robot.q_nominal + 0.01 * rng.standard_normal((6, 7))
    v = 0.05 * rng.standard_normal((6, 7))
    tau = robot.gravity(robot.q_nominal) + rng.standard_normal((6, 7))
    force = np.abs(rng.normal(5.0, 1.0, 6))
    for k in range(6):
        joints = JointState()
        joints.header.stamp = _stamp(k)
        joints.name = list(robot.joint_names)
        joints.position, joints.velocity, joints.effort = (
            q[k].tolist(),
            v[k].tolist(),
            tau[k].tolist(),
        )
        wrench = WrenchStamped()
        wrench.header.stamp = _stamp(k)
        wrench.header.frame_id = "contact_world_aligned"
        wrench.wrench.force.z = float(force[k])
        pub_j.publish(joints)
        pub_w.publish(wrench)
        ros.spin_for(0.02)
    assert ros.spin_until(lambda: len(commands) == 3, timeout=30)
    assert node.rejected.total() == 0
    mpc = ModelPredictiveController(robot, mpc_config(scenario), build_task(scenario, robot))
    for i, k in enumerate((0, 2, 4)):
        expected = mpc.step(
            MpcMeasurement(q=q[k], v=v[k], force=force[k : k + 1], torque=tau[k]), k * 1e-3
        )
        got = command_fields(commands[i], 7)
        assert node.cycle_of(commands[i].header.stamp) == k
        np.testing.assert_array_equal(got["torque"], expected.torque)


# -- profiles and overrides ------------------------------------------------------------------------
def test_each_class_has_its_profile():
    sensor = topics.publisher_qos(topics.SENSED_WRENCH)
    assert (sensor.reliability, sensor.durability, sensor.depth) == (
        qos_profile_sensor_data.reliability,
        qos_profile_sensor_data.durability,
        qos_profile_sensor_data.depth,
    )
    reader = topics.subscriber_qos(True, topics.SENSED_JOINT_STATES)
    assert reader.reliability == ReliabilityPolicy.BEST_EFFORT
    for topic in (topics.MPC_COMMAND, topics.MOTOR_TORQUE):
        for qos in (topics.publisher_qos(topic), topics.subscriber_qos(False, topic)):
            assert qos.reliability == ReliabilityPolicy.RELIABLE
            assert qos.durability == DurabilityPolicy.VOLATILE
    for topic in (topics.METRICS_READY, topics.ROBOT_DESCRIPTION):
        assert topics.publisher_qos(topic).durability == DurabilityPolicy.TRANSIENT_LOCAL
    # the reference inputs match `ros2 topic pub`'s default publisher (reliable, volatile)
    for topic in (topics.MPC_REFERENCE, topics.MPC_FORCE_SETPOINT):
        reader = topics.subscriber_qos(True, topic)
        assert (reader.reliability, reader.durability, reader.depth) == (
            ReliabilityPolicy.RELIABLE,
            DurabilityPolicy.VOLATILE,
            1,
        )
    # the only replayed data: nothing else is transient local by default
    for topic, kind in topics.QOS_CLASSES.items():
        latched = topics.publisher_qos(topic).durability == DurabilityPolicy.TRANSIENT_LOCAL
        assert latched == (kind == topics.LATCHED), topic
    # the graph's overrides, under a namespace
    graph = topics.graph_qos_overrides("/arm1")
    assert graph["qos_overrides./arm1/ft_sensor/wrench.subscription.reliability"] == "reliable"
    assert graph["qos_overrides./arm1/ft_sensor/wrench.publisher.depth"] == topics.PUBLISHER_DEPTH
    # lockstep starts by the barrier (topics.START_READY), not by replay: nothing is transient local
    assert not any("durability" in name for name in graph)


def _qos_of(node: Node, topic: str, publishers: bool):
    infos = (
        node.get_publishers_info_by_topic if publishers else node.get_subscriptions_info_by_topic
    )(topic)
    return [i.qos_profile for i in infos if i.node_name == "mpc"]


def test_qos_is_overridden_per_topic_with_ros_parameters(ros):
    """``--ros-args -p qos_overrides./ft_sensor/wrench.subscription.reliability:=reliable``
    changes that subscription only: a best-effort driver then no longer matches it, while the
    joint states still match; the command publisher's depth too."""
    args = [
        "--ros-args",
        "-p",
        "qos_overrides./ft_sensor/wrench.subscription.reliability:=reliable",
        "-p",
        "qos_overrides./mpc/command.publisher.depth:=7",
    ]
    node = ros.add(
        MpcNode(context=ros.context, parameter_overrides=overrides("mpc"), cli_args=args)
    )
    assert node.get_parameter("qos_overrides./ft_sensor/wrench.subscription.reliability").value == (
        "reliable"
    )
    driver = ros.add(Node("driver", context=ros.context))
    pub_j = driver.create_publisher(
        JointState, "/joint_sensor/joint_states", qos_profile_sensor_data
    )
    pub_w = driver.create_publisher(WrenchStamped, "/ft_sensor/wrench", qos_profile_sensor_data)
    assert ros.spin_until(lambda: pub_j.get_subscription_count() == 1)
    ros.spin_for(0.2)
    assert pub_w.get_subscription_count() == 0  # reliable reader, best-effort writer
    [wrench] = _qos_of(driver, "/ft_sensor/wrench", publishers=False)
    [joints] = _qos_of(driver, "/joint_sensor/joint_states", publishers=False)
    assert wrench.reliability == ReliabilityPolicy.RELIABLE
    assert joints.reliability == ReliabilityPolicy.BEST_EFFORT
    assert node.publisher.qos_profile.depth == 7


def test_an_override_rclpy_cannot_apply_is_a_clear_error(ros):
    args = ["--ros-args", "-p", "qos_overrides./mpc/command.publisher.reliability:=sometimes"]
    with pytest.raises(ConfigError, match=r"qos_overrides\./mpc/command\.publisher"):
        MpcNode(context=ros.context, parameter_overrides=overrides("mpc"), cli_args=args)
