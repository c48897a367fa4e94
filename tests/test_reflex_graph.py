"""The robot's reflexes on the node graph and in ``ffmpc run``: a lockstep graph run pushed over a
velocity limit is aborted exactly as the ROS-free runner's run (one reflex model), the summary
says which limit, which joint and when, and ``ffmpc run`` exits 3 (``EXIT_ABORTED``); with a
fault injected, a reflex stop is a safe outcome (exit 0, said on stderr).
"""

from __future__ import annotations

import json

import pytest
from ros_helpers import assert_same_run

from ffmpc_core.scenario import load_scenario
from ffmpc_ros.cli import EXIT_ABORTED, _run_verdict, main
from studies.polishing import run_polishing

#: A 100 N push on the tool for 50 ms at 0.05 s: joint A5 over its velocity limit (the runner:
#: at 0.052 s with the force-feedback MPC).
PUSH = {
    "plant.push_enabled": True,
    "plant.push_time": 0.05,
    "plant.push_force": (0.0, 100.0, 0.0),
    "plant.push_duration": 0.05,
}


def test_a_graph_run_over_a_limit_is_aborted_as_the_runner_s_and_ffmpc_run_exits_3(tmp_path, capfd):
    path = tmp_path / "run.json"
    args = ["run", "polishing", "--single-process", "--duration", "0.2", "--json", str(path)]
    args += ["--set", "plant.push_enabled=true", "--set", "plant.push_time=0.05"]
    args += ["--set", "plant.push_force=[0.0, 100.0, 0.0]", "--set", "plant.push_duration=0.05"]
    code = main(args)
    err = capfd.readouterr().err
    assert code == EXIT_ABORTED, err
    assert "ABORTED: the robot stopped itself: velocity reflex at t = 0.052 s" in err
    doc = json.loads(path.read_text())
    assert doc["aborted"] and doc["reflex"]["aborted"] and doc["reflex"]["enabled"]
    runner = run_polishing(load_scenario("polishing", PUSH), duration=0.2)
    event = runner.reflex["event"]
    graph_event = doc["reflex"]["event"]
    assert graph_event == {**event, "value": pytest.approx(event["value"], rel=1e-12)}
    assert graph_event["joint"] == 4 and graph_event["kind"] == "velocity"


def test_the_graph_s_aborted_run_is_the_runner_s_run_bit_for_bit():
    from ffmpc_ros.bringup import GraphOptions, run_graph

    scenario = load_scenario("polishing", PUSH)
    graph = run_graph(scenario, GraphOptions(duration=0.15, single_process=True))
    runner = run_polishing(scenario, duration=0.15)
    assert graph.aborted and runner.aborted
    assert_same_run(graph, runner)


def _summary(faults: bool) -> dict:
    return {
        "faults": [{"fault": "loop-stall@0.5+0.03"}] if faults else [],
        "max_velocity_ratio": [0.5] * 7,
        "max_torque_ratio": [0.4] * 7,
        "safe_hold_s": 0.0,
    }


EVENT = {"kind": "communication", "message": "communication reflex at t = 0.521 s: ..."}


def test_the_exit_status_of_a_reflex_stop(capsys):
    """Without a fault: a reflex stop is an aborted run (3), before any timing or limit failure;
    with a fault: a safe outcome (0), said so; a crossing with the reflexes off is not a stop
    (the limits judge the run, 1)."""
    assert _run_verdict(_summary(False), EVENT, True, ["missed"], []) == EXIT_ABORTED == 3
    assert "ABORTED: the robot stopped itself: communication reflex" in capsys.readouterr().err
    assert _run_verdict(_summary(True), EVENT, True, ["missed"], ["joint 1 ..."]) == 0
    err = capsys.readouterr().err
    assert "handled safely: the robot's own communication reflex stopped it" in err
    assert _run_verdict(_summary(False), EVENT, False, [], ["joint 5 velocity ..."]) == 1
    assert "reflex off: communication reflex" in capsys.readouterr().err
    assert _run_verdict(_summary(False), None, False, [], []) == 0
