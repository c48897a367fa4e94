"""Where the generated reference pages get their facts: the ONLY module of the manual that reads
the project's code. Each function returns plain records (dataclasses below); ``render.py`` turns
them into MyST Markdown. When a source moves (the configuration schema rebuilt as one typed
tree, a new topic table), re-point the function here and nothing else.

Sources, one function each:

* :func:`cli_tree` — ``ffmpc_ros.cli.build_parser()``, the argument parser of ``ffmpc`` (with the
  entry-point commands of ``studies/cli.py`` it loads: ``ffmpc study``, ``tune``, ``demo``,
  ``bench mpc|impact``);
* :func:`scenario_parameters` — ``ffmpc_core.scenario.SCHEMA`` (kind, unit, range, choices,
  description) with the defaults of the shipped ``polishing`` scenario
  (``ffmpc_ros.params.scenario_flat(load_scenario("polishing"))``) and of the dataclasses
  (``scenario_flat(Scenario("defaults"))``, what a node started alone runs);
* :func:`study_parameters` — ``ffmpc_core.impact.scenario.IMPACT_SCHEMA`` and
  ``EXPLORATION_SCHEMA`` (``ConfigSchema.params``, defaults ``ConfigSchema.flatten(root())``);
* :func:`shipped_scenarios` — ``ffmpc_core/scenarios/*.yaml`` through ``load_scenario`` /
  ``ConfigSchema.load``: the values each file sets;
* :func:`node_parameters` — ``ffmpc_ros.params.NODE_SPECS`` (what every node declares:
  ``node_scenario_names``, ``node_impact_names``, ``NodeSpec.graph_parameters``,
  ``NodeSpec.is_live``) — the same functions ``declare_node_parameters`` declares them with;
* :func:`topics` — ``ffmpc_ros.topics`` (``TOPICS``, ``IMPACT_GRAPH_TOPICS``, ``VIEW_TOPICS``,
  ``REFERENCE_TOPICS``, ``qos_class``, ``publisher_qos``, ``subscriber_qos``, ``clock_qos``)
  joined with the rate, subscribers and content columns of ``msgs_notes/topics.md`` (the
  contract ``tests/test_ros_layouts.py`` holds equal to ``topics.py``);
* :func:`services` — the service rows of ``msgs_notes/topics.md``;
* :func:`layouts` — ``ffmpc_ros.layouts.LAYOUTS``;
* :func:`messages` — the ``.msg`` files of ``msg/`` (the package ``ffmpc_msgs``).
"""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: The repository root (docs/_ext/ffmpc_docs/sources.py → three levels up).
ROOT = Path(__file__).resolve().parents[3]
#: The shipped scenario the reference quotes as "default" (``ffmpc run`` without a scenario
#: file runs ``polishing``; so do the studies).
DEFAULT_SCENARIO = "polishing"


# -- the command line ----------------------------------------------------------------------------
@dataclass(frozen=True)
class CliOption:
    """One argument of a command: flags (empty for a positional), metavar, help, default."""

    flags: tuple[str, ...]
    dest: str
    metavar: str
    help: str
    default: Any
    choices: tuple[str, ...]
    required: bool
    repeatable: bool
    takes_value: bool


@dataclass(frozen=True)
class CliCommand:
    """One command (``ffmpc``, ``ffmpc run``, ``ffmpc study impact``): its words, one-line help,
    description, usage line, arguments and sub-commands."""

    words: tuple[str, ...]
    help: str
    description: str
    usage: str
    arguments: tuple[CliOption, ...]
    subcommands: tuple[CliCommand, ...] = ()

    @property
    def name(self) -> str:
        return " ".join(self.words)

    def walk(self) -> list[CliCommand]:
        """This command and every sub-command below it, depth first."""
        out = [self]
        for sub in self.subcommands:
            out += sub.walk()
        return out


def _option(action: argparse.Action) -> CliOption:
    metavar = action.metavar
    if isinstance(metavar, tuple):
        metavar = " ".join(metavar)
    if metavar is None and action.nargs != 0:
        metavar = action.dest.upper() if action.option_strings else action.dest
    default = action.default
    if default is argparse.SUPPRESS:
        default = None
    choices = tuple(str(c) for c in action.choices) if action.choices else ()
    return CliOption(
        flags=tuple(action.option_strings),
        dest=action.dest,
        metavar=str(metavar or ""),
        help=(action.help or "").replace("%%", "%") if action.help != argparse.SUPPRESS else "",
        default=default,
        choices=choices,
        required=bool(action.required) or not action.option_strings,
        repeatable=isinstance(action, argparse._AppendAction),
        takes_value=action.nargs != 0,
    )


def _command(parser: argparse.ArgumentParser, words: tuple[str, ...], help_: str) -> CliCommand:
    arguments: list[CliOption] = []
    subs: list[CliCommand] = []
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            for name, sub in action.choices.items():
                subs.append(_command(sub, (*words, name), helps.get(name, "")))
            continue
        arguments.append(_option(action))
    usage = " ".join(parser.format_usage().split())
    usage = usage.removeprefix("usage: ")
    return CliCommand(
        words=words,
        help=help_,
        description=parser.description or "",
        usage=usage,
        arguments=tuple(arguments),
        subcommands=tuple(subs),
    )


def cli_tree() -> CliCommand:
    """The whole ``ffmpc`` command line, from ``ffmpc_ros.cli.build_parser()`` (the entry-point
    commands included: they must be installed, ``make install``)."""
    import os

    os.environ.setdefault("COLUMNS", "100")  # usage lines do not depend on the terminal
    from ffmpc_ros.cli import build_parser

    parser = build_parser()
    return _command(parser, ("ffmpc",), parser.description or "")


# -- parameters ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Param:
    """One configuration parameter: dotted name, kind, unit, range or choices, default(s) and
    meaning. ``defaults`` maps a label ("polishing.yaml", "dataclass") to a value; ``live``: a
    node changes it while it runs."""

    name: str
    kind: str
    unit: str
    range: tuple[float, float] | None
    choices: tuple[Any, ...]
    length: int | str | None
    optional: bool
    description: str
    expected: str
    defaults: dict[str, Any] = field(default_factory=dict)
    live: bool = False


def _param(spec: Any, defaults: dict[str, Any], live: bool = False) -> Param:
    return Param(
        name=spec.name,
        kind=spec.kind,
        unit=spec.unit,
        range=spec.range,
        choices=tuple(spec.choices),
        length=spec.length,
        optional=spec.optional,
        description=spec.description,
        expected=spec.expected(),
        defaults=defaults,
        live=live,
    )


def _live_scenario_names() -> set[str]:
    """The scenario names some node applies while it runs (``NodeSpec.live``, mapped back from
    the node's ROS names)."""
    from ffmpc_core.scenario import Scenario
    from ffmpc_ros.params import NODE_SPECS, node_scenario_names, scenario_flat

    flat = scenario_flat(Scenario(name="defaults"))
    live = set()
    for spec in NODE_SPECS.values():
        for ros, name in node_scenario_names(spec, flat).items():
            if spec.is_live(ros):
                live.add(name)
    return live


def scenario_parameters() -> list[Param]:
    """Every scenario parameter of the node graph and the polishing studies
    (``ffmpc_core.scenario.SCHEMA``), in the schema's order, with the value of the shipped
    ``polishing`` scenario and the dataclass default."""
    from ffmpc_core.scenario import SCHEMA, Scenario, load_scenario
    from ffmpc_ros.params import scenario_flat

    shipped = scenario_flat(load_scenario(DEFAULT_SCENARIO))
    built_in = scenario_flat(Scenario(name="defaults"))
    live = _live_scenario_names()
    out = []
    for name, spec in SCHEMA.items():
        defaults = {f"{DEFAULT_SCENARIO}.yaml": shipped.get(name), "built-in": built_in.get(name)}
        out.append(_param(spec, defaults, name in live))
    return out


@dataclass(frozen=True)
class StudySchema:
    """The parameters of a study configured by one dataclass tree (``ConfigSchema``)."""

    key: str
    title: str
    scenario_file: str
    command: str
    params: tuple[Param, ...]


def study_parameters() -> list[StudySchema]:
    """The impact and exploration studies' schemas (``IMPACT_SCHEMA``, ``EXPLORATION_SCHEMA``)
    with the dataclass defaults (the shipped ``impact.yaml`` / ``explore.yaml`` hold the same
    values: ``tests/test_study_config.py``)."""
    from ffmpc_core.impact.scenario import (
        EXPLORATION_SCHEMA,
        IMPACT_SCHEMA,
        ExplorationConfig,
        ImpactStudyConfig,
    )

    out = []
    for key, title, schema, root, command in (
        ("impact", "Impact study", IMPACT_SCHEMA, ImpactStudyConfig, "ffmpc study impact"),
        (
            "explore",
            "Exploration study",
            EXPLORATION_SCHEMA,
            ExplorationConfig,
            "ffmpc study explore",
        ),
    ):
        defaults = schema.flatten(root())
        params = tuple(
            _param(spec, {"default": defaults[name]}) for name, spec in schema.params.items()
        )
        out.append(StudySchema(key, title, f"{key}.yaml", command, params))
    return out


@dataclass(frozen=True)
class ShippedScenario:
    """A scenario file of ``ffmpc_core/scenarios/`` and the values it sets that differ from the
    reference scenario's (``polishing``), or every value for a study file."""

    name: str
    kind: str  # "graph" (load_scenario) or the study key
    differences: dict[str, Any]


def shipped_scenarios() -> list[ShippedScenario]:
    """Every shipped scenario file and how it differs from ``polishing`` (graph scenarios)."""
    from ffmpc_core.scenario import SCENARIO_DIR, STUDY_SCENARIOS, load_scenario
    from ffmpc_ros.params import scenario_flat

    reference = scenario_flat(load_scenario(DEFAULT_SCENARIO))
    out = []
    for path in sorted(SCENARIO_DIR.glob("*.yaml")):
        if path.stem in STUDY_SCENARIOS:
            out.append(ShippedScenario(path.stem, path.stem, {}))
            continue
        flat = scenario_flat(load_scenario(path.stem))
        diff = {k: v for k, v in flat.items() if reference.get(k) != v}
        out.append(ShippedScenario(path.stem, "graph", diff))
    return out


@dataclass(frozen=True)
class NodeParam:
    """One ROS parameter of a node: its ROS name, where it comes from (``scenario``: a
    scenario name; ``impact``: an impact-study name; ``graph``: the node's own), type, range,
    default, description, and whether it is writable while the node runs."""

    ros_name: str
    origin: str
    source_name: str
    kind: str
    unit: str
    range: tuple[float, float] | None
    default: Any
    description: str
    live: bool


@dataclass(frozen=True)
class NodeParams:
    """Every parameter one node declares (``NODE_SPECS[node]``)."""

    node: str
    section: str | None
    params: tuple[NodeParam, ...]


def _graph_kind(default: Any) -> str:
    if isinstance(default, bool):
        return "bool"
    if isinstance(default, int):
        return "int"
    if isinstance(default, float):
        return "float"
    if isinstance(default, str):
        return "str"
    if isinstance(default, list):
        return "floats"
    return "floats"  # declared by type only (Parameter.Type.DOUBLE_ARRAY): no default


def node_parameters() -> list[NodeParams]:
    """What each node of ``ffmpc_ros.params.NODE_SPECS`` declares, in the order
    ``declare_node_parameters`` declares it (scenario names, impact-study names, graph
    parameters), with the defaults a node started alone has."""
    from ffmpc_core.impact.scenario import IMPACT_SCHEMA
    from ffmpc_core.scenario import SCHEMA, Scenario
    from ffmpc_ros.params import (
        NODE_SPECS,
        impact_flat,
        node_impact_names,
        node_scenario_names,
        scenario_flat,
    )

    flat = scenario_flat(Scenario(name="defaults"))
    impact_defaults = impact_flat()
    out = []
    for node, spec in NODE_SPECS.items():
        rows: list[NodeParam] = []
        for ros, name in node_scenario_names(spec, flat).items():
            p = SCHEMA[name]
            rows.append(
                NodeParam(
                    ros,
                    "scenario",
                    name,
                    p.kind,
                    p.unit,
                    p.range,
                    flat[name],
                    p.description,
                    spec.is_live(ros),
                )
            )
        for name in node_impact_names(spec):
            p = IMPACT_SCHEMA.params[name]
            rows.append(
                NodeParam(
                    name,
                    "impact",
                    name,
                    p.kind,
                    p.unit,
                    p.range,
                    impact_defaults[name],
                    p.description,
                    False,
                )
            )
        for g in spec.graph_parameters:
            default = g.default if isinstance(g.default, bool | int | float | str | list) else None
            rows.append(
                NodeParam(
                    g.name,
                    "graph",
                    g.name,
                    _graph_kind(g.default),
                    "",
                    g.range,
                    default,
                    g.description,
                    False,
                )
            )
        out.append(NodeParams(node, spec.section, tuple(rows)))
    return out


# -- topics, services, layouts, messages ---------------------------------------------------------
NOTES = ROOT / "msgs_notes"


def _table_rows(text: str) -> list[list[str]]:
    """The rows of every Markdown table of ``text`` (cells stripped; separator rows left out)."""
    rows = []
    for line in text.splitlines():
        if line.startswith("|") and not re.match(r"^\|\s*-", line):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows


@dataclass(frozen=True)
class Qos:
    """A QoS profile in words."""

    reliability: str
    durability: str
    depth: int

    @property
    def text(self) -> str:
        return f"{self.reliability}, {self.durability}, depth {self.depth}"


def _qos(profile: Any) -> Qos:
    return Qos(profile.reliability.name, profile.durability.name, int(profile.depth))


@dataclass(frozen=True)
class Topic:
    """One topic of the contract: relative name (as in ``ffmpc_ros.topics``), type, publisher,
    the graphs it belongs to, QoS class and profiles, and the notes' rate, subscribers and
    content."""

    name: str
    type: str
    publisher: str
    graphs: tuple[str, ...]
    qos_class: str
    publisher_qos: Qos
    subscriber_qos_lockstep: Qos
    subscriber_qos_real_time: Qos
    rate: str
    subscribers: str
    content: str


#: The graphs of the contract, as ``ffmpc_ros.topics`` lists them.
GRAPHS = (
    ("polishing", "TOPICS"),
    ("impact", "IMPACT_GRAPH_TOPICS"),
    ("live view", "VIEW_TOPICS"),
    ("operator input", "REFERENCE_TOPICS"),
)


def _notes_topic_rows() -> dict[tuple[str, str], list[str]]:
    """{(topic, publisher): [type, publisher, subscribers, rate, QoS, content]} of
    ``msgs_notes/topics.md``."""
    rows = _table_rows((NOTES / "topics.md").read_text(encoding="utf-8"))
    out = {}
    for r in rows:
        if len(r) == 7 and "/msg/" in r[1]:
            out[(r[0].strip("`"), r[2].strip("`"))] = r[1:]
    return out


def topics() -> list[Topic]:
    """Every topic of ``ffmpc_ros.topics`` (the graphs of :data:`GRAPHS`), once per (name,
    publisher), with its QoS from the module's profile functions."""
    from ffmpc_ros import topics as t

    notes = _notes_topic_rows()
    order: list[tuple[str, str, str]] = []
    graphs: dict[tuple[str, str], list[str]] = {}
    for graph, attr in GRAPHS:
        for name, ros_type, publisher in getattr(t, attr):
            key = (name, publisher)
            if key not in graphs:
                order.append((name, ros_type, publisher))
                graphs[key] = []
            graphs[key].append(graph)
    out = []
    for name, ros_type, publisher in order:
        if name == t.CLOCK:
            pub = sub_lock = sub_rt = _qos(t.clock_qos())
            kind = "clock"
        else:
            kind = t.qos_class(name)
            pub = _qos(t.publisher_qos(name))
            sub_lock = _qos(t.subscriber_qos(True, name))
            sub_rt = _qos(t.subscriber_qos(False, name))
        row = notes.get((name, publisher), ["", "", "", "", "", ""])
        out.append(
            Topic(
                name,
                ros_type,
                publisher,
                tuple(graphs[(name, publisher)]),
                kind,
                pub,
                sub_lock,
                sub_rt,
                rate=row[3],
                subscribers=row[2],
                content=row[5],
            )
        )
    return out


@dataclass(frozen=True)
class GraphOverride:
    """A QoS override the bring-up sets on its own nodes (``topics.GRAPH_OVERRIDES``)."""

    qos_class: str
    role: str
    policies: dict[str, Any]


def graph_overrides() -> list[GraphOverride]:
    """``ffmpc_ros.topics.GRAPH_OVERRIDES``: what ``ffmpc run`` / the launch files change."""
    from ffmpc_ros.topics import GRAPH_OVERRIDES

    return [
        GraphOverride(kind, role, dict(policies))
        for kind, roles in GRAPH_OVERRIDES.items()
        for role, policies in roles.items()
    ]


def absolute_names() -> tuple[str, ...]:
    """The names that stay absolute under a namespace (``topics.ABSOLUTE_NAMES``)."""
    from ffmpc_ros.topics import ABSOLUTE_NAMES

    return tuple(sorted(ABSOLUTE_NAMES))


@dataclass(frozen=True)
class Service:
    """A service row of ``msgs_notes/topics.md``: name, type, server, effect."""

    name: str
    type: str
    server: str
    effect: str


def services() -> list[Service]:
    """The services of the contract (``msgs_notes/topics.md``; ``tests/test_ros_layouts.py``
    checks the names of ``ffmpc_ros.topics``)."""
    rows = _table_rows((NOTES / "topics.md").read_text(encoding="utf-8"))
    return [
        Service(r[0].strip("`"), r[1].strip("`"), r[2].strip("`"), r[3])
        for r in rows
        if len(r) == 4 and "/srv/" in r[1]
    ]


@dataclass(frozen=True)
class LayoutField:
    """One field of an array layout."""

    name: str
    size: str
    unit: str
    meaning: str


@dataclass(frozen=True)
class Layout:
    """A ``std_msgs/Float64MultiArray`` layout (``ffmpc_ros.layouts.ArrayLayout``)."""

    name: str
    version: int
    label: str
    topics: tuple[str, ...]
    fields: tuple[LayoutField, ...]


def layouts() -> list[Layout]:
    """Every layout of ``ffmpc_ros.layouts.LAYOUTS`` and the topics that carry it (the notes'
    section titles, ``## name (version N) — `topic```)."""
    from ffmpc_ros.layouts import LAYOUTS

    text = (NOTES / "layouts.md").read_text(encoding="utf-8")
    carried: dict[str, tuple[str, ...]] = {}
    for match in re.finditer(r"^## (\w+) \(version \d+\) — (.+)$", text, re.M):
        carried[match.group(1)] = tuple(re.findall(r"`([^`]+)`", match.group(2)))
    return [
        Layout(
            name,
            layout.version,
            layout.label,
            carried.get(name, ()),
            tuple(LayoutField(f.name, str(f.size), f.unit, f.meaning) for f in layout.fields),
        )
        for name, layout in LAYOUTS.items()
    ]


@dataclass(frozen=True)
class MessageDefinition:
    """An interface definition file of the project's message packages."""

    package: str
    kind: str  # msg, srv, action
    name: str
    path: str  # relative to the repository root
    text: str

    @property
    def full_name(self) -> str:
        return f"{self.package}/{self.kind}/{self.name}"


def messages() -> list[MessageDefinition]:
    """Every ``.msg``/``.srv``/``.action`` of ``msg/`` (``ffmpc_msgs``) and of the packages
    built beside it (``msg/<package>/<kind>/``)."""
    out = []
    base = ROOT / "msg"
    for path in sorted(base.glob("*.msg")):
        out.append(_definition("ffmpc_msgs", "msg", path))
    for path in sorted(base.glob("*/*/*")):
        if path.suffix in (".msg", ".srv", ".action"):
            out.append(_definition(path.parts[-3], path.suffix[1:], path))
    return out


def _definition(package: str, kind: str, path: Path) -> MessageDefinition:
    return MessageDefinition(
        package, kind, path.stem, str(path.relative_to(ROOT)), path.read_text(encoding="utf-8")
    )


def is_finite_number(value: Any) -> bool:
    """Whether ``value`` is a finite int or float (not a bool)."""
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
