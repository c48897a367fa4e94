"""The joint-sensor and F/T-sensor nodes alone: input → output equal to the ROS-free models with
the same device generator, and bad input rejected with one throttled log line."""

from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import WrenchStamped
from ros_helpers import joint_state, overrides, publish_clock, recorder, wrench
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from ffmpc_core.polishing import device_generator, force_sensing_model, joint_sensing_model
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.ft_sensor_node import FtSensorNode
from ffmpc_ros.joint_sensor_node import JointSensorNode


def test_joint_sensor_reproduces_eq_30_with_its_generator(ros):
    scenario = load_scenario("polishing", {"seed": 7, "joint_sensor.delay_cycles": 2})
    node = ros.add(
        JointSensorNode(
            context=ros.context, parameter_overrides=overrides("joint_sensor", scenario)
        )
    )
    probe = ros.probe()
    out = recorder(probe, JointState, topics.SENSED_JOINT_STATES)
    pub = probe.create_publisher(JointState, topics.PLANT_JOINT_STATES, topics.publisher_qos())
    rng = np.random.default_rng(0)
    q, v, tau = rng.normal(size=(6, 7)), rng.normal(size=(6, 7)), rng.normal(size=(6, 7))
    names = list(node.joint_names)
    for k in range(6):
        order = names[::-1] if k == 3 else names  # any order of the names is accepted
        idx = [names.index(n) for n in order]
        pub.publish(joint_state(node, k, q[k][idx], v[k][idx], tau[k][idx], order))
    assert ros.spin_until(lambda: len(out) == 6)
    model = joint_sensing_model(scenario, 7, device_generator(7, "joint_sensor"))
    for k, msg in enumerate(out):
        q_hat, v_hat = model.step(q[k], v[k])
        assert node.cycle_of(msg.header.stamp) == k and list(msg.name) == names
        np.testing.assert_array_equal(msg.position, q_hat)
        np.testing.assert_array_equal(msg.velocity, v_hat)
        np.testing.assert_array_equal(msg.effort, tau[k])  # τ̂ passes through undelayed
    # δs = 2 cycles really delays: the output at k = 2 is q(0) + noise of 1e-3 rad.
    assert np.max(np.abs(np.array(out[2].position) - q[0])) < 5e-3
    assert node.rejected.total() == 0


def test_joint_sensor_rejects_bad_input_with_one_log_line_per_kind(ros):
    node = ros.add(
        JointSensorNode(context=ros.context, parameter_overrides=overrides("joint_sensor"))
    )
    probe = ros.probe()
    out = recorder(probe, JointState, topics.SENSED_JOINT_STATES)
    pub = probe.create_publisher(JointState, topics.PLANT_JOINT_STATES, topics.publisher_qos())
    clock = probe.create_publisher(Clock, topics.CLOCK, topics.clock_qos())
    ok = np.zeros(7)
    names = list(node.joint_names)
    pub.publish(joint_state(node, 5, ok, ok, ok))
    assert ros.spin_until(lambda: len(out) == 1)
    bad = [
        ("value", joint_state(node, 6, [np.nan] + [0.0] * 6, ok, ok)),
        ("value", joint_state(node, 6, ok, [np.inf] + [0.0] * 6, ok)),
        ("value", joint_state(node, 6, ok[:6], ok[:6], ok[:6], names[:6])),  # wrong length
        ("value", joint_state(node, 6, ok, ok, ok, names[:6] + ["elbow"])),  # unknown name
        ("value", joint_state(node, 6, ok, ok, ok[:5])),  # effort too short
        ("order", joint_state(node, 5, ok, ok, ok)),  # duplicate stamp
        ("order", joint_state(node, 3, ok, ok, ok)),  # out of order
    ]
    no_time = joint_state(node, 6, ok, ok, ok)
    no_time.header.stamp.nanosec = 1_000_000_000  # not a ROS time (nanosec < 10⁹)
    bad.append(("stamp", no_time))
    for _, msg in bad:
        pub.publish(msg)
    assert ros.spin_until(lambda: node.rejected.total() == len(bad))
    topic = topics.resolve(topics.PLANT_JOINT_STATES)
    assert node.rejected[f"{topic}:value"] == 5 and node.rejected[f"{topic}:order"] == 2
    assert node.rejected[f"{topic}:stamp"] == 1
    assert node.log_lines[f"{topic}:value"] == 1  # throttled: one line for five rejections
    # Off the grid: 6.4 ms belongs to cycle 6 (the newest at or before it); the sensor model
    # passes its stamp through.
    off_grid = joint_state(node, 6, ok, ok, ok)
    off_grid.header.stamp.nanosec += 400_000
    pub.publish(off_grid)
    assert ros.spin_until(lambda: len(out) == 2)
    assert (out[-1].header.stamp.sec, out[-1].header.stamp.nanosec) == (0, 6_400_000)
    assert node.cycle_of(out[-1].header.stamp) == 6
    assert node.rejected.total() == len(bad)
    # Stale: the clock says 1 s, the sample is from 0.9 s (max_input_age 0.05 s).
    publish_clock(clock, node, 1000)
    assert ros.spin_until(lambda: node.get_clock().now().nanoseconds == 1_000_000_000)
    pub.publish(joint_state(node, 900, ok, ok, ok))
    assert ros.spin_until(lambda: node.rejected[f"{topic}:stale"] == 1)
    pub.publish(joint_state(node, 1000, ok, ok, ok))  # a good sample still goes through
    assert ros.spin_until(lambda: len(out) == 3)
    assert node.cycle_of(out[-1].header.stamp) == 1000


def _ft(ros, scenario):
    node = ros.add(
        FtSensorNode(context=ros.context, parameter_overrides=overrides("ft_sensor", scenario))
    )
    probe = ros.probe()
    pub = probe.create_publisher(WrenchStamped, topics.PLANT_WRENCH, topics.publisher_qos())
    out = recorder(probe, WrenchStamped, topics.SENSED_WRENCH)
    filtered = recorder(probe, WrenchStamped, topics.FILTERED_WRENCH)
    contact = recorder(probe, Bool, topics.IN_CONTACT)
    return node, probe, pub, out, filtered, contact


def test_ft_sensor_reproduces_eq_32_filters_and_detects_contact(ros):
    scenario = load_scenario("polishing", {"seed": 3, "ft_sensor.filter_cutoff_frequency": 30.0})
    node, _, pub, out, filtered, contact = _ft(ros, scenario)
    # Normal force ramps 0 → 20 N → 0 over 80 cycles, then 0; lateral forces and moments are not
    # measured by the 1-D sensor (mpc.contact.dimension 1 along z).
    normal = np.concatenate([np.linspace(0, 20, 40), np.linspace(20, 0, 40), np.zeros(20)])
    for k, fz in enumerate(normal):
        ros.set_clock(node, k)
        pub.publish(wrench(node, k, (3.0, -2.0, fz), (0.1, 0.2, 0.3)))
    assert ros.spin_until(lambda: len(contact) == len(normal))
    model = force_sensing_model(scenario, device_generator(3, "force_sensor"))
    alpha = 1 - np.exp(-2 * np.pi * 30.0 * 1e-3)
    y, state, fs = None, False, scenario.ft_sensor
    for k, fz in enumerate(normal):
        f_hat = model.step(np.array([fz]))[0]
        y = f_hat if y is None else y + alpha * (f_hat - y)
        if state and y < fs.contact_off_force:
            state = False
        elif not state and y > fs.contact_on_force:
            state = True
        w = out[k].wrench
        assert (w.force.x, w.force.y, w.force.z) == (0.0, 0.0, f_hat)
        assert (w.torque.x, w.torque.y, w.torque.z) == (0.0, 0.0, 0.0)
        assert out[k].header.frame_id == topics.WRENCH_FRAME
        assert filtered[k].wrench.force.z == pytest.approx(y, abs=1e-12)
        assert contact[k].data == state
    flags = [c.data for c in contact]
    on, off = flags.index(True), len(flags) - flags[::-1].index(True)
    assert 5 < on < 40 < off < 90  # contact starts on the way up, ends on the way down
    assert flags[-1] is False and all(flags[on:off])


def test_ft_sensor_tare_and_rejections(ros):
    scenario = load_scenario("polishing", {"ft_sensor.tare_samples": 20})
    node, probe, pub, out, _, _ = _ft(ros, scenario)
    client = probe.create_client(Trigger, topics.TARE_SERVICE)
    assert client.wait_for_service(timeout_sec=5.0)

    def tare():
        future = client.call_async(Trigger.Request())
        assert ros.spin_until(future.done)
        return future.result()

    assert not tare().success  # no measurement yet
    for k in range(30):
        ros.set_clock(node, k)
        pub.publish(wrench(node, k, (0.0, 0.0, 1.5)))  # a 1.5 N bias, not in contact
    assert ros.spin_until(lambda: len(out) == 30)
    recent = [m.wrench.force.z for m in out[-20:]]
    result = tare()
    assert result.success and "20 samples" in result.message
    np.testing.assert_allclose(node.offset, [np.mean(recent)], rtol=1e-12)
    ros.set_clock(node, 30)
    pub.publish(wrench(node, 30, (0.0, 0.0, 1.5)))
    assert ros.spin_until(lambda: len(out) == 31)
    assert abs(out[-1].wrench.force.z) < 2.5  # 1.5 N bias removed; noise σ = 0.5 N
    for k in range(31, 60):
        ros.set_clock(node, k)
        pub.publish(wrench(node, k, (0.0, 0.0, 40.0)))
    assert ros.spin_until(lambda: node.in_contact)
    assert not tare().success  # refused in contact
    n = len(out)
    ros.set_clock(node, 61)
    pub.publish(wrench(node, 60, (0.0, 0.0, 40.0), frame="world"))
    pub.publish(wrench(node, 61, (np.nan, 0.0, 40.0)))
    pub.publish(wrench(node, 59, (0.0, 0.0, 40.0)))
    assert ros.spin_until(lambda: node.rejected.total() == 3)
    assert node.rejected[f"{topics.resolve(topics.PLANT_WRENCH)}:value"] == 2
    assert node.rejected[f"{topics.resolve(topics.PLANT_WRENCH)}:order"] == 1
    ros.spin_for(0.05)
    assert len(out) == n
