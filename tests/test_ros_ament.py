"""`ros2 run ffmpc_ros NODE` resolution: every executable is found through ament_index_python
the way ros2run finds it (AMENT_PREFIX_PATH → package prefix → lib/ffmpc_ros/EXE, executable),
and runs (``--help``)."""

from __future__ import annotations

import importlib.metadata
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_prefix, get_package_share_directory

from ffmpc_ros.ament import (
    EXECUTABLES,
    PACKAGE,
    install_ament_layout,
    launcher_text,
    share_files,
)

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
    share = Path(get_package_share_directory(PACKAGE))
    assert (share / "launch" / "polishing.launch.yaml").is_file()  # ros2 launch ffmpc_ros ...
    assert (share / "config" / "polishing.yaml").read_text() == (
        ROOT / "ffmpc_core" / "scenarios" / "polishing.yaml"
    ).read_text()
    first_line = (tmp_path / "lib" / PACKAGE / "mpc").read_text().splitlines()[0]
    assert first_line == f"#!{sys.executable}"


def test_the_venv_prefix_resolves_when_the_layout_is_installed(monkeypatch):
    marker = Path(sys.prefix) / "share/ament_index/resource_index/packages" / PACKAGE
    if not marker.is_file():
        pytest.skip("layout not installed in this environment: run `python -m ffmpc_ros.ament`")
    _check_prefix(Path(sys.prefix), monkeypatch)


def test_the_build_ships_the_same_layout_and_console_scripts():
    """`pip install .` gets the layout from CMakeLists.txt (scikit-build-core's data directory):
    the shipped launchers are the generated ones, the marker is empty, the manifest is the root
    package.xml, every node has a console script, and the installed distribution recorded them."""
    layout = ROOT / "ffmpc_ros" / "ros_layout"
    marker = layout / "resource" / PACKAGE
    assert marker.read_text() == ""
    shipped = {p.name: p for p in (layout / "lib").iterdir()}
    assert set(shipped) == set(EXECUTABLES)
    for exe, path in shipped.items():
        assert path.read_text() == launcher_text(exe) and os.access(path, os.X_OK)
    cmake = (ROOT / "CMakeLists.txt").read_text()
    for text in (
        "ffmpc_ros/ros_layout/resource/ffmpc_ros",
        '"${SKBUILD_DATA_DIR}/share/ament_index/resource_index/packages"',
        '"${CMAKE_CURRENT_SOURCE_DIR}/package.xml"',
        '"${SKBUILD_DATA_DIR}/share/ffmpc_ros"',
        "ffmpc_ros/ros_layout/lib/*",
        '"${SKBUILD_DATA_DIR}/lib/ffmpc_ros"',
        "ffmpc_ros/ros_layout/launch/*.launch.yaml",
        '"${SKBUILD_DATA_DIR}/share/ffmpc_ros/launch"',
        "ffmpc_core/scenarios/*.yaml",
        '"${SKBUILD_DATA_DIR}/share/ffmpc_ros/config"',
    ):
        assert text in cmake, text
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    scripts = project["project"]["scripts"]
    for exe, module in EXECUTABLES.items():
        assert scripts[f"ffmpc-{exe.replace('_', '-')}"] == f"{module}:main"
    try:
        files = importlib.metadata.files("ffmpc")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("ffmpc is not installed in this environment")
    if files is None or not any(str(f).endswith("share/ffmpc_ros/package.xml") for f in files):
        pytest.skip("this ffmpc install was not built by scikit-build-core")
    located = {Path(f.locate()).resolve() for f in files}
    prefix = Path(sys.prefix).resolve()
    expected = [prefix / "lib" / PACKAGE / exe for exe in EXECUTABLES]
    expected += [
        prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE,
        prefix / "share" / PACKAGE / "package.xml",
    ]
    expected += [
        prefix / "share" / PACKAGE / d / f.name for d, fs in share_files().items() for f in fs
    ]
    for path in expected:
        assert path in located, path
