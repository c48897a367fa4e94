"""`ros2 run ffmpc_ros NODE` resolution: every executable is found through ament_index_python
the way ros2run finds it (AMENT_PREFIX_PATH → package prefix → lib/ffmpc_ros/EXE, executable),
and runs (``--help``)."""

from __future__ import annotations

import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix, get_package_share_directory

from ffmpc_ros.ament import EXECUTABLES, PACKAGE, install_ament_layout, launcher_text

ROOT = Path(__file__).resolve().parents[1]
tomllib = pytest.importorskip("tomllib")  # Python >= 3.11


def _ros2run_path(executable: str) -> str:
    """What ros2run.api.get_executable_path does."""
    prefix = get_package_prefix(PACKAGE)
    path = os.path.join(prefix, "lib", PACKAGE, executable)
    assert os.path.isfile(path) and os.access(path, os.X_OK), path
    return path


def _check_prefix(prefix: Path, monkeypatch) -> None:
    monkeypatch.setenv("AMENT_PREFIX_PATH", os.pathsep.join([str(prefix), sys.prefix]))
    assert Path(get_package_prefix(PACKAGE)) == prefix
    manifest = ET.parse(Path(get_package_share_directory(PACKAGE)) / "package.xml").getroot()
    assert manifest.findtext("name") == PACKAGE
    assert manifest.find("export/build_type").text == "ament_python"
    paths = {exe: _ros2run_path(exe) for exe in EXECUTABLES}
    listed = sorted(p.name for p in (prefix / "lib" / PACKAGE).iterdir() if os.access(p, os.X_OK))
    assert listed == sorted(EXECUTABLES)  # ros2 pkg executables ffmpc_ros
    children = {
        exe: subprocess.Popen([path, "--help"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        for exe, path in paths.items()
    }
    for exe, child in children.items():
        out, err = child.communicate(timeout=120)
        assert child.returncode == 0, (exe, err.decode()[-2000:])
        assert b"--params-file" in out, exe


def test_installed_layout_resolves_like_ros2_run(tmp_path, monkeypatch):
    install_ament_layout(tmp_path)
    _check_prefix(tmp_path, monkeypatch)
    first_line = (tmp_path / "lib" / PACKAGE / "mpc").read_text().splitlines()[0]
    assert first_line == f"#!{sys.executable}"


def test_the_venv_prefix_resolves_when_the_layout_is_installed(monkeypatch):
    marker = Path(sys.prefix) / "share/ament_index/resource_index/packages" / PACKAGE
    if not marker.is_file():
        pytest.skip("layout not installed in this environment: run `python -m ffmpc_ros.ament`")
    _check_prefix(Path(sys.prefix), monkeypatch)


def test_pyproject_ships_the_same_layout_and_console_scripts():
    """A regular `pip install .` gets the layout from data-files: the shipped launchers are the
    generated ones, the manifest is the root package.xml, and every node has a console script."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    data = project["tool"]["setuptools"]["data-files"]
    assert data["share/ffmpc_ros"] == ["package.xml"]
    marker = ROOT / data["share/ament_index/resource_index/packages"][0]
    assert marker.name == PACKAGE and marker.read_text() == ""
    shipped = {Path(p).name: ROOT / p for p in data[f"lib/{PACKAGE}"]}
    assert set(shipped) == set(EXECUTABLES)
    for exe, path in shipped.items():
        assert path.read_text() == launcher_text(exe) and os.access(path, os.X_OK)
    scripts = project["project"]["scripts"]
    for exe, module in EXECUTABLES.items():
        assert scripts[f"ffmpc-{exe.replace('_', '-')}"] == f"{module}:main"
