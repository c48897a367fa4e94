"""The node graph as data: which node runs which class, and the parameter file they all read.

Shared by the bring-up (``ffmpc_ros.bringup``), the real-time runner (``ffmpc_ros.realtime``) and
the bag recorder and re-run (``ffmpc_ros.bag``); it imports none of them, so none of them has
to import another for these.
"""

from __future__ import annotations

import importlib
import os
import shutil
from collections.abc import Mapping, Sequence
from typing import Any

import yaml

from ffmpc_core.config import ContactConfig
from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import (
    ANY_NAMESPACE,
    CONTACT_DIMENSION,
    SCHEMA,
    SECTIONS,
    WILDCARD,
    Scenario,
    read_sections,
)
from ffmpc_ros import topics
from ffmpc_ros.params import NODE_SPECS, node_parameter_values, node_scenario_names, scenario_flat

#: node name → "module:class"; the module's ``main`` is the executable.
NODES: dict[str, str] = {
    "plant": "ffmpc_ros.plant_node:PlantNode",
    "joint_sensor": "ffmpc_ros.joint_sensor_node:JointSensorNode",
    "ft_sensor": "ffmpc_ros.ft_sensor_node:FtSensorNode",
    "mpc": "ffmpc_ros.mpc_node:MpcNode",
    "pid": "ffmpc_ros.pid_node:PidNode",
    # robot_description, /tf and /tf_static (reads the joint states only: the loop does not
    # wait for it, but the plant's start counts its /clock readers)
    "state_publisher": "ffmpc_ros.state_publisher_node:StatePublisherNode",
}
METRICS_NODE = "ffmpc_ros.metrics_node:MetricsNode"
#: The LFC-law node (the agimus linear_feedback_controller's law), the PID's place in a graph
#: run with ``low_level="lfc"`` (ros2_control's interfaces only).
LFC_NODE = "ffmpc_ros.lfc_node:LfcNode"
#: The low-level nodes a polishing graph can run (``node_table``).
LOW_LEVELS = ("pid", "lfc")


def node_table(interfaces: str = topics.FFMPC_INTERFACES, low_level: str = "pid") -> dict[str, str]:
    """The node table of a polishing graph: :data:`NODES`, with the LFC-law node ``lfc`` in the
    PID's place for ``low_level="lfc"``; ConfigError for an unknown value, or for the LFC-law
    node without ros2_control's interfaces (it speaks only those)."""
    if interfaces not in topics.INTERFACES:
        raise ConfigError(
            f"interfaces must be one of {list(topics.INTERFACES)}, got {interfaces!r}"
        )
    if low_level not in LOW_LEVELS:
        raise ConfigError(f"low_level must be one of {list(LOW_LEVELS)}, got {low_level!r}")
    if low_level == "pid":
        return dict(NODES)
    if interfaces != topics.ROS2_CONTROL_INTERFACES:
        raise ConfigError(
            "the LFC-law node reads linear_feedback_controller_msgs/Control: it needs "
            f"interfaces={topics.ROS2_CONTROL_INTERFACES!r}"
        )
    return {
        ("lfc" if name == "pid" else name): (LFC_NODE if name == "pid" else path)
        for name, path in NODES.items()
    }


#: A service request without an answer after this long (wall s) is sent again: a service
#: reports ready once its request reader matched ours, but a response sent before the server's
#: writer matched our reader is lost, and the request then never completes (ROS 2's service
#: discovery race). The bring-up's parameter fetch retried so; the recorder's did not, and a
#: recorder that never gets a node's parameters holds the plant's start for good (the suspected
#: cause of the runs that did not start in test_bag_graph and test_live_view, never seen alone).
SERVICE_RETRY = 3.0


def load_node_class(path: str) -> Any:
    """The class named by a ``"module:class"`` entry of :data:`NODES` (imports the module)."""
    module, _, cls = path.partition(":")
    return getattr(importlib.import_module(module), cls)


def graph_parameters(
    scenario: Scenario,
    lockstep: bool,
    duration: float,
    namespace: str | None = topics.ROOT_NAMESPACE,
    interfaces: str = topics.FFMPC_INTERFACES,
    low_level: str = "pid",
) -> dict[str, dict]:
    """{node: {ROS name: value}} of every node of the graph under ``namespace``, metrics node
    included, with the graph's QoS overrides (``topics.graph_qos_overrides``: the sensor topics
    reliable, lockstep and real time alike); ``interfaces`` and ``low_level``:
    :func:`node_table` (given to the nodes only when they differ from the defaults)."""
    nodes = node_table(interfaces, low_level)
    graph: dict[str, Any] = {
        "lockstep": lockstep,
        "duration": float(duration),
        "start_delay": 0.0,  # the start barrier makes sure of the matches (no settling time)
        "start_subscribers": 2,  # the joint-sensor and metrics nodes
        # every node's two /clock readers: the plant's own, the other nodes' and the metrics'
        "start_clock_subscribers": topics.CLOCK_READERS_PER_NODE * (len(nodes) + 1),
        # the lockstep start barrier: every node of the graph, the metrics node included
        "start_nodes": len(nodes) + 1,
        "wait_for_metrics": True,  # the metrics node has matched every topic it records
    }
    if interfaces != topics.FFMPC_INTERFACES:
        graph["interfaces"] = interfaces
    if low_level != "pid":
        graph["low_level"] = low_level
    names = [*nodes, "metrics"]
    qos = topics.graph_qos_overrides(namespace)
    return {n: {**node_parameter_values(n, scenario, **graph), **qos} for n in names}


def file_parameters(
    path: str | os.PathLike, node: str, namespace: str | None = topics.ROOT_NAMESPACE
) -> dict[str, Any]:
    """``{ROS name: value as written}`` that rcl gives node ``node`` under ``namespace`` from
    the scenario file ``path``: the names of its ``/**`` section and of the node's own section
    (``/**/NODE`` reaches the node in any namespace, ``NODE`` at the root only). ConfigError
    for a section a scenario file does not have (``ffmpc_core.scenario.read_parameter_file``
    refuses it too), which could reach the node otherwise."""
    root = topics.normalize_namespace(namespace) == topics.ROOT_NAMESPACE
    reaching = [WILDCARD, ANY_NAMESPACE + node] + ([node] if root else [])
    sections = read_sections(path)
    known = {WILDCARD, *SECTIONS, *(ANY_NAMESPACE + s for s in SECTIONS)}
    unknown = sorted(set(sections) - known)
    if unknown:
        raise ConfigError(f"{path}: unknown node sections {unknown}; expected {SECTIONS}")
    out: dict[str, Any] = {}
    for key in reaching:
        out.update(sections.get(key, {}))
    return out


def run_file_values(node: str, values: Mapping[str, Any], given: Mapping[str, Any]) -> dict:
    """``values`` (node ``node``'s ``{ROS name: value}``) without the scenario parameters that
    ``given`` (what the node reads from the scenario file, :func:`file_parameters`) holds with
    the same value, as the schema reads both (bit for bit: ``repr`` of the checked values)."""
    names = node_scenario_names(NODE_SPECS[node], scenario_flat(Scenario(name="names")))
    dimension = next(
        (values[r] for r, name in names.items() if name == CONTACT_DIMENSION and r in values),
        ContactConfig.dimension,
    )
    out = {}
    for ros, value in values.items():
        name = names.get(ros)
        if name is None or ros not in given or not _same(name, given[ros], value, dimension):
            out[ros] = value
    return out


def _same(name: str, a: Any, b: Any, dimension: int) -> bool:
    """Whether scenario parameter ``name`` reads ``a`` and ``b`` as the same value."""
    try:
        return repr(SCHEMA[name].check(a, dimension)) == repr(SCHEMA[name].check(b, dimension))
    except ConfigError:
        return False


def write_graph_params(
    params: Mapping[str, Mapping[str, Any]],
    directory: str,
    namespace: str | None = topics.ROOT_NAMESPACE,
    scenario_file: str = "",
) -> list[str]:
    """The run's parameter files, written into ``directory``, and the ROS arguments that give
    them to a node, in this order: with a ``scenario_file`` (``Scenario.source``), a copy of it
    as it is (each node reads its values there, as ``ros2 launch`` gives it), then the run's
    file (:func:`write_params_file`) with what the copy does not give each node
    (:func:`run_file_values`: the graph parameters, the other sections' values it declares,
    the values the run changed); without one, the run's file with every value."""
    path = os.path.join(directory, "graph_params.yaml")
    if not scenario_file:
        write_params_file(params, path, namespace)
        return ["--params-file", path]
    copy = os.path.join(directory, "scenario.yaml")
    shutil.copyfile(scenario_file, copy)
    rest = {
        node: run_file_values(node, values, file_parameters(copy, node, namespace))
        for node, values in params.items()
    }
    write_params_file(rest, path, namespace)
    return ["--params-file", copy, "--params-file", path]


def split_parameter_args(ros_args: Sequence[str]) -> tuple[dict[str, Any], list[str]]:
    """The ``-p NAME:=VALUE`` (``--param``) pairs of a node's ROS arguments as ``{NAME: value}``
    (read as rcl reads them, ``ffmpc_core.values.load_yaml``), and the other arguments. The
    bring-up writes the values into the node's section of the run's file: rcl takes a ``-p``
    as a ``/**`` value, which the scenario file's ``/**/NODE`` section, given before it, wins
    over. ConfigError for a ``-p`` that is not ``NAME:=VALUE`` with a YAML value."""
    from ffmpc_core.values import load_yaml

    values: dict[str, Any] = {}
    rest: list[str] = []
    args = iter(ros_args)
    for arg in args:
        if arg not in ("-p", "--param"):
            rest.append(arg)
            continue
        assignment = next(args, "")
        name, eq, text = assignment.partition(":=")
        try:
            values[name] = load_yaml(text)
        except yaml.YAMLError:
            eq = ""
        if not name or not eq:
            raise ConfigError(f"{arg} {assignment!r}: expected NAME:=VALUE (a YAML value)")
    return values, rest


def nested_parameters(flat: Mapping[str, Any]) -> dict:
    """``{"a.b": 1}`` → ``{"a": {"b": 1}}``: dotted ROS parameter names as a YAML tree."""
    out: dict = {}
    for key, value in flat.items():
        parts = key.split(".")
        d = out
        for p in parts[:-1]:
            d = d.setdefault(p, {})
        d[parts[-1]] = value
    return out


def params_file_key(node: str, namespace: str | None = topics.ROOT_NAMESPACE) -> str:
    """The section key of ``node`` in a parameter file for a graph under ``namespace``: the bare
    name at the root (rcl reads ``plant`` as ``/plant``), the fully qualified name otherwise
    (``/arm1/plant``: a bare name never matches a namespaced node)."""
    ns = topics.normalize_namespace(namespace)
    return node if ns == topics.ROOT_NAMESPACE else f"{ns}/{node}"


def write_params_file(
    params: Mapping[str, Mapping[str, Any]],
    path: str,
    namespace: str | None = topics.ROOT_NAMESPACE,
) -> None:
    """A ROS 2 parameter file with one section per node (:func:`params_file_key`), each
    node's ``{ROS name: value}`` written as it is: dotted names stay dotted keys
    (``contact.stiffness: 10000.0``; rcl reads a dotted key as the parameter of that name,
    as it reads the nested form)."""
    doc = {
        params_file_key(node, namespace): {"ros__parameters": dict(values)}
        for node, values in params.items()
    }
    with open(path, "w", encoding="utf-8") as fh:
        yaml.safe_dump(doc, fh, sort_keys=False)
