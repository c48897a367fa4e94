"""The node graph's parameter files (``ffmpc_ros.graph_nodes.write_graph_params``): each node
process is given the scenario file as it is, then the run's file with only what that file does
not give it. No ROS graph here (tests/test_ros_params.py reads the files with rcl)."""

from __future__ import annotations

import pytest
import yaml

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import Scenario, load_scenario, resolve_scenario_path
from ffmpc_ros.graph_nodes import (
    file_parameters,
    graph_parameters,
    run_file_values,
    split_parameter_args,
    write_graph_params,
)


def _run_file(tmp_path, scenario, namespace="/"):
    params = graph_parameters(scenario, lockstep=True, duration=0.5, namespace=namespace)
    args = write_graph_params(params, str(tmp_path), namespace, scenario.source)
    run = yaml.safe_load((tmp_path / "graph_params.yaml").read_text())
    return args, params, run


def test_the_stiffness_reaches_the_mpc_from_the_scenario_file_only(tmp_path):
    """`ffmpc run polishing`: the MPC's K is not in the run's file (the node reads the scenario
    file's `/**/mpc` section); the values of other sections it declares, the graph parameters
    and a `--set` value are."""
    scenario = load_scenario("polishing", {"mpc.formulation": "classical", "pid.kp": 0.2})
    assert scenario.source == str(resolve_scenario_path("polishing").resolve())
    args, params, run = _run_file(tmp_path, scenario)
    copy = tmp_path / "scenario.yaml"
    assert args == [
        "--params-file",
        str(copy),
        "--params-file",
        str(tmp_path / "graph_params.yaml"),
    ]
    assert copy.read_bytes() == resolve_scenario_path("polishing").read_bytes()
    mpc = run["mpc"]["ros__parameters"]
    assert "contact.stiffness" not in mpc and "horizon" not in mpc and "task.reach" not in mpc
    assert mpc["formulation"] == "classical"  # the --set value (the file says force_feedback)
    assert mpc["plant.time_step"] == 0.001 and mpc["pid.delay_cycles"] == 5  # other sections
    assert mpc["lockstep"] is True and run["plant"]["ros__parameters"]["duration"] == 0.5
    pid = run["pid"]["ros__parameters"]
    assert pid["kp"] == 0.2 and "ki" not in pid
    # every value a node holds is in the run's file or, the same, in the scenario file
    for node, values in params.items():
        given = file_parameters(copy, node)
        for name, value in values.items():
            assert name in run[node]["ros__parameters"] or given[name] == value, (node, name)


def test_a_scenario_built_in_code_gives_every_value(tmp_path):
    """Without a scenario file (a Scenario built in code), the run's file holds every value."""
    args, params, run = _run_file(tmp_path, Scenario(name="code"))
    assert args == ["--params-file", str(tmp_path / "graph_params.yaml")]
    assert run["mpc"]["ros__parameters"]["contact.stiffness"] == params["mpc"]["contact.stiffness"]


def test_a_section_reaches_the_nodes_as_rcl_gives_it(tmp_path):
    """`/**/mpc` reaches /mpc and /arm1/mpc, a bare `mpc` the root's only; a value the file
    writes differently but the schema reads the same (1000 and 1000.0) is the file's; one it
    reads otherwise is the run's."""
    path = tmp_path / "mine.yaml"
    path.write_text(
        "/**:\n  ros__parameters: {base: polishing, seed: 3}\n"
        "mpc:\n  ros__parameters: {contact: {stiffness: 1000}, horizon: 7}\n"
    )
    scenario = load_scenario(path)
    assert scenario.mpc.contact.stiffness == 1000.0 and scenario.mpc.ocp.horizon == 7
    assert file_parameters(path, "mpc")["contact.stiffness"] == 1000
    assert "contact.stiffness" not in file_parameters(path, "mpc", "/arm1")
    assert file_parameters(path, "pid", "/arm1") == {"base": "polishing", "seed": 3}
    values = {"contact.stiffness": 1000.0, "horizon": 8, "lockstep": True}
    given = file_parameters(path, "mpc")
    assert run_file_values("mpc", values, given) == {"horizon": 8, "lockstep": True}
    # the node's stiffness: a float -0.0 is not the file's 0 (bit for bit)
    assert run_file_values("mpc", {"contact.stiffness": -0.0}, {"contact.stiffness": 0}) == {
        "contact.stiffness": -0.0
    }


def test_node_param_values_are_split_from_the_other_ros_arguments():
    """`--node-param` gives `-p NAME:=VALUE` pairs: read as rcl reads them, for the node's
    section of the run's file; other arguments stay arguments; a malformed one is refused."""
    values, rest = split_parameter_args(
        ["-p", "horizon:=6", "--log-level", "debug", "--param", "period:=2e-3", "-p", "x:=[1, 2]"]
    )
    assert values == {"horizon": 6, "period": 0.002, "x": [1, 2]}
    assert rest == ["--log-level", "debug"]
    for bad in (["-p", "horizon"], ["-p", ":=3"], ["-p", "x:=[1, 2"], ["-p"]):
        with pytest.raises(ConfigError, match="expected NAME:=VALUE"):
            split_parameter_args(bad)
