"""Sphinx extension of the ffmpc manual: the generated reference pages and the API rule.

* A page holds a marker line ``<!-- ffmpc:NAME [ARG] -->``; when Sphinx reads it
  (``source-read``), the marker is replaced by the MyST Markdown of generator NAME
  (:data:`GENERATORS`), built from the code at build time (``sources.py`` reads the code,
  ``render.py`` writes Markdown). Such pages are read again on every build
  (``env-get-outdated``), so an incremental build never shows a stale reference.
* ``make docs`` fails (a warning, and the build runs with ``-W``) when a public object of
  ``ffmpc_core`` has no docstring (``apicheck.py``), or when an equation of the papers is
  neither named by a docstring nor explained in ``equations.NOT_IMPLEMENTED``.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from sphinx.application import Sphinx
from sphinx.util import logging

from . import apicheck, equations, render, sources

logger = logging.getLogger(__name__)

MARKER = re.compile(r"^<!-- ffmpc:([\w-]+)(?: ([^ ]+))? -->$", re.M)
RESULTS = sources.ROOT / "benchmarks" / "results"


def _results(arg: str | None) -> str:
    path = RESULTS / (arg or "")
    doc = json.loads(path.read_text(encoding="utf-8"))
    return render.provenance(doc, str(path.relative_to(sources.ROOT)))


def _bench_mpc(arg: str | None) -> str:
    doc = json.loads((RESULTS / "bench" / "bench_mpc.json").read_text(encoding="utf-8"))
    return render.bench_mpc_table(doc)


def _bench_impact(arg: str | None) -> str:
    doc = json.loads((RESULTS / "bench" / "bench_impact.json").read_text(encoding="utf-8"))
    return render.bench_impact_table(doc)


def _study(arg: str | None) -> str:
    study = next(s for s in sources.study_parameters() if s.key == arg)
    return render.study_page(study)


def _equations(arg: str | None) -> str:
    found = equations.equation_map()
    for paper, n in equations.unmapped(found):
        logger.warning(
            "ffmpc: %s eq %d is named by no docstring of ffmpc_core and not listed in "
            "docs/_ext/ffmpc_docs/equations.py NOT_IMPLEMENTED",
            paper,
            n,
            type="ffmpc",
        )
    for paper, n in equations.stale_exemptions(found):
        logger.warning(
            "ffmpc: %s eq %d is listed as not implemented but a docstring names it",
            paper,
            n,
            type="ffmpc",
        )
    return render.equations_page(found)


#: Marker name → function of the marker's argument that returns MyST Markdown.
GENERATORS: dict[str, Callable[[str | None], str]] = {
    "cli": lambda _: render.cli_page(sources.cli_tree()),
    "scenario-parameters": lambda _: render.scenario_page(sources.scenario_parameters()),
    "study-parameters": _study,
    "shipped-scenarios": lambda _: render.shipped_page(sources.shipped_scenarios()),
    "node-parameters": lambda _: render.node_page(sources.node_parameters()),
    "topics": lambda _: render.topics_page(
        sources.topics(), sources.graph_overrides(), sources.absolute_names()
    ),
    "services": lambda _: render.services_page(sources.services()),
    "layouts": lambda _: render.layouts_page(sources.layouts()),
    "messages": lambda _: render.messages_page(sources.messages()),
    "equations": _equations,
    "results": _results,
    "bench-mpc": _bench_mpc,
    "bench-impact": _bench_impact,
}

#: Documents that hold a marker (filled by ``source-read``), re-read on every build.
_generated_docs: set[str] = set()


def _source_read(app: Sphinx, docname: str, source: list[str]) -> None:
    text = source[0]
    if "<!-- ffmpc:" not in text:
        return

    def fill(match: re.Match[str]) -> str:
        name, arg = match.group(1), match.group(2)
        if name not in GENERATORS:
            logger.warning("ffmpc: unknown generator %r", name, location=docname, type="ffmpc")
            return ""
        return GENERATORS[name](arg)

    source[0] = MARKER.sub(fill, text)
    _generated_docs.add(docname)


def _outdated(app: Sphinx, env: Any, added: set, changed: set, removed: set) -> list[str]:
    return sorted(d for d in _marker_docs(app) if d in env.found_docs)


def _marker_docs(app: Sphinx) -> set[str]:
    """Documents whose source holds a marker (found by reading the sources: also before the
    first ``source-read`` of this process)."""
    out = set(_generated_docs)
    src = Path(app.srcdir)
    for path in src.rglob("*.md"):
        if "_build" in path.parts or "_autosummary" in path.parts:
            continue
        if "<!-- ffmpc:" in path.read_text(encoding="utf-8"):
            out.add(str(path.relative_to(src).with_suffix("")).replace("\\", "/"))
    return out


def _check_api(app: Sphinx) -> None:
    for m in apicheck.undocumented(app.config.ffmpc_api_package):
        logger.warning(
            "ffmpc: public %s %s has no docstring",
            m.kind,
            m.qualname,
            location=(m.file, m.line) if m.file else None,
            type="ffmpc",
        )


_IDENTIFIER = re.compile(r"^~?[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*(\(\))?$")
#: Packages of the project that this manual has no API pages for (other layers).
_OTHER_LAYERS = ("sim_bridge", "ffmpc_ros", "studies")


def _missing_reference(app: Sphinx, env: Any, node: Any, contnode: Any) -> Any:
    """Resolve what nitpicky mode would flag but is no reference to a documented object.

    * a short name (``InputError``) that names exactly one documented object of the Python
      domain: link it (docstrings name classes of other modules of ffmpc_core unqualified);
    * text that is not a dotted identifier (napoleon reads ``name (world frame): ...`` or an
      attribute's ``unit: meaning`` as a type): plain text;
    * a private name, a type variable, an instance attribute (``:attr:``) without a docstring,
      or a module of another layer of the project: plain text.

    Anything else (a misspelt or removed public object of ffmpc_core) stays a warning."""
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "")
    if not _IDENTIFIER.match(target):
        return contnode
    name = target.lstrip("~").removesuffix("()")
    domain = env.get_domain("py")
    matches = [
        full
        for full, obj in domain.objects.items()
        if (full == name or full.endswith("." + name)) and not obj.aliased
    ]
    if len(matches) == 1:
        return _link(app, node, contnode, matches[0])
    if "." in name and not matches:  # Class.member inherited from an undocumented base: the class
        owner = name.rsplit(".", 1)[0]
        owners = [f for f in domain.objects if f == owner or f.endswith("." + owner)]
        if len(owners) == 1 and domain.objects[owners[0]].objtype == "class":
            return _link(app, node, contnode, owners[0])
    if any(part.startswith("_") for part in name.split(".")) or name.startswith(_OTHER_LAYERS):
        return contnode
    if node.get("reftype") == "attr" or _is_type_variable(name) or _in_attribute_type(node):
        return contnode
    return None


def _link(app: Sphinx, node: Any, contnode: Any, full: str) -> Any:
    from sphinx.util.nodes import make_refnode

    obj = app.env.get_domain("py").objects[full]
    return make_refnode(app.builder, node["refdoc"], obj.docname, obj.node_id, contnode, full)


def _in_attribute_type(node: Any) -> bool:
    """Whether ``node`` is in the "type" napoleon made of an attribute's text: the ``Type``
    field of a data or attribute, or an entry of a class's ``Variables`` field (its
    ``Attributes:`` section). The project writes ``unit or symbol: meaning`` where napoleon
    expects ``type: description`` (``N: the force at which ...``), and ``name (symbol):`` in
    attribute lists. Parameter and return types (from the annotations) stay checked."""
    from docutils import nodes

    parent = node.parent
    while parent is not None and not isinstance(parent, nodes.field):
        parent = parent.parent
    if parent is None:
        return False
    name = parent.next_node(nodes.field_name)
    return name is not None and name.astext().strip() in ("Type", "Variables")


def _is_type_variable(name: str) -> bool:
    import importlib
    from typing import TypeVar

    module, _, attr = name.rpartition(".")
    try:
        return isinstance(getattr(importlib.import_module(module), attr), TypeVar)
    except (ImportError, AttributeError, ValueError):
        return False


_LITERAL = re.compile(r"(``.+?``|`[^`]+`)")


def _bars_are_text(
    app: Sphinx, what: str, name: str, obj: Any, options: Any, lines: list[str]
) -> None:
    """``|x|`` in a docstring is an absolute value or a norm, never a reStructuredText
    substitution (the project's docstrings have none): escape the bars outside literals
    (inline ````code````, roles, ``::`` literal blocks)."""
    block: int | None = None  # indent of the line that opened a literal block
    for i, line in enumerate(lines):
        indent = len(line) - len(line.lstrip())
        if block is not None and (not line.strip() or indent > block):
            continue
        block = None
        if line.rstrip().endswith("::"):
            block = indent
        if "|" in line:
            parts = _LITERAL.split(line)
            lines[i] = "".join(
                part if k % 2 else part.replace("|", "\\|") for k, part in enumerate(parts)
            )


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_config_value("ffmpc_api_package", "ffmpc_core", "env")
    app.connect("autodoc-process-docstring", _bars_are_text)
    app.connect("missing-reference", _missing_reference)
    app.connect("source-read", _source_read)
    app.connect("env-get-outdated", _outdated)
    app.connect("builder-inited", _check_api)
    return {"version": "1", "parallel_read_safe": False, "parallel_write_safe": True}
