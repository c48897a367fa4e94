"""The ``ffmpc`` command line's extension points (ffmpc_ros/cli_extensions.py): the studies'
commands come from entry points, a broken extension is one warning line, built-ins win."""

from __future__ import annotations

import argparse
from importlib import metadata

import pytest

from ffmpc_ros.cli import main
from ffmpc_ros.cli_extensions import (
    BENCH_GROUP,
    COMMAND_GROUP,
    CommandExtension,
    add_extension_parsers,
    load_extensions,
)

GROUP = "ffmpc.test"


class EchoCommand(CommandExtension):
    """A command that returns its --code."""

    help = "echo a code"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--code", type=int, default=0)

    def main(self, args: argparse.Namespace) -> int:
        return args.code


class NotACommand:
    pass


def _ep(name: str, value: str) -> metadata.EntryPoint:
    return metadata.EntryPoint(name=name, value=value, group=GROUP)


def test_the_installed_groups_name_the_studies_commands() -> None:
    commands = {ep.name: ep.value for ep in metadata.entry_points(group=COMMAND_GROUP)}
    bench = {ep.name: ep.value for ep in metadata.entry_points(group=BENCH_GROUP)}
    assert commands == {
        "demo": "studies.cli:DemoCommand",
        "ft": "studies.ft_cli:FtCommand",
        "study": "studies.cli:StudyCommand",
        "tune": "studies.cli:TuneCommand",
    }
    assert bench == {"impact": "studies.cli:BenchImpactVerb", "mpc": "studies.cli:BenchMpcVerb"}
    loaded = load_extensions(COMMAND_GROUP, warn=pytest.fail)
    assert sorted(loaded) == ["demo", "ft", "study", "tune"]


def test_load_skips_broken_foreign_and_repeated_entry_points() -> None:
    warnings: list[str] = []
    found = load_extensions(
        GROUP,
        [
            _ep("echo", "test_cli_extensions:EchoCommand"),
            _ep("echo", "test_cli_extensions:EchoCommand"),
            _ep("gone", "no_such_module_xyz:Command"),
            _ep("plain", "test_cli_extensions:NotACommand"),
        ],
        warn=warnings.append,
    )
    assert list(found) == ["echo"] and isinstance(found["echo"], EchoCommand)
    assert len(warnings) == 3
    assert any("'gone'" in w and "ModuleNotFoundError" in w for w in warnings)
    assert any("'plain'" in w and "not a CommandExtension" in w for w in warnings)
    assert any("'echo'" in w and "taken" in w for w in warnings)
    assert all("\n" not in w for w in warnings)


def test_added_parsers_run_the_extension_and_keep_built_ins() -> None:
    parser = argparse.ArgumentParser(prog="ffmpc")
    sub = parser.add_subparsers(dest="command", required=True)
    sub.add_parser("check").set_defaults(func=lambda args: 0)
    warnings: list[str] = []
    added = add_extension_parsers(
        sub,
        GROUP,
        reserved=["check"],
        entry_points=[
            _ep("echo", "test_cli_extensions:EchoCommand"),
            _ep("check", "test_cli_extensions:EchoCommand"),
        ],
        warn=warnings.append,
    )
    assert added == ["echo"]
    assert warnings == [f"{GROUP} entry point 'check' shadows a built-in command; skipped"]
    args = parser.parse_args(["echo", "--code", "7"])
    assert args.func(args) == 7
    args = parser.parse_args(["check"])
    assert args.func(args) == 0  # the built-in, not the extension


def test_ffmpc_help_lists_the_studies_commands(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in ("study", "tune", "run", "bench"):
        assert command in out.split("positional arguments:")[1]
    assert main(["bench", "--help"]) == 0
    assert "impact planner cycle time" in capsys.readouterr().out
    assert main(["study", "--help"]) == 0
    out = capsys.readouterr().out
    for study in ("polishing", "force-square", "paper", "impact", "explore"):
        assert study in out


def test_an_extension_error_names_the_whole_command(
    capsys: pytest.CaptureFixture[str],
) -> None:
    code = main(["study", "impact", "--set", "plant.dice_stiffness=0"])
    err = capsys.readouterr().err
    assert code == 2
    assert err.startswith("ffmpc study impact: error: ") and err.count("\n") == 1
