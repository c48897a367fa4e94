"""The whole node graph against the ROS-free runner: in lockstep, single-process and
multi-process, every logged signal and both metric sets are bit-identical to ``run_polishing``
for the same scenario and seed (same objects, same float64 inputs — CDR carries doubles
exactly —, same times t = k·time_step, same generators). Real time: tests/test_realtime.py."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest
from ros_helpers import assert_same_run

from ffmpc_core.scenario import load_scenario
from ffmpc_ros.bringup import GraphOptions, graph_parameters, run_graph
from ffmpc_ros.graph_nodes import write_params_file
from studies.cli import _polishing_overrides
from studies.polishing import run_polishing

#: The polishing scenarios' settings before the searched weights, as a ``--set-file``.
UNTUNED = (
    Path(__file__).resolve().parents[1]
    / "benchmarks/results/paper/seeds100-119-friction/untuned.yaml"
)


def test_single_process_graph_equals_the_runner_for_one_second():
    """Force-feedback with the Riccati feedback on (the PID node then also reads λ̂), seed 0:
    1 s of simulated time, through first contact and the force ramp — and the robot's velocity
    reflex: joint A4 crosses the LBR iiwa 14's 75°/s at 0.634 s, the robot stops itself in both
    (one reflex model), the nodes and the runner's loop run on to the end. With the time-based
    switch to contact (``task.approach_speed`` 0), under which this run reaches the table
    within the second; the guarded approach's graph against the runner: ``make demo``. At the
    settings before the searched weights (``UNTUNED``: untuned weights, no observer): at the
    scenario defaults the Riccati feedback drives A5 past its limit at 0.248 s, in the reach,
    before the table."""
    overrides = {
        **_polishing_overrides(argparse.Namespace(set_file=[str(UNTUNED)], set=None)),
        "seed": 0,
        "mpc.formulation": "force_feedback",
        "mpc.riccati_feedback": True,
        "task.approach_speed": 0.0,
    }
    scenario = load_scenario("polishing", overrides)
    graph = run_graph(scenario, GraphOptions(duration=1.0, single_process=True, timeout=120))
    runner = run_polishing(scenario, duration=1.0)
    assert_same_run(graph, runner)
    assert graph.log["force_true"].max() > 5.0  # the run reached the table
    assert graph.aborted and runner.aborted
    assert graph.reflex_event == runner.reflex["event"] and runner.reflex["event"]["joint"] == 3
    status = graph.plant_status
    assert status["done"] == 1.0 and status["steps"] == 1000 and status["deadline_misses"] == 0
    assert status["latency_count"] == 1000


def test_multi_process_graph_equals_the_runner():
    scenario = load_scenario("polishing", {"seed": 1, "mpc.formulation": "classical"})
    graph = run_graph(scenario, GraphOptions(duration=0.2, single_process=False, timeout=120))
    runner = run_polishing(scenario, duration=0.2)
    assert_same_run(graph, runner)


def test_real_time_refuses_the_lockstep_only_options():
    """Real time has its own execution model (ffmpc_ros.realtime, tested in test_realtime.py)."""
    from ffmpc_core.errors import ConfigError

    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    with pytest.raises(ConfigError, match="two processes"):
        run_graph(scenario, GraphOptions(duration=0.2, single_process=True, lockstep=False))
    with pytest.raises(ConfigError, match="two processes"):
        run_graph(
            scenario, GraphOptions(duration=0.2, lockstep=False, record="/tmp/never_written.mcap")
        )


def test_generated_parameter_file_is_a_ros_parameter_file(tmp_path):
    """The file ``ffmpc run`` hands the processes: one section per node, ros__parameters."""
    import yaml

    scenario = load_scenario("polishing", {"mpc.formulation": "torque_feedback"})
    params = graph_parameters(scenario, lockstep=True, duration=0.5)
    path = tmp_path / "graph.yaml"
    write_params_file(params, str(path))
    doc = yaml.safe_load(path.read_text())
    assert set(doc) == {
        *("plant", "joint_sensor", "ft_sensor", "mpc", "pid", "metrics", "state_publisher")
    }
    # each node's slice as flat dotted names (rcl reads them as those parameters)
    assert doc["mpc"]["ros__parameters"]["formulation"] == "torque_feedback"
    assert doc["mpc"]["ros__parameters"]["pid.delay_cycles"] == 5  # another section's value
    assert doc["mpc"]["ros__parameters"]["contact.stiffness"] == scenario.mpc.contact.stiffness
    assert doc["pid"]["ros__parameters"]["mpc.formulation"] == "torque_feedback"
    assert doc["plant"]["ros__parameters"]["task.normal_force"] == 50.0
    assert not any(k.startswith("mpc.") for k in doc["joint_sensor"]["ros__parameters"])
