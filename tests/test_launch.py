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
import yaml
from rclpy.context import Context
from rclpy.node import Node

from ffmpc_core.scenario import flatten, load_scenario
from ffmpc_ros.launch import (
    LaunchError,
    find_launch_file,
    load_launch_file,
    node_command,
    parse_launch_arguments,
    substitute,
    unreached_sections,
)
from studies.polishing import run_polishing

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
        "state_publisher",
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
        assert node.get_parameter("horizon").value == load_scenario("polishing").mpc.ocp.horizon
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
        horizon = load_scenario("polishing").mpc.ocp.horizon
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
    runner = run_polishing(load_scenario("polishing", {"mpc.formulation": "classical"}), 0.1)
    assert metrics["metrics_true"] == runner.metrics_true.to_dict()
    assert metrics["metrics_measured"] == runner.metrics_measured.to_dict()
    assert "[launch] metrics exited with 0" in done.stdout
    if namespace:  # every node under it (its log name: arm1.mpc)
        for name in ("plant", "joint_sensor", "ft_sensor", "mpc", "pid", "metrics"):
            assert f"[arm1.{name}]: started" in done.stdout, name
    assert sorted(p.name for p in tmp_path.glob("*.log")) == sorted(
        f"{n}.log"
        for n in ("plant", "joint_sensor", "ft_sensor", "mpc", "pid", "metrics", "state_publisher")
    )
    started = re.findall(r"^\[launch\] started \w+ \(pid (\d+)\)$", done.stdout, re.MULTILINE)
    pids = [int(p) for p in started]
    assert len(pids) == 7  # the seven nodes
    for pid in pids:  # every node stopped with the launch
        assert (
            not Path(f"/proc/{pid}").exists()
            or "zombie" in Path(f"/proc/{pid}/status").read_text().lower()
        )


# --- the real launch_ros, when one is found (not on CI: no wheel; docs/explanation/design.md, "More
# measured facts", has the recipe that builds it into a venv of its own) ---

#: Run with a Python that has launch_ros: the command line launch_ros builds for every node of
#: a YAML launch file (Node._perform_substitutions, as Node.execute does before it starts the
#: process), with the parameter files it writes for {name, value} entries, as JSON.
_LAUNCH_ROS_COMMANDS = """
import json, os, sys
import yaml
from launch import LaunchContext
from launch.actions import DeclareLaunchArgument
from launch.frontend import Parser
from launch.utilities import perform_substitutions
from launch_ros.actions import Node

path, *items = sys.argv[1:]
root, parser = Parser.load(path)
context = LaunchContext()
context.launch_configurations.update(dict(i.split(':=', 1) for i in items))
out = []
for action in parser.parse_description(root).entities:
    if isinstance(action, DeclareLaunchArgument):
        action.visit(context)
        continue
    assert isinstance(action, Node), action
    action._perform_substitutions(context)
    special = {'name': '__node:=' + action.node_name.rsplit('/', 1)[-1]}
    if action.expanded_node_namespace:
        special['ns'] = '__ns:=' + action.expanded_node_namespace
    context.extend_locals({'ros_specific_arguments': special})
    cmd = [perform_substitutions(context, part) for part in action.cmd]
    written = {}
    for flag, arg in zip(cmd, cmd[1:]):
        if flag == '--params-file' and os.path.basename(arg).startswith('launch_params_'):
            with open(arg) as fh:
                written[arg] = yaml.safe_load(fh)
            os.unlink(arg)
    out.append({'cmd': cmd, 'written': written, 'on_exit': repr(action._ExecuteLocal__on_exit)})
print(json.dumps(out))
"""


def _launch_ros_python() -> tuple[str, str] | None:
    """(python, ros2) of a ros2 CLI with launch_ros: ``FFMPC_ROS2`` or ``ros2`` on PATH, whose
    interpreter is read from its ``#!`` line; None when there is none."""
    import shutil

    ros2 = os.environ.get("FFMPC_ROS2") or shutil.which("ros2")
    if not ros2 or not os.path.isfile(ros2):
        return None
    first = Path(ros2).read_text(errors="replace").splitlines()[0]
    python = first[2:].strip().split()[0] if first.startswith("#!") else ""
    if "env" in Path(python).name:  # #!/usr/bin/env python3
        python = shutil.which("python3") or ""
    if not python:
        return None
    probe = subprocess.run(
        [python, "-c", "import launch_ros, launch_yaml, ros2launch"], capture_output=True
    )
    return (python, ros2) if probe.returncode == 0 else None


_REAL = _launch_ros_python()
needs_launch_ros = pytest.mark.skipif(
    _REAL is None,
    reason="no ros2 CLI with launch_ros (FFMPC_ROS2 or ros2 on PATH): no wheel on the index",
)


def _real_env() -> dict[str, str]:
    """AMENT_PREFIX_PATH: this venv (ros2 finds ffmpc_ros in it), the environment's, and the
    prefix of the ros2 CLI's interpreter (launch finds its own share files there)."""
    assert _REAL is not None
    prefixes = [sys.prefix, *filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(":"))]
    prefixes.append(str(Path(_REAL[0]).parents[1]))
    return dict(os.environ, AMENT_PREFIX_PATH=":".join(dict.fromkeys(prefixes)))


def _matches(key: str, fqn: str) -> bool:
    """Whether rcl gives a parameter-file section keyed ``key`` to the node ``fqn``."""
    name = fqn.rsplit("/", 1)[-1]
    return key in ("/**", f"/**/{name}", fqn) or f"/{key}" == fqn


def _effective(cmd: list[str], written: dict[str, dict]) -> tuple[dict, dict, list]:
    """(special remaps __node/__ns, the node's parameters from its files in order, the other
    remaps) of a node command line."""
    special, remaps, files = {}, [], []
    for flag, arg in zip(cmd, cmd[1:], strict=False):
        if flag == "-r":
            source, _, target = arg.partition(":=")
            if source in ("__node", "__ns"):
                special[source] = target
            else:
                remaps.append((source, target))
        elif flag == "--params-file":
            files.append(arg)
    namespace = special.get("__ns", "/").rstrip("/")
    fqn = f"{namespace}/{special['__node']}"
    params: dict = {}
    for path in files:
        if path in written:
            doc = written[path]
        else:
            with open(path, encoding="utf-8") as fh:
                doc = yaml.safe_load(fh)
        for key, body in doc.items():
            if _matches(key, fqn):
                params.update(flatten(body["ros__parameters"]))
    return {"fqn": fqn, "exe": cmd[0]}, params, remaps


LAUNCHES = [
    ("polishing.launch.yaml", []),
    ("polishing.launch.yaml", ["formulation:=classical", "duration:=0.5", "namespace:=/arm1"]),
    ("impact.launch.yaml", ["regulation:=ff_mpc", "duration:=1.0", "approach_height:=0.05"]),
    ("impact.launch.yaml", ["namespace:=/arm2"]),
]


@needs_launch_ros
@pytest.mark.parametrize(("name", "arguments"), LAUNCHES)
def test_launch_ros_builds_the_same_nodes_as_ffmpc_launch(tmp_path, name, arguments):
    """Every node: the same executable, fully qualified name, remaps and effective parameters
    (every file in order, the sections rcl gives the node) with the real launch_ros as with
    ``ffmpc launch``, and the same nodes end the launch."""
    assert _REAL is not None
    path = find_launch_file(name)
    done = subprocess.run(
        [_REAL[0], "-c", _LAUNCH_ROS_COMMANDS, path, *arguments],
        capture_output=True,
        text=True,
        timeout=120,
        env=_real_env(),
    )
    assert done.returncode == 0, done.stderr[-3000:]
    real = json.loads(done.stdout.splitlines()[-1])
    ours = load_launch_file(path, parse_launch_arguments(arguments)).nodes
    assert len(real) == len(ours)
    for node, theirs in zip(ours, real, strict=True):
        mine = _effective(node_command(node, tmp_path), {})
        assert _effective(theirs["cmd"], theirs["written"]) == mine, node.label
        assert ("Shutdown" in theirs["on_exit"]) == node.shutdown_on_exit, node.label
        assert mine[1], node.label  # parameters reached the node
        if node.name == "mpc":  # the scenario file's section reached it, in any namespace
            assert mine[1]["horizon"] == load_scenario("polishing").mpc.ocp.horizon


@needs_launch_ros
@pytest.mark.parametrize("namespace", ["", "/arm1"])
def test_ros2_launch_runs_the_graph_and_equals_the_runner(namespace):
    """The real ``ros2 launch ffmpc_ros polishing.launch.yaml`` gives the runner's metrics."""
    assert _REAL is not None
    python, ros2 = _REAL
    command = [ros2, "launch"]
    side = Path(python).resolve().parents[1]
    if side != Path(sys.prefix).resolve() and list(side.glob("lib/python*/site-packages/ros_*")):
        # a ros2 CLI in a venv of ROS wheels of its own: the nodes get this venv's libraries
        # (its wheels' bootstrap sets LD_LIBRARY_PATH), not the CLI venv's
        command += ["--launch-prefix", "env -u LD_LIBRARY_PATH -u _ROS_WHEELS_BOOTSTRAP_COMPLETE"]
    command += ["ffmpc_ros", "polishing.launch.yaml", "formulation:=classical", "duration:=0.1"]
    command += [f"namespace:={namespace}"] if namespace else []
    done = subprocess.run(
        command,
        capture_output=True,
        text=True,
        timeout=240,
        env=dict(_real_env(), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST"),
    )
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-3000:]
    line = next(x for x in output.splitlines() if "metrics: {" in x)
    metrics = json.loads(line[line.index("{") :])
    runner = run_polishing(load_scenario("polishing", {"mpc.formulation": "classical"}), 0.1)
    assert metrics["metrics_true"] == runner.metrics_true.to_dict()
    assert metrics["metrics_measured"] == runner.metrics_measured.to_dict()
    assert "was required: shutting down launched system" in output  # on_exit: shutdown


def test_parameter_values_are_evaluated_as_launch_ros_does(tmp_path):
    """A value with a substitution is read as YAML, a plain string stays a string, and what
    launch_ros refuses (a list of mixed types, not YAML) is refused here too."""
    text = (
        "launch:\n- arg: {name: x, default: '2'}\n"
        "- node:\n    pkg: ffmpc_ros\n    exec: mpc\n    param:\n"
        "    - {name: a, value: '1.0'}\n    - {name: b, value: ['1', '2']}\n"
        "    - {name: d, value: $(var x)}\n    - {name: e, value: 'on'}\n"
    )
    node = load_launch_file(_write(tmp_path, text)).nodes[0]
    assert node.parameters == (("a", "1.0"), ("b", ["1", "2"]), ("d", 2), ("e", "on"))
    mixed = text.replace("['1', '2']", "['1', '$(var x)']")
    with pytest.raises(LaunchError, match="parameter b: .* not a non-empty list of one type"):
        load_launch_file(_write(tmp_path, mixed))
    with pytest.raises(LaunchError, match="parameter d: '\\[1' is not a YAML value"):
        load_launch_file(_write(tmp_path, text), {"x": "[1"})


def test_a_bare_section_under_a_namespace_is_reported(tmp_path):
    """A file keyed ``mpc:`` reaches /mpc only: under /arm1 the launcher says so (and passes
    the file unchanged, as ros2 launch does)."""
    params = tmp_path / "p.yaml"
    params.write_text("mpc:\n  ros__parameters: {horizon: 7}\n")
    text = (
        "launch:\n- node: {pkg: ffmpc_ros, exec: mpc, name: mpc, namespace: /arm1, "
        f"param: [{{from: {params}}}]}}\n"
    )
    node = load_launch_file(_write(tmp_path, text)).nodes[0]
    assert unreached_sections(node) == [f"{params}: mpc"]
    assert str(params) in node_command(node, tmp_path)
    at_root = load_launch_file(_write(tmp_path, text.replace(", namespace: /arm1", ""))).nodes[0]
    assert unreached_sections(at_root) == []


def test_exits_and_stops_follow_ros2_launch(tmp_path, monkeypatch):
    """A node without on_exit may exit (here failing: 3) and the launch goes on; the node with
    ``on_exit: shutdown`` ends it; a node that ignores SIGINT gets SIGTERM after 5 s. The exit
    code is the first failure (ros2 launch would exit 0)."""
    import io

    from ffmpc_ros.launch import run_launch

    prefix = tmp_path / "prefix"
    (prefix / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (prefix / "share" / "ament_index" / "resource_index" / "packages" / "fakepkg").touch()
    (prefix / "lib" / "fakepkg").mkdir(parents=True)
    scripts = {
        "fail": "exit 3",
        "done": "sleep 2; exit 0",
        "stubborn": "trap 'echo got SIGINT' INT; trap 'exit 0' TERM; while :; do sleep 0.1; done",
    }
    for name, body in scripts.items():
        exe = prefix / "lib" / "fakepkg" / name
        exe.write_text(f"#!/bin/sh\n{body}\n")
        exe.chmod(0o755)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    text = (
        "launch:\n"
        "- node: {pkg: fakepkg, exec: fail, output: screen}\n"
        "- node: {pkg: fakepkg, exec: done, output: screen, on_exit: shutdown}\n"
        "- node: {pkg: fakepkg, exec: stubborn, output: screen}\n"
    )
    out = io.StringIO()
    code = run_launch(load_launch_file(_write(tmp_path, text)), log_dir=tmp_path / "l", out=out)
    lines = out.getvalue().splitlines()
    assert code == 3
    assert lines.index("[launch] fail exited with 3") < lines.index("[launch] done exited with 0")
    assert "[stubborn] got SIGINT" in lines
    assert "[launch] stubborn still running: SIGTERM" in lines
    assert not any("SIGKILL" in line for line in lines)
