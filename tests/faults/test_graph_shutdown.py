"""``ffmpc run`` stopped from outside, a second graph on the same domain, a node that dies.

* SIGTERM of ``ffmpc run --record``: exit 143, one line and no traceback, every child gone, the
  bag readable by ``mcap``'s reader and by ``rosbags`` with no recovery. Meanwhile a second
  ``ffmpc run`` on the same ROS domain is refused at once with the foreign publishers named.
* SIGKILL of ``ffmpc run --record``: no child survives, the bag is still readable by both.
* A node killed behind the bring-up's back: non-zero exit naming the node and its status.

Children are found by the marker the bring-up puts in their command lines
(``ffmpc_ros.bringup.child_marker``), in ``/proc``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from ffmpc_ros.bringup import child_marker

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def _start(tmp_path: Path, *args: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "ffmpc_ros.cli", "run", "polishing", *args]
    return subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=open(tmp_path / "stderr.txt", "w"),  # noqa: SIM115
        text=True,
        env=os.environ,
    )


def children_of(pid: int) -> dict[int, str]:
    """{pid: command line} of the live processes carrying the bring-up ``pid``'s marker."""
    marker = child_marker(pid).encode()
    out = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
            state = (entry / "stat").read_text().rpartition(")")[2].split()[0]
        except OSError:
            continue
        if marker in cmdline.split(b"\0") and state != "Z":
            out[int(entry.name)] = cmdline.replace(b"\0", b" ").decode(errors="replace")
    return out


def _wait_running(proc: subprocess.Popen, bag: Path, timeout: float = 180.0) -> None:
    """Until the bag holds recorded messages (the run is stepping)."""
    deadline = time.monotonic() + timeout
    err = bag.parent / "stderr.txt"
    while time.monotonic() < deadline:
        assert proc.poll() is None, f"the run ended before it was stopped: {err.read_text()}"
        if bag.exists() and bag.stat().st_size > 200_000:
            return
        time.sleep(0.2)
    pytest.fail(f"the run did not start: {err.read_text()[-3000:]}; {children_of(proc.pid)}")


def _wait_no_children(pid: int, timeout: float = 15.0) -> dict[int, str]:
    deadline = time.monotonic() + timeout
    left = children_of(pid)
    while left and time.monotonic() < deadline:
        time.sleep(0.1)
        left = children_of(pid)
    return left


def _read_both(bag: Path) -> tuple[int, int]:
    """Messages read by mcap's reader and by rosbags (both must open the bag as is)."""
    with open(bag, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        assert summary is not None  # a finalised bag: summary and footer written
        n_mcap = sum(1 for _ in reader.iter_messages())
    with AnyReader([bag], default_typestore=TYPESTORE) as reader:
        n_rosbags = 0
        for connection, _, raw in reader.messages():
            if connection.topic == "/clock":
                reader.deserialize(raw, connection.msgtype)
            n_rosbags += 1
    return n_mcap, n_rosbags


def test_sigterm_closes_the_bag_and_a_second_graph_is_refused(tmp_path):
    bag = tmp_path / "run.mcap"
    proc = _start(tmp_path, "--duration", "20", "--record", str(bag))
    try:
        _wait_running(proc, bag)
        assert len(children_of(proc.pid)) == 7  # six nodes (state publisher included), the recorder
        t0 = time.monotonic()
        second = subprocess.run(
            [sys.executable, "-m", "ffmpc_ros.cli", "run", "polishing", "--duration", "0.1"],
            capture_output=True,
            text=True,
            timeout=120,
            env=os.environ,
        )
        refused_in = time.monotonic() - t0
        assert second.returncode == 2, second.stderr[-2000:]
        assert "foreign nodes on this graph's topics" in second.stderr, second.stderr
        # Discovery is incremental: the refusal names the running graph's nodes discovered so far
        # (all of them on a quiet machine; two in one fresh-clone run on a busy one, only the
        # metrics node in another, only the recorder in a third).
        graph = ("/plant", "/joint_sensor", "/ft_sensor", "/mpc", "/pid", "/metrics")
        named = [n for n in (*graph, "/state_publisher", "/ffmpc_recorder") if n in second.stderr]
        assert named, second.stderr
        assert refused_in < 60.0  # never a silent hang
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = (tmp_path / "stderr.txt").read_text()
    assert code == 143, err
    assert "Traceback" not in err
    assert err.strip().splitlines()[-1].startswith("ffmpc run: terminated (SIGTERM)")
    assert _wait_no_children(proc.pid) == {}
    n_mcap, n_rosbags = _read_both(bag)
    assert n_mcap == n_rosbags > 1000


def test_sigkill_of_the_parent_leaves_no_process_and_a_readable_bag(tmp_path):
    bag = tmp_path / "run.mcap"
    proc = _start(tmp_path, "--duration", "20", "--record", str(bag))
    try:
        _wait_running(proc, bag)
        assert len(children_of(proc.pid)) == 7
        proc.kill()
        proc.wait(timeout=10)
        left = _wait_no_children(proc.pid)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert left == {}
    n_mcap, n_rosbags = _read_both(bag)
    assert n_mcap == n_rosbags > 1000


def test_a_node_that_dies_takes_the_run_down_with_its_name(tmp_path):
    bag = tmp_path / "run.mcap"
    proc = _start(tmp_path, "--duration", "20", "--record", str(bag))
    try:
        _wait_running(proc, bag)
        (pid_node,) = [p for p, cmd in children_of(proc.pid).items() if "pid_node" in cmd]
        os.kill(pid_node, signal.SIGKILL)
        code = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = (tmp_path / "stderr.txt").read_text()
    assert code == 2, err
    assert f"node pid (pid {pid_node}) died unexpectedly: killed by SIGKILL" in err
    assert "Traceback" not in err
    assert _wait_no_children(proc.pid) == {}
    _read_both(bag)  # the recorder was stopped cleanly too
