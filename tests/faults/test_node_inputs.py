"""Faults at the nodes' inputs: stamps from the future, a rejected wrench under Riccati feedback,
run-time changes of ``use_sim_time`` and the discovery range of every entry point."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest
from ffmpc_msgs.msg import MpcCommand
from geometry_msgs.msg import WrenchStamped
from rclpy.parameter import Parameter
from ros_helpers import joint_state, mpc_command, overrides, recorder, wrench
from sensor_msgs.msg import JointState

from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.discovery import DISCOVERY_RANGE_VARIABLE, ensure_local_discovery
from ffmpc_ros.input_gate import MAX_FUTURE_STAMP
from ffmpc_ros.joint_sensor_node import JointSensorNode
from ffmpc_ros.pid_node import PidNode


def test_a_stamp_from_the_future_is_rejected_and_never_becomes_the_nodes_now(ros, robot):
    node = ros.add(
        JointSensorNode(context=ros.context, parameter_overrides=overrides("joint_sensor"))
    )
    probe = ros.probe()
    out = recorder(probe, JointState, topics.SENSED_JOINT_STATES)
    pub = probe.create_publisher(JointState, topics.PLANT_JOINT_STATES, topics.publisher_qos())
    q, v, tau = robot.q_nominal, np.zeros(7), np.zeros(7)
    ros.set_clock(node, 10)
    pub.publish(joint_state(node, 10, q, v, tau))
    assert ros.spin_until(lambda: len(out) == 1)
    # One hour ahead, then just beyond the tolerance: both rejected, one log line each kind.
    ahead = int(round(MAX_FUTURE_STAMP / node.time_step)) + 1
    for k in (10 + 3_600_000, 11 + ahead):
        pub.publish(joint_state(node, k, q, v, tau))
    kind = f"{topics.resolve(topics.PLANT_JOINT_STATES)}:future"
    assert ros.spin_until(lambda: node.rejected[kind] == 2)
    assert node.log_lines[kind] == 1
    # Genuine messages still go through: the future stamps were never adopted.
    for k in (11, 12):
        ros.set_clock(node, k)
        pub.publish(joint_state(node, k, q, v, tau))
    assert ros.spin_until(lambda: len(out) == 3)
    assert [node.cycle_of(m.header.stamp) for m in out] == [10, 11, 12]
    # Within the tolerance (the /clock of cycle k may arrive after its data): accepted.
    pub.publish(joint_state(node, 12 + ahead - 1, q, v, tau))
    assert ros.spin_until(lambda: len(out) == 4)


def test_a_node_without_a_time_yet_judges_stamps_from_its_first_clock_on(ros):
    """Before any /clock sample the node's clock is 0: it cannot tell a stamp from the future,
    and accepts it (a lockstep MPC whose clock stayed at 0 for 11 cycles rejected genuine
    inputs as from the future, and the run left the runner's). From the first /clock on, a
    stamp beyond the tolerance is rejected again, even one of time 0."""
    from rosgraph_msgs.msg import Clock

    node = ros.add(
        JointSensorNode(context=ros.context, parameter_overrides=overrides("joint_sensor"))
    )
    ahead = int(round(MAX_FUTURE_STAMP / node.time_step)) + 1
    assert node.get_clock().now().nanoseconds == 0
    assert node.gate.check_cycle("plant/joint_states", ahead)  # no time yet: accepted
    node.clock_reader.on_clock(Clock())  # the first /clock, t = 0
    assert not node.gate.check_cycle("other/topic", ahead)
    assert node.rejected[f"{node.name_of('other/topic')}:future"] == 1


def test_a_command_from_the_future_is_rejected_by_the_pid(ros, robot):
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    node = ros.add(
        PidNode(context=ros.context, parameter_overrides=overrides("pid", scenario, lockstep=False))
    )
    probe = ros.probe()
    pub_c = probe.create_publisher(MpcCommand, topics.MPC_COMMAND, topics.publisher_qos())
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    motor = recorder(probe, JointState, topics.MOTOR_TORQUE)
    gravity = robot.gravity(robot.q_nominal)
    spoof = np.full(7, 1e3)  # would saturate every joint
    ros.set_clock(node, 4)
    pub_c.publish(mpc_command(4_000_000, spoof))
    assert ros.spin_until(
        lambda: node.rejected[f"{topics.resolve(topics.MPC_COMMAND)}:future"] == 1
    )
    pub_c.publish(mpc_command(4, gravity))
    pub_j.publish(joint_state(node, 4, robot.q_nominal, np.zeros(7), gravity))
    assert ros.spin_until(lambda: len(motor) == 1)
    assert node.lowlevel.command_time == pytest.approx(4e-3)  # the genuine one was taken
    np.testing.assert_allclose(node.report.last_output.desired_torque, gravity)


def test_one_rejected_wrench_does_not_stall_the_riccati_feedback_loop(ros, robot):
    """Force-feedback with Riccati feedback in lockstep: the PID waits for each cycle's wrench.
    A NaN wrench is rejected; the cycle goes on with the newest good λ̂ (held), and a loop whose
    wrenches stop altogether goes on without feedback after the lockstep timeout."""
    scenario = load_scenario(
        "polishing", {"mpc.formulation": "force_feedback", "mpc.riccati_feedback": True}
    )
    node = ros.add(
        PidNode(
            context=ros.context,
            parameter_overrides=overrides("pid", scenario, lockstep_timeout=0.2),
        )
    )
    probe = ros.probe()
    pub_c = probe.create_publisher(MpcCommand, topics.MPC_COMMAND, topics.publisher_qos())
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    pub_w = probe.create_publisher(WrenchStamped, topics.SENSED_WRENCH, topics.publisher_qos())
    motor = recorder(probe, JointState, topics.MOTOR_TORQUE)
    desired = recorder(probe, JointState, topics.DESIRED_TORQUE)
    q, gravity = robot.q_nominal, robot.gravity(robot.q_nominal)
    gain = np.zeros((7, 15))
    gain[:, 14] = 0.01  # τ = τ* + 0.01·(λ̂ − λ_solve): the held force shows in the torque
    state = np.concatenate([q, np.zeros(7), [0.0]])
    for k in range(12):
        ros.set_clock(node, k)
        if k % 2 == 0:
            pub_c.publish(mpc_command(k, gravity, nx=15, gain=gain, state=state))
        force = np.nan if k in (3, 4) else 10.0 + k
        pub_w.publish(wrench(node, k, (0.0, 0.0, force)))
        if k < 8:
            pub_j.publish(joint_state(node, k, q, np.zeros(7), gravity))
            assert ros.spin_until(lambda k=k: len(motor) == k + 1, timeout=5.0), k
    assert node.rejected[f"{topics.resolve(topics.SENSED_WRENCH)}:value"] == 2
    # Cycles 3 and 4 used the held λ̂ of cycle 2 (12 N); the others their own.
    assert ros.spin_until(lambda: len(desired) == 8)
    tau = [np.array(m.effort) for m in desired]
    assert tau[3][0] == pytest.approx(gravity[0] + 0.01 * 12.0)
    assert tau[5][0] == pytest.approx(gravity[0] + 0.01 * 15.0)
    # Wrenches stop: after the lockstep timeout the loop goes on (held λ̂ while fresh).
    for k in range(12, 16):
        ros.set_clock(node, k)
        pub_j.publish(joint_state(node, k, q, np.zeros(7), gravity))
    assert ros.spin_until(lambda: len(motor) == 12, timeout=10.0)
    assert all(np.all(np.abs(m.effort) <= robot.torque_limit) for m in motor)


def test_use_sim_time_is_fixed_at_start(ros):
    node = ros.add(
        JointSensorNode(context=ros.context, parameter_overrides=overrides("joint_sensor"))
    )
    (result,) = node.set_parameters([Parameter("use_sim_time", value=False)])
    assert not result.successful and "fixed at start" in result.reason
    assert node.get_parameter("use_sim_time").value is True
    (result,) = node.set_parameters([Parameter("seed", value=5)])
    assert not result.successful  # every scenario parameter is read-only


def test_discovery_stays_on_this_machine_unless_the_user_widens_it(monkeypatch):
    monkeypatch.delenv(DISCOVERY_RANGE_VARIABLE, raising=False)
    assert ensure_local_discovery() == "LOCALHOST"
    assert os.environ[DISCOVERY_RANGE_VARIABLE] == "LOCALHOST"
    monkeypatch.setenv(DISCOVERY_RANGE_VARIABLE, "SUBNET")
    assert ensure_local_discovery() == "SUBNET"  # a range chosen on purpose is kept


@pytest.mark.parametrize(
    "module", ["ffmpc_ros.joint_sensor_node", "ffmpc_ros.pid_node", "ffmpc_ros.plant_node"]
)
def test_a_node_started_by_hand_reports_localhost_discovery(module):
    env = {k: v for k, v in os.environ.items() if k != DISCOVERY_RANGE_VARIABLE}
    proc = subprocess.Popen(
        [sys.executable, "-m", module],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 30.0
        lines = []
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line)
            if "discovery" in line:
                break
        assert any("discovery LOCALHOST" in line for line in lines), "".join(lines)
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_the_plant_brakes_and_holds_when_the_motor_torques_stop(ros, robot):
    """Real time, plant alone: one torque that sets the arm moving, then nothing. The drives hold
    it for the data sheet's 20 ms, then the communication reflex (``ffmpc_core.reflex``: the
    robot's own, as an iiwa's FRI or a Panda's libfranka session ends) stops the robot — one log
    line, the event on /plant/status — instead of applying that torque for ever; the robot is
    braked to rest and held."""
    from ffmpc_ros.plant_node import PlantNode

    params = overrides("plant", None, lockstep=False, duration=0.4)
    node = ros.add(PlantNode(context=ros.context, parameter_overrides=params))
    probe = ros.probe()
    pub = probe.create_publisher(JointState, topics.MOTOR_TORQUE, topics.publisher_qos())
    torque = robot.gravity(robot.q_nominal) + 0.05 * robot.torque_limit * np.array(
        [0, 1, 0, 1, 0, 0, 0]
    )
    assert ros.spin_until(lambda: node.k >= 1, timeout=10)
    pub.publish(joint_state(node, node.k, robot.q_nominal, np.zeros(7), torque))
    assert ros.spin_until(lambda: node.done, timeout=20)
    reflex = node.reflex_plant.reflex
    assert reflex.event is not None and reflex.event.kind == "communication", reflex.event
    assert reflex.stopped and reflex.stop_cycles > 300
    v_end = np.abs(node.state.v) / robot.velocity_limit
    assert v_end.max() < 0.05, v_end  # braked to (nearly) rest within the run
