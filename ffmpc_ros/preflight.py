"""Checks made before anything starts: every command of ``ffmpc`` (and the studies' commands)
refuses bad input with one line and exit 2 before a node, a process, a calibration run or a
file write begins.

* the ROS environment (:func:`ffmpc_ros.discovery.check_ros_environment`: ``ROS_DOMAIN_ID``,
  ``ROS_AUTOMATIC_DISCOVERY_RANGE``);
* output paths (:func:`check_output`): an existing path is refused unless ``--force`` (then a
  file is replaced, a directory never), and a path that cannot be written (its directory is
  missing, read-only or not a directory) is refused — found by creating and removing a probe
  file there, since permission bits say nothing for root or a read-only mount;
* the same file as input and output (:func:`check_distinct`);
* faults against the graph (:func:`check_faults`: the mode, the node a ``node-kill`` names, and
  the run's duration: a fault that starts after the end would never be injected), and fault
  windows (:func:`check_fault_windows`).

Numbers everywhere are read by :mod:`ffmpc_core.values` (ROS 2's rules).
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterable, Sequence
from pathlib import Path

from ffmpc_core.errors import ConfigError
from ffmpc_core.faults import Fault


def check_output(path: str | os.PathLike, *, force: bool = False, what: str = "output") -> Path:
    """``path`` as a Path if a new file (or a rosbag2 folder) may be written there: it does not
    exist (or, with ``force``, is a file that will be replaced), its directory exists and is
    writable. ConfigError naming ``what`` (``--json``) otherwise; nothing is changed."""
    out = Path(path)
    if not str(path):
        raise ConfigError(f"{what}: expected a path, got ''")
    if out.exists() or out.is_symlink():
        if out.is_dir():
            raise ConfigError(f"{what} {path}: a directory exists there; never replaced")
        if not force:
            raise ConfigError(f"{what} {path}: exists; never overwritten (--force replaces it)")
    parent = out.parent
    if not parent.is_dir():
        raise ConfigError(f"{what} {path}: no directory {str(parent)!r}")
    try:
        fd, probe = tempfile.mkstemp(prefix=".ffmpc-write-check-", dir=parent)
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise ConfigError(f"{what} {path}: cannot write in {str(parent)!r} ({reason})") from None
    os.close(fd)
    os.unlink(probe)
    return out


def replace_forced(path: str | os.PathLike | None, force: bool) -> None:
    """With ``--force``, remove the existing FILE ``path`` that :func:`check_output` allowed to
    be replaced (a writer that refuses an existing file, the bag recorder, then writes anew).
    Call it once every check passed, just before the run starts."""
    if path is not None and force and Path(path).is_file():
        os.unlink(path)


def check_distinct(
    outputs: Iterable[tuple[str, str | os.PathLike | None]],
    inputs: Iterable[str | os.PathLike | None],
) -> None:
    """ConfigError when two outputs, or an output and an input, are the same file (``--force
    --json scenario.yaml`` would replace the scenario it runs)."""
    seen: dict[Path, str] = {}
    for item in inputs:
        if item is not None and Path(item).exists():
            seen[Path(item).resolve()] = f"the input {item}"
    for what, item in outputs:
        if item is None:
            continue
        key = Path(item).resolve()
        if key in seen:
            raise ConfigError(f"{what} {item}: the same file as {seen[key]}")
        seen[key] = f"{what} {item}"


def check_fault_windows(windows: Sequence[Sequence[float]], duration: float) -> None:
    """Each ``--fault-window START END``: finite, 0 <= START < END, START before the end of the
    run (``duration`` s)."""
    for start, end in windows:
        if not (0.0 <= start < end) or end == float("inf"):
            raise ConfigError(
                f"--fault-window {start:g} {end:g}: expected 0 <= START < END (simulated s)"
            )
        if start >= duration:
            raise ConfigError(
                f"--fault-window {start:g} {end:g}: starts after the run ends ({duration:g} s)"
            )


def check_faults(
    faults: Sequence[Fault],
    *,
    duration: float,
    nodes: Iterable[str],
    single_process: bool,
    lockstep: bool,
) -> None:
    """Every fault can be injected in this run (ConfigError, one line, naming the first that
    cannot): its kind in this mode (``ffmpc_ros.fault_injector.check_supported``), the node a
    ``node-kill`` names among the graph's ``nodes``, and a start before the end of the run
    (``duration`` simulated s: a later one would be reported "handled safely" with nothing
    injected)."""
    from ffmpc_ros.fault_injector import check_supported

    check_supported(faults, single_process, lockstep)
    names = list(nodes)
    for fault in faults:
        if fault.node is not None and fault.node not in names:
            raise ConfigError(
                f"fault {fault}: no node {fault.node!r} in this graph (nodes: {', '.join(names)})"
            )
        if fault.start >= duration:
            raise ConfigError(
                f"fault {fault}: starts at {fault.start:g} s, after the run ends "
                f"({duration:g} s simulated): it would never be injected"
            )
