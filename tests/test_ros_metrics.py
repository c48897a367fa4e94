"""The metrics node alone: it aligns the topics cycle by cycle exactly as the runner logs them
(τ̂ of cycle k comes with the state of cycle k + 1) and computes the metrics with the runner's
code; in real time it fills the cycles the controller skipped with the held values."""

from __future__ import annotations

import json

import numpy as np
from geometry_msgs.msg import WrenchStamped
from ros_helpers import joint_state, overrides, recorder, wrench
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from ffmpc_core.polishing import PolishingLog, build_task, polishing_run_metrics
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import layouts, topics
from ffmpc_ros.metrics_node import MetricsNode

N = 30


def _signals(seed=0):
    rng = np.random.default_rng(seed)
    robot = load_robot("iiwa")
    return {
        "q": robot.q_nominal + 0.01 * rng.standard_normal((N + 1, 7)),
        "tau_hat": rng.normal(0, 10, (N + 1, 7)),
        "force_true": np.abs(rng.normal(10, 3, N + 1)),
        "force_measured": rng.normal(10, 3, N + 1),
        "tau_desired": rng.normal(0, 10, (N, 7)),
        "tau_motor": rng.normal(0, 10, (N, 7)),
    }


def _feed(ros, node, s, skip=()):
    probe = ros.probe()
    qos = topics.publisher_qos()
    pubs = {
        "joints": probe.create_publisher(JointState, topics.PLANT_JOINT_STATES, qos),
        "truth": probe.create_publisher(Float64MultiArray, topics.PLANT_TRUTH, qos),
        "wrench": probe.create_publisher(WrenchStamped, topics.SENSED_WRENCH, qos),
        "desired": probe.create_publisher(JointState, topics.DESIRED_TORQUE, qos),
        "motor": probe.create_publisher(JointState, topics.MOTOR_TORQUE, qos),
    }
    summary = recorder(probe, String, topics.METRICS_SUMMARY)
    normal = np.array([0.0, np.sin(0.1), np.cos(0.1)])
    for k in range(N + 1):
        pubs["joints"].publish(joint_state(node, k, s["q"][k], np.zeros(7), s["tau_hat"][k]))
        truth = {
            "t": k * 1e-3,
            "normal_force": s["force_true"][k],
            "in_contact": 1.0,
            "robot_collision": 0.0,
            "table_normal": normal,
            "contact_position": np.zeros(3),
        }
        pubs["truth"].publish(layouts.PLANT_TRUTH.pack(truth))
        if k == N:
            break
        pubs["wrench"].publish(wrench(node, k, (0.0, 0.0, s["force_measured"][k])))
        if k not in skip:
            empty = np.zeros(0)
            pubs["desired"].publish(joint_state(node, k, empty, empty, s["tau_desired"][k]))
            pubs["motor"].publish(joint_state(node, k, empty, empty, s["tau_motor"][k]))
        ros.spin_for(0.002)
    return summary, normal


def test_metrics_node_logs_like_the_runner(ros):
    scenario = load_scenario("polishing")
    params = overrides("metrics", scenario, duration=N * 1e-3)
    node = ros.add(MetricsNode(context=ros.context, parameter_overrides=params))
    s = _signals()
    summary, normal = _feed(ros, node, s)
    assert ros.spin_until(node.finished)
    robot = load_robot("iiwa")
    task = build_task(scenario, robot)
    log = PolishingLog(N, robot, task)
    for k in range(N):
        log.record(
            k,
            k * 1e-3,
            s["q"][k],
            s["force_true"][k],
            s["force_measured"][k],
            s["tau_desired"][k],
            s["tau_hat"][k + 1],  # τ̂ of cycle k arrives with the state of cycle k + 1
            s["tau_motor"][k],
        )
    for name, values in log.arrays.items():
        np.testing.assert_array_equal(node.log.arrays[name], values, err_msg=name)
    assert node.metrics == polishing_run_metrics(log.arrays, task, normal)
    assert ros.spin_until(lambda: len(summary) == 1)
    doc = json.loads(summary[0].data)
    assert doc["cycles"] == N and doc["filled"] == 0
    assert doc["metrics_true"] == node.metrics[0].to_dict()


def test_metrics_node_real_time_fills_skipped_cycles(ros):
    scenario = load_scenario("polishing")
    params = overrides("metrics", scenario, duration=N * 1e-3, lockstep=False)
    node = ros.add(MetricsNode(context=ros.context, parameter_overrides=params))
    s = _signals(1)
    _feed(ros, node, s, skip={0, 1, 7})
    assert ros.spin_until(node.finished, timeout=5)
    assert node.filled == 6  # τ^d and τ^m of three cycles
    start = node.robot.gravity(node.robot.q_nominal)
    np.testing.assert_array_equal(node.log.arrays["tau_motor"][0], start)  # the start torque
    np.testing.assert_array_equal(node.log.arrays["tau_motor"][1], start)
    np.testing.assert_array_equal(node.log.arrays["tau_desired"][7], s["tau_desired"][6])
    np.testing.assert_array_equal(node.log.arrays["tau_motor"][8], s["tau_motor"][8])
