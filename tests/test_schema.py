"""One schema (ffmpc_core.scenario.SCHEMA): strict types, one error format, and the ROS-free
runner and the nodes accept and refuse the same values with the same message."""

from __future__ import annotations

import math
import re

import pytest
from ros_helpers import RosHarness

from ffmpc_core.errors import ConfigError
from ffmpc_core.robots import ROBOT_NAMES
from ffmpc_core.scenario import (
    FLOAT,
    INT,
    SCHEMA,
    Scenario,
    load_scenario,
)
from ffmpc_ros.ft_sensor_node import FtSensorNode
from ffmpc_ros.joint_sensor_node import JointSensorNode
from ffmpc_ros.mpc_node import MpcNode
from ffmpc_ros.params import (
    NODE_SPECS,
    node_parameter_values,
    node_scenario_names,
    parameter_overrides,
    scenario_descriptor,
    scenario_flat,
)
from ffmpc_ros.pid_node import PidNode
from ffmpc_ros.plant_node import PlantNode

ONE_LINE = re.compile(r"^[\w.]+ = .+: (expected .+|unknown scenario parameter.*)$")
NODES = {"mpc": MpcNode, "pid": PidNode, "joint_sensor": JointSensorNode}
NODES |= {"ft_sensor": FtSensorNode, "plant": PlantNode}


def _refusal(overrides: dict) -> str:
    with pytest.raises(ConfigError) as info:
        load_scenario("polishing", overrides)
    message = str(info.value)
    assert ONE_LINE.match(message), message
    return message


@pytest.mark.parametrize(
    "name, value, expected",
    [
        ("mpc.contact.stiffness", True, "mpc.contact.stiffness = True: expected a number"),
        ("task.normal_force", True, "task.normal_force = True: expected a number in [0, 500] N"),
        ("task.normal_force", "50", "task.normal_force = '50': expected a number"),
        ("task.normal_force", math.nan, "task.normal_force = nan"),
        ("task.normal_force", math.inf, "task.normal_force = inf"),
        ("task.normal_force", [50.0], "task.normal_force = [50.0]"),
        ("mpc.horizon", 5.0, "mpc.horizon = 5.0: expected an integer in [1, 1000]"),
        ("mpc.horizon", True, "mpc.horizon = True: expected an integer"),
        ("mpc.horizon", 0, "mpc.horizon = 0: expected an integer in [1, 1000]"),
        ("pid.enabled", 1, "pid.enabled = 1: expected true or false"),
        ("plant.push_force", 3.0, "plant.push_force = 3.0: expected a list of 3 numbers"),
        ("plant.push_force", [1.0, 2.0], "expected a list of 3 numbers"),
        ("plant.push_force", [1.0, True, 0.0], "plant.push_force = [1.0, True, 0.0]"),
        ("mpc.contact.stiffness", [1.0, 2.0], "a list of 1 (mpc.contact.dimension)"),
        ("mpc.weights.classical.posture_diag", [1.0, 2.0], "or a list of 7 of them"),
        ("mpc.formulation", "rigid", "expected one of 'classical', 'torque_feedback'"),
        ("mpc.command_delay", "soon", "'pid', 'measured' or a number of seconds"),
        ("mpc.command_delay", 0.0015, "a whole number of plant steps (0.001 s)"),
        ("seed", -1, "seed = -1: expected an integer in [0, 2147483647]"),
        ("robot", "ur5", "robot = 'ur5': expected one of 'iiwa', 'panda'"),
        ("mpc.horizn", 3, "did you mean mpc.horizon"),
        ("mpc.weights.rigid.force", 1.0, "= 1.0: unknown scenario parameter"),
    ],
)
def test_strict_types_one_line_errors(name, value, expected):
    assert expected in _refusal({name: value})


def test_good_values_are_canonical():
    s = load_scenario(
        "polishing",
        {
            "task.normal_force": 60,  # an integer is a number
            "mpc.contact.dimension": 3,
            "mpc.contact.stiffness": [1, 2, 3],
            "plant.push_force": [0, 0, 5],
            "mpc.weights.force_feedback.posture_diag": 2,
        },
    )
    assert s.task.normal_force == 60.0 and type(s.task.normal_force) is float
    assert s.mpc.contact.stiffness == (1.0, 2.0, 3.0)
    assert s.plant.push_force == (0.0, 0.0, 5.0)
    assert s.mpc.cost_weights().posture_diag == 2.0


def test_scenario_file_values_are_checked_too(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(BASED + "mpc:\n  ros__parameters:\n    contact: {stiffness: true}\n")
    with pytest.raises(ConfigError, match=r"^mpc.contact.stiffness = True: expected"):
        load_scenario(path)


#: A scenario file's first section when it changes a shipped scenario (a partial file is refused).
BASED = "/**:\n  ros__parameters:\n    base: polishing\n"


def _write(tmp_path, text: str):
    path = tmp_path / "x.yaml"
    path.write_text(text)
    return path


def test_a_node_section_is_keyed_by_its_name_or_for_any_namespace(tmp_path):
    """``/**/mpc`` (what the shipped files use: rcl gives it to /arm1/mpc too) reads as ``mpc``;
    a file with both keys for one node is refused."""
    bare, anywhere, both = (tmp_path / f"{n}.yaml" for n in ("bare", "anywhere", "both"))
    section = "  ros__parameters:\n    horizon: 7\n"
    bare.write_text(BASED + "mpc:\n" + section)
    anywhere.write_text(BASED + "/**/mpc:\n" + section)
    both.write_text(BASED + "mpc:\n" + section + "/**/mpc:\n" + section)
    assert load_scenario(anywhere).mpc.ocp.horizon == load_scenario(bare).mpc.ocp.horizon == 7
    with pytest.raises(ConfigError, match=r"sections 'mpc' and '/\*\*/mpc' are the same node"):
        load_scenario(both)
    with pytest.raises(ConfigError, match=r"unknown node section '/\*\*/planet'"):
        load_scenario(_write(tmp_path, "/**/planet:\n" + section))


def test_schema_covers_every_field_and_generates_every_descriptor():
    assert set(SCHEMA["robot"].choices) == set(ROBOT_NAMES)
    flat = scenario_flat(Scenario(name="d"))
    assert set(flat) == set(SCHEMA)  # every scenario parameter has one declaration
    for name, spec in SCHEMA.items():
        desc = scenario_descriptor(spec)
        assert desc.read_only and desc.description, name
        if spec.kind == FLOAT and spec.range is not None:
            r = desc.floating_point_range[0]
            assert (r.from_value, min(r.to_value, math.inf)) == pytest.approx(
                (spec.range[0], min(spec.range[1], 1e300))
            ), name
        if spec.kind == INT:
            r = desc.integer_range[0]
            lo, hi = spec.range or (min(spec.choices), max(spec.choices))
            assert (r.from_value, r.to_value) == (lo, hi), name
        spec.check(flat[name])  # the defaults pass their own schema


# -- the runner and the nodes agree -----------------------------------------------------------
#: (scenario name, value): good and bad values, each given to load_scenario and to a node.
AGREEMENT = [
    ("mpc.horizon", 10),
    ("mpc.horizon", -1),
    ("mpc.horizon", 5.0),
    ("mpc.horizon", "5"),
    ("task.normal_force", 60),
    ("task.normal_force", 60.0),
    ("task.normal_force", "50"),
    ("task.normal_force", math.nan),
    ("task.normal_force", 1e4),
    ("task.normal_force", True),
    ("plant.time_step", 0.002),
    ("plant.time_step", 0.0),
    ("mpc.contact.stiffness", True),
    ("mpc.contact.stiffness", 2000.0),
    ("mpc.contact.stiffness", [2000.0]),
    ("mpc.contact.stiffness", [1.0, 2.0]),
    ("mpc.contact.dimension", 2),
    ("mpc.formulation", "classical"),
    ("mpc.formulation", "rigid"),
    ("mpc.formulation", 3),
    ("mpc.command_delay", 0.005),
    ("mpc.command_delay", "soon"),
    ("mpc.command_delay", -0.001),
    ("mpc.weights.force_feedback.force_phase", 5),
    ("mpc.weights.force_feedback.force_phase", -1.0),
    ("mpc.weights.force_feedback.state_limit", 0.5),
    ("mpc.weights.force_feedback.state_limit", -1.0),
    ("mpc.weights.classical.state_limit_fraction", 0.8),
    ("mpc.weights.classical.state_limit_fraction", 1.5),
    ("mpc.weights.classical.posture_diag", [1.0] * 7),
    ("mpc.weights.classical.posture_diag", [1.0, 2.0]),
    ("pid.kp", 0.2),
    ("pid.kp", True),
    ("pid.enabled", False),
    ("pid.enabled", 1),
    ("pid.delay_cycles", 2.5),
    ("seed", 7),
    ("seed", -1),
    ("joint_sensor.position_noise_std", -1.0),
    ("ft_sensor.tare_samples", 0),
    ("ft_sensor.tare_samples", 10),
    ("plant.push_force", [1, 0, 0]),
    ("plant.push_force", [1.0, 2.0]),
    ("plant.push_force", [True, False, True]),
    ("plant.table_tilt_axis", 1.0),
]


def _node_for(name: str) -> tuple[str, str]:
    """(node, ROS parameter name) of the first node that reads scenario parameter ``name``."""
    flat = scenario_flat(Scenario(name="d"))
    for node in ("mpc", "pid", "joint_sensor", "ft_sensor", "plant"):
        for ros, scen in node_scenario_names(NODE_SPECS[node], flat).items():
            if scen == name:
                return node, ros
    raise AssertionError(name)


@pytest.fixture(scope="module")
def ros():
    harness = RosHarness()
    yield harness
    harness.close()


@pytest.mark.parametrize("name, value", AGREEMENT, ids=[f"{n}={v!r}" for n, v in AGREEMENT])
def test_runner_and_node_agree(ros, name, value):
    base = load_scenario("polishing")
    try:
        runner = load_scenario("polishing", {name: value})
        runner_error = None
    except ConfigError as exc:
        runner, runner_error = None, str(exc)
    node, ros_name = _node_for(name)
    values = node_parameter_values(node, base)
    values[ros_name] = value
    try:
        built = NODES[node](context=ros.context, parameter_overrides=parameter_overrides(values))
        node_error = None
    except ConfigError as exc:
        built, node_error = None, str(exc)
    assert node_error == runner_error, (node_error, runner_error)
    if built is not None:
        try:
            assert scenario_flat(built.scenario)[name] == scenario_flat(runner)[name]
            if name == "mpc.command_delay":
                assert built.scenario.pid.delay_cycles == runner.pid.delay_cycles == 5
        finally:
            built.destroy_node()
