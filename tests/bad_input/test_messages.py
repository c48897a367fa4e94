"""Inputs from outside the graph, through a real rclpy publisher in this process (issue 28):

* a foreign ``/mpc/command`` (absurd, malformed, off the MPC's ticks) is rejected without
  taking the tick from the MPC's own command: the lockstep PID steps on with the genuine one at
  once (no ``lockstep_timeout`` stall, no safe hold);
* the MPC's reference inputs match a publisher with rclpy's default QoS (RELIABLE, VOLATILE:
  what ``ros2 topic pub`` uses), and the value is kept as the MPC's live parameter;
* a live number sent as text (``ros2 param set /mpc contact.stiffness 1e4`` sends the string
  "1e4") is read as ROS 2 reads the number; text that is no number is refused."""

from __future__ import annotations

import numpy as np
import pytest
from ffmpc_msgs.msg import MpcCommand
from geometry_msgs.msg import PoseStamped
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from ros_helpers import joint_state, mpc_command, overrides, recorder
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from ffmpc_core.lowlevel import LowLevelMode
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.mpc_node import MpcNode
from ffmpc_ros.pid_node import PidNode

#: Wall s the PID may take to step a cycle whose inputs are all there; far below its
#: lockstep_timeout (5 s), the stall a lost command costs.
STEP_WAIT = 2.0


def test_a_foreign_command_never_takes_the_mpcs_tick(ros, robot):
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    node = ros.add(PidNode(context=ros.context, parameter_overrides=overrides("pid", scenario)))
    assert node.lockstep and node.lockstep_timeout > 2 * STEP_WAIT and node.every == 2
    probe = ros.probe("foreign")
    pub_c = probe.create_publisher(MpcCommand, topics.MPC_COMMAND, topics.publisher_qos())
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    motor = recorder(probe, JointState, topics.MOTOR_TORQUE)
    assert ros.spin_until(lambda: pub_c.get_subscription_count() > 0 and len(node.accepted) == 0)
    q, gravity = robot.q_nominal, robot.gravity(robot.q_nominal)
    topic = topics.resolve(topics.MPC_COMMAND)
    for k in (0, 1, 2, 3, 4, 5, 6):
        ros.set_clock(node, k)
        if k % 2 == 0:
            # before the MPC's own command: a finite but absurd one stamped from /clock, a
            # malformed one stamped 0, and a valid one for the next cycle (no tick)
            pub_c.publish(mpc_command(k, np.full(7, 1e6)))
            malformed = mpc_command(0, gravity)
            malformed.feedforward = list(gravity[:6])  # six torques for seven joints
            pub_c.publish(malformed)
            pub_c.publish(mpc_command(k + 1, 0.5 * gravity))
            assert ros.spin_until(lambda k=k: node.rejected[f"{topic}:tick"] == k // 2 + 1)
            pub_c.publish(mpc_command(k, gravity))  # the graph's MPC
        pub_j.publish(joint_state(node, k, q, np.zeros(7), gravity))
        assert ros.spin_until(lambda k=k: len(motor) == k + 1, timeout=STEP_WAIT), k
        assert node.report.last_output.mode != LowLevelMode.FALLBACK, k
        np.testing.assert_allclose(node.report.last_output.desired_torque, gravity, atol=1e-9)
    assert node.lowlevel.command_time == pytest.approx(6e-3)  # every tick took its own
    assert node.rejected[f"{topic}:value"] == 8  # the absurd and the malformed ones
    assert node.rejected[f"{topic}:tick"] == 4
    assert "lockstep" not in node.rejected and node.lowlevel.invalid_commands == 0
    assert all(np.all(np.abs(m.effort) <= robot.torque_limit) for m in motor)


@pytest.fixture
def mpc(ros):
    return ros.add(MpcNode(context=ros.context, parameter_overrides=overrides("mpc")))


def test_reference_inputs_match_a_default_publisher_and_stay_as_parameters(ros, mpc):
    """What ``ros2 topic pub --once /mpc/force_setpoint std_msgs/msg/Float64 "{data: 30.0}"``
    does: a publisher with rclpy's default QoS (depth 10: RELIABLE, VOLATILE), one message
    once a subscription matched. The MPC's latched (TRANSIENT_LOCAL) readers never matched it."""
    probe = ros.probe("operator")
    pub_force = probe.create_publisher(Float64, "mpc/force_setpoint", 10)
    pub_ref = probe.create_publisher(PoseStamped, "mpc/reference", 10)
    assert ros.spin_until(
        lambda: pub_force.get_subscription_count() == 1 and pub_ref.get_subscription_count() == 1
    )
    pub_force.publish(Float64(data=30.0))
    target = PoseStamped()
    target.header.frame_id = topics.WORLD_FRAME
    centre = mpc.task.circle_center()
    target.pose.position.x, target.pose.position.y, target.pose.position.z = (
        float(x) for x in centre + [0.03, 0.0, 0.0]
    )
    pub_ref.publish(target)
    assert ros.spin_until(lambda: len(mpc.live.pending) == 2)
    assert mpc.get_parameter("task.normal_force").value == 30.0
    np.testing.assert_allclose(mpc.get_parameter("position_offset").value, [0.03, 0.0, 0.0])
    assert not mpc.rejected


def test_a_live_number_given_as_text_is_read_as_ros_reads_it(ros, mpc):
    client = AsyncParameterClient(ros.probe("tuner"), "mpc")
    assert client.wait_for_services(timeout_sec=10.0)

    def set_text(text: str):
        future = client.set_parameters(
            [Parameter("contact.stiffness", Parameter.Type.STRING, text)]
        )
        assert ros.spin_until(future.done)
        return future.result().results[0]

    ok = set_text("1e4")
    assert ok.successful, ok.reason
    assert mpc.get_parameter("contact.stiffness").type_ == Parameter.Type.DOUBLE
    assert mpc.get_parameter("contact.stiffness").value == 10000.0
    for text, reason in (("stiff", "expected a number"), ("1e+10", "out of range")):
        refused = set_text(text)
        assert not refused.successful and reason in refused.reason, refused.reason
    assert mpc.get_parameter("contact.stiffness").value == 10000.0
