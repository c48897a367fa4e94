"""One reader of parameter values (``ffmpc_core.values``), held equal to ROS 2's own: rcl's YAML
parameter parser (the one a node runs on ``-p name:=value`` and ``--params-file``) is asked, in
this process, through a real rclpy node, and must type every spelling as ffmpc does; a scenario
file then reads the same in the ROS-free runner and in a node."""

from __future__ import annotations

import math

import pytest
import rclpy
import yaml
from rclpy.context import Context
from rclpy.node import Node

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import load_scenario
from ffmpc_core.values import load_value, load_yaml, parse_number, parse_scalar

#: Spellings of numbers, bools and strings, and rcl's corners (octal, hex, hex floats, overflow
#: to a string, underflow to a string, int64 overflow to a double).
SPELLINGS = [
    "1e4", "1e+09", "1E4", "-1e-3", "2.5", ".5", "5.", "+3", "-3", "42", "010", "08", "0x1f",
    "-0x10", "0b101", "1_000", "1:30", ".inf", "-.inf", "+.INF", ".NaN", "inf", "Infinity",
    "nan", "0x1p3", "0x1.8p1", "1e400", "1e-400", "1e-310", "2.2250738585072014e-308",
    "9223372036854775807", "9223372036854775808", "yes", "No", "on", "OFF", "y", "N", "True",
    "tRue", "abc", "1e", "e4", "1.2.3", "0", "-0", "00", "1e+", "0x",
]  # fmt: skip


@pytest.fixture(scope="module")
def rcl():
    """A function: the value rcl gives ``text`` on ``-p v:=text`` and in a parameter file."""
    import os

    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))

    def read(text: str, tmp_path) -> tuple[object, object]:
        values = []
        path = tmp_path / "p.yaml"
        path.write_text(f"/**:\n  ros__parameters:\n    v: {text}\n")
        for args in (["-p", f"v:={text}"], ["--params-file", str(path)]):
            node = Node(
                "rcl_reader",
                context=context,
                cli_args=["--ros-args", *args],
                automatically_declare_parameters_from_overrides=True,
            )
            values.append(node.get_parameter("v").value)
            node.destroy_node()
        return values[0], values[1]

    yield read
    rclpy.shutdown(context=context)


def _same(a: object, b: object) -> bool:
    if type(a) is not type(b):
        return False
    if isinstance(a, float) and math.isnan(a):
        return math.isnan(b)  # type: ignore[arg-type]
    return a == b


@pytest.mark.parametrize("text", SPELLINGS)
def test_every_spelling_reads_as_rcl_reads_it(text, rcl, tmp_path):
    on_command_line, in_file = rcl(text, tmp_path)
    assert _same(parse_scalar(text), on_command_line), (text, parse_scalar(text), on_command_line)
    assert _same(load_yaml(f"v: {text}")["v"], in_file), (text, in_file)


def test_quoted_and_tagged_scalars_stay_strings_and_keys_stay_names():
    doc = load_yaml("a: '1e4'\nb: \"5\"\nc: !!str 7\nyes: 1e4\n")
    assert doc == {"a": "1e4", "b": "5", "c": "7", "yes": 10000.0}


def test_a_list_of_mixed_types_is_refused_in_a_file_as_rcl_refuses_it(rcl, tmp_path):
    with pytest.raises(ConfigError, match="Sequence should be of same type"):
        load_yaml("v: [0, 1.0, 0]\n")
    with pytest.raises(Exception, match="Sequence should be of same type"):
        rcl("[0, 1.0, 0]", tmp_path)
    # one command-line value (--set) may mix them: the schema types it, rcl never sees the text
    assert load_value("[0, 40.0, 0]") == [0, 40.0, 0]


def test_parse_number_takes_numbers_only():
    assert parse_number("1e+09") == 1e9 and parse_number(" 0x10 ") == 16.0
    for text in ("true", "abc", "[1]", ""):
        with pytest.raises(ConfigError, match="expected a number"):
            parse_number(text)
    with pytest.raises(yaml.YAMLError):
        load_yaml("v: [1")


def test_a_scenario_file_reads_the_same_in_the_runner_and_in_a_node(tmp_path):
    """``stiffness: 1e4`` (and a base scenario) in the runner and in a node given the file with
    ``--params-file``, as ``ros2 run ffmpc_ros mpc`` would: both 10000.0, and every value the node
    declares from the base equals the runner's."""
    import os

    from ffmpc_ros.params import NODE_SPECS, declare_node_parameters, scenario_flat

    path = tmp_path / "sci.yaml"
    path.write_text(
        "/**:\n  ros__parameters:\n    base: polishing\n"
        "/**/mpc:\n  ros__parameters:\n    horizon: 7\n    contact: {stiffness: 1e4}\n"
    )
    runner = load_scenario(path)
    assert runner.mpc.contact.stiffness == 10000.0 and runner.mpc.ocp.horizon == 7
    assert runner.plant.random_tilt_deg == load_scenario("polishing").plant.random_tilt_deg
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ["ROS_DOMAIN_ID"]))
    try:
        node = Node("mpc", context=context, cli_args=["--ros-args", "--params-file", str(path)])
        values = declare_node_parameters(node, NODE_SPECS["mpc"])
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)
    assert values["contact.stiffness"] == 10000.0 and values["horizon"] == 7
    flat = scenario_flat(runner)
    for ros, value in values.items():
        scenario_name = f"mpc.{ros}" if f"mpc.{ros}" in flat else ros
        if scenario_name in flat and ros != "horizon":
            expected = flat[scenario_name]
            expected = list(expected) if isinstance(expected, tuple) else expected
            assert value == expected, ros
