"""/diagnostics: every node reports once per DIAGNOSTICS_PERIOD (wall) its input rates and
rejections (OK, WARN after a rejection), and the MPC and PID their own state (ERROR for a failed
solve or the safe hold)."""

from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from ros_helpers import joint_state, overrides
from sensor_msgs.msg import JointState

from ffmpc_core.lowlevel import LowLevelMode, LowLevelOutput
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.joint_sensor_node import JointSensorNode
from ffmpc_ros.mpc_node import MpcNode
from ffmpc_ros.node_diagnostics import DIAGNOSTICS_PERIOD, DIAGNOSTICS_TOPIC
from ffmpc_ros.pid_node import PidNode


def _values(status: DiagnosticStatus) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def test_a_node_reports_its_inputs_and_rejections_once_a_period(ros):
    node = ros.add(
        JointSensorNode(context=ros.context, parameter_overrides=overrides("joint_sensor"))
    )
    probe = ros.probe()
    reports: list[DiagnosticArray] = []
    probe.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, reports.append, 10)
    pub = probe.create_publisher(JointState, topics.PLANT_JOINT_STATES, topics.publisher_qos())
    robot = load_robot("iiwa")
    ros.set_clock(node, 0)
    for k in range(5):
        pub.publish(joint_state(node, k, robot.q_nominal, np.zeros(7), np.zeros(7)))
    assert ros.spin_until(lambda: node.accepted[topics.resolve(topics.PLANT_JOINT_STATES)] == 5)
    assert ros.spin_until(lambda: len(reports) >= 1, timeout=3 * DIAGNOSTICS_PERIOD)
    (status,) = reports[-1].status
    values = _values(status)
    assert status.name == "/joint_sensor" and status.hardware_id == "ffmpc"
    assert status.level == DiagnosticStatus.OK and status.message == "ok"
    assert float(values[f"input_rate_hz {topics.resolve(topics.PLANT_JOINT_STATES)}"]) > 0.0
    assert values["rejected_total"] == "0"
    bad = joint_state(node, 5, robot.q_nominal, np.zeros(7), np.zeros(7))
    bad.name = ["nope"] * 7  # unknown joints: rejected
    pub.publish(bad)
    seen = len(reports)
    assert ros.spin_until(lambda: len(reports) > seen, timeout=3 * DIAGNOSTICS_PERIOD)
    (status,) = reports[-1].status
    assert status.level == DiagnosticStatus.WARN and "1 inputs rejected" in status.message
    assert _values(status)["rejected_in_period"] == "1"
    seen = len(reports)
    assert ros.spin_until(lambda: len(reports) > seen, timeout=3 * DIAGNOSTICS_PERIOD)
    assert reports[-1].status[0].level == DiagnosticStatus.OK  # a new period, no rejection


def test_mpc_and_pid_report_their_own_state(ros):
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    mpc = ros.add(MpcNode(context=ros.context, parameter_overrides=overrides("mpc", scenario)))
    mpc.solve_times.extend([0.4e-3, 0.6e-3, 0.5e-3])
    status = mpc.diagnostics.status()
    values = _values(status)
    assert status.level == DiagnosticStatus.OK and values["solves"] == "3"
    assert values["solve_time_p50_ms"] == "0.500" and values["solve_time_max_ms"] == "0.600"
    mpc.reject("solve", "cycle 4: the test's failed solve")
    status = mpc.diagnostics.status()
    assert status.level == DiagnosticStatus.ERROR and status.message == "1 solves failed"
    assert "solve_time_p50_ms" not in _values(status)  # no solve in this period
    assert mpc.diagnostics.status().level == DiagnosticStatus.OK
    pid = ros.add(PidNode(context=ros.context, parameter_overrides=overrides("pid", scenario)))
    assert _values(pid.diagnostics.status())["mode"] == "none (no cycle yet)"
    zeros = np.zeros(7)
    pid.report.last_output = LowLevelOutput(zeros, zeros, LowLevelMode.FALLBACK, 0.006, 0.0)
    status = pid.diagnostics.status()
    assert status.level == DiagnosticStatus.ERROR and "safe hold" in status.message
    assert _values(status)["mode"] == "fallback"
    pid.report.last_output = LowLevelOutput(zeros, zeros, LowLevelMode.TRACK, 0.001, 1.0)
    assert pid.diagnostics.status().level == DiagnosticStatus.OK
