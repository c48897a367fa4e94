"""The plant node alone: lockstep stepping with the actuation model of eq 31 (bit-identical to
the ROS-free plant + actuation), bad motor torques rejected or saturated, real-time mode with
deadline misses counted and published."""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import WrenchStamped
from ros_helpers import joint_state, overrides, recorder
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.polishing import actuation_model, build_task, device_generator, draw_run
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
        tau_hat = robot.gravity(robot.q_nominal)
        for k in range(7):
            s = plant.state()
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
                plant.step(tau_hat)
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
    """No controller: every step of a 50-cycle real-time run misses its deadline; the plant keeps
    applying the last torque (the gravity hold) and publishes the count."""
    node, probe, _ = _plant(ros, load_scenario("polishing"), lockstep=False, duration=0.05)
    status = recorder(probe, Float64MultiArray, topics.PLANT_STATUS)
    assert ros.spin_until(lambda: node.done, timeout=10)
    assert ros.spin_until(lambda: any(layouts.PLANT_STATUS.unpack(s)["done"] for s in status))
    final = layouts.PLANT_STATUS.unpack(status[-1])
    assert final["steps"] == 50 and final["lockstep"] == 0.0
    assert final["deadline_misses"] == 50 and node.deadline_misses == 50
    assert final["wall_time"] >= 0.045  # paced by the wall clock (1 ms per step)
