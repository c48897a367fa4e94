"""MyST Markdown of the generated reference pages, from the records of ``sources.py`` and
``equations.py``. Pure text: nothing here reads the project's code."""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from typing import Any

from . import equations as eq
from . import sources as src

_ESCAPE = re.compile(r"([\\`*_\[\]<>|$~])")


def esc(text: Any) -> str:
    """``text`` as literal Markdown inline text (one line; table-safe)."""
    return _ESCAPE.sub(r"\\\1", " ".join(str(text).split()))


def code(text: Any) -> str:
    """``text`` as inline code (one line; table-safe)."""
    body = " ".join(str(text).split()).replace("|", "\\|")
    fence = "``" if "`" in body else "`"
    pad = " " if body.startswith("`") or body.endswith("`") else ""
    return f"{fence}{pad}{body}{pad}{fence}"


def slug(text: str) -> str:
    """A label for a heading target (letters, digits and dashes)."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-")


def table(header: Iterable[str], rows: Iterable[Iterable[str]]) -> str:
    """A Markdown table; cells are used as given (escape them first)."""
    head = list(header)
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def number(value: float) -> str:
    """A number as the schema writes it (``1e+09``, ``0.001``, ``inf``)."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, int):
        return str(value)
    if math.isinf(value):
        return "∞" if value > 0 else "−∞"
    return f"{value:g}"


def value(v: Any) -> str:
    """A parameter value as inline code (YAML-like: true, null, lists in brackets)."""
    if v is None:
        return code("null")
    if isinstance(v, bool):
        return code(str(v).lower())
    if isinstance(v, int | float):
        return code(number(v))
    if isinstance(v, list | tuple):
        return code(
            "[" + ", ".join(number(x) if isinstance(x, int | float) else str(x) for x in v) + "]"
        )
    if isinstance(v, str):
        return code(repr(v)) if v == "" else code(v)
    return code(v)


def _strip_links(text: str) -> str:
    """Markdown links of the notes (relative to ``msgs_notes/``) as their text."""
    return re.sub(r"\[([^\]]+)\]\([^)]+\)", r"\1", text)


def notes_md(text: str) -> str:
    """A cell of ``msgs_notes/`` (Markdown already) for a table here: links as their text
    (they point into the notes), ``<`` escaped; inline code and emphasis kept."""
    parts = re.split(r"(`[^`]*`)", _strip_links(text))
    return "".join(p if k % 2 else p.replace("<", "\\<") for k, p in enumerate(parts)).replace(
        "|", "\\|"
    )


# -- the command line ----------------------------------------------------------------------------
def cli_page(root: src.CliCommand) -> str:
    """Every command of ``ffmpc``, depth first: usage, description, sub-commands, arguments."""
    out = []
    for cmd in root.walk():
        level = "#" * min(1 + len(cmd.words), 6)
        out.append(f"({slug('cli ' + cmd.name)})=\n{level} `{cmd.name}`\n")
        if cmd.help and cmd.help != cmd.description:
            out.append(esc(cmd.help) + "\n")
        if cmd.description:
            out.append(esc(cmd.description) + "\n")
        out.append(f"```text\n{cmd.usage}\n```\n")
        if cmd.subcommands:
            rows = [
                [f"{{ref}}`{sub.words[-1]} <{slug('cli ' + sub.name)}>`", esc(sub.help)]
                for sub in cmd.subcommands
            ]
            out.append(table(["command", "what it does"], rows))
        args = [a for a in cmd.arguments]
        if args:
            out.append(
                table(["argument", "value", "default", "description"], [_cli_row(a) for a in args])
            )
    return "\n".join(out)


def _cli_row(a: src.CliOption) -> list[str]:
    name = ", ".join(code(f) for f in a.flags) if a.flags else code(a.metavar or a.dest)
    if a.choices:
        kind = " \\| ".join(code(c) for c in a.choices)
    elif a.takes_value and a.flags:
        kind = code(a.metavar)
    else:
        kind = "flag" if a.flags else "required" if a.required else ""
    if a.repeatable:
        kind += " (repeatable)"
    default = "" if a.default in (None, False) or not a.flags else value(a.default)
    return [name, kind, default, esc(a.help)]


# -- parameters ----------------------------------------------------------------------------------
_KIND = {
    "bool": "bool",
    "int": "integer",
    "float": "number",
    "str": "string",
    "floats": "list of numbers",
    "float_or_floats": "number or list",
    "command_delay": "`pid`, `measured` or s",
}


def kind_text(p: src.Param) -> str:
    """The kind in words, with the list length."""
    text = _KIND.get(p.kind, p.kind)
    if p.kind in ("floats", "float_or_floats") and p.length is not None:
        text += f" ({p.length})" if isinstance(p.length, int) else f" ({code(p.length)})"
    if p.optional:
        text += " or null"
    return text


def range_text(p: src.Param | src.NodeParam) -> str:
    """Range or choices in words."""
    choices = getattr(p, "choices", ())
    if choices:
        return ", ".join(value(c) for c in choices)
    if p.range is None:
        return ""
    lo, hi = p.range
    if math.isinf(hi) or hi >= 1e300:
        return f"≥ {number(lo)}"
    return f"[{number(lo)}, {number(hi)}]"


def _group(name: str) -> str:
    head, _, rest = name.partition(".")
    if head == "mpc" and rest.startswith(("contact.", "weights.")):
        parts = name.split(".")
        return ".".join(parts[:3]) if parts[1] == "weights" else "mpc.contact"
    return head if rest else "shared"


_GROUP_TITLES = {
    "shared": "Shared by every node (`/**`)",
    "task": "`task`: the task (shared, `/**`)",
    "plant": "`plant`: the simulated robot and table",
    "joint_sensor": "`joint_sensor`: joint measurement (eq 30)",
    "ft_sensor": "`ft_sensor`: force measurement (eq 32)",
    "mpc": "`mpc`: the model predictive controller",
    "mpc.contact": "`mpc.contact`: the contact model of the MPC",
    "pid": "`pid`: the torque PID and the low-level loop",
}


def scenario_page(params: list[src.Param]) -> str:
    """The scenario parameters, one table per section (``mpc.weights.<formulation>`` apart)."""
    groups: dict[str, list[src.Param]] = {}
    for p in params:
        groups.setdefault(_group(p.name), []).append(p)
    out = []
    for key, rows in groups.items():
        title = _GROUP_TITLES.get(key)
        if title is None and key.startswith("mpc.weights."):
            title = f"`{key}`: cost weights of the {key.split('.')[-1].replace('_', '-')} MPC"
        out.append(f"({slug('param ' + key)})=\n### {title or code(key)}\n")
        out.append(
            table(
                [
                    "parameter",
                    "type",
                    "unit",
                    "range",
                    f"default ({src.DEFAULT_SCENARIO}.yaml)",
                    "description",
                ],
                [_scenario_row(p) for p in rows],
            )
        )
    return "\n".join(out)


def _scenario_row(p: src.Param) -> list[str]:
    shipped = p.defaults.get(f"{src.DEFAULT_SCENARIO}.yaml")
    built_in = p.defaults.get("built-in")
    default = value(shipped)
    if built_in != shipped:
        default += f" (built-in {value(built_in)})"
    description = esc(p.description)
    if p.live:
        description = "**live** — " + description
    return [code(p.name), kind_text(p), esc(p.unit), range_text(p), default, description]


def study_page(study: src.StudySchema) -> str:
    """The parameters of one ``ConfigSchema`` study."""
    rows = [
        [
            code(p.name),
            kind_text(p),
            esc(p.unit),
            range_text(p),
            value(p.defaults["default"]),
            esc(p.description),
        ]
        for p in study.params
    ]
    return table(["parameter", "type", "unit", "range", "default", "description"], rows)


def shipped_page(scenarios: list[src.ShippedScenario]) -> str:
    """The shipped scenario files and what each changes from the reference scenario."""
    rows = []
    for s in scenarios:
        if s.kind != "graph":
            what = f"the {esc(s.kind)} study's scenario (its parameters below; defaults as listed)"
        elif s.name == src.DEFAULT_SCENARIO:
            what = "the reference scenario (the defaults above)"
        elif not s.differences:
            what = f"the same values as `{src.DEFAULT_SCENARIO}`"
        else:
            what = "; ".join(f"{code(k)} = {value(v)}" for k, v in s.differences.items())
        rows.append([code(s.name), what])
    return table(["scenario", f"what it sets that differs from `{src.DEFAULT_SCENARIO}`"], rows)


_ORIGIN = {"scenario": "scenario", "impact": "impact study", "graph": "node"}


def node_page(nodes: list[src.NodeParams]) -> str:
    """Every node's parameters: the scenario and study values it declares, then its own."""
    out = []
    for n in nodes:
        out.append(f"({slug('node ' + n.node)})=\n### `{n.node}`\n")
        section = (
            f"section `{n.section}` of a scenario file" if n.section else "no section of its own"
        )
        out.append(f"Executable `ros2 run ffmpc_ros {n.node}`; {section}.\n")
        declared = [p for p in n.params if p.origin != "graph"]
        if declared:
            rows = []
            for p in declared:
                where = "scenario" if p.origin == "scenario" else "impact study"
                target = (
                    slug("param " + _group(p.source_name))
                    if p.origin == "scenario"
                    else "params-impact"
                )
                source = f"{where} {{ref}}`{p.source_name} <{target}>`"
                rows.append([code(p.ros_name), source, "**live**" if p.live else "read-only"])
            out.append(
                "Scenario and study values it declares (type, unit, range and default as "
                "in their tables):\n"
            )
            out.append(table(["ROS parameter", "from", "while running"], rows))
        own = [p for p in n.params if p.origin == "graph"]
        out.append("Its own parameters:\n")
        out.append(
            table(
                ["ROS parameter", "type", "range", "default", "description"],
                [
                    [
                        code(p.ros_name),
                        _KIND.get(p.kind, p.kind),
                        range_text(p),
                        value(p.default) if p.default is not None else "unset",
                        esc(p.description),
                    ]
                    for p in own
                ],
            )
        )
    return "\n".join(out)


# -- topics --------------------------------------------------------------------------------------
def topics_page(
    topics: list[src.Topic], overrides: list[src.GraphOverride], absolute: tuple[str, ...]
) -> str:
    """Every topic by graph (an overview, then each topic's QoS profiles and content), and the
    bring-up's overrides."""
    out = []
    for graph, _attr in src.GRAPHS:
        rows = [t for t in topics if graph in t.graphs]
        out.append(f"({slug('topics ' + graph)})=\n### {graph.capitalize()}\n")
        out.append(
            table(
                ["topic", "type", "publisher", "rate", "QoS class"],
                [
                    [code(t.name), code(t.type), esc(t.publisher), notes_md(t.rate),
                     code(t.qos_class)]
                    for t in rows
                ],
            )
        )  # fmt: skip
        out.append(
            table(
                ["topic", "subscribers", "QoS profiles", "content"],
                [
                    [code(t.name), notes_md(t.subscribers), _qos_cell(t), notes_md(t.content)]
                    for t in rows
                ],
            )
        )
    out.append("(topics-qos-overrides)=\n### What `ffmpc run` and the launch files override\n")
    out.append(
        "The graph's bring-up passes ROS 2's QoS override parameters "
        "(`qos_overrides.<topic>.<publisher|subscription>.<policy>`) to its own nodes, per class:\n"
    )
    out.append(
        table(
            ["class", "role", "policies"],
            [
                [
                    code(o.qos_class),
                    esc(o.role),
                    ", ".join(f"{esc(k)} = {value(v)}" for k, v in o.policies.items()),
                ]
                for o in overrides
            ],
        )
    )
    out.append(
        "Names are relative and resolve under the graph's namespace, except "
        + ", ".join(code(n) for n in absolute)
        + " (a namespaced graph remaps `/clock`, `/tf` and `/tf_static` into its namespace).\n"
    )
    return "\n".join(out)


def _qos_cell(t: src.Topic) -> str:
    text = f"publisher {esc(t.publisher_qos.text)}"
    lock, rt = t.subscriber_qos_lockstep, t.subscriber_qos_real_time
    if lock == t.publisher_qos and rt == lock:
        return text + "; subscribers the same"
    if lock == rt:
        return text + f"; subscribers {esc(lock.text)}"
    return text + f"; subscribers {esc(lock.text)} (real time: depth {rt.depth})"


def services_page(services: list[src.Service]) -> str:
    """The services of the graph."""
    return table(
        ["service", "type", "server", "effect"],
        [[code(s.name), code(s.type), esc(s.server), notes_md(s.effect)] for s in services],
    )


def layouts_page(layouts: list[src.Layout]) -> str:
    """Every array layout, field by field."""
    out = []
    for layout in layouts:
        out.append(
            f"({slug('layout ' + layout.name)})=\n### `{layout.name}` (version {layout.version})\n"
        )
        carried = ", ".join(code(t) for t in layout.topics) or "—"
        out.append(f"Label {code(layout.label)}; carried by {carried}.\n")
        out.append(
            table(
                ["field", "size", "unit", "meaning"],
                [[code(f.name), code(f.size), esc(f.unit), esc(f.meaning)] for f in layout.fields],
            )
        )
    return "\n".join(out)


# -- messages ------------------------------------------------------------------------------------
_FIELD = re.compile(r"^\s*([A-Za-z_][\w/]*(?:\[\d*\])?)\s+([A-Za-z_]\w*)\s*(=\s*\S.*|\S.*)?$")


def message_fields(text: str) -> list[tuple[str, str, str, str]]:
    """(type, name, constant value or default, comment) of each field of a definition; the
    comment lines just above a field and its trailing comment are its description. Sections of
    a service or action (``---``) restart the comments."""
    out = []
    pending: list[str] = []
    for line in text.splitlines():
        stripped = line.strip()
        if stripped.startswith("#"):
            pending.append(stripped.lstrip("#").strip())
            continue
        if not stripped or stripped == "---":
            pending = [] if stripped == "---" else pending
            if not stripped:
                pending = []
            if stripped == "---":
                out.append(("---", "", "", ""))
            continue
        body, _, trailing = line.partition("#")
        match = _FIELD.match(body)
        if not match:
            pending = []
            continue
        ros_type, name, rest = match.groups()
        rest = (rest or "").strip()
        comment = " ".join([*pending, trailing.strip()]).strip()
        out.append((ros_type, name, rest.lstrip("= ").strip(), comment))
        pending = []
    return out


def messages_page(definitions: list[src.MessageDefinition]) -> str:
    """Every interface definition: a field table and the file itself."""
    out = []
    for d in definitions:
        out.append(f"({slug('msg ' + d.full_name)})=\n## `{d.full_name}`\n")
        out.append(f"File {code(d.path)}.\n")
        rows = []
        for ros_type, name, extra, comment in message_fields(d.text):
            if ros_type == "---":
                rows.append(["—", "—", "—", "*(request / response / feedback separator)*"])
                continue
            rows.append([code(name), code(ros_type), code(extra) if extra else "", esc(comment)])
        if rows:
            out.append(table(["field", "type", "value", "meaning"], rows))
        out.append(f"```text\n{d.text.rstrip()}\n```\n")
    return "\n".join(out)


# -- equations -----------------------------------------------------------------------------------
_ROLE = {"module": "py:mod", "class": "py:class", "function": "py:func", "method": "py:meth"}


def equations_page(implementations: list[eq.Implementation]) -> str:
    """Per paper, each equation and the objects whose docstrings name it, then the equations
    no function implements and why."""
    out = []
    for paper in eq.PAPERS:
        out.append(f"({slug('eq ' + paper.key)})=\n## {esc(paper.citation)}\n")
        rows = []
        for n in paper.equations:
            objs = [i for i in implementations if i.paper == paper.key and n in i.equations]
            if objs:
                where = "<br>".join(
                    f"{{{_ROLE[i.kind]}}}`{i.qualname.removeprefix('ffmpc_core.')} <{i.qualname}>` "
                    f"({esc(i.kind)})"
                    for i in objs
                )
            else:
                where = "not implemented: " + esc(eq.NOT_IMPLEMENTED.get((paper.key, n), "?"))
            rows.append([f"eq {n}", where])
        out.append(table(["equation", "implemented by (docstrings that name it)"], rows))
    return "\n".join(out)


# -- results -------------------------------------------------------------------------------------
_PINNED = (
    "pin",
    "crocoddyl",
    "mim-solvers",
    "example-robot-data",
    "numpy",
    "scipy",
    "daqp",
    "osqp",
    "pybullet",
    "ros-jazzy-rclpy",
)


def provenance(doc: dict[str, Any], path: str) -> str:
    """What produced a results file: its command line, date and the recorded versions."""
    command = doc.get("command_line") or doc.get("command") or "not recorded"
    when = doc.get("created_utc") or doc.get("created") or doc.get("date") or "not recorded"
    versions = doc.get("versions") or {}
    if not versions and isinstance(doc.get("python"), str):
        versions = {"python": doc["python"]}
    pinned = ", ".join(f"{k} {versions[k]}" for k in _PINNED if k in versions)
    ffmpc = versions.get("ffmpc", "not recorded in the file")
    lines = [
        f":::{{admonition}} Provenance of `{path}`\n",
        f"- Command: {code(command)}",
        f"- Date: {esc(when)}",
        f"- ffmpc version: {esc(ffmpc)}",
    ]
    if pinned:
        lines.append(f"- Packages: {esc(pinned)}")
    if isinstance(doc.get("machine"), str | dict):
        machine = doc["machine"]
        if isinstance(machine, dict):
            machine = ", ".join(f"{k} {v}" for k, v in machine.items())
        lines.append(f"- Machine: {esc(machine)}")
    lines.append(":::\n")
    return "\n".join(lines)


def _ms(value: Any) -> str:
    return f"{value:.3f}" if isinstance(value, int | float) else ""


def bench_mpc_table(doc: dict[str, Any]) -> str:
    """The cases of ``ffmpc bench mpc --json`` as a table."""
    rows = []
    for c in doc.get("cases", []):
        rows.append([
            str(c.get("nodes", "")),
            number(round(c["dt"] * 1e3, 6)) if isinstance(c.get("dt"), float) else "",
            code(c.get("formulation", "")),
            _ms(c.get("step_median_ms")), _ms(c.get("p90_ms")), _ms(c.get("solve_median_ms")),
            number(c.get("iterations_median", 0)), number(c.get("iterations_max", 0)),
            f"{100 * c.get('cap_hit_fraction', 0):.1f} %",
            f"{c.get('ratio_to_reference', 0):.2f}", f"{c.get('final_force_N', 0):.2f}",
        ])  # fmt: skip
    return table(
        ["N", "Δt (ms)", "formulation", "step median (ms)", "step p90 (ms)",
         "solve median (ms)", "iterations median", "iterations max", "cap hit",
         "ratio to reference", "force at end (N)"],
        rows,
    )  # fmt: skip


def bench_impact_table(doc: dict[str, Any]) -> str:
    """The two pipelines of ``ffmpc bench impact --json`` as a table."""
    rows = []
    for label, p in (("daqp", doc.get("daqp", {})), ("osqp (reference)", doc.get("reference", {}))):
        rows.append([
            esc(label), _ms(p.get("median_ms")), _ms(p.get("p90_ms")), _ms(p.get("p99_ms")),
            _ms(p.get("cpu_median_ms")), _ms(p.get("mapping_median_ms")),
            _ms(p.get("eq14_median_ms")), str(p.get("eq14_failures", "")),
            str(p.get("eq14_highs_fallbacks", "")),
        ])  # fmt: skip
    out = table(
        ["pipeline", "median (ms)", "p90 (ms)", "p99 (ms)", "CPU median (ms)",
         "mapping median (ms)", "eq 14 median (ms)", "eq 14 failures", "HiGHS fallbacks"],
        rows,
    )  # fmt: skip
    ratio = doc.get("ratio_reference_over_new")
    if isinstance(ratio, int | float):
        out += (
            f"\nOSQP over DAQP (median): {ratio:.1f}× wall time, "
            f"{doc.get('cpu_ratio_reference_over_new', 0):.1f}× CPU time, over "
            f"{doc.get('cycles', '?')} cycles; the largest difference of the pre-impact velocity "
            f"from the polished OSQP solution {doc.get('max_velocity_difference_polished', 0):.1e} "
            f"m/s; load average {doc.get('load_average_1min', 0):.1f}.\n"
        )
    return out
