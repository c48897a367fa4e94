"""``ffmpc run --fault``: every fault kind through the real node graph (short lockstep runs).

Each run is ``ffmpc run polishing --duration 0.3`` as a subprocess on this test process's ROS
domain. A fault is handled safely when the run exits 0 and no joint went over its velocity or
torque limit (ratios from the plant's own ``/plant/joint_states``). Also: a message stamped
from the future is rejected by every node that reads it and never adopted, a kind a mode cannot
inject is refused with one line (exit 2), and a shared parameter that differs between two nodes
stops the run before it starts, naming both nodes and both values.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from ffmpc_core.faults import parse_fault

DURATION = "0.3"


def ffmpc_run(tmp_path, *args: str, timeout: float = 240.0) -> tuple[int, str, dict | None]:
    """Run ``ffmpc run polishing`` with ``args``: (exit code, stderr, JSON summary or None)."""
    out = tmp_path / "run.json"
    cmd = [sys.executable, "-m", "ffmpc_ros.cli", "run", "polishing", "--json", str(out), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=os.environ)
    summary = json.loads(out.read_text()) if out.exists() else None
    return proc.returncode, proc.stderr, summary


def _assert_safe(summary: dict) -> None:
    assert len(summary["max_velocity_ratio"]) == 7 and len(summary["max_torque_ratio"]) == 7
    assert 0.0 < max(summary["max_velocity_ratio"]) <= 1.0
    assert 0.0 < max(summary["max_torque_ratio"]) <= 1.0


def _rejected(summary: dict, node: str, suffix: str) -> int:
    counts = summary["rejected_messages"][node] or {}
    return sum(n for kind, n in counts.items() if kind.endswith(suffix))


@pytest.mark.parametrize(
    "faults",
    [
        pytest.param(("mpc-dropout@0.1+0.05", "sensor-dropout@0.2+0.05"), id="dropouts"),
        pytest.param(("node-kill@0.15",), id="node-kill"),
    ],
)
def test_process_faults_are_held_safely(tmp_path, faults):
    args = [a for f in faults for a in ("--fault", f)]
    code, err, summary = ffmpc_run(tmp_path, "--duration", DURATION, *args)
    assert code == 0, err[-3000:]
    _assert_safe(summary)
    report = {f["fault"]: f for f in summary["faults"]}
    assert set(report) == {str(parse_fault(f)) for f in faults}
    for fault in report.values():
        assert fault["injected_at_s"] >= fault["start_s"] - 1e-9
        assert fault["action"].startswith(("SIGSTOP", "SIGKILL"))
    if faults == ("node-kill@0.15",):
        assert report["node-kill:mpc@0.15"]["node"] == "mpc"
        assert summary["rejected_messages"]["mpc"] is None  # killed: no exit report
        # the PID went on without the MPC, in the safe hold
        assert summary["safe_hold_s"] >= 0.1
    else:
        assert summary["safe_hold_s"] > 0.0
    assert f"faults {', '.join(report)}: handled safely" in err


def test_message_faults_are_rejected_never_adopted(tmp_path):
    code, err, summary = ffmpc_run(
        tmp_path,
        "--duration",
        DURATION,
        "--fault",
        "future-stamp@0.05+0.05",
        "--fault",
        "nan-wrench@0.15+0.05",
        "--fault",
        "torque-spike@0.22+0.03",
        timeout=120.0,
    )
    assert code == 0, err[-3000:]
    _assert_safe(summary)
    injected = {f["kind"]: f["messages_injected"] for f in summary["faults"]}
    assert all(n > 0 for n in injected.values()), injected
    # Every node reading the sensor topics rejected the messages from the future (a node
    # that did not exit within 5 s of SIGINT, e.g. mid-solve on a loaded machine, reports
    # nothing: None) ...
    reported = [n for n in ("mpc", "pid") if summary["rejected_messages"][n] is not None]
    assert reported, summary["rejected_messages"]
    for node in reported:
        assert _rejected(summary, node, "/joint_sensor/joint_states:future") > 0, summary[
            "rejected_messages"
        ]
    # ... and never adopted one: an adopted stamp 1 s ahead would make every genuine message
    # after it "not newer" (:order) and stop the graph; the run went to the end instead.
    assert summary["metrics_true"] is not None and summary["sim_time_s"] == pytest.approx(0.3)
    # NaN wrenches were rejected too (as a value, or, when the bring-up lagged behind the
    # plant, by their stamp: late, duplicate or stale).
    nan_rejected = sum(
        n
        for node in reported
        for kind, n in (summary["rejected_messages"][node] or {}).items()
        if kind.startswith("/ft_sensor/wrench:")
    )
    assert nan_rejected > 0, summary["rejected_messages"]


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--real-time", "--fault", "nan-wrench@0.1"], "not supported in real time"),
        (["--real-time", "--fault", "loop-stall@0.1"], "loop-stall needs a duration"),
        (["--fault", "mpc-stall@0.1+0.05"], "mpc-stall is not supported in lockstep"),
        (["--single-process", "--fault", "node-kill@0.1"], "not supported in --single-process"),
        (["--fault", "node-kill@0.1+0.2"], "node-kill takes no duration"),
        (["--fault", "teleport@0.1"], "fault kind must be one of"),
    ],
)
def test_unsupported_faults_are_refused_with_one_line(tmp_path, args, message):
    code, err, summary = ffmpc_run(tmp_path, *args, timeout=60.0)
    assert code == 2 and summary is None
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], err


def test_shared_parameter_for_one_node_stops_the_run_before_it_starts(tmp_path):
    """The PID given another formulation than the MPC (a per-node ``-p``): refused before any
    node is spawned (each node gets its slice of the one scenario; nothing is read back)."""
    code, err, summary = ffmpc_run(
        tmp_path,
        "--duration",
        DURATION,
        "--formulation",
        "force_feedback",
        "--node-param",
        "pid:mpc.formulation:=classical",
        timeout=120.0,
    )
    assert code == 2 and summary is None
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "pid:mpc.formulation: the scenario value mpc.formulation" in lines[0]
    assert "mpc, metrics also take" in lines[0] and "--set mpc.formulation=VALUE" in lines[0]


def test_only_a_shared_scenario_value_is_refused_for_one_node():
    """check_unshared: a node's own value (the PID's gain) and graph parameters pass; the
    control period the PID and the MPC both take does not."""
    from ffmpc_core.errors import ConfigError
    from ffmpc_ros.bringup import check_unshared

    graph = ["plant", "joint_sensor", "ft_sensor", "mpc", "pid", "state_publisher", "metrics"]
    check_unshared({"pid": ["-p", "kp:=0.2", "-p", "lockstep_timeout:=9.0"]}, graph)
    check_unshared({"mpc": ["-p", "horizon:=7"]}, graph)
    with pytest.raises(ConfigError, match=r"pid:mpc.period: the scenario value mpc.period"):
        check_unshared({"pid": ["-p", "kp:=0.2", "-p", "mpc.period:=0.004"]}, graph)
    with pytest.raises(ConfigError, match="plant.time_step, which plant, joint_sensor"):
        check_unshared({"mpc": ["-p", "plant.time_step:=0.002"]}, graph)
