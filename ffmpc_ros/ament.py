"""The ROS 2 install layout of ffmpc, so that ``ros2 run ffmpc_ros NODE`` finds the nodes.

``ros2 run PKG EXE`` (ros2run) resolves ``<prefix>/lib/PKG/EXE`` where ``<prefix>`` is the
first entry of ``AMENT_PREFIX_PATH`` holding the ament index marker
``share/ament_index/resource_index/packages/PKG``; ``share/PKG/package.xml`` is the manifest,
``share/PKG/launch/*.launch.yaml`` the launch files (``ros2 launch ffmpc_ros polishing.launch.yaml``
or ``ffmpc launch``) and ``share/PKG/config/*.yaml`` the scenario parameter files they read.

``pip install .`` (and ``pip install -e .``) installs these files: CMakeLists.txt puts them in
the wheel's data directory (scikit-build-core), with launchers that run ``/usr/bin/env python3``.
``python -m ffmpc_ros.ament`` (run by the Makefile) writes the same layout into the environment's
prefix with launchers whose shebang is this interpreter, so ``ros2 run`` uses the venv without
activating it.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

PACKAGE = "ffmpc_ros"

#: executable → module whose ``main()`` it runs.
EXECUTABLES: dict[str, str] = {
    "plant": "ffmpc_ros.plant_node",
    "joint_sensor": "ffmpc_ros.joint_sensor_node",
    "ft_sensor": "ffmpc_ros.ft_sensor_node",
    "mpc": "ffmpc_ros.mpc_node",
    "pid": "ffmpc_ros.pid_node",
    "lfc": "ffmpc_ros.lfc_node",
    "metrics": "ffmpc_ros.metrics_node",
    "impact_planner": "ffmpc_ros.impact_planner_node",
    "contact_learner": "ffmpc_ros.contact_learner_node",
    "dice_plant": "ffmpc_ros.dice_plant_node",
    "impact_controller": "ffmpc_ros.impact_controller_node",
    "state_publisher": "ffmpc_ros.state_publisher_node",
}

_ROOT = Path(__file__).resolve().parent


def manifest_path() -> Path:
    """package.xml of the source tree (the project root)."""
    return _ROOT.parent / "package.xml"


def share_files() -> dict[str, list[Path]]:
    """Files installed under ``share/ffmpc_ros/<folder>``: the launch files (``launch``) and the
    scenario parameter files (``config``), from the source tree."""
    return {
        "launch": sorted((_ROOT / "ros_layout" / "launch").glob("*.launch.yaml")),
        "config": sorted((_ROOT.parent / "ffmpc_core" / "scenarios").glob("*.yaml")),
    }


#: The live view's Foxglove layout, in ``share/ffmpc_ros`` (installed there by CMakeLists.txt).
FOXGLOVE_LAYOUT = Path("foxglove") / "ffmpc_layout.json"


def foxglove_layout_path() -> Path:
    """The Foxglove layout of ``ffmpc run --view``: ``<sys.prefix>/share/ffmpc_ros/...`` when
    installed, else the source tree's ``share/ffmpc_ros/...``."""
    installed = Path(sys.prefix) / "share" / PACKAGE / FOXGLOVE_LAYOUT
    if installed.is_file():
        return installed
    return _ROOT.parent / "share" / PACKAGE / FOXGLOVE_LAYOUT


def launcher_text(executable: str, interpreter: str | None = None) -> str:
    """The launcher of one executable; ``interpreter=None`` uses ``/usr/bin/env python3``."""
    module = EXECUTABLES[executable]
    shebang = interpreter or "/usr/bin/env python3"
    return (
        f"#!{shebang}\n"
        f'"""`ros2 run {PACKAGE} {executable}`: the {executable} node of the ffmpc graph '
        f'(module {module})."""\n\nimport sys\n\nfrom {module} import main\n\nsys.exit(main())\n'
    )


def install_ament_layout(prefix: str | os.PathLike | None = None) -> list[Path]:
    """Write the marker, the manifest and one launcher per node under ``prefix`` (default: this
    environment's ``sys.prefix``); returns the files written."""
    root = Path(prefix if prefix is not None else sys.prefix)
    marker = root / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE
    marker.parent.mkdir(parents=True, exist_ok=True)
    marker.write_text("")
    share = root / "share" / PACKAGE
    share.mkdir(parents=True, exist_ok=True)
    manifest = share / "package.xml"
    if not manifest_path().is_file():
        raise FileNotFoundError(
            f"{manifest_path()} not found: install_ament_layout needs the source tree "
            "(an editable install); a regular install gets the layout from pyproject data-files"
        )
    manifest.write_text(manifest_path().read_text(encoding="utf-8"), encoding="utf-8")
    written = [marker, manifest]
    for folder, sources in share_files().items():
        (share / folder).mkdir(exist_ok=True)
        for source in sources:
            target = share / folder / source.name
            target.write_text(source.read_text(encoding="utf-8"), encoding="utf-8")
            written.append(target)
    lib = root / "lib" / PACKAGE
    lib.mkdir(parents=True, exist_ok=True)
    for exe in EXECUTABLES:
        path = lib / exe
        path.write_text(launcher_text(exe, sys.executable), encoding="utf-8")
        path.chmod(0o755)
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ffmpc_ros.ament", description=__doc__)
    parser.add_argument(
        "--prefix", default=sys.prefix, help="install prefix (default: %(default)s)"
    )
    args = parser.parse_args(argv)
    for path in install_ament_layout(args.prefix):
        print(path)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
