"""Relative names: the graph's topics and services resolve under a namespace, so the whole node
graph runs under ``--namespace /arm1``, and two graphs run side by side on one ROS domain.

Only ``/clock``, ``/diagnostics``, ``/tf`` and ``/tf_static`` are absolute
(``ffmpc_ros.topics.ABSOLUTE_NAMES``); a namespaced graph remaps ``/clock``, ``/tf`` and
``/tf_static`` to its own (``-r /clock:=clock -r /tf:=tf -r /tf_static:=tf_static``)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest
from rclpy.validate_full_topic_name import validate_full_topic_name

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.graph_nodes import params_file_key
from studies.polishing import run_polishing

#: Module constants of topics.py that hold strings but are no topic or service names.
NOT_NAMES = {"WRENCH_FRAME", "COMMAND_FRAME", "ROOT_NAMESPACE", "CLOCK_REMAP_TARGET"}


def _graph_names() -> dict[str, str]:
    """{constant: name} of every topic and service name topics.py defines."""
    return {
        key: value
        for key, value in vars(topics).items()
        if key.isupper() and isinstance(value, str) and key not in NOT_NAMES
    }


def test_every_name_is_relative_except_the_documented_absolute_ones():
    names = _graph_names()
    assert topics.ABSOLUTE_NAMES == {"/clock", "/diagnostics", "/tf", "/tf_static"}
    listed = {t for t, _, _ in (*topics.TOPICS, *topics.IMPACT_TOPICS, *topics.VIEW_TOPICS)}
    assert listed <= set(names.values())  # the tables use the constants
    assert {"TARE_SERVICE", "IMPACT_RESET_SERVICE", "CONTACT_LEARNER_RESET_SERVICE"} <= set(names)
    absolute = {k: v for k, v in names.items() if v.startswith("/")}
    assert set(absolute.values()) == topics.ABSOLUTE_NAMES, absolute
    for key, name in names.items():
        full = topics.resolve(name, "/arm1")
        validate_full_topic_name(full)  # a valid ROS name once expanded
        if name in topics.ABSOLUTE_NAMES - set(topics.GRAPH_REMAPS):
            assert full == name, key
        else:
            assert full.startswith("/arm1/"), (key, full)
        assert topics.resolve(name) == (name if name.startswith("/") else "/" + name)


def test_namespace_helpers():
    assert topics.normalize_namespace(None) == topics.normalize_namespace("") == "/"
    assert topics.normalize_namespace("arm1") == topics.normalize_namespace("/arm1/") == "/arm1"
    assert topics.normalize_namespace("/cell_2/arm1") == "/cell_2/arm1"
    for bad in ("1arm", "/a//b", "arm 1", "/arm-1"):
        with pytest.raises(ConfigError, match="not a ROS namespace"):
            topics.normalize_namespace(bad)
    assert topics.graph_ros_args("/") == []  # the root graph runs exactly as before
    assert topics.graph_ros_args("arm1") == [
        *("-r", "__ns:=/arm1", "-r", "/clock:=clock"),
        *("-r", "/tf:=tf", "-r", "/tf_static:=tf_static"),
    ]
    assert topics.resolve(topics.CLOCK, "/arm1") == "/arm1/clock"
    assert topics.resolve(topics.TF, "/arm1") == "/arm1/tf"
    assert topics.resolve(topics.TF_STATIC, "/arm1") == "/arm1/tf_static"
    assert topics.resolve(topics.TF) == "/tf"
    assert topics.resolve(topics.DIAGNOSTICS, "/arm1") == "/diagnostics"
    assert topics.resolve(topics.MPC_COMMAND, "/arm1") == "/arm1/mpc/command"
    assert topics.namespace_of(["/clock", "/a/b/plant/joint_states", "/rosout"]) == "/a/b"
    assert topics.namespace_of(["/plant/joint_states"]) == "/"
    assert params_file_key("mpc", "/") == "mpc" and params_file_key("mpc", "/arm1") == "/arm1/mpc"


def test_every_node_lives_in_its_namespace():
    """Each node executable's class, started with the graph's ROS arguments for /arm1: every
    publisher, subscription and service is inside /arm1, except the absolute ones — /diagnostics,
    ROS's own /rosout and /parameter_events — and /clock, which the remap moves to /arm1/clock."""
    from ros_helpers import RosHarness, overrides

    from ffmpc_ros.graph_nodes import NODES, load_node_class

    classes = {
        **NODES,
        "metrics": "ffmpc_ros.metrics_node:MetricsNode",
        "lfc": "ffmpc_ros.lfc_node:LfcNode",
        "impact_planner": "ffmpc_ros.impact_planner_node:ImpactPlannerNode",
        "contact_learner": "ffmpc_ros.contact_learner_node:ContactLearnerNode",
    }
    cli_args = ["--ros-args", *topics.graph_ros_args("/arm1")]
    allowed = {"/diagnostics", "/rosout", "/parameter_events"}
    extra = {"impact_planner": {"acceleration_limit": [10.0] * 7}}  # iiwa: no data sheet
    ros = RosHarness()
    try:
        for name, path in classes.items():
            node = ros.add(
                load_node_class(path)(
                    context=ros.context,
                    parameter_overrides=overrides(name, **extra.get(name, {})),
                    cli_args=cli_args,
                )
            )
            assert node.get_fully_qualified_name() == f"/arm1/{name}"
            used = {
                *(p.topic_name for p in node.publishers),
                *(s.topic_name for s in node.subscriptions),
                *(node.resolve_service_name(s.srv_name) for s in node.services),
            }
            outside = sorted(n for n in used if not n.startswith("/arm1/") and n not in allowed)
            assert not outside, (name, outside)
            assert "/clock" not in used and "/arm1/clock" in used, name
            # rejection keys are the expanded names (the bag's)
            assert node.name_of(topics.SENSED_WRENCH) == "/arm1/ft_sensor/wrench"
    finally:
        ros.close()


def _scenario(seed: int):
    return load_scenario("polishing", {"seed": seed, "mpc.formulation": "classical"})


def test_ffmpc_run_namespace_equals_the_runner_and_records_namespaced_names(tmp_path, capfd):
    """``ffmpc run polishing --namespace /arm1 --record``, multi-process lockstep: the metrics
    are the ROS-free runner's, the bag holds the resolved names (/arm1/...), and the bag tools
    work on it: the metrics computed from the bag, and the MPC re-run bit for bit."""
    from ffmpc_ros.bag.analysis import bag_study
    from ffmpc_ros.bag.reader import BagReader
    from ffmpc_ros.bag.recorder import DOMAIN_TOPICS
    from ffmpc_ros.bag.rerun import bag_namespace, rerun_node
    from ffmpc_ros.cli import main

    bag, out = tmp_path / "arm1.mcap", tmp_path / "arm1.json"
    argv = ["run", "polishing", "--namespace", "/arm1", "--duration", "0.2", "--seed", "1"]
    argv += ["--formulation", "classical", "--record", str(bag), "--json", str(out)]
    assert main(argv) == 0, capfd.readouterr().err
    summary = json.loads(out.read_text())
    runner = run_polishing(_scenario(1), duration=0.2)
    assert summary["namespace"] == "/arm1"
    assert summary["metrics_true"] == runner.metrics_true.to_dict()
    assert summary["metrics_measured"] == runner.metrics_measured.to_dict()
    assert not any(summary["rejected_messages"].values()), summary["rejected_messages"]
    with BagReader(bag) as reader:
        names = set(reader.topics)
        assert bag_namespace(reader) == "/arm1"
        assert {t for t, _, _ in topics.resolved_topics("/arm1")} <= names
        assert all(t.startswith("/arm1/") or t in DOMAIN_TOPICS for t in names), names
        assert reader.topics["/arm1/clock"].count == 201
        assert {f"/arm1/{n}" for n in ("plant", "mpc", "pid", "metrics")} <= set(reader.parameters)
    study = bag_study(bag)
    assert study.metrics_true == runner.metrics_true and study.matches_recorded is True
    report = rerun_node(bag, "mpc")
    assert report.identical and report.ok, report.describe()
    # the classical MPC reads λ̂ too: the guarded approach's contact detection
    assert report.inputs == {
        "/arm1/joint_sensor/joint_states": 201,
        "/arm1/ft_sensor/wrench": 201,
    }
    # bag play: the recorded names; with a clock rate, the player drives the bag's clock
    from ros_helpers import RosHarness

    from ffmpc_ros.bag.player import BagPlayer

    ros = RosHarness()
    try:
        with BagReader(bag) as reader:
            player = BagPlayer(ros.probe("player"), reader, clock_rate=100.0)
            assert player.clock_topic == "/arm1/clock" and "/arm1/clock" not in player.publishers
            assert player.clock_publisher.topic_name == "/arm1/clock"
            assert "/arm1/plant/joint_states" in player.publishers
    finally:
        ros.close()


@pytest.mark.xfail(
    reason=(
        "known, open: in 1 of 2 full-suite runs from a fresh clone the in-process /arm1 graph "
        "reached its last cycle (200, t = 0.2 s) and was not seen to finish: the bring-up's "
        "stall watch stopped it after 30 s ('no simulated progress'); the file passed 5 of 5 "
        "runs alone"
    ),
    strict=False,
)
def test_two_graphs_side_by_side_on_one_domain():
    """Two multi-process lockstep graphs, /arm1 (here) and /arm2 (an ``ffmpc run`` process),
    started together on the SAME ROS domain: both finish and each equals the runner.

    Why each graph has its own clock (``-r /clock:=clock``: /arm1/clock, /arm2/clock). Without
    the remap both plants publish the one /clock: the second graph is refused before it starts
    (the first graph's plant is a foreign publisher on its /clock), and with
    ``allow_foreign=True`` the nodes of both graphs took their time from both plants: measured
    here (0.3 s runs), /arm2 finished while /arm1 stalled at cycle 16 (t = 0.016 s) until its
    stall timeout. ``ROS_DOMAIN_ID`` per graph would avoid it too, but not let two cells share
    a domain."""
    from ffmpc_ros.bringup import GraphOptions, run_graph

    # One domain for both graphs, not the one the rest of this pytest process uses: nodes of
    # earlier tests still shutting down there are no part of this test.
    domain = 1 + (int(os.environ["ROS_DOMAIN_ID"]) + 50) % 100
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    cmd = [sys.executable, "-m", "ffmpc_ros.cli", "run", "polishing", "--namespace", "/arm2"]
    cmd += ["--duration", "0.2", "--seed", "2", "--formulation", "classical"]
    results: dict = {}

    def arm1() -> None:
        results["arm1"] = run_graph(
            _scenario(1),
            GraphOptions(duration=0.2, namespace="/arm1", timeout=150, domain_id=domain),
        )

    thread = threading.Thread(target=arm1)
    other = subprocess.Popen(
        cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    thread.start()
    try:
        out, err = other.communicate(timeout=180)
    finally:
        if other.poll() is None:
            other.kill()
        thread.join(timeout=180)
    assert other.returncode == 0, err[-2000:]
    arm2 = json.loads(out)
    assert arm2["namespace"] == "/arm2"
    runner2 = run_polishing(_scenario(2), duration=0.2)
    detail = {k: arm2.get(k) for k in ("rejected_messages", "plant_status", "warnings")}
    assert arm2["metrics_true"] == runner2.metrics_true.to_dict(), (detail, err[-3000:])
    assert arm2["metrics_measured"] == runner2.metrics_measured.to_dict()
    from ros_helpers import assert_same_run

    assert "arm1" in results, "the /arm1 graph did not finish"
    assert results["arm1"].namespace == "/arm1"
    assert_same_run(results["arm1"], run_polishing(_scenario(1), duration=0.2))
