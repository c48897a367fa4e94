"""Import-graph checker: the four packages' layer order and the absence of import cycles.

Every ``import``/``from ... import`` statement of every module counts, wherever it stands
(module level, inside a function, under ``if TYPE_CHECKING``), and so does
``importlib.import_module("literal")``. Relative imports are resolved against the importing
module. ``from package import name`` is an edge to ``package.name`` when that is a module of the
tree, to ``package`` otherwise.

Used by ``tests/test_layers.py``; run it by hand with ``python tests/layer_check.py [ROOT]``.
"""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

#: Lowest layer first: a package may import only packages at or before its own position.
LAYERS: tuple[str, ...] = ("ffmpc_core", "sim_bridge", "ffmpc_ros", "studies")


@dataclass(frozen=True)
class ImportEdge:
    """One import statement: ``importer`` imports ``imported`` at ``path``:``line``."""

    importer: str
    imported: str
    path: str
    line: int


def module_names(root: Path, packages: Sequence[str] = LAYERS) -> dict[str, Path]:
    """Dotted name of every ``*.py`` module under ``root/<package>`` (``__init__`` = package)."""
    modules: dict[str, Path] = {}
    for package in packages:
        base = root / package
        if not base.is_dir():
            continue
        for path in sorted(base.rglob("*.py")):
            parts = list(path.relative_to(root).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts = parts[:-1]
            modules[".".join(parts)] = path
    return modules


def _resolve_relative(importer: str, is_package: bool, level: int, module: str | None) -> str:
    """Absolute name of ``from <level dots><module> import ...`` written in ``importer``."""
    parts = importer.split(".")
    if not is_package:
        parts = parts[:-1]  # a plain module's anchor is its package
    if level - 1 > len(parts):
        raise ValueError(f"{importer}: relative import beyond the top-level package")
    if level > 1:
        parts = parts[: len(parts) - (level - 1)]
    if module:
        parts = [*parts, *module.split(".")]
    return ".".join(parts)


def _is_import_module_call(node: ast.Call) -> bool:
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    return name == "import_module"


def imports_of(name: str, path: Path, known: Iterable[str]) -> list[ImportEdge]:
    """Every import in module ``name`` (file ``path``) of a module of the tree, resolved."""
    known_set = set(known)
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    is_package = path.name == "__init__.py"
    edges: list[ImportEdge] = []

    def add(target: str, line: int) -> None:
        # The longest prefix of `target` that is a module of the tree.
        parts = target.split(".")
        while parts and ".".join(parts) not in known_set:
            parts.pop()
        if parts:
            edges.append(ImportEdge(name, ".".join(parts), str(path), line))

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                add(alias.name, node.lineno)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = _resolve_relative(name, is_package, node.level, node.module)
            else:
                base = node.module or ""
            for alias in node.names:
                candidate = f"{base}.{alias.name}" if base else alias.name
                add(candidate if candidate in known_set else base, node.lineno)
        elif isinstance(node, ast.Call) and _is_import_module_call(node):
            if node.args and isinstance(node.args[0], ast.Constant):
                value = node.args[0].value
                if isinstance(value, str) and not value.startswith("."):
                    add(value, node.lineno)
    return edges


def import_edges(root: Path, packages: Sequence[str] = LAYERS) -> list[ImportEdge]:
    """Every intra-tree import edge of the packages under ``root``, self-imports left out."""
    modules = module_names(root, packages)
    edges: list[ImportEdge] = []
    for name, path in modules.items():
        edges.extend(e for e in imports_of(name, path, modules) if e.imported != name)
    return edges


def layer_violations(
    edges: Iterable[ImportEdge], layers: Sequence[str] = LAYERS
) -> list[ImportEdge]:
    """The edges that go from a lower layer up to a higher one."""
    rank = {package: i for i, package in enumerate(layers)}
    bad = []
    for edge in edges:
        src = rank.get(edge.importer.split(".")[0])
        dst = rank.get(edge.imported.split(".")[0])
        if src is not None and dst is not None and dst > src:
            bad.append(edge)
    return bad


def strongly_connected_components(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm, iterative; every node of ``graph`` (keys and targets) is placed."""
    nodes = set(graph) | {t for targets in graph.values() for t in targets}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    components: list[list[str]] = []
    counter = 0
    for start in sorted(nodes):
        if start in index:
            continue
        work: list[tuple[str, list[str]]] = [(start, sorted(graph.get(start, ())))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on_stack.add(start)
        while work:
            node, successors = work[-1]
            if successors:
                succ = successors.pop()
                if succ not in index:
                    index[succ] = low[succ] = counter
                    counter += 1
                    stack.append(succ)
                    on_stack.add(succ)
                    work.append((succ, sorted(graph.get(succ, ()))))
                elif succ in on_stack:
                    low[node] = min(low[node], index[succ])
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                components.append(sorted(component))
    return components


def cycles(edges: Iterable[ImportEdge], level: str = "module") -> list[list[str]]:
    """Import cycles (SCCs of more than one node) between modules or between top-level packages.

    ``level="package"`` collapses each module to its top-level package (``ffmpc_ros.bag.cli`` →
    ``ffmpc_ros``), so a cycle through several modules of different packages shows as one.
    """
    if level not in ("module", "package"):
        raise ValueError(f"level must be 'module' or 'package', not {level!r}")

    def node_of(name: str) -> str:
        return name if level == "module" else name.split(".")[0]

    graph: dict[str, set[str]] = {}
    for edge in edges:
        src, dst = node_of(edge.importer), node_of(edge.imported)
        if src != dst:
            graph.setdefault(src, set()).add(dst)
    return [c for c in strongly_connected_components(graph) if len(c) > 1]


def main(argv: Sequence[str] | None = None) -> int:
    """Print every violation under ROOT (default: the repository); exit 1 if there is one."""
    args = sys.argv[1:] if argv is None else list(argv)
    root = Path(args[0]) if args else Path(__file__).resolve().parents[1]
    edges = import_edges(root)
    failures = 0
    for edge in layer_violations(edges):
        print(f"up a layer: {edge.importer} -> {edge.imported} ({edge.path}:{edge.line})")
        failures += 1
    for level in ("module", "package"):
        for component in cycles(edges, level):
            print(f"{level} cycle: {' <-> '.join(component)}")
            failures += 1
    print(f"{len(edges)} import edges, {failures} violations")
    return 1 if failures else 0


if __name__ == "__main__":
    raise SystemExit(main())
