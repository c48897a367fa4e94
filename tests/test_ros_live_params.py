"""Live parameters and the MPC's reference topics: set through the real parameter services
(rclpy's AsyncParameterClient) on running nodes, checked, applied at the next solve/cycle, and
read back from the ffmpc_core objects; bad values and messages refused with a reason and counted.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from ffmpc_msgs.msg import MpcCommand
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from ros_helpers import joint_state, mpc_command, overrides, recorder, wrench
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64

from ffmpc_core.lowlevel import LowLevelCommand, LowLevelMeasurement
from ffmpc_core.polishing import lowlevel_controller
from ffmpc_core.scenario import PAPER_SCHEDULE, load_scenario
from ffmpc_ros import topics
from ffmpc_ros.mpc_node import MpcNode
from ffmpc_ros.params import NODE_SPECS
from ffmpc_ros.pid_node import PidNode


def _client(ros, node_name: str) -> AsyncParameterClient:
    client = AsyncParameterClient(ros.probe(f"param_client_{node_name}"), node_name)
    assert ros.spin_until(client.services_are_ready, timeout=10.0)
    return client


def _call(ros, future):
    assert ros.spin_until(future.done, timeout=10.0), "no answer from the parameter service"
    return future.result()


def _set(ros, client, name, value):
    """Set one parameter through the node's set_parameters service; its SetParametersResult."""
    return _call(ros, client.set_parameters([Parameter(name, value=value)])).results[0]


def _solve_tick(ros, node, pub_j, pub_w, robot, k, commands, force=20.0):
    """Publish the measurements of cycle k (an MPC tick) and wait for its command."""
    q, v = robot.q_nominal, np.zeros(7)
    n = len(commands)
    pub_w.publish(wrench(node, k, (0.0, 0.0, force)))
    pub_j.publish(joint_state(node, k, q, v, robot.gravity(q)))
    assert ros.spin_until(lambda: len(commands) == n + 1), f"no command for tick {k}"


def _mpc_under_test(ros):
    """An MPC node of the polishing scenario, the list its commands go to, publishers of its
    joint-state and wrench inputs, and a parameter client of it."""
    node = ros.add(MpcNode(context=ros.context, parameter_overrides=overrides("mpc")))
    probe = ros.probe()
    commands = recorder(probe, MpcCommand, topics.MPC_COMMAND)
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    pub_w = probe.create_publisher(WrenchStamped, topics.SENSED_WRENCH, topics.publisher_qos())
    return node, commands, pub_j, pub_w, _client(ros, "mpc")


def _pid_under_test(ros, scenario):
    """A PID node of ``scenario``, publishers of its joint-state and command inputs, the list its
    motor torques go to, and a parameter client of it."""
    node = ros.add(PidNode(context=ros.context, parameter_overrides=overrides("pid", scenario)))
    probe = ros.probe()
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    pub_c = probe.create_publisher(MpcCommand, topics.MPC_COMMAND, topics.publisher_qos())
    motor = recorder(probe, JointState, topics.MOTOR_TORQUE)
    return node, pub_j, pub_c, motor, _client(ros, "pid")


def _stiffness(mpc) -> set[float]:
    """The nominal K (N/m) of every OCP node of a ModelPredictiveController."""
    nodes = [*mpc.nodes, mpc.terminal_node]
    return {float(k) for n in nodes for k in n.model.nominal_stiffness}


def test_stiffness_set_on_a_running_mpc_changes_the_ocp_from_the_next_solve(ros, robot, capfd):
    """contact.stiffness 1000 → 1500 N/m through the service: accepted, the OCP's K is still 1000
    until the next solve and 1500 in every node (and the δo predictor) after it; -5 N/m, NaN and
    a string are refused with a reason, one log line each, and change nothing."""
    node, commands, pub_j, pub_w, client = _mpc_under_test(ros)
    (desc,) = _call(ros, client.describe_parameters(["contact.stiffness"])).descriptors
    assert not desc.read_only and desc.floating_point_range[0].from_value == 0.0
    assert desc.floating_point_range[0].to_value == pytest.approx(1e9)
    _solve_tick(ros, node, pub_j, pub_w, robot, 0, commands)  # the node is running
    assert _stiffness(node.mpc) == {1000.0}

    result = _set(ros, client, "contact.stiffness", 1500.0)
    assert result.successful, result.reason
    assert node.get_parameter("contact.stiffness").value == 1500.0
    assert node.live.pending == {"contact.stiffness": 1500.0}
    assert _stiffness(node.mpc) == {1000.0}  # not before the next solve
    _solve_tick(ros, node, pub_j, pub_w, robot, 2, commands)
    assert _stiffness(node.mpc) == {1500.0}
    assert node.mpc.config.contact.stiffness == 1500.0
    assert float(node.mpc._predictor.model.nominal_stiffness[0]) == 1500.0
    assert node.live.changes == [(2, "contact.stiffness", 1500.0)]

    capfd.readouterr()
    for bad in (-5.0, math.nan, "stiff"):
        result = _set(ros, client, "contact.stiffness", bad)
        assert not result.successful and "contact.stiffness" in result.reason, result.reason
    # (rclpy's own range check answers first for a float; the schema's for the rest)
    assert "out of range" in _set(ros, client, "contact.stiffness", -5.0).reason
    reason = _set(ros, client, "contact.damping", -1).reason  # an integer: no rclpy range check
    assert "expected a number in [0, 1e+06] N·s/m" in reason
    assert node.live.refused == {"contact.stiffness": 4, "contact.damping": 1}
    log = capfd.readouterr().err
    assert log.count("parameter refused") == 5 and "accepted" not in log  # one line each
    assert node.get_parameter("contact.stiffness").value == 1500.0 and not node.live.pending
    _solve_tick(ros, node, pub_j, pub_w, robot, 4, commands)
    assert _stiffness(node.mpc) == {1500.0} and len(node.live.changes) == 1

    # read-only stays read-only; another formulation's weights are refused with the reason
    assert "read-only" in _set(ros, client, "horizon", 3).reason
    result = _set(ros, client, "weights.classical.posture", 1.0)
    assert not result.successful and "runs the force_feedback formulation" in result.reason
    result = _set(ros, client, "weights.force_feedback.posture", 0.5)
    assert result.successful
    _solve_tick(ros, node, pub_j, pub_w, robot, 6, commands)
    assert {n.model.weight("posture") for n in node.mpc.nodes} == {0.5}


def test_free_space_position_weight_set_live_changes_only_free_space(ros, robot):
    """weights.force_feedback.ee_position_free through the service: from the next solve, c4 of
    the stand-still (free space) is the new value and c4 in contact keeps the scenario's."""
    node, commands, pub_j, pub_w, client = _mpc_under_test(ros)
    _solve_tick(ros, node, pub_j, pub_w, robot, 0, commands)
    before = node.schedule.task.weights
    assert before == load_scenario("polishing").mpc.phase_weights()  # the scenario file's
    assert before.free_ee_position != 250.0
    assert _set(ros, client, "weights.force_feedback.ee_position_free", 250.0).successful
    assert node.schedule.task.weights == before  # not before the next solve
    _solve_tick(ros, node, pub_j, pub_w, robot, 2, commands)
    after = node.schedule.task.weights
    assert after.free_ee_position == 250.0
    assert (after.contact_ee_position, after.force) == (before.contact_ee_position, before.force)
    assert node.schedule.reference(0.01).ee_position_weight == 250.0
    assert not _set(ros, client, "weights.force_feedback.ee_position_free", -1.0).successful


def test_live_parameters_are_exactly_the_declared_ones(ros):
    """Every node's writable parameters are its NodeSpec.live ones (the one table)."""
    mpc = ros.add(MpcNode(context=ros.context, parameter_overrides=overrides("mpc")))
    pid = ros.add(PidNode(context=ros.context, parameter_overrides=overrides("pid")))
    for node, expected in ((mpc, 2 + 1 + 1 + 3 * 8), (pid, 5)):
        writable = [d.name for d in node.describe_parameters(list(node.params)) if not d.read_only]
        assert all(node.spec.is_live(n) for n in writable)
        assert len(writable) == expected, writable
    assert NODE_SPECS["pid"].live == ("kp", "ki", "kd", "torque_limit_fraction", "stale_timeout")


def test_torque_limit_set_live_saturates_the_next_cycle_and_a_looser_one_is_refused(ros, robot):
    """torque_limit_fraction 1 → 0.3 at cycle 4: from cycle 4 on, every motor torque equals the
    core low level's with ``set_limits(0.3)`` and is within 0.3 × the data-sheet limits (it
    reached the full limits before); 1.5 (above the data sheet) and a command timeout below the
    MPC period are refused with a reason, and change nothing."""
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    node, pub_j, pub_c, motor, client = _pid_under_test(ros, scenario)
    refused = _set(ros, client, "torque_limit_fraction", 1.5)
    assert not refused.successful and "torque_limit_fraction" in refused.reason
    refused = _set(ros, client, "stale_timeout", 0.001)
    assert not refused.successful and "MPC period" in refused.reason
    assert node.lowlevel.config.pid.stale_timeout == scenario.pid.stale_timeout
    reference = lowlevel_controller(scenario, robot)
    limit = robot.torque_limit
    q, v = robot.q_nominal, np.zeros(7)
    change = 4
    for k in range(8):
        if k == change:
            assert _set(ros, client, "torque_limit_fraction", 0.3).successful
            reference.set_limits(torque_limit_fraction=0.3)
        if k % 2 == 0:
            torque = 2.0 * limit * np.where(np.arange(7) % 2 == 0, 1.0, -1.0)  # beyond the limits
            pub_c.publish(mpc_command(k, torque))
            command = LowLevelCommand(torque, np.zeros(14), np.zeros((7, 14)))
            reference.set_command(command, k * 1e-3)
        pub_j.publish(joint_state(node, k, q, v, robot.gravity(q)))
        assert ros.spin_until(lambda k=k: len(motor) == k + 1), f"no motor torque for cycle {k}"
        expected = reference.step(LowLevelMeasurement(q, v, robot.gravity(q)), k * 1e-3)
        got = np.asarray(motor[k].effort)
        np.testing.assert_array_equal(got, expected.motor_torque)
        bound = (0.3 if k >= change else 1.0) * limit
        assert np.all(np.abs(got) <= bound + 1e-12)
        if k == change - 1:
            assert np.max(np.abs(got) / limit) > 0.3  # the old limit let more through
    assert node.live.changes == [(change, "torque_limit_fraction", 0.3)]
    assert node.live.refused["torque_limit_fraction"] == 1


def test_pid_gains_change_the_motor_torque_of_the_next_cycle_as_eq_33(ros, robot):
    """kp 0.1 → 0.6 and ki 20 → 45 1/s at cycle 5: cycles 0–4 equal the core PID with the old
    gains; cycle 5 equals τ_old − ΔK_P·e − ΔK_I·∫e (eq 33 with e and ∫e of that cycle), i.e.
    the core PID given the same gains at the same cycle."""
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    node, pub_j, pub_c, motor, client = _pid_under_test(ros, scenario)
    rng = np.random.default_rng(3)
    q = robot.q_nominal + 0.01 * rng.standard_normal((8, 7))
    v = 0.05 * rng.standard_normal((8, 7))
    tau = robot.gravity(robot.q_nominal) + rng.standard_normal((8, 7))
    torques = robot.gravity(robot.q_nominal) + rng.normal(0, 3, (8, 7))
    old, new = lowlevel_controller(scenario, robot), lowlevel_controller(scenario, robot)
    change = 5
    for k in range(8):
        if k == change:
            for name, value in (("kp", 0.6), ("ki", 45.0)):
                assert _set(ros, client, name, value).successful
            assert node.lowlevel.pid.gains.kp[0] == 0.1  # queued for the next cycle
            new.pid.set_gains(kp=0.6, ki=45.0)
        if k % 2 == 0:
            pub_c.publish(mpc_command(k, torques[k]))
            for ref in (old, new):
                command = LowLevelCommand(torques[k], np.zeros(14), np.zeros((7, 14)))
                ref.set_command(command, k * 1e-3)
        pub_j.publish(joint_state(node, k, q[k], v[k], tau[k]))
        assert ros.spin_until(lambda k=k: len(motor) == k + 1), f"no motor torque for cycle {k}"
        integral_before = new.pid.integral
        meas = LowLevelMeasurement(q[k], v[k], tau[k])
        out_old = old.step(meas, k * 1e-3).motor_torque
        out_new = new.step(meas, k * 1e-3).motor_torque
        got = np.asarray(motor[k].effort)
        if k < change:
            np.testing.assert_array_equal(got, out_old)
            continue
        np.testing.assert_array_equal(got, out_new)
        if k == change:
            integral = new.pid.integral
            error = (integral - integral_before) / 1e-3  # e = τ̂ − τ^d(t − δo) of this cycle
            eq33 = out_old - (0.6 - 0.1) * error - (45.0 - 20.0) * integral
            np.testing.assert_allclose(got, eq33, rtol=0, atol=1e-9)
            assert np.max(np.abs(got - out_old)) > 0.05  # the gains did change the torque
    assert node.live.changes == [(change, "kp", 0.6), (change, "ki", 45.0)]
    assert node.lowlevel.pid.gains.ki[0] == 45.0


def test_bad_references_are_rejected_and_counted_a_good_one_retargets(ros, robot):
    """mpc/reference and mpc/force_setpoint: NaN, a wrong frame_id, a target 0.15 m from the
    task's and a negative force are rejected (counted, one log line per kind); a good target
    sets position_offset = target − circle centre and a good force task.normal_force, both
    applied at the next solve."""
    node = ros.add(MpcNode(context=ros.context, parameter_overrides=overrides("mpc")))
    probe = ros.probe()
    commands = recorder(probe, MpcCommand, topics.MPC_COMMAND)
    pub_j = probe.create_publisher(JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos())
    pub_w = probe.create_publisher(WrenchStamped, topics.SENSED_WRENCH, topics.publisher_qos())
    pub_ref = probe.create_publisher(PoseStamped, "mpc/reference", topics.reference_qos())
    pub_force = probe.create_publisher(Float64, "mpc/force_setpoint", topics.reference_qos())
    # the reference inputs are volatile (a default `ros2 topic pub` matches): publish once matched
    assert ros.spin_until(
        lambda: pub_ref.get_subscription_count() > 0 and pub_force.get_subscription_count() > 0
    )
    centre = node.task.circle_center()

    def pose(p, frame="world"):
        msg = PoseStamped()
        msg.header.frame_id = frame
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = map(float, p)
        msg.pose.orientation.w = 1.0
        return msg

    ref, force = topics.MPC_REFERENCE, topics.MPC_FORCE_SETPOINT
    cases = [
        (pub_ref, pose([math.nan, centre[1], centre[2]]), f"{ref}:value"),
        (pub_ref, pose(centre + [0.01, 0, 0], frame="base_link"), f"{ref}:frame"),
        (pub_ref, pose(centre + [0.15, 0, 0]), f"{ref}:workspace"),
        (pub_force, Float64(data=math.nan), f"{force}:value"),
        (pub_force, Float64(data=-3.0), f"{force}:value"),
    ]
    for pub, msg, kind in cases:
        before = node.rejected[kind]
        pub.publish(msg)
        assert ros.spin_until(lambda kind=kind, b=before: node.rejected[kind] == b + 1), kind
    assert node.rejected == {
        f"{ref}:value": 1,
        f"{ref}:frame": 1,
        f"{ref}:workspace": 1,
        f"{force}:value": 2,
    }
    assert node.log_lines[f"{force}:value"] == 1  # one line per kind (throttled)
    assert list(node.get_parameter("position_offset").value) == [0.0, 0.0, 0.0]
    assert not node.live.pending

    pub_ref.publish(pose(centre + [0.02, -0.01, 0.0]))
    pub_force.publish(Float64(data=30.0))
    assert ros.spin_until(lambda: len(node.live.pending) == 2)
    np.testing.assert_allclose(
        node.get_parameter("position_offset").value, [0.02, -0.01, 0.0], atol=1e-12
    )
    assert node.get_parameter("task.normal_force").value == 30.0
    assert node.schedule.force_setpoint == 50.0  # not before the next solve
    _solve_tick(ros, node, pub_j, pub_w, robot, 0, commands)
    assert node.schedule.force_setpoint == 30.0
    np.testing.assert_allclose(node.schedule.position_offset, [0.02, -0.01, 0.0], atol=1e-12)
    assert node.accepted[ref] == node.accepted[force] == 1


def test_force_setpoint_mid_run_retargets_a_lockstep_graph(ros):
    """The five loop nodes in lockstep (one executor), polishing with the phases shortened
    (contact at 0.3 s, 50 N reached at 0.6 s): 30 N published on mpc/force_setpoint at 0.7 s
    makes the true normal force settle near 30 N (0.5 s blend) instead of 50 N."""
    from ffmpc_ros.graph_nodes import NODES, graph_parameters, load_node_class
    from ffmpc_ros.params import parameter_overrides

    scenario = load_scenario(
        "polishing",
        {
            "task.still": 0.05,
            "task.reach": 0.25,
            "task.force_ramp": 0.3,
            **PAPER_SCHEDULE,  # no touch phase, the circle stepped
        },
    )
    duration, change = 1.5, 0.7
    params = graph_parameters(scenario, lockstep=True, duration=duration)
    params["plant"].update(
        wait_for_metrics=False,
        start_subscribers=1,  # the joint sensor (no metrics node here)
        start_nodes=len(NODES),  # the start barrier: the five loop nodes
    )
    for values in params.values():  # every node knows the graph's /clock readers
        values["start_clock_subscribers"] = topics.CLOCK_READERS_PER_NODE * len(NODES)
    nodes = {
        name: ros.add(
            load_node_class(path)(
                context=ros.context, parameter_overrides=parameter_overrides(params[name])
            )
        )
        for name, path in NODES.items()
    }
    probe = ros.probe()
    forces = []  # (t, true normal force on the tool, N)
    probe.create_subscription(
        WrenchStamped,
        topics.PLANT_WRENCH,
        lambda m: forces.append((nodes["plant"].cycle_of(m.header.stamp), m.wrench.force.z)),
        topics.subscriber_qos(True),
    )
    pub = probe.create_publisher(Float64, "mpc/force_setpoint", topics.reference_qos())
    steps = int(round(duration / scenario.plant.time_step))
    sent = []

    def done() -> bool:
        if not sent and len(forces) >= change * 1000:  # publish once, at 0.7 s
            pub.publish(Float64(data=30.0))
            sent.append(len(forces))
        return len(forces) >= steps - 1

    assert ros.spin_until(done, timeout=600.0), f"{len(forces)} of {steps} cycles"
    mpc = nodes["mpc"]
    ((k, name, value),) = mpc.live.changes
    assert name == "task.normal_force" and value == 30.0 and change <= k * 1e-3 < change + 0.02
    f = np.array([x for _, x in sorted(forces)])
    before = f[int(0.6 * 1000) : int(change * 1000)].mean()  # 50 N reached, before the change
    after = f[int(1.3 * 1000) :].mean()  # 0.6 s after the change (blend 0.5 s)
    print(f"mean normal force: {before:.2f} N before (0.6-0.7 s), {after:.2f} N at 1.3-1.5 s")
    assert abs(before - 50.0) < 6.0, before
    assert abs(after - 30.0) < 4.0, after
    assert sum(mpc.rejected.values()) == 0, mpc.rejected
