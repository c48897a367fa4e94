"""The MPC and PID nodes alone: the same numbers as the ROS-free objects, lockstep waiting,
stale-command fallback, and bad input rejected with the output kept safe."""

from __future__ import annotations

import numpy as np
import pytest
from ffmpc_msgs.msg import MpcCommand
from geometry_msgs.msg import WrenchStamped
from ros_helpers import joint_state, mpc_command, overrides, recorder, wrench
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.lowlevel import LowLevelCommand, LowLevelMeasurement, LowLevelMode
from ffmpc_core.mpc import ModelPredictiveController, MpcMeasurement
from ffmpc_core.polishing import build_task, lowlevel_controller, mpc_config
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import layouts, topics
from ffmpc_ros.command_msg import command_fields
from ffmpc_ros.mpc_node import MpcNode
from ffmpc_ros.pid_node import PidNode

#: The time-based switch to contact: these MPC nodes are fed joint states only (a guarded
#: approach's MPC node also waits for the wrench, its contact detection's input).
TIMED = {"task.approach_speed": 0.0}


def _measurements(robot, n, seed=0):
    rng = np.random.default_rng(seed)
    q = robot.q_nominal + 0.01 * rng.standard_normal((n, 7))
    v = 0.05 * rng.standard_normal((n, 7))
    tau = robot.gravity(robot.q_nominal) + rng.standard_normal((n, 7))
    force = np.abs(rng.normal(5.0, 1.0, n))
    return q, v, tau, force


def test_mpc_node_solves_every_period_with_the_runner_numbers(ros, robot):
    """Force-feedback: a solve at k = 0, 2, 4 once the joint state AND the wrench of that cycle
    are in (whatever their arrival order), bit-identical to ModelPredictiveController."""
    scenario = load_scenario("polishing")
    node = ros.add(MpcNode(context=ros.context, parameter_overrides=overrides("mpc", scenario)))
    # lockstep: the solver's settings of the ROS-free runner (no real-time budget)
    assert node.mpc.config.constrained_iterations == 0
    probe = ros.probe()
    out = recorder(probe, MpcCommand, topics.MPC_COMMAND)
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    pub_w = probe.create_publisher(WrenchStamped, topics.SENSED_WRENCH, topics.publisher_qos())
    q, v, tau, force = _measurements(robot, 6)
    for k in range(6):
        if k % 2:  # wrench first on odd cycles
            pub_w.publish(wrench(node, k, (0.0, 0.0, force[k])))
            ros.spin_for(0.01)
        pub_j.publish(joint_state(node, k, q[k], v[k], tau[k]))
        if k == 2:
            ros.spin_for(0.05)
            assert len(out) == 1  # cycle 2 waits for its wrench
        if k % 2 == 0:
            pub_w.publish(wrench(node, k, (0.0, 0.0, force[k])))
    assert ros.spin_until(lambda: len(out) == 3, timeout=30)
    mpc = ModelPredictiveController(robot, mpc_config(scenario), build_task(scenario, robot))
    for i, k in enumerate((0, 2, 4)):
        meas = MpcMeasurement(q=q[k], v=v[k], force=force[k : k + 1], torque=tau[k])
        expected = mpc.step(meas, k * 1e-3)
        got = command_fields(out[i], 7)
        assert got["t"] == k * 1e-3 and got["sequence"] == i and got["nx"] == 15
        np.testing.assert_array_equal(got["torque"], expected.torque)
        np.testing.assert_array_equal(got["state"], expected.state)
        np.testing.assert_array_equal(got["feedback_gain"].reshape(7, 15), expected.feedback_gain)
    # Bad input: no solve from a NaN state, a wrench in the wrong frame, unknown joints.
    pub_j.publish(joint_state(node, 6, [np.nan] * 7, v[0], tau[0]))
    pub_w.publish(wrench(node, 6, (0.0, 0.0, 1.0), frame="tool"))
    pub_j.publish(joint_state(node, 7, q[0], v[0], tau[0], [f"j{i}" for i in range(7)]))
    assert ros.spin_until(lambda: node.rejected.total() == 3)
    ros.spin_for(0.05)
    assert len(out) == 3


def test_mpc_node_stays_on_the_tick_grid_after_an_outage(ros, robot):
    """Lockstep, after cycles it never heard (a frozen and resumed process): the next solve is
    the next tick k = j·every the PID waits on, never the first cycle that completes (5, 7)."""
    scenario = load_scenario("polishing", {"mpc.formulation": "classical", **TIMED})
    node = ros.add(MpcNode(context=ros.context, parameter_overrides=overrides("mpc", scenario)))
    probe = ros.probe()
    out = recorder(probe, MpcCommand, topics.MPC_COMMAND)
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    q, v, tau, _ = _measurements(robot, 9)
    for k in (0, 5, 6, 7, 8):  # cycles 1-4 lost
        pub_j.publish(joint_state(node, k, q[k], v[k], tau[k]))
        ros.spin_for(0.01)
    assert ros.spin_until(lambda: len(out) == 3, timeout=30)
    ros.spin_for(0.05)
    times = [command_fields(m, 7)["t"] for m in out]
    assert times == [0.0, 6e-3, 8e-3]
    # A backlog tick (within max_input_age, but more than a period behind the plant's clock)
    # is not solved: its command would come too late and it would hide the outage.
    ros.set_clock(node, 40)
    for k in (34, 35, 36, 40):
        pub_j.publish(joint_state(node, k, q[0], v[0], tau[0]))
        ros.spin_for(0.01)
    assert ros.spin_until(lambda: len(out) == 4, timeout=30), (len(out), node.rejected)
    ros.spin_for(0.05)
    assert command_fields(out[3], 7)["t"] == 40e-3
    assert node.rejected["solve:late"] == 2  # ticks 34 and 36 (4 and 6 ms behind)


def _pid(ros, scenario, lockstep=True):
    node = ros.add(
        PidNode(
            context=ros.context,
            parameter_overrides=overrides("pid", scenario, lockstep=lockstep),
        )
    )
    probe = ros.probe()
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    pub_c = probe.create_publisher(MpcCommand, topics.MPC_COMMAND, topics.publisher_qos())
    motor = recorder(probe, JointState, topics.MOTOR_TORQUE)
    desired = recorder(probe, JointState, topics.DESIRED_TORQUE)
    status = recorder(probe, Float64MultiArray, topics.LOWLEVEL_STATUS)
    return node, pub_j, pub_c, motor, desired, status


def test_pid_node_waits_for_the_command_in_lockstep_and_matches_the_core(ros, robot):
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    node, pub_j, pub_c, motor, desired, _ = _pid(ros, scenario)
    q, v, tau, _ = _measurements(robot, 8, seed=1)
    torques = robot.gravity(robot.q_nominal) + np.random.default_rng(2).normal(0, 3, (8, 7))
    reference = lowlevel_controller(scenario, robot)
    for k in range(8):
        pub_j.publish(joint_state(node, k, q[k], v[k], tau[k]))
        if k % 2 == 0:
            ros.spin_for(0.03)
            assert len(motor) == k  # an MPC cycle: waits for the command of cycle k
            pub_c.publish(mpc_command(k, torques[k]))
            command = LowLevelCommand(torques[k], np.zeros(14), np.zeros((7, 14)))
            reference.set_command(command, k * 1e-3)
        assert ros.spin_until(lambda k=k: len(motor) == len(desired) == k + 1)
        out = reference.step(LowLevelMeasurement(q[k], v[k], tau[k]), k * 1e-3)
        assert node.cycle_of(motor[k].header.stamp) == k
        np.testing.assert_array_equal(motor[k].effort, out.motor_torque)
        np.testing.assert_array_equal(desired[k].effort, out.desired_torque)
    assert node.lowlevel.mode == LowLevelMode.TRACK


def test_pid_node_falls_back_to_hold_when_the_mpc_goes_stale(ros, robot):
    """Real-time mode: commands every 2 cycles until t = 20 ms, then none: the PID tracks until
    the command is 4 ms (two MPC periods) old and holds from the next cycle on."""
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    node, pub_j, pub_c, motor, _, status = _pid(ros, scenario, lockstep=False)
    q, v, tau, _ = _measurements(robot, 40, seed=3)
    gravity = robot.gravity(robot.q_nominal)
    for k in range(40):
        ros.set_clock(node, k)
        if k % 2 == 0 and k <= 20:
            pub_c.publish(mpc_command(k, gravity))
            ros.spin_for(0.005)
        pub_j.publish(joint_state(node, k, q[k], v[k], tau[k]))
        assert ros.spin_until(lambda k=k: len(status) == k + 1)
    modes = [layouts.LOWLEVEL_STATUS.unpack(s)["mode"] for s in status]
    ages = [layouts.LOWLEVEL_STATUS.unpack(s)["command_age"] for s in status]
    assert all(m == LowLevelMode.TRACK for m in modes[:25])
    assert modes[25] == LowLevelMode.FALLBACK and ages[25] == pytest.approx(0.005)
    assert all(m == LowLevelMode.FALLBACK for m in modes[25:])
    assert all(np.all(np.abs(m.effort) <= robot.torque_limit) for m in motor)


def test_pid_node_rejects_bad_commands_and_saturates(ros, robot):
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    node, pub_j, pub_c, motor, desired, _ = _pid(ros, scenario)  # lockstep: every sample read
    q, v, tau, _ = _measurements(robot, 4, seed=4)
    good = mpc_command(0, np.full(7, 1e3))  # 6–25× the limits: saturated, not rejected
    nan = mpc_command(2, np.full(7, np.nan))
    wrong_nx = mpc_command(2, np.zeros(7), nx=21)  # a torque-feedback command
    wrong_nv = mpc_command(2, np.zeros(6), nv=6)
    old_version = mpc_command(2, np.zeros(7))
    old_version.version = 1  # the retired array layout's version
    other_joints = mpc_command(2, np.zeros(7), names=[f"j{i}" for i in range(7)])
    no_gain = mpc_command(2, np.zeros(7))
    no_gain.feedback_gain.data = no_gain.feedback_gain.data[:-1]
    no_time = mpc_command(2, np.zeros(7))
    no_time.header.stamp.nanosec = 1_500_000_000  # not a time (an off-grid one is accepted)
    bad = (nan, wrong_nx, wrong_nv, old_version, other_joints, no_gain)
    for msg in (good, *bad, no_time):
        pub_c.publish(msg)
    assert ros.spin_until(lambda: node.rejected.total() == 7)
    topic = topics.resolve(topics.MPC_COMMAND)
    assert node.rejected[f"{topic}:value"] == 6 and node.rejected[f"{topic}:stamp"] == 1
    assert node.log_lines[f"{topic}:value"] == 1
    pub_j.publish(joint_state(node, 0, q[0], v[0], tau[0]))
    pub_j.publish(joint_state(node, 1, q[1], v[1], tau[1][:3], list(node.joint_names)))
    assert ros.spin_until(lambda: len(motor) == len(desired) == 1 and node.rejected.total() == 8)
    np.testing.assert_array_equal(desired[0].effort, robot.torque_limit)
    assert np.all(np.abs(motor[0].effort) <= robot.torque_limit)


def test_mpc_node_real_time_path_solves_on_ticks_only(ros, robot):
    """``lockstep: false``: the node warms up, then ``spin_realtime`` (its own wait set, no
    executor) solves on the MPC ticks (k = 0, 2, 4 …) only and ignores the cycles between."""
    import os
    import threading

    import rclpy
    from rclpy.context import Context

    scenario = load_scenario("polishing", {"mpc.formulation": "classical", **TIMED})
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    node = MpcNode(context=context, parameter_overrides=overrides("mpc", scenario, lockstep=False))
    spinner = threading.Thread(target=node.spin_realtime, daemon=True)
    spinner.start()
    try:
        probe = ros.probe()
        out = recorder(probe, MpcCommand, topics.MPC_COMMAND)
        pub = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
        # both sides of both matches made: sensor data is best effort and commands volatile, so
        # a sample sent before the reader's side matched is lost (a fresh-clone run lost k = 2)
        assert ros.spin_until(
            lambda: (
                pub.get_subscription_count() > 0
                and node.inputs[0].get_publisher_count() > 0
                and node.publisher.get_subscription_count() > 0
            ),
            timeout=10,
        )
        q, v, tau, _ = _measurements(robot, 6)
        for k in (1, 2, 3, 4, 5):
            pub.publish(joint_state(node, k, q[k], v[k], tau[k]))
            done = ros.spin_until(lambda k=k: len(out) == k // 2, timeout=10)
            ros.spin_for(0.05)  # an odd cycle would have been solved by now
            assert done and len(out) == k // 2, k
        got = [command_fields(m, 7) for m in out]
        assert [g["t"] for g in got] == [0.002, 0.004] and [g["sequence"] for g in got] == [0, 1]
        assert all(np.all(np.isfinite(g["torque"])) for g in got)
        assert node.mpc.nx == 14 and len(node.solve_times) == 2
        # real time: one SQP iteration of the constrained solver per tick (real_time_iterations)
        assert node.mpc.config.constrained_iterations == 1
    finally:
        rclpy.shutdown(context=context)
        spinner.join(timeout=5)
        assert not spinner.is_alive()
        node.destroy_node()
