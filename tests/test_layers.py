"""Layers read top-down: ffmpc_core ← sim_bridge ← ffmpc_ros ← studies, with no import cycle.

The checker (``tests/layer_check.py``) reads every module's AST: module-level and function-level
imports, relative imports resolved, ``importlib.import_module("literal")``. The planted-violation
tests run it on small trees written to ``tmp_path`` so that it is seen to fail.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from layer_check import (
    LAYERS,
    cycles,
    import_edges,
    layer_violations,
    main,
    strongly_connected_components,
)

ROOT = Path(__file__).resolve().parents[1]


def _describe(edges) -> str:
    return "\n".join(f"{e.importer} -> {e.imported} ({e.path}:{e.line})" for e in edges)


def test_the_tree_has_edges_in_every_layer() -> None:
    edges = import_edges(ROOT)
    importers = {e.importer.split(".")[0] for e in edges}
    assert importers == set(LAYERS)
    assert len(edges) > 300  # the walk found the imports, not an empty tree


def test_no_import_goes_up_a_layer() -> None:
    bad = layer_violations(import_edges(ROOT))
    assert not bad, "imports that go up a layer:\n" + _describe(bad)


@pytest.mark.parametrize("level", ["module", "package"])
def test_no_import_cycle(level: str) -> None:
    found = cycles(import_edges(ROOT), level)
    assert not found, f"{level} import cycles: {found}"


def test_sim_bridge_holds_the_plants_and_the_scenes_only() -> None:
    """No experiment and no closed loop in sim_bridge: the experiments are in studies/, the top
    layer, and the loop is ffmpc_core.runner (scenes: the scenarios as plants; the PyBullet
    plant, the MuJoCo plant and its contact forces)."""
    modules = {p.stem for p in (ROOT / "sim_bridge").glob("*.py")}
    assert modules == {"__init__", "plant", "mujoco_plant", "contact_forces", "scenes"}


def test_the_layer_order_is_core_simulator_ros_studies() -> None:
    assert LAYERS == ("ffmpc_core", "sim_bridge", "ffmpc_ros", "studies")


def test_studies_are_the_top_layer_and_ros_never_imports_them() -> None:
    edges = import_edges(ROOT)
    ros = {e.imported.split(".")[0] for e in edges if e.importer.startswith("ffmpc_ros.")}
    assert "studies" not in ros, [
        (e.importer, e.imported)
        for e in edges
        if e.importer.startswith("ffmpc_ros.") and e.imported.startswith("studies")
    ]
    assert ros <= {"ffmpc_core", "sim_bridge", "ffmpc_ros"}
    # the studies' commands build on the command line's argument types and extension point
    assert any(e.importer == "studies.cli" and e.imported.startswith("ffmpc_ros.") for e in edges)


def test_the_old_arrow_ros_to_studies_is_reported(tmp_path: Path) -> None:
    """The order before issue 14 (the command line importing the studies) now fails."""
    root = _tree(
        tmp_path,
        {
            "studies/impact_study.py": "from ffmpc_ros.cli_args import parse_overrides\n",
            "ffmpc_ros/cli_args.py": "",
            "ffmpc_ros/cli.py": "def f():\n    from studies.impact_study import run\n",
        },
    )
    bad = layer_violations(import_edges(root))
    assert [(e.importer, e.imported, e.line) for e in bad] == [
        ("ffmpc_ros.cli", "studies.impact_study", 2)
    ]
    assert main([str(root)]) == 1


def test_core_imports_neither_ros_nor_the_simulator() -> None:
    banned = {"rclpy", "pybullet", "mujoco", "rosbags", "mcap", "mcap_ros2"}
    hits = []
    for path in sorted((ROOT / "ffmpc_core").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and not node.level and node.module:
                names = [node.module]
            hits += [f"{path}:{node.lineno} {n}" for n in names if n.split(".")[0] in banned]
    assert not hits, hits


# -- the checker on planted violations -------------------------------------------------------
def _tree(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text, encoding="utf-8")
    for package in LAYERS:
        (root / package).mkdir(exist_ok=True)
        (root / package / "__init__.py").touch()
    return root


def test_checker_accepts_a_clean_tree(tmp_path: Path) -> None:
    root = _tree(
        tmp_path,
        {
            "ffmpc_core/math.py": "import numpy\n",
            "sim_bridge/plant.py": "from ffmpc_core import math\n",
            "ffmpc_ros/node.py": "from sim_bridge.plant import x\nfrom ffmpc_core.math import y\n",
        },
    )
    edges = import_edges(root)
    assert {(e.importer, e.imported) for e in edges} == {
        ("sim_bridge.plant", "ffmpc_core.math"),
        ("ffmpc_ros.node", "sim_bridge.plant"),
        ("ffmpc_ros.node", "ffmpc_core.math"),
    }
    assert layer_violations(edges) == []
    assert cycles(edges) == [] and cycles(edges, "package") == []
    assert main([str(root)]) == 0


def test_checker_finds_a_lazy_import_up_a_layer(tmp_path: Path) -> None:
    root = _tree(
        tmp_path,
        {
            "sim_bridge/node.py": "def main():\n    from ffmpc_ros.base import Node\n",
            "ffmpc_ros/base.py": "from sim_bridge import plant\n",
            "sim_bridge/plant.py": "",
        },
    )
    edges = import_edges(root)
    bad = layer_violations(edges)
    assert [(e.importer, e.imported, e.line) for e in bad] == [
        ("sim_bridge.node", "ffmpc_ros.base", 2)
    ]
    assert cycles(edges, "package") == [["ffmpc_ros", "sim_bridge"]]
    assert cycles(edges, "module") == []  # node -> base -> plant: no module cycle
    assert main([str(root)]) == 1


def test_checker_resolves_relative_imports_and_finds_a_module_cycle(tmp_path: Path) -> None:
    root = _tree(
        tmp_path,
        {
            "ffmpc_ros/cli.py": "def f():\n    from .bag.cli import add\n",
            "ffmpc_ros/bag/__init__.py": "",
            "ffmpc_ros/bag/cli.py": "from ..cli import parse\nfrom . import reader\n",
            "ffmpc_ros/bag/reader.py": "",
        },
    )
    edges = import_edges(root)
    assert {(e.importer, e.imported) for e in edges} == {
        ("ffmpc_ros.cli", "ffmpc_ros.bag.cli"),
        ("ffmpc_ros.bag.cli", "ffmpc_ros.cli"),
        ("ffmpc_ros.bag.cli", "ffmpc_ros.bag.reader"),
    }
    assert layer_violations(edges) == []
    assert cycles(edges) == [["ffmpc_ros.bag.cli", "ffmpc_ros.cli"]]
    assert main([str(root)]) == 1


def test_checker_sees_import_module_with_a_literal(tmp_path: Path) -> None:
    root = _tree(
        tmp_path,
        {
            "ffmpc_core/plugins.py": (
                "import importlib\n\ndef load():\n"
                "    return importlib.import_module('sim_bridge.plant')\n"
            ),
            "sim_bridge/plant.py": "",
        },
    )
    bad = layer_violations(import_edges(root))
    assert [(e.importer, e.imported) for e in bad] == [("ffmpc_core.plugins", "sim_bridge.plant")]


def test_strongly_connected_components() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": {"e"}, "e": {"d"}, "f": set()}
    components = sorted(strongly_connected_components(graph))
    assert components == [["a", "b", "c"], ["d", "e"], ["f"]]
