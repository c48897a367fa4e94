"""``ffmpc run --record``: a whole lockstep run recorded with no message dropped (counted per
topic: published vs recorded), single- and multi-process; the bag describes its run (every
node's parameters, the scenario) and the metrics computed from it are the run's."""

from __future__ import annotations

import json
from collections import Counter

import pytest
import yaml
from rclpy.publisher import Publisher
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import Reader as Rosbag2Reader
from sensor_msgs.msg import JointState

from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.bag.analysis import bag_study
from ffmpc_ros.bag.machine import MACHINE_RECORD, machine_fingerprint, same_machine
from ffmpc_ros.bag.reader import BagReader
from ffmpc_ros.bag.rerun import RerunTolerance, compare_outputs, message_time, rerun_node
from ffmpc_ros.bag.ros_types import message_class
from ffmpc_ros.bringup import NODES, GraphOptions, run_graph

SCENARIO = {"seed": 3, "mpc.formulation": "classical"}
DURATION = 0.2


@pytest.fixture(scope="module")
def single_process_run(tmp_path_factory):
    """A single-process recorded run, with every publish of the process counted by topic."""
    published: Counter[str] = Counter()
    original = Publisher.publish

    def counting(self, msg):
        published[self.topic_name] += 1
        return original(self, msg)

    path = tmp_path_factory.mktemp("graph") / "single.mcap"
    Publisher.publish = counting
    try:
        result = run_graph(
            load_scenario("polishing", SCENARIO),
            GraphOptions(duration=DURATION, single_process=True, timeout=120, record=path),
        )
    finally:
        Publisher.publish = original
    return result, path, published


def _cycles(bag: BagReader, topic: str) -> list[int]:
    cls = message_class(bag.topics[topic].type)
    out = []
    for m in bag.messages([topic]):
        t = message_time(deserialize_message(m.data, cls))
        out.append(int(round(t * 1e3)))
    return out


def test_single_process_run_records_every_published_message(single_process_run):
    result, path, published = single_process_run
    steps = int(round(DURATION / 1e-3))
    with BagReader(path) as bag:
        assert bag.recovery.complete
        for topic, type_name, _ in topics.resolved_topics():
            assert bag.topics[topic].type == type_name
            assert bag.topics[topic].count == published[topic] > 0, topic
            assert result.bag["received"][topic] == published[topic]
        # In lockstep every per-cycle topic carries each cycle 0..steps exactly once.
        for topic in (
            topics.CLOCK,
            topics.resolve(topics.PLANT_JOINT_STATES),
            topics.resolve(topics.SENSED_WRENCH),
        ):
            assert _cycles(bag, topic) == list(range(steps + 1)), topic
        assert _cycles(bag, topics.resolve(topics.MPC_COMMAND)) == list(range(0, steps + 1, 2))
        assert _cycles(bag, topics.resolve(topics.MOTOR_TORQUE)) == list(range(steps + 1))
        assert bag.start_time == 0 and bag.end_time == steps * 1_000_000  # simulated time


def test_the_bag_describes_its_run(single_process_run):
    result, path, _ = single_process_run
    with BagReader(path) as bag:
        params = bag.parameters
        assert {f"/{n}" for n in [*NODES, "metrics"]} <= set(params)
        assert params["/mpc"]["formulation"] == "classical"
        assert (
            params["/plant"]["seed"] == 3 and params["/plant"]["start_subscribers"] == 4
        )  # + probe, recorder
        assert params["/pid"]["plant.time_step"] == 0.001
        run = bag.metadata_named("ffmpc_run")
        scenario = yaml.safe_load(run["scenario"])
        assert scenario["mpc"]["ros__parameters"]["formulation"] == "classical"
        assert yaml.safe_load(run["params_file"])["plant"]["ros__parameters"]["duration"] == 0.2
    study = bag_study(path)
    assert study.metrics_true == result.metrics_true
    assert study.metrics_measured == result.metrics_measured
    assert study.matches_recorded is True


def test_multi_process_run_records_as_many_messages(single_process_run, tmp_path):
    """The run is deterministic, so the multi-process bag holds exactly what the single-process
    graph published. Recorded as a rosbag2 folder (a path without ``.mcap``), which rosbags'
    rosbag2 reader opens."""
    _, _, published = single_process_run
    path = tmp_path / "multi"
    result = run_graph(
        load_scenario("polishing", SCENARIO),
        GraphOptions(duration=DURATION, single_process=False, timeout=120, record=path),
    )
    with BagReader(path) as bag:
        for topic, _, _ in topics.resolved_topics():
            assert bag.topics[topic].count == published[topic], topic
        assert {f"/{n}" for n in [*NODES, "metrics"]} <= set(bag.parameters)
    study = bag_study(path)
    assert study.metrics_true == result.metrics_true and study.matches_recorded is True
    with Rosbag2Reader(path) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
    assert all(counts[topic] == published[topic] for topic, _, _ in topics.resolved_topics())


def test_ffmpc_run_record_and_refusal_to_overwrite(tmp_path, capfd):
    from ffmpc_ros.cli import main

    path = tmp_path / "cli.mcap"
    args = ["run", "polishing", "--duration", "0.05", "--single-process", "--record", str(path)]
    assert main(args) == 0
    out = capfd.readouterr().out
    summary = json.loads(out[out.index("{") :])
    assert summary["bag"]["received"][topics.resolve(topics.PLANT_JOINT_STATES)] == 51
    size = path.stat().st_size
    assert main(args) == 2
    assert "never overwritten" in capfd.readouterr().err
    assert path.stat().st_size == size
    assert main(["bag", "info", str(path)]) == 0
    info = capfd.readouterr().out
    assert "Topic: /mpc/command" in info and "complete" in info
    # Recorded here: the bag carries this machine's fingerprint, so a re-run must be bit-exact.
    with BagReader(path) as bag:
        assert bag.metadata_named(MACHINE_RECORD) == machine_fingerprint()
    report = rerun_node(path, "mpc")
    assert report.same_machine and report.identical and report.ok, report.describe()


def _joint_state(position: list[float]) -> JointState:
    msg = JointState()
    msg.name = ["a", "b"]
    msg.position = position
    return msg


def test_rerun_comparison_tolerates_round_off_but_not_a_change(monkeypatch):
    recorded = [_joint_state([1.0, 1000.0]), _joint_state([2.0, 3000.0])]
    round_off = [_joint_state([1.0, 1000.0 + 1e-9]), _joint_state([2.0, 3000.0])]
    changed = [_joint_state([1.0, 1000.0]), _joint_state([2.0, 3000.01])]
    c = compare_outputs("/js", recorded, round_off)
    assert (c.identical, c.within_tolerance, c.exact, c.reproduced) == (1, 2, False, True)
    assert c.first_difference.startswith("message 0")
    c = compare_outputs("/js", recorded, changed)
    assert (c.identical, c.within_tolerance, c.reproduced) == (1, 1, False)
    assert c.first_difference.startswith("message 1")
    assert compare_outputs("/js", recorded, changed, RerunTolerance(relative=1e-5)).reproduced
    assert not compare_outputs("/js", recorded, recorded[:1]).reproduced  # a message missing
    # The fingerprint follows the BLAS kernel choice.
    here = machine_fingerprint()
    assert same_machine(here) and not same_machine(None)
    monkeypatch.setenv("OPENBLAS_CORETYPE", "SomeOtherCore")
    assert not same_machine(here)
