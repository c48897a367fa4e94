"""``ffmpc launch``: the YAML launch subset (``ffmpc_ros.launch``) and the installed
``polishing.launch.yaml``, whose run gives the ROS-free runner's metrics exactly."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import rclpy
from rclpy.context import Context
from rclpy.node import Node

from ffmpc_core.scenario import load_scenario
from ffmpc_ros.launch import (
    LaunchError,
    find_launch_file,
    load_launch_file,
    node_command,
    parse_launch_arguments,
    substitute,
    unreached_sections,
)
from sim_bridge.runner import run_scenario

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "ffmpc_ros" / "ros_layout" / "launch" / "polishing.launch.yaml"


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "x.launch.yaml"
    path.write_text(text)
    return path


def test_the_polishing_launch_file_parses_with_its_arguments():
    description = load_launch_file(SOURCE, {"formulation": "classical", "duration": "0.5"})
    assert [n.label for n in description.nodes] == [
        "plant",
        "joint_sensor",
        "ft_sensor",
        "mpc",
        "pid",
        "metrics",
    ]
    mpc = description.nodes[3]
    assert mpc.parameters[0][0] == "file" and mpc.parameters[0][1].endswith("polishing.yaml")
    assert ("formulation", "classical") in mpc.parameters
    plant = description.nodes[0]
    assert ("duration", 0.5) in plant.parameters  # a whole substitution is read as YAML
    assert all(n.shutdown_on_exit for n in description.nodes)  # a lockstep graph dies whole
    assert description.arguments["formulation"] == "classical"
    assert find_launch_file("polishing.launch.yaml").endswith("launch/polishing.launch.yaml")


def test_unsupported_content_is_refused_by_name(tmp_path):
    cases = {
        "launch:\n- group: {}\n": "unsupported launch tag 'group'",
        "launch:\n- node: {pkg: ffmpc_ros, exec: mpc, respawn: true}\n": "respawn",
        "launch:\n- arg: {name: a}\n": "has no default",
        "launch:\n- node: {pkg: ffmpc_ros, exec: mpc, on_exit: restart}\n": "only 'shutdown'",
        "launch:\n- node: {pkg: ffmpc_ros, exec: mpc, name: $(var nope)}\n": "no such launch",
        "launch:\n- node: {pkg: ffmpc_ros, exec: mpc, name: $(eval 1)}\n": "unsupported subst",
        "nodes: []\n": "one mapping 'launch:'",
    }
    for text, message in cases.items():
        with pytest.raises(LaunchError, match=message):
            load_launch_file(_write(tmp_path, text))
    with pytest.raises(LaunchError, match="unknown launch argument"):
        load_launch_file(SOURCE, {"formulaton": "classical"})
    with pytest.raises(LaunchError, match="NAME:=VALUE"):
        parse_launch_arguments(["formulation=classical"])
    with pytest.raises(LaunchError, match="not set and no default"):
        substitute("$(env FFMPC_SURELY_UNSET_VARIABLE)", {})
    assert substitute("$(env FFMPC_SURELY_UNSET_VARIABLE fallback)/x", {}) == "fallback/x"


def test_a_value_entry_overrides_the_scenario_files_node_section(tmp_path):
    """As with launch_ros, ``{name, value}`` entries win over an earlier parameter file even
    where that file has a section for the node (a plain ``-p`` would lose there)."""
    description = load_launch_file(SOURCE, {"formulation": "classical"})
    mpc = description.nodes[3]
    command = node_command(mpc, tmp_path)
    assert Path(command[0]).name == "mpc" and os.access(command[0], os.X_OK)
    context = Context()
    rclpy.init(context=context, args=["mpc", *command[1:]])
    try:
        node = Node("mpc", context=context, automatically_declare_parameters_from_overrides=True)
        assert node.get_parameter("formulation").value == "classical"
        assert node.get_parameter("lockstep").value is True
        assert node.get_parameter("horizon").value == load_scenario("polishing").mpc.horizon
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_under_a_namespace_the_node_still_reads_the_scenario_files_section(tmp_path):
    """``namespace:=/arm1``: the node runs as /arm1/mpc; the scenario file, passed unchanged as
    ``ros2 launch`` passes it, reaches it through its section keyed ``/**/mpc``."""
    description = load_launch_file(SOURCE, {"formulation": "classical", "namespace": "/arm1"})
    mpc = description.nodes[3]
    command = node_command(mpc, tmp_path)
    assert "__ns:=/arm1" in command and "/clock:=clock" in command
    assert command[command.index("--params-file") + 1] == mpc.parameters[0][1]  # unchanged
    assert unreached_sections(mpc) == []
    context = Context()
    rclpy.init(context=context, args=["mpc", *command[1:]])
    try:
        node = Node("mpc", context=context, automatically_declare_parameters_from_overrides=True)
        assert node.get_fully_qualified_name() == "/arm1/mpc"
        assert node.resolve_topic_name("/clock") == "/arm1/clock"
        assert node.get_parameter("formulation").value == "classical"
        horizon = load_scenario("polishing").mpc.horizon
        assert node.get_parameter("horizon").value == horizon  # the file's mpc section
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


@pytest.mark.parametrize("namespace", ["", "/arm1"])
def test_ffmpc_launch_runs_the_graph_and_equals_the_runner(tmp_path, namespace):
    args = ["polishing.launch.yaml", "formulation:=classical", "duration:=0.1"]
    args += [f"namespace:={namespace}"] if namespace else []
    done = subprocess.run(
        [sys.executable, "-m", "ffmpc_ros.cli", "launch", *args, "--timeout", "120"]
        + ["--log-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=240,
        env=dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"),
    )
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    line = next(x for x in done.stdout.splitlines() if "metrics: {" in x)
    metrics = json.loads(line[line.index("{") :])
    runner = run_scenario(load_scenario("polishing", {"mpc.formulation": "classical"}), 0.1)
    assert metrics["metrics_true"] == runner.metrics_true.to_dict()
    assert metrics["metrics_measured"] == runner.metrics_measured.to_dict()
    assert "[launch] metrics exited with 0" in done.stdout
    if namespace:  # every node under it (its log name: arm1.mpc)
        for name in ("plant", "joint_sensor", "ft_sensor", "mpc", "pid", "metrics"):
            assert f"[arm1.{name}]: started" in done.stdout, name
    assert sorted(p.name for p in tmp_path.glob("*.log")) == sorted(
        f"{n}.log" for n in ("plant", "joint_sensor", "ft_sensor", "mpc", "pid", "metrics")
    )
    started = re.findall(r"^\[launch\] started \w+ \(pid (\d+)\)$", done.stdout, re.MULTILINE)
    pids = [int(p) for p in started]
    assert len(pids) == 6
    for pid in pids:  # every node stopped with the launch
        assert (
            not Path(f"/proc/{pid}").exists()
            or "zombie" in Path(f"/proc/{pid}/status").read_text().lower()
        )
