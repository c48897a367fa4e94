"""The plant node alone: lockstep stepping with the actuation model of eq 31 (bit-identical to
the ROS-free plant + actuation), bad motor torques rejected or saturated, real-time mode with
deadline misses counted and published."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from ros_helpers import joint_state, overrides, recorder
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.polishing import actuation_model, build_task, device_generator, draw_run
from ffmpc_core.reflex import reflex_plant
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import layouts, topics
from ffmpc_ros.plant_node import PlantNode
from sim_bridge.plant import Plant
from sim_bridge.scenes import polishing_plant_config as plant_config


def _plant(ros, scenario, **graph):
    node = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides("plant", scenario, **graph))
    )
    probe = ros.probe()
    pub = probe.create_publisher(JointState, topics.MOTOR_TORQUE, topics.publisher_qos())
    return node, probe, pub


def test_plant_node_steps_in_lockstep_like_the_plant_and_actuation(ros):
    scenario = load_scenario("polishing", {"seed": 5})
    node, probe, pub = _plant(ros, scenario)
    states = recorder(probe, JointState, topics.PLANT_JOINT_STATES)
    wrenches = recorder(probe, WrenchStamped, topics.PLANT_WRENCH)
    truth = recorder(probe, Float64MultiArray, topics.PLANT_TRUTH)
    clock: list = []
    probe.create_subscription(Clock, topics.CLOCK, clock.append, topics.clock_qos())
    assert ros.spin_until(lambda: len(states) == 1)
    robot = node.robot
    rng = np.random.default_rng(0)
    commands = robot.gravity(robot.q_nominal) + rng.normal(0.0, 5.0, (6, 7))
    commands[3, 0] = 1e4  # beyond the limit: saturated, not rejected
    for k in range(6):
        pub.publish(joint_state(node, k, [], [], commands[k]))
        assert ros.spin_until(lambda k=k: len(states) == len(wrenches) == len(truth) == k + 2)
    # The same cycle without ROS.
    draws = draw_run(scenario, robot, device_generator(5, "draws"))
    task = build_task(scenario, robot)
    actuation = actuation_model(scenario, robot, draws, device_generator(5, "actuation"))
    with Plant(robot, plant_config(scenario, task, draws.tilt_angle)) as plant:
        plant.reset(robot.q_nominal)
        stepped = reflex_plant(plant, robot)  # the robot's reflexes, as the node's plant
        tau_hat = robot.gravity(robot.q_nominal)
        for k in range(7):
            s = stepped.state()
            msg = states[k]
            assert node.cycle_of(msg.header.stamp) == k
            np.testing.assert_array_equal(msg.position, s.q)
            np.testing.assert_array_equal(msg.velocity, s.v)
            np.testing.assert_array_equal(msg.effort, tau_hat)
            w = wrenches[k].wrench
            np.testing.assert_array_equal(
                [w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z],
                s.wrench_world,
            )
            assert wrenches[k].header.frame_id == topics.WRENCH_FRAME
            got = layouts.PLANT_TRUTH.unpack(truth[k])
            assert got["normal_force"] == s.normal_force and got["t"] == k * 1e-3
            np.testing.assert_array_equal(got["table_normal"], plant.table_normal)
            if k < 6:
                tau_hat = actuation.step(robot.clip_torque(commands[k]), s.v)
                stepped.step(tau_hat)
    ticks = [node.cycle_of(c.clock) for c in clock]  # /clock is volatile: late joiners miss some
    assert ticks[-1] == 6 and ticks == sorted(set(ticks)) and len(ticks) >= 5
    assert node.latencies and len(node.latencies) == 6


def test_plant_node_rejects_bad_motor_torques(ros):
    node, probe, pub = _plant(ros, load_scenario("polishing"))
    states = recorder(probe, JointState, topics.PLANT_JOINT_STATES)
    assert ros.spin_until(lambda: len(states) == 1)
    g = node.robot.gravity(node.robot.q_nominal)
    names = list(node.joint_names)
    for msg in (
        joint_state(node, 1, [], [], g),  # a future cycle
        joint_state(node, 0, [], [], [np.nan] + list(g[1:])),
        joint_state(node, 0, [], [], g[:6], names[:6]),
        joint_state(node, 0, [], [], g, names[:6] + ["gripper"]),
    ):
        pub.publish(msg)
    assert ros.spin_until(lambda: node.rejected.total() == 4)
    topic = topics.resolve(topics.MOTOR_TORQUE)
    assert node.rejected[f"{topic}:cycle"] == 1 and node.rejected[f"{topic}:value"] == 3
    assert node.log_lines[f"{topic}:value"] == 1
    ros.spin_for(0.05)
    assert node.k == 0 and len(states) == 1  # nothing stepped
    pub.publish(joint_state(node, 0, [], [], g))
    assert ros.spin_until(lambda: len(states) == 2)


def test_plant_node_real_time_counts_deadline_misses(ros):
    """No controller: every step of a 50-cycle real-time run misses its deadline; the drives hold
    the last torque (the gravity hold) for the data sheet's 20 ms, then the communication reflex
    stops the robot (``ffmpc_core.reflex``); the count and the reflex's event are published."""
    node, probe, _ = _plant(ros, load_scenario("polishing"), lockstep=False, duration=0.05)
    status = recorder(probe, Float64MultiArray, topics.PLANT_STATUS)
    assert ros.spin_until(lambda: node.done, timeout=10)
    assert ros.spin_until(lambda: any(layouts.PLANT_STATUS.unpack(s)["done"] for s in status))
    final = layouts.PLANT_STATUS.unpack(status[-1])
    assert final["steps"] == 50 and final["lockstep"] == 0.0
    assert final["deadline_misses"] == 50 and node.deadline_misses == 50
    assert final["wall_time"] >= 0.045  # paced by the wall clock (1 ms per step)
    event = layouts.reflex_event_from_status(final, node.joint_names)
    assert final["reflex_stopped"] == 1.0 and event is not None
    # the first published state is cycle 0's, its step the first without a command: the 21st
    # step without one (t = 0.020 s) is the first under the stop
    assert event.kind == "communication" and event.t == pytest.approx(0.020)
    assert event.value == pytest.approx(0.021) and event.limit == 0.02
    assert node.reflex_plant.reflex.stop_cycles == 50 - 20


def test_plant_node_steps_through_the_reflex_like_the_runner_s_plant(ros):
    """Lockstep: motor torques that drive joint A4 over its velocity limit. The plant node's
    states are the ROS-free reflex plant's bit for bit (one reflex model); the robot stops from
    the cycle after the crossing, later torques are ignored, /plant/status carries the event."""
    scenario = load_scenario("polishing", {"seed": 2})
    node, probe, pub = _plant(ros, scenario)
    states = recorder(probe, JointState, topics.PLANT_JOINT_STATES)
    status = recorder(probe, Float64MultiArray, topics.PLANT_STATUS)
    assert ros.spin_until(lambda: len(states) == 1)
    robot = node.robot
    push = np.array([0, 0, 0, 60.0, 0, 0, 0])
    cycles = 60
    for k in range(cycles):
        s = states[k]
        pub.publish(joint_state(node, k, [], [], robot.gravity(np.array(s.position)) + push))
        assert ros.spin_until(lambda k=k: len(states) == k + 2)
    assert ros.spin_until(
        lambda: any(layouts.PLANT_STATUS.unpack(m)["reflex_stopped"] for m in status)
    )
    event = layouts.reflex_event_from_status(
        layouts.PLANT_STATUS.unpack(status[-1]), node.joint_names
    )
    assert event is not None and event.kind == "velocity" and event.joint == 3 and event.stopped
    draws = draw_run(scenario, robot, device_generator(2, "draws"))
    task = build_task(scenario, robot)
    actuation = actuation_model(scenario, robot, draws, device_generator(2, "actuation"))
    with Plant(robot, plant_config(scenario, task, draws.tilt_angle)) as plant:
        plant.reset(robot.q_nominal)
        stepped = reflex_plant(plant, robot)
        for k in range(cycles):
            s = stepped.state()
            np.testing.assert_array_equal(states[k].position, s.q)
            np.testing.assert_array_equal(states[k].velocity, s.v)
            tau_hat = actuation.step(robot.clip_torque(robot.gravity(s.q) + push), s.v)
            stepped.step(tau_hat)
        assert stepped.reflex.event == event
    k_stop = int(round(event.t / 1e-3))
    v4 = [abs(m.velocity[3]) for m in states]
    assert v4[k_stop] > robot.velocity_limit[3] and v4[k_stop + 1] < v4[k_stop]
    assert v4[-1] < 0.5 * v4[k_stop]  # braking while the torques keep pushing
