"""Helpers of the bad-input tests (issue 28): :func:`run_cases` runs many
command lines at once (a few processes at a time: each one imports ROS and refuses in 1-3 s)
and records, for each, the exit code, stdout, stderr and whether any file of the work directory
changed."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / "bags" / "polishing_short.mcap"
BIN = Path(sys.executable).parent
#: Command lines run at the same time (each is one process; the machine has 2 cores).
PARALLEL = 4


@dataclass(frozen=True)
class Result:
    """What one command line did."""

    code: int
    stdout: str
    stderr: str
    changed: tuple[str, ...]  # files of the work directory added, removed or modified


def snapshot(root: Path) -> dict[str, str]:
    """{relative path: sha256} of every file under ``root`` (directories as 'dir')."""
    out = {}
    for path in sorted(root.rglob("*")):
        rel = str(path.relative_to(root))
        out[rel] = "dir" if path.is_dir() else hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def changed(before: Mapping[str, str], after: Mapping[str, str]) -> tuple[str, ...]:
    return tuple(sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k)))


def run_cases(
    cases: Mapping[str, tuple[Sequence[str], Mapping[str, str]]], root: Path, timeout: float = 120
) -> dict[str, Result]:
    """Run every ``{id: (argv, extra environment)}`` (argv[0] an executable of this venv) in
    ``root``, :data:`PARALLEL` at a time. The work directory is snapshotted before the batch and
    after it: a case that changed a file shows in every result's ``changed`` (the tests assert
    none did), and the batch is run again one case at a time to name the culprit."""

    def one(argv: Sequence[str], env: Mapping[str, str]) -> tuple[int, str, str]:
        exe = str(BIN / argv[0]) if (BIN / argv[0]).exists() else argv[0]
        proc = subprocess.run(
            [exe, *argv[1:]],
            cwd=root,
            env={**os.environ, **env},
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        return proc.returncode, proc.stdout, proc.stderr

    before = snapshot(root)
    with ThreadPoolExecutor(PARALLEL) as pool:
        futures = {cid: pool.submit(one, argv, env) for cid, (argv, env) in cases.items()}
        outputs = {cid: f.result() for cid, f in futures.items()}
    diff = changed(before, snapshot(root))
    results = {cid: Result(*out, diff) for cid, out in outputs.items()}
    if diff:  # name the case that changed something
        for cid, (argv, env) in cases.items():
            start = snapshot(root)
            out = one(argv, env)
            results[cid] = Result(*out, changed(start, snapshot(root)))
    return results


def truncate(source: Path, target: Path, size: int) -> Path:
    """The first ``size`` bytes of ``source`` (a recorder killed mid-write)."""
    target.write_bytes(source.read_bytes()[:size])
    return target


def copy_bag(source: Path, target: Path, keep, until_ns: int) -> Path:
    """A complete bag with ``source``'s topics, definitions and metadata and the messages whose
    topic ``keep`` accepts, logged before ``until_ns`` (from the bag's start)."""
    from ffmpc_ros.bag.reader import BagReader
    from ffmpc_ros.bag.writer import BagWriter

    with BagReader(source) as src, BagWriter(target) as dst:
        for info in src.topics.values():
            dst.add_topic(
                info.topic,
                info.type,
                qos_profiles=info.qos_profiles,
                type_hash=info.type_hash,
                definition=info.definition,
            )
        for name, data in src.metadata:
            if name != "rosbag2":
                dst.add_metadata(name, data)
        start = src.start_time
        for m in src.messages():
            if keep(m.topic) and m.log_time - start < until_ns:
                dst.write(m.topic, m.data, m.log_time, m.publish_time, m.sequence)
    return target
