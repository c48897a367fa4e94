"""The results a node process hands back (ffmpc_ros.node_results): written whole, read back
equal, a missing file is "no results", anything else without the schema is refused."""

from __future__ import annotations

import json
from collections import Counter

import pytest

from ffmpc_ros.bringup import rejected_from_results, results_path
from ffmpc_ros.node_results import (
    SCHEMA,
    NodeResultsError,
    read_node_results,
    write_node_results,
)


def test_results_read_back_equal(tmp_path):
    path = tmp_path / "mpc.results.json"
    counts = Counter({"/joint_sensor/joint_states:future": 3, "/ft_sensor/wrench:stale": 1})
    write_node_results(path, "mpc", counts)
    assert read_node_results(path) == ("mpc", dict(counts))
    assert json.loads(path.read_text())["schema"] == SCHEMA
    assert not (tmp_path / "mpc.results.json.tmp").exists()  # renamed over, never half written
    write_node_results(path, "mpc", Counter())
    assert read_node_results(path) == ("mpc", {})


def test_a_missing_file_is_no_results_and_a_foreign_one_is_refused(tmp_path):
    assert read_node_results(tmp_path / "none.json") is None
    bad = tmp_path / "bad.json"
    for text, message in (
        ("{not json", "not a node results file"),
        ('{"node": "mpc", "rejected": {}}', "schema"),
        (json.dumps({"schema": SCHEMA, "node": "mpc", "rejected": {"a": "3"}}), "integers"),
        (json.dumps({"schema": SCHEMA, "node": 1, "rejected": {}}), "'node' and 'rejected'"),
    ):
        bad.write_text(text)
        with pytest.raises(NodeResultsError, match=message):
            read_node_results(bad)


def test_the_bring_up_collects_the_nodes_that_wrote_results(tmp_path):
    """A node that ended normally wrote its file; a killed one (or the recorder) none."""
    write_node_results(results_path(str(tmp_path), "pid"), "pid", Counter({"x:stale": 2}))
    write_node_results(results_path(str(tmp_path), "plant"), "plant", Counter())
    got = rejected_from_results(str(tmp_path), ["plant", "pid", "mpc", "recorder"])
    assert got == {"plant": {}, "pid": {"x:stale": 2}}
