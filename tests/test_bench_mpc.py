"""``ffmpc bench mpc``: case selection and the JSON output (a tiny run; no speed is asserted)."""

from __future__ import annotations

import json

import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_ros.cli import main
from studies.bench_mpc import CONFIGURATIONS, parse_cases

KEYS = {
    "formulation",
    "nodes",
    "dt",
    "median_ms",
    "p90_ms",
    "iterations_median",
    "iterations_max",
    "cap_hit_fraction",
    "ratio_to_reference",
    "step_median_ms",
    "solve_median_ms",
    "constraints",
    "csqp_fraction",
    "qp_iterations_median",
    "constraint_violation_max",
}


def test_parse_cases():
    # By default: the three formulations (native) with and without their constraints, the
    # force-capped force-feedback case and the Python force-feedback model.
    assert parse_cases(None) == [
        (
            n,
            dt,
            [
                "reference",
                "classical",
                "torque_feedback",
                "force_feedback",
                "classical_unconstrained",
                "torque_feedback_unconstrained",
                "force_feedback_unconstrained",
                "force_feedback_capped",
                "force_feedback_python",
            ],
        )
        for n, dt in CONFIGURATIONS
    ]
    assert parse_cases(["torque_feedback_python:5"]) == [
        (5, 0.003, ["reference", "torque_feedback_python"])
    ]
    assert parse_cases(["force_feedback:20", "classical"]) == [
        (5, 0.003, ["reference", "classical"]),
        (20, 0.010, ["reference", "classical", "force_feedback"]),
    ]
    for bad in (["rigid"], ["classical:7"], ["classical:x"]):
        with pytest.raises(ConfigError):
            parse_cases(bad)


def test_bench_writes_json(tmp_path, capsys):
    path = tmp_path / "bench.json"
    argv = ["bench", "mpc", "--solves", "4", "--cases", "classical:5", "force_feedback:5"]
    argv += ["force_feedback_unconstrained:5"]
    assert main([*argv, "--json", str(path)]) == 0
    printed = capsys.readouterr().out
    assert "step med" in printed and "force_feedback" in printed  # the table is still printed
    doc = json.loads(path.read_text())
    cases = doc["cases"]
    # the unconstrained twin runs before the constrained case it is the cost's reference of
    names = ["reference", "force_feedback_unconstrained", "classical", "force_feedback"]
    assert [c["formulation"] for c in cases] == names
    assert [c["constraints"] for c in cases] == [False, False, True, True]
    ff, twin = cases[3], cases[1]
    assert ff["constraint_cost_ratio"] == pytest.approx(ff["median_ms"] / twin["median_ms"])
    assert "constraint_cost_ratio" not in cases[2]  # its twin did not run
    ref = cases[0]
    for case in cases:
        assert KEYS <= set(case)
        assert case["nodes"] == 5 and case["dt"] == pytest.approx(0.003)
        assert case["solves"] == 3  # the cold first step is left out
        assert 0.0 <= case["cap_hit_fraction"] <= 1.0
        assert 1 <= case["iterations_median"] <= case["iterations_max"] <= 8
        # the step contains the solve
        assert case["median_ms"] == case["step_median_ms"] >= case["solve_median_ms"] > 0.0
        assert case["p90_ms"] >= case["median_ms"]
        assert case["ratio_to_reference"] == pytest.approx(case["median_ms"] / ref["median_ms"])
    assert ref["ratio_to_reference"] == 1.0
