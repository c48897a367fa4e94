"""``ffmpc launch``'s steps, each alone, on a fake package of shell-script nodes:
prepare_launch (command lines, warnings, refusals before anything starts), then a
LaunchSession's spawn, pump, reap, run (its three ends: no node left, the time limit, a signal)
and stop."""

from __future__ import annotations

import io
import signal
import time
from pathlib import Path

import pytest

from ffmpc_ros.launch import LaunchError, LaunchSession, load_launch_file, prepare_launch

SCRIPTS = {
    "talk": "echo one; echo two; exit 0",
    "fail": "echo failing; exit 3",
    "wait": "exec sleep 30",
    "late": "sleep 1; echo late line; exit 0",
}


@pytest.fixture
def package(tmp_path, monkeypatch) -> Path:
    """A package ``fakepkg`` whose executables are :data:`SCRIPTS`."""
    prefix = tmp_path / "prefix"
    index = prefix / "share" / "ament_index" / "resource_index" / "packages"
    index.mkdir(parents=True)
    (index / "fakepkg").touch()
    (prefix / "lib" / "fakepkg").mkdir(parents=True)
    for name, body in SCRIPTS.items():
        exe = prefix / "lib" / "fakepkg" / name
        exe.write_text(f"#!/bin/sh\n{body}\n")
        exe.chmod(0o755)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(prefix))
    return tmp_path


def _launch(tmp_path: Path, *nodes: str):
    text = "launch:\n" + "".join(f"- node: {{pkg: fakepkg, {n}}}\n" for n in nodes)
    path = tmp_path / "x.launch.yaml"
    path.write_text(text)
    return load_launch_file(path)


def test_prepare_builds_every_command_and_refuses_before_anything_starts(package) -> None:
    out = io.StringIO()
    description = _launch(
        package, "exec: talk, name: a, param: [{name: x, value: 2}]", "exec: fail, name: b"
    )
    commands = prepare_launch(description, package / "logs", out)
    assert [node.label for node, _ in commands] == ["a", "b"]
    a = commands[0][1]
    assert a[0].endswith("lib/fakepkg/talk") and "__node:=a" in a
    # the {name, value} entry: a parameter file in the log directory, keyed by the node's name
    params = Path(a[a.index("--params-file") + 1])
    assert params.parent == package / "logs" and "/a:" in params.read_text()
    assert out.getvalue() == ""  # nothing to warn about
    twice = _launch(package, "exec: talk, name: a", "exec: fail, name: a")
    with pytest.raises(LaunchError, match="two nodes share a name"):
        prepare_launch(twice, package / "logs2", out)
    with pytest.raises(LaunchError, match="no executable 'nope'"):
        prepare_launch(_launch(package, "exec: nope"), package / "logs3", out)
    # a section keyed by the bare name does not reach a namespaced node: one warning line
    scenario = package / "p.yaml"
    scenario.write_text("a:\n  ros__parameters: {x: 1}\n")
    namespaced = _launch(
        package, f"exec: talk, name: a, namespace: /arm1, param: [{{from: {scenario}}}]"
    )
    prepare_launch(namespaced, package / "logs4", out)
    assert out.getvalue().startswith("[launch] WARNING a: section ") and "/**/a" in out.getvalue()


def test_spawn_pump_and_reap(package) -> None:
    out = io.StringIO()
    description = _launch(
        package, "exec: talk, output: screen", "exec: fail", "exec: wait, on_exit: shutdown"
    )
    session = LaunchSession(package / "logs", out)
    try:
        session.spawn(prepare_launch(description, package / "logs", out))
        assert list(session.children) == ["talk", "fail", "wait"] == list(session.running)
        deadline = time.monotonic() + 20.0
        while len(session.running) > 1 and time.monotonic() < deadline:
            session.pump()
            assert not session.reap()  # no shutdown node exited
        assert list(session.running) == ["wait"] and session.code == 3  # the first failure
        session.pump()  # the end of the pipes (end of file: unregistered)
        session.children["wait"].terminate()
        session.children["wait"].wait()
        assert session.reap()  # the shutdown node ended the launch: its code, not 0
        assert session.code == -signal.SIGTERM and session.running == {}
    finally:
        session.stop()
    text = out.getvalue()
    assert "[talk] one\n" in text and "[talk] two\n" in text
    assert "[fail]" not in text  # output: log
    assert "[launch] fail exited with 3" in text and "[launch] started wait (pid " in text
    assert (package / "logs" / "fail.log").read_text() == "failing\n"  # log output too
    assert (package / "logs" / "talk.log").read_text() == "one\ntwo\n"


def test_run_ends_on_the_time_limit_a_signal_or_the_last_exit(package) -> None:
    out = io.StringIO()
    description = _launch(package, "exec: wait", "exec: talk, output: screen")
    session = LaunchSession(package / "logs", out)
    try:
        session.spawn(prepare_launch(description, package / "logs", out))
        started = time.monotonic()
        assert session.run(0.3, []) == 124  # past the time limit
        assert time.monotonic() - started < 5.0 and "wait" in session.running
    finally:
        session.stop()  # SIGINT, which the node dies of
    assert all(child.poll() is not None for child in session.children.values())
    assert "[launch] time limit 0.3 s: stopping" in out.getvalue()
    signalled = LaunchSession(package / "logs_b", io.StringIO())
    try:
        signalled.spawn(prepare_launch(_launch(package, "exec: wait"), package / "logs_b", out))
        assert signalled.run(None, [signal.SIGTERM]) == 128 + signal.SIGTERM
    finally:
        signalled.stop()
    # no node left: the launch ends by itself with the first failure's code
    alone = LaunchSession(package / "logs_c", io.StringIO())
    try:
        alone.spawn(prepare_launch(_launch(package, "exec: late"), package / "logs_c", out))
        assert alone.run(30.0, []) == 0 and alone.running == {}
    finally:
        alone.stop()  # what the pipe still held is in the log too
    assert (package / "logs_c" / "late.log").read_text() == "late line\n"
