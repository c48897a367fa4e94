"""ros2_control's terms: the plant driven through a forward_command_controller-style effort command
topic (bad sizes rejected with one log line), the LFC-law node (the agimus
linear_feedback_controller's law from Control messages), and the whole graph in which the MPC
publishes Control and the LFC-law node drives the plant through the effort topic, against the
normal graph's metrics."""

from __future__ import annotations

import numpy as np
import pytest
from linear_feedback_controller_msgs.msg import Control, Sensor
from ros_helpers import assert_same_run, joint_state, overrides, recorder
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import ConfigError
from ffmpc_core.linear_feedback import LinearFeedbackCommand, linear_feedback_torque
from ffmpc_core.lowlevel import LowLevelMode
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import layouts, lfc_msgs, topics
from ffmpc_ros.bringup import GraphOptions, run_graph
from ffmpc_ros.graph_nodes import node_table
from ffmpc_ros.lfc_node import LfcNode
from ffmpc_ros.plant_node import PlantNode
from studies.polishing import run_polishing

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
    assert sensors[0].header.stamp == node.grid.stamp_of(0)
    control = lfc_msgs.control_message(node.grid.stamp_of(0), "classical", names, sol)
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
    bad = lfc_msgs.control_message(node.grid.stamp_of(2), "classical", names[::-1], sol)
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


def test_ros2_control_graph_with_the_pid_equals_the_runner():
    """Control instead of MpcCommand, Sensor instead of the sensed joint states, the effort
    command topic instead of pid/motor_torque, same numbers: with the paper's scheme (no Riccati
    feedback) the PID uses the Control's feed-forward only, and CDR carries doubles exactly, so
    the run is bit-identical to the ROS-free runner — the normal graph's twin
    (tests/test_ros_graph.py). With the time-based switch to contact (``task.approach_speed``
    0): with the guarded approach this seed's tool has not met the table within the second."""
    scenario = load_scenario("polishing", {"seed": 2, "task.approach_speed": 0.0})
    graph = run_graph(
        scenario,
        GraphOptions(
            duration=1.0, single_process=True, timeout=300, interfaces=ROS2_CONTROL, low_level="pid"
        ),
    )
    assert_same_run(graph, run_polishing(scenario, duration=1.0))
    assert graph.log["force_true"].max() > 5.0  # the run reached the table


#: The LFC graph against the normal one (the tolerances docs/explanation/ros.md, "MPC on a
#: ros2_control robot",
#: states with both sets of metrics): same MPC, scenario and seed; the low level differs by
#: design (the LFC's τ_ff + K·(x₀ ⊖ x) at 1 kHz instead of τ* through the torque PID of eq 33,
#: which also rejects the actuation bias and gain of eq 31), so the metrics differ, both ways.
LFC_DURATION = 2.0  # s: reach, force ramp, then the start of the circle (the metrics' window)
#: |E_λ(lfc) − E_λ(normal)| ≤ 1 N (2 % of the 50 N set-point), |ΔE_P| ≤ 2.5 mm
LFC_TOLERANCE = {"force_mae": 1.0, "position_mae_mm": 2.5}
#: |λmax(lfc) − λmax(normal)| ≤ 10 % of the normal graph's
LFC_MAX_FORCE_TOLERANCE = 0.1


def test_mpc_publishes_control_and_the_lfc_law_drives_the_plant_like_the_normal_graph():
    """The MPC publishes linear_feedback_controller_msgs/Control, the LFC-law node (not ffmpc's
    PID) applies it through the effort command topic at the plant's rate: E_λ, E_P and λmax of
    the true force stay within LFC_TOLERANCE and LFC_MAX_FORCE_TOLERANCE of the normal graph's
    (the ROS-free runner, equal to the normal graph bit for bit), contact holds, no input is
    rejected and the law tracked every cycle (no hold, no fallback)."""
    scenario = load_scenario("polishing", {"seed": 0})
    graph = run_graph(
        scenario,
        GraphOptions(
            duration=LFC_DURATION,
            single_process=True,
            timeout=600,
            interfaces=ROS2_CONTROL,
            low_level="lfc",
        ),
    )
    normal = run_polishing(scenario, duration=LFC_DURATION)
    lfc, ref = graph.metrics_true.to_dict(), normal.metrics_true.to_dict()
    print({"lfc": lfc, "normal": ref})
    for name, tolerance in LFC_TOLERANCE.items():
        assert abs(lfc[name] - ref[name]) <= tolerance, (name, lfc[name], ref[name])
    peak = abs(lfc["max_force"] - ref["max_force"])
    assert peak <= LFC_MAX_FORCE_TOLERANCE * ref["max_force"], (lfc["max_force"], ref["max_force"])
    assert ref["max_force"] > 40.0  # the window holds contact at the set-point
    assert lfc["contact_break_percent"] == ref["contact_break_percent"] == 0.0
    assert not any(graph.safety["rejected_messages"].values())
    assert graph.safety["safe_hold_s"] == 0.0
    assert max(graph.safety["max_velocity_ratio"]) < 1.0
    modes = graph.timing["mode_cycles"]
    assert modes["track"] == round(LFC_DURATION / scenario.plant.time_step)
    # the law's effort differs from the runner's PID torque: not the same controller
    assert not np.array_equal(graph.log["tau_motor"], normal.log["tau_motor"])


def test_the_ros2_control_launch_files_start_the_mpc_and_the_pid_against_remapped_topics():
    from ffmpc_ros.launch import find_launch_file, load_launch_file

    path = find_launch_file("ros2_control_mpc.launch.yaml")
    (mpc,) = load_launch_file(path, {"robot": "panda", "wrench": "/ati/wrench"}).nodes
    assert mpc.executable == "mpc" and mpc.parameters[0][0] == "file"
    for entry in (("robot", "panda"), ("interfaces", ROS2_CONTROL), ("lockstep", False)):
        assert entry in mpc.parameters
    assert (topics.LFC_CONTROL, "/" + topics.LFC_CONTROL) in mpc.remaps
    assert (topics.LFC_SENSOR, "/" + topics.LFC_SENSOR) in mpc.remaps
    assert (topics.SENSED_WRENCH, "/ati/wrench") in mpc.remaps
    path = find_launch_file("ros2_control_mpc_pid.launch.yaml")
    arguments = {
        "robot": "iiwa",
        "namespace": "/lbr",
        "joint_states": "/lbr/joint_states",
        "effort_commands": "/lbr/effort_controller/commands",
    }
    mpc, pid = load_launch_file(path, arguments).nodes
    assert (mpc.executable, pid.executable) == ("mpc", "pid")
    assert mpc.namespace == pid.namespace == "/lbr"
    assert ("interfaces", ROS2_CONTROL) in pid.parameters and ("lockstep", False) in pid.parameters
    assert (topics.SENSED_JOINT_STATES, "/lbr/joint_states") in pid.remaps
    assert (topics.EFFORT_COMMANDS, "/lbr/effort_controller/commands") in pid.remaps


@pytest.mark.xfail(
    reason=(
        "known, open: at the polishing defaults (the searched classical weights, the observer, "
        "the 65 % velocity box) the real-time classical MPC of this launch rejects most solves "
        "(velocity rows 1.1-1.7 % of the limit past their bound, tolerance 1 %; 6374 rejected "
        "in one 90 s run), so the robot side stays in its safe hold and never reaches TRACK; "
        "it passed at the earlier defaults"
    ),
    strict=False,
)
def test_the_mpc_launch_file_drives_a_simulated_ros2_control_robot(ros, tmp_path):
    """``ffmpc launch ros2_control_mpc.launch.yaml`` (the MPC alone, real time, ros2_control's
    terms) against a simulated robot that speaks those terms: the plant in real time (it
    publishes /clock), the sensor models and the LFC-law node in the agimus controller's place.
    The robot's side receives the MPC's Controls on the launch file's default topics and tracks
    them (TRACK mode), with nothing rejected but a few Controls that arrived too late. Wiring and
    real-time behaviour only: the timing of a Python plant in one executor is not a real robot's."""
    import os
    import signal
    import subprocess
    import sys

    from ffmpc_ros.ft_sensor_node import FtSensorNode
    from ffmpc_ros.joint_sensor_node import JointSensorNode

    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    graph = {"lockstep": False, "duration": 60.0}
    robot_side = [
        ros.add(
            cls(
                context=ros.context,
                parameter_overrides=overrides(name, scenario, **graph, **extra),
            )
        )
        for name, cls, extra in (
            ("plant", PlantNode, {"interfaces": ROS2_CONTROL}),
            ("joint_sensor", JointSensorNode, {}),
            ("ft_sensor", FtSensorNode, {}),
            ("lfc", LfcNode, {}),
        )
    ]
    lfc = robot_side[-1]
    command = [sys.executable, "-m", "ffmpc_ros.cli", "launch", "ros2_control_mpc.launch.yaml"]
    command += ["formulation:=classical", "--timeout", "120", "--log-dir", str(tmp_path)]
    launch = subprocess.Popen(
        command,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"),
    )
    control_topic = f"/{topics.LFC_CONTROL}"
    try:
        tracked = ros.spin_until(
            lambda: (
                lfc.accepted[control_topic] >= 50
                and lfc.report.last_output is not None
                and lfc.report.last_output.mode == LowLevelMode.TRACK
            ),
            timeout=90.0,
        )
    finally:
        launch.send_signal(signal.SIGINT)
        out, _ = launch.communicate(timeout=30)
    print(dict(lfc.accepted), dict(lfc.rejected), robot_side[0].deadline_misses, robot_side[0].k)
    assert tracked, (dict(lfc.accepted), dict(lfc.rejected), out[-3000:])
    # A Control older than max_input_age when it arrives is refused, as it must be in real time;
    # on a loaded 2-core CI machine one such late Control was seen (1 against >= 50 accepted).
    # Anything else refused (order, future stamp, value, layout) is a wiring fault.
    late = {key: n for key, n in lfc.rejected.items() if key.endswith(":stale")}
    assert not {key: n for key, n in lfc.rejected.items() if key not in late}, dict(lfc.rejected)
    assert sum(late.values()) <= 0.05 * lfc.accepted[control_topic], (late, dict(lfc.accepted))
    assert "[launch] started mpc" in out
