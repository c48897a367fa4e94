"""The bring-up's steps, each alone: plan_graph (checks and parameters, nothing started), then a
GraphSession's spawn, bring_up, watch, run, stop and collect on a short single-process run, and
stop after a failed start."""

from __future__ import annotations

import os

import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.bringup import GraphOptions, GraphSession, plan_graph
from ffmpc_ros.fault_injector import FAULT_LOCKSTEP_TIMEOUT


@pytest.fixture(scope="module")
def scenario():
    return load_scenario("polishing", {"mpc.formulation": "classical"})


def test_plan_checks_options_before_anything_starts(scenario, tmp_path) -> None:
    refused = [
        GraphOptions(interfaces=topics.ROS2_CONTROL_INTERFACES, lockstep=False),
        GraphOptions(node_ros_args={"pid": ["-p", "kp:=0.2"]}, single_process=True),
        GraphOptions(node_ros_args={"nobody": ["-p", "x:=1"]}),
        GraphOptions(lockstep=False, record=str(tmp_path / "rt.mcap")),
        GraphOptions(lockstep=False, single_process=True),
    ]
    for options in refused:
        with pytest.raises(ConfigError):
            plan_graph(scenario, options)
    existing = tmp_path / "there.mcap"
    existing.write_bytes(b"")
    from ffmpc_ros.bag.errors import BagExistsError

    with pytest.raises(BagExistsError):
        plan_graph(scenario, GraphOptions(record=str(existing)))


def test_plan_gives_each_node_its_parameters_and_the_extra_readers_to_wait_for(
    scenario, tmp_path
) -> None:
    plain = plan_graph(scenario, GraphOptions(duration=0.2, domain_id=7, namespace="arm1"))
    assert plain.domain == 7 and plain.namespace == "/arm1" and plain.duration == 0.2
    assert set(plain.table) <= set(plain.params) and "metrics" in plain.params
    recorded = plan_graph(
        scenario,
        GraphOptions(
            duration=0.2,
            record=str(tmp_path / "run.mcap"),
            faults=["mpc-dropout@0.05+0.02"],
            fault_windows=[(0.1, 0.12)],
        ),
    )
    plant, plant_recorded = plain.params["plant"], recorded.params["plant"]
    # the recorder is one more joint-state reader the plant waits for, and two /clock readers
    assert plant_recorded["start_subscribers"] == plant["start_subscribers"] + 1
    for node, values in recorded.params.items():
        before = plain.params[node]["start_clock_subscribers"]
        assert values["start_clock_subscribers"] == before + 2
    assert recorded.windows[0] == (0.1, 0.12)
    assert recorded.windows[1][0] == pytest.approx(0.05)  # the fault's own window
    # a process fault: the PID waits for a command a short while only
    assert recorded.params["pid"]["lockstep_timeout"] == FAULT_LOCKSTEP_TIMEOUT
    assert "lockstep_timeout" not in plain.params["pid"]
    assert not os.path.exists(tmp_path / "run.mcap")  # nothing started


def test_session_steps_run_a_short_single_process_graph(scenario) -> None:
    import time

    options = GraphOptions(duration=0.03, single_process=True, timeout=300.0)
    plan = plan_graph(scenario, options)
    session = GraphSession(plan, time.perf_counter())
    try:
        session.spawn()
        assert [n.get_name() for n in session.graph_nodes] == list(plan.table)
        assert session.children == {}  # single process: no child
        session.bring_up()  # the in-process nodes started themselves
        assert all(n.lifecycle_state == "active" for n in session.graph_nodes)
        session.watch()
        assert session.metrics.steps == 30 and session.injector is None
        session.run()
        assert session.metrics.finished()
    finally:
        outputs = session.stop()
    assert not session.context.ok()  # everything released
    assert set(outputs.rejected) == set(plan.table) and outputs.bag is None
    result = session.collect(outputs)
    assert result.single_process and result.lockstep and result.sim_time == pytest.approx(0.03)
    assert result.safety["rejected_messages"]["metrics"] == {}
    assert result.metrics_true.position_mae_mm > 0.0


def test_stop_after_a_failed_start_releases_everything(scenario) -> None:
    import time

    plan = plan_graph(scenario, GraphOptions(duration=0.03))
    session = GraphSession(plan, time.perf_counter())
    directory = session.tmp.name
    outputs = session.stop()  # nothing spawned (the foreign check refused, say)
    assert outputs.rejected == {} and outputs.view is None
    assert not session.context.ok() and not os.path.exists(directory)


def test_node_session_release_reads_what_the_children_left() -> None:
    """The shared steps' end (NodeSession.release, bag_report): the rejections each node process
    wrote into the run's directory, the recorder's counts; the context released."""
    import json
    import time

    from ffmpc_ros.bringup import NodeSession, results_path
    from ffmpc_ros.node_results import write_node_results

    domain = int(os.environ["ROS_DOMAIN_ID"])
    session = NodeSession(topics.ROOT_NAMESPACE, domain, time.perf_counter(), "ffmpc_test_")
    directory = session.tmp.name
    write_node_results(results_path(directory, "pid"), "pid", {"/mpc/command:stale": 2})
    session.logs = {"pid": "pid.log", "mpc": "mpc.log"}  # the mpc process wrote nothing (killed)
    session.counts_path = os.path.join(directory, "recorder_counts.json")
    with open(session.counts_path, "w", encoding="utf-8") as fh:
        json.dump({"received": {"/clock": 3}}, fh)
    assert session.release(quiet=True) == {"pid": {"/mpc/command:stale": 2}}
    assert not session.context.ok()
    assert session.bag_report(None) is None
    assert session.bag_report("run.mcap") == {"path": "run.mcap", "received": {"/clock": 3}}
    session.tmp.cleanup()


def test_node_session_turn_stops_on_a_dead_child_or_a_stall() -> None:
    """One turn of a run's loop (NodeSession.turn): a child that died stops the run with its
    name, exit status and last lines (not one a fault killed); no new cycle for stall_timeout
    wall s stops it with what each stage last did."""
    import subprocess
    import time

    from ffmpc_ros.bringup import GraphError, NodeSession, ProgressWatch

    domain = int(os.environ["ROS_DOMAIN_ID"])
    session = NodeSession(topics.ROOT_NAMESPACE, domain, time.perf_counter(), "ffmpc_test_")
    try:
        log = os.path.join(session.tmp.name, "pid.log")
        with open(log, "w", encoding="utf-8") as out:
            child = subprocess.Popen(["sh", "-c", "echo broken; exit 4"], stdout=out)
        child.wait()
        session.children, session.logs = {"pid": child}, {"pid": log}
        now = time.perf_counter()
        watch = ProgressWatch(now, stall_timeout=0.5, start_timeout=10.0)
        session.turn(watch, 0, now, lambda: "", killed=["pid"])  # killed by a fault: no error
        with pytest.raises(
            GraphError, match=r"(?s)node pid \(pid \d+\) died .*exit status 4.*broken"
        ):
            session.turn(watch, 1, now, lambda: "")
        session.children = {}
        with pytest.raises(GraphError, match="no simulated progress for 1.0 s.*: plant at 0"):
            session.turn(watch, 0, now + 1.0, lambda: "plant at 0")
    finally:
        session.release(quiet=True)
        session.tmp.cleanup()
