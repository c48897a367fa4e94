"""Node parameters: declared with descriptions and ranges, read-only but for the live ones
(test_ros_live_params.py), loaded from the scenario files (ROS 2 parameter-file format) into
the same Scenario the ROS-free runner reads."""

from __future__ import annotations

from dataclasses import replace

import pytest
import yaml
from rcl_interfaces.msg import ParameterType
from ros_helpers import overrides

from ffmpc_core.config import FORMULATIONS
from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import (
    SCENARIO_DIR,
    STUDY_SCENARIOS,
    load_scenario,
    resolve_scenario_path,
)
from ffmpc_ros.joint_sensor_node import JointSensorNode
from ffmpc_ros.mpc_node import MpcNode
from ffmpc_ros.params import NODE_SPECS, node_parameter_values, scenario_from_parameters
from ffmpc_ros.plant_node import PlantNode
from ffmpc_ros.state_publisher_node import StatePublisherNode

NUMERIC = (ParameterType.PARAMETER_DOUBLE, ParameterType.PARAMETER_INTEGER)


def _params_file_args(name="polishing"):
    return ["--ros-args", "--params-file", str(resolve_scenario_path(name))]


def test_nodes_load_the_scenario_file_into_the_runner_scenario(ros):
    """`--params-file polishing.yaml`: each node's sections equal load_scenario's (the file sets
    random_tilt_deg 6 for the plant, the tuned force_phase for the force-feedback MPC, seed and
    task for all)."""
    reference = load_scenario("polishing")
    mpc = ros.add(MpcNode(context=ros.context, cli_args=_params_file_args()))
    plant = ros.add(PlantNode(context=ros.context, cli_args=_params_file_args()))
    got = mpc.scenario.mpc
    assert replace(got, weights={}) == replace(reference.mpc, weights={})
    for form in FORMULATIONS:  # the node holds every weight; the values are the file's
        assert got.cost_weights(form) == reference.mpc.cost_weights(form)
        assert got.phase_weights(form) == reference.mpc.phase_weights(form)
    assert mpc.scenario.task == reference.task
    raw = yaml.safe_load(resolve_scenario_path("polishing").read_text())
    ff = raw["/**/mpc"]["ros__parameters"]["weights"]["force_feedback"]  # the file, as text
    assert mpc.scenario.mpc.phase_weight("force_phase", 0.0) == ff["force_phase"]
    assert plant.scenario.plant == reference.plant and plant.scenario.seed == reference.seed
    assert plant.scenario.plant.random_tilt_deg == 6.0
    assert mpc.get_parameter("use_sim_time").value is True


def test_nodes_read_the_run_parameter_file_into_the_runner_scenario(ros, tmp_path):
    """The parameter file ``ffmpc run`` writes (each node's parameters as flat dotted keys,
    ``contact.stiffness: 1234.5``), read by rcl: the MPC and PID nodes build the sections they
    declare equal to the runner's, the ``--set`` values included."""
    from ffmpc_ros.graph_nodes import graph_parameters, write_params_file
    from ffmpc_ros.pid_node import PidNode

    reference = load_scenario(
        "polishing",
        {
            "mpc.contact.stiffness": 1234.5,
            "mpc.weights.force_feedback.force_diag": 2.0,
            "pid.kp": 0.2,
            "pid.delay_cycles": 4,
        },
    )
    path = tmp_path / "graph_params.yaml"
    write_params_file(graph_parameters(reference, lockstep=True, duration=0.5), str(path))
    mpc_section = yaml.safe_load(path.read_text())["mpc"]["ros__parameters"]
    assert mpc_section["contact.stiffness"] == 1234.5 and "contact" not in mpc_section
    args = ["--ros-args", "--params-file", str(path)]
    mpc = ros.add(MpcNode(context=ros.context, cli_args=args))
    pid = ros.add(PidNode(context=ros.context, cli_args=args))
    assert mpc.get_parameter("contact.stiffness").value == 1234.5
    assert replace(mpc.scenario.mpc, weights={}) == replace(reference.mpc, weights={})
    for form in FORMULATIONS:
        assert mpc.scenario.mpc.cost_weights(form) == reference.mpc.cost_weights(form)
    assert mpc.scenario.task == reference.task
    assert mpc.scenario.pid.delay_cycles == 4
    assert pid.scenario.pid == reference.pid
    assert pid.scenario.mpc.ocp.period == reference.mpc.ocp.period


def test_nodes_given_the_scenario_file_then_the_run_file_build_the_runner_scenario(ros, tmp_path):
    """What ``ffmpc run`` gives a node process (``graph_nodes.write_graph_params``): the
    scenario file as it is, then the run's file with what that file does not give the node.
    Read by rcl, every scenario parameter of the plant, sensor, MPC and PID nodes equals the
    runner's; K comes from the scenario file, the --set values from the run's file, and a
    --node-param value (in the node's section of the run's file) wins over the scenario
    file's section."""
    from ffmpc_ros.ft_sensor_node import FtSensorNode
    from ffmpc_ros.graph_nodes import graph_parameters, split_parameter_args, write_graph_params
    from ffmpc_ros.params import node_scenario_names, scenario_flat
    from ffmpc_ros.pid_node import PidNode

    reference = load_scenario(
        "polishing",
        {"mpc.formulation": "classical", "pid.kp": 0.2, "pid.delay_cycles": 4, "seed": 3},
    )
    params = graph_parameters(reference, lockstep=True, duration=0.5)
    node_param, rest = split_parameter_args(["-p", "horizon:=6", "--log-level", "warn"])
    assert node_param == {"horizon": 6} and rest == ["--log-level", "warn"]
    params["mpc"].update(node_param)  # as the bring-up's _spawn does
    files = write_graph_params(params, str(tmp_path), scenario_file=reference.source)
    run = yaml.safe_load((tmp_path / "graph_params.yaml").read_text())
    assert "contact.stiffness" not in run["mpc"]["ros__parameters"]
    args = ["--ros-args", *files]
    expected = scenario_flat(reference) | {"mpc.horizon": 6}
    for cls, node in (
        (PlantNode, "plant"),
        (JointSensorNode, "joint_sensor"),
        (FtSensorNode, "ft_sensor"),
        (MpcNode, "mpc"),
        (PidNode, "pid"),
    ):
        built = ros.add(cls(context=ros.context, cli_args=args))
        got = scenario_flat(built.scenario)
        names = node_scenario_names(NODE_SPECS[node], expected)
        assert names, node
        for ros_name, name in names.items():
            assert repr(got[name]) == repr(expected[name]), (node, ros_name)


def test_every_parameter_has_a_description_and_numbers_a_range(ros):
    node = ros.add(
        JointSensorNode(context=ros.context, parameter_overrides=overrides("joint_sensor"))
    )
    mpc = ros.add(MpcNode(context=ros.context, parameter_overrides=overrides("mpc")))
    state = ros.add(
        StatePublisherNode(context=ros.context, parameter_overrides=overrides("state_publisher"))
    )
    from ffmpc_ros.lfc_node import LfcNode

    lfc = ros.add(LfcNode(context=ros.context, parameter_overrides=overrides("lfc")))
    for n in (node, mpc, state, lfc):
        names = [p for p in n.params]
        assert len(names) > 5
        for desc in n.describe_parameters(names):
            assert desc.description, desc.name
            # read-only but for the node's live parameters (NODE_SPECS[...].live)
            assert desc.read_only != n.spec.is_live(desc.name), desc.name
            if desc.type in NUMERIC and not desc.dynamic_typing:
                assert desc.floating_point_range or desc.integer_range, desc.name
    assert set(NODE_SPECS) == {
        "plant",
        "joint_sensor",
        "ft_sensor",
        "mpc",
        "pid",
        "lfc",
        "metrics",
        "impact_planner",
        "contact_learner",
        "dice_plant",
        "impact_controller",
        "state_publisher",
    }


def test_out_of_range_and_invalid_values_are_refused_at_start(ros):
    scenario = load_scenario("polishing")
    bad = [p for p in overrides("joint_sensor", scenario) if p.name != "position_noise_std"]
    from rclpy.parameter import Parameter

    bad.append(Parameter("position_noise_std", value=-1.0))
    # rclpy's refusal comes out as the runner's ConfigError (ffmpc_core.scenario.SCHEMA)
    with pytest.raises(ConfigError, match=r"joint_sensor.position_noise_std = -1.0: expected"):
        JointSensorNode(context=ros.context, parameter_overrides=bad)
    wrong = [p for p in overrides("mpc", scenario) if p.name != "formulation"]
    wrong.append(Parameter("formulation", value="rigid"))
    with pytest.raises(ValueError, match="formulation"):
        MpcNode(context=ros.context, parameter_overrides=wrong)


@pytest.mark.parametrize(
    "name", sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml") if p.stem not in STUDY_SCENARIOS)
)
def test_every_shipped_scenario_reaches_every_node_unchanged(name):
    """node parameters → Scenario gives back each node's sections of every shipped scenario."""
    scenario = load_scenario(name)
    sections = {
        "plant": ("plant", "task", "seed", "robot"),
        "joint_sensor": ("joint_sensor", "seed", "robot"),
        "ft_sensor": ("ft_sensor", "seed"),
        "mpc": ("task", "robot"),
        "pid": ("pid",),
        "metrics": ("task", "robot", "seed"),
    }
    for node, names in sections.items():
        spec = NODE_SPECS[node]
        values = node_parameter_values(node, scenario)
        got = scenario_from_parameters(spec, values, node)
        for section in names:
            assert getattr(got, section) == getattr(scenario, section), (node, section)
        assert got.plant.time_step == scenario.plant.time_step
    mpc = scenario_from_parameters(NODE_SPECS["mpc"], node_parameter_values("mpc", scenario), "m")
    assert replace(mpc.mpc, weights={}) == replace(scenario.mpc, weights={})
    assert mpc.mpc.cost_weights() == scenario.mpc.cost_weights()
    assert mpc.pid.delay_cycles == scenario.pid.delay_cycles
    pid = scenario_from_parameters(NODE_SPECS["pid"], node_parameter_values("pid", scenario), "p")
    assert pid.mpc.ocp.period == scenario.mpc.ocp.period
    assert pid.mpc.riccati_feedback == scenario.mpc.riccati_feedback
