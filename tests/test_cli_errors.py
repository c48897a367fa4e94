"""Every malformed ``ffmpc`` invocation: one line on stderr, exit 2, never a traceback.

The table covers every command (run, study polishing|force-square|impact|explore, bench
mpc|impact, bag info|play|plot|metrics|rerun|recover|record, check, demo). Each case must be
refused before any simulation starts, so the whole table runs in seconds. A few go through a
subprocess of the ``ffmpc`` console script to see the real stderr, and a node started with bad
parameters must exit non-zero with one line naming the parameter.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ffmpc_ros.cli import main

REPO = Path(__file__).resolve().parents[1]
BAG = REPO / "bags" / "polishing_short.mcap"
FFMPC = Path(sys.executable).parent / "ffmpc"


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, str]:
    """Paths the table refers to: an existing file and directory, a non-bag, bad scenarios."""
    root = tmp_path_factory.mktemp("cli")
    (root / "exists.txt").write_text("x")
    (root / "exists_dir").mkdir()
    (root / "notabag.mcap").write_text("this is not an MCAP file\n")
    (root / "empty.mcap").write_bytes(b"")
    (root / "broken.yaml").write_text("plant:\n  ros__parameters: {time_step: [1, 2\n")
    (root / "list.yaml").write_text("- 1\n- 2\n")
    (root / "badsection.yaml").write_text("planet:\n  ros__parameters: {time_step: 0.001}\n")
    (root / "boolstiff.yaml").write_text(
        "/**:\n  ros__parameters: {base: polishing}\n"
        "mpc:\n  ros__parameters:\n    contact: {stiffness: true}\n"
    )
    return {p.name: str(p) for p in root.iterdir()} | {"root": str(root)}


#: (id, argv with {placeholders} for ``files`` and {bag}, text the error line must contain)
CASES: list[tuple[str, list[str], str]] = [
    # -- ffmpc (no command), syntax --------------------------------------------------------
    ("no-command", [], "required"),
    ("unknown-command", ["fly"], "invalid choice"),
    # -- run --------------------------------------------------------------------------------
    ("run-unknown-scenario", ["run", "nosuchscenario"], "no scenario 'nosuchscenario'"),
    ("run-missing-file", ["run", "/nonexistent/dir/x.yaml"], "no scenario"),
    ("run-set-no-equals", ["run", "polishing", "--set", "mpc.horizon"], "expected NAME=VALUE"),
    ("run-set-empty-name", ["run", "polishing", "--set", "=3"], "expected NAME=VALUE"),
    ("run-set-bad-yaml", ["run", "polishing", "--set", "mpc.horizon=[1, 2"], "not a YAML"),
    ("run-set-unknown", ["run", "polishing", "--set", "mpc.horizn=3"], "did you mean mpc.horizon"),
    ("run-set-bool-number", ["run", "polishing", "--set", "mpc.contact.stiffness=true"], "= True"),
    ("run-set-str-number", ["run", "polishing", "--set", "task.normal_force=abc"], "a number"),
    ("run-set-float-int", ["run", "polishing", "--set", "mpc.horizon=5.5"], "an integer"),
    ("run-set-out-of-range", ["run", "polishing", "--set", "mpc.horizon=-1"], "[1, 1000]"),
    ("run-set-nan", ["run", "polishing", "--set", "task.normal_force=.nan"], "nan"),
    ("run-bad-namespace", ["run", "polishing", "--namespace", "/arm 1"], "not a ROS namespace"),
    ("run-namespace-digit", ["run", "polishing", "--namespace", "1arm"], "starts with a number"),
    ("run-set-mapping", ["run", "polishing", "--set", "task={a: 1}"], "not a mapping"),
    ("run-set-list-len", ["run", "polishing", "--set", "plant.push_force=[1, 2]"], "3 numbers"),
    ("run-seed-negative", ["run", "polishing", "--seed", "-1"], "argument --seed"),
    ("run-seed-text", ["run", "polishing", "--seed", "one"], "expected an integer"),
    ("run-duration-negative", ["run", "polishing", "--duration", "-2"], "argument --duration"),
    ("run-duration-nan", ["run", "polishing", "--duration", "nan"], "finite"),
    ("run-timeout-zero", ["run", "polishing", "--timeout", "0"], "argument --timeout"),
    ("run-formulation", ["run", "polishing", "--formulation", "rigid"], "invalid choice"),
    ("run-bad-flag", ["run", "polishing", "--fast"], "unrecognized arguments"),
    ("run-record-exists", ["run", "polishing", "--record", "{exists.txt}"], "exists"),
    ("run-json-dir", ["run", "polishing", "--json", "{exists_dir}"], "argument --json"),
    ("run-cpus-bad", ["run", "polishing", "--real-time", "--cpus", "a,b"], "--cpus"),
    ("run-priority-high", ["run", "polishing", "--real-time", "--priority", "200"], "0..99"),
    (
        "run-real-time-node-param",
        ["run", "polishing", "--real-time", "--node-param", "pid:kp:=0.2"],
        "the mpc node's only",
    ),
    (
        "run-real-time-iterations-negative",
        ["run", "polishing", "--real-time", "--node-param", "mpc:real_time_iterations:=-1"],
        "real_time_iterations",
    ),
    ("run-yaml-broken", ["run", "{broken.yaml}"], "not a YAML file"),
    ("run-yaml-list", ["run", "{list.yaml}"], "expected a mapping"),
    ("run-yaml-section", ["run", "{badsection.yaml}"], "unknown node section"),
    ("run-yaml-bool-stiffness", ["run", "{boolstiff.yaml}"], "mpc.contact.stiffness = True"),
    # -- study polishing | force-square | impact | explore -----------------------------------
    ("study-no-kind", ["study"], "required"),
    ("study-seeds-zero", ["study", "polishing", "--seeds", "0"], "argument --seeds"),
    ("study-first-seed-neg", ["study", "polishing", "--first-seed", "-4"], "--first-seed"),
    ("study-workers-zero", ["study", "polishing", "--workers", "0"], "argument --workers"),
    ("study-duration-inf", ["study", "force-square", "--duration", "inf"], "finite"),
    ("study-scenario-missing", ["study", "polishing", "--scenario", "nope"], "no scenario"),
    ("study-set-unknown", ["study", "polishing", "--set", "pid.gain=3"], "pid.gain = 3"),
    ("study-set-bool", ["study", "force-square", "--set", "pid.kp=yes"], "pid.kp = True"),
    ("study-out-exists", ["study", "polishing", "--out", "{exists_dir}"], "--force"),
    ("study-plot-seed", ["study", "polishing", "--seeds", "2", "--plot-seed", "7"], "plot-seed"),
    ("study-formulation", ["study", "polishing", "--formulations", "mpc"], "invalid choice"),
    ("study-delays-negative", ["study", "polishing", "--command-delays", "-1"], "--command-delays"),
    (
        "study-delays-and-set",
        ["study", "polishing", "--command-delays", "0", "--set", "mpc.command_delay=0"],
        "give it once",
    ),
    ("paper-seeds-zero", ["study", "paper", "--seeds", "0"], "argument --seeds"),
    ("paper-delays-word", ["study", "paper", "--command-delays", "soon"], "measured"),
    ("paper-set-delay", ["study", "paper", "--set", "mpc.command_delay=0"], "--command-delays"),
    ("paper-set-unknown", ["study", "paper", "--set", "pid.gain=3"], "pid.gain = 3"),
    ("paper-out-exists", ["study", "paper", "--out", "{exists_dir}"], "--force"),
    (
        "study-workers-scheduler",
        ["study", "polishing", "--workers", "2", "--scheduler", "x"],
        "exclude",
    ),
    ("impact-target-nan", ["study", "impact", "--target-force", "nan"], "--target-force"),
    ("impact-dice-neg", ["study", "impact", "--dice-stiffness", "-3"], "--dice-stiffness"),
    ("impact-runs", ["study", "impact", "--runs", "fast+slow"], "invalid choice"),
    ("impact-out-exists", ["study", "impact", "--out", "{exists_dir}"], "exists"),
    (
        "impact-set-unknown",
        ["study", "impact", "--set", "plant.dice_stifness=3000"],
        "did you mean",
    ),
    ("impact-set-range", ["study", "impact", "--set", "plant.dice_stiffness=0"], "in [1, 1e+07]"),
    ("impact-set-type", ["study", "impact", "--set", "planner.horizon=2.5"], "an integer"),
    ("impact-set-choice", ["study", "impact", "--set", "strategy=fast"], "one of 'strike_first'"),
    (
        "impact-set-twice",
        ["study", "impact", "--dice-stiffness", "3000", "--set", "plant.dice_stiffness=4000"],
        "also given by --dice-stiffness",
    ),
    (
        "impact-set-graph-name",
        ["study", "impact", "--set", "mpc.formulation=classical"],
        "unknown scenario parameter",
    ),
    ("impact-scenario", ["study", "impact", "--scenario", "polishing"], "unknown node section"),
    ("impact-scenario-missing", ["study", "impact", "--scenario", "nosuch"], "no scenario"),
    ("explore-material", ["study", "explore", "--materials", "wood"], "invalid choice"),
    ("explore-set-unknown", ["study", "explore", "--set", "sine_cycle=2"], "did you mean"),
    (
        "explore-set-velocities",
        ["study", "explore", "--set", "impact_velocities=[0.2, -1]"],
        "impact_velocities = [0.2, -1]",
    ),
    ("explore-set-bad-yaml", ["study", "explore", "--set", "gains.position=[1"], "not a YAML"),
    ("explore-cycles", ["study", "explore", "--sine-cycles", "0"], "--sine-cycles"),
    ("explore-velocity", ["study", "explore", "--impact-velocities", "-0.2"], "velocities"),
    # -- bench --------------------------------------------------------------------------------
    ("bench-mpc-solves", ["bench", "mpc", "--solves", "0"], "argument --solves"),
    ("bench-mpc-cases", ["bench", "mpc", "--cases", "rigid"], "--cases"),
    ("bench-mpc-cases-n", ["bench", "mpc", "--cases", "classical:7"], "--cases"),
    ("bench-mpc-json-dir", ["bench", "mpc", "--json", "/nonexistent/dir/x.json"], "no directory"),
    ("bench-impact-cycles", ["bench", "impact", "--cycles", "-5"], "argument --cycles"),
    ("bench-impact-sim", ["bench", "impact", "--sim-duration", "0"], "--sim-duration"),
    # -- bag ------------------------------------------------------------------------------------
    ("bag-info-missing", ["bag", "info", "/nonexistent.mcap"], "no bag file"),
    ("bag-info-notabag", ["bag", "info", "{notabag.mcap}"], "not an MCAP file"),
    ("bag-info-empty", ["bag", "info", "{empty.mcap}"], "not an MCAP file"),
    ("bag-info-dir", ["bag", "info", "{exists_dir}"], "no bag file"),
    ("bag-play-rate", ["bag", "play", "{bag}", "--rate", "0"], "argument --rate"),
    ("bag-play-topic", ["bag", "play", "{bag}", "--topics", "/nope"], "not in the bag"),
    ("bag-play-remap", ["bag", "play", "{bag}", "--remap", "a-b"], "remap"),
    ("bag-plot-notabag", ["bag", "plot", "{notabag.mcap}"], "not an MCAP file"),
    ("bag-plot-out-exists", ["bag", "plot", "{bag}", "--out", "{exists.txt}"], "exists"),
    ("bag-metrics-notabag", ["bag", "metrics", "{notabag.mcap}"], "not an MCAP file"),
    ("bag-rerun-node", ["bag", "rerun", "{bag}", "--node", "plant"], "invalid choice"),
    ("bag-rerun-rtol", ["bag", "rerun", "{bag}", "--rtol", "-1"], "argument --rtol"),
    ("bag-rerun-set", ["bag", "rerun", "{bag}", "--set", "mpc.horizon=0"], "mpc.horizon = 0"),
    ("bag-rerun-set-name", ["bag", "rerun", "{bag}", "--set", "nothing=1"], "no parameter"),
    ("bag-recover-exists", ["bag", "recover", "{bag}", "{exists.txt}"], "exists"),
    ("bag-recover-notabag", ["bag", "recover", "{notabag.mcap}", "{root}/out.mcap"], "MCAP"),
    ("bag-record-exists", ["bag", "record", "{exists.txt}"], "exists"),
    ("bag-record-duration", ["bag", "record", "{root}/new.mcap", "--duration", "-1"], "duration"),
    # -- check, demo ----------------------------------------------------------------------------
    ("check-samples", ["check", "--samples", "0"], "argument --samples"),
    ("check-seed", ["check", "--seed", "x"], "argument --seed"),
    ("demo-seed", ["demo", "--seed", "-1"], "argument --seed"),
    ("demo-extra", ["demo", "extra"], "unrecognized arguments"),
]


def _argv(template: list[str], files: dict[str, str]) -> list[str]:
    out = []
    for arg in template:
        for key, value in (files | {"bag": str(BAG)}).items():
            arg = arg.replace("{" + key + "}", value)
        out.append(arg)
    return out


def test_the_table_is_big_and_covers_every_command():
    assert len(CASES) >= 40
    assert len({c[0] for c in CASES}) == len(CASES)
    commands = {
        tuple(c[1][:2]) if c[1][:1] in (["study"], ["bench"], ["bag"]) else tuple(c[1][:1])
        for c in CASES
    }
    for needed in (
        ("run",),
        ("check",),
        ("demo",),
        ("study", "polishing"),
        ("study", "force-square"),
        ("study", "paper"),
        ("study", "impact"),
        ("study", "explore"),
        ("bench", "mpc"),
        ("bench", "impact"),
        *(("bag", b) for b in ("info", "play", "plot", "metrics", "rerun", "recover", "record")),
    ):
        assert needed in commands, needed


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_malformed_invocation_one_line_exit_2(case, files, capfd):
    _, template, expected = case
    code = main(_argv(template, files))
    out, err = capfd.readouterr()
    lines = err.strip().splitlines()
    assert code == 2, (code, err)
    assert len(lines) == 1, err
    assert "Traceback" not in err and "Traceback" not in out
    assert lines[0].startswith("ffmpc"), lines[0]
    assert expected in lines[0], lines[0]


def test_help_still_exits_0(capsys):
    assert main(["run", "--help"]) == 0
    assert "scenario" in capsys.readouterr().out


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.mark.skipif(not FFMPC.exists() and shutil.which("ffmpc") is None, reason="no ffmpc")
@pytest.mark.parametrize(
    "argv, expected",
    [
        (["run", "polishing", "--set", "mpc.contact.stiffness=true"], "mpc.contact.stiffness"),
        (["study", "polishing", "--seeds", "-3"], "argument --seeds"),
        (["bag", "info", "/nonexistent.mcap"], "no bag file"),
        (["run", "polishing", "--set", "seed=-1"], "seed = -1"),
    ],
)
def test_console_script_real_stderr(argv, expected):
    exe = str(FFMPC) if FFMPC.exists() else shutil.which("ffmpc")
    proc = subprocess.run(
        [exe, *argv], capture_output=True, text=True, timeout=120, env=_env(), check=False
    )
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and expected in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    "module, param, expected",
    [
        ("ffmpc_ros.mpc_node", "horizon:=-1", "mpc.horizon = -1: expected an integer"),
        ("ffmpc_ros.mpc_node", "contact.stiffness:=true", "mpc.contact.stiffness = True"),
        ("ffmpc_ros.pid_node", "kp:=abc", "pid.kp = 'abc': expected a number"),
        ("ffmpc_ros.joint_sensor_node", "max_input_age:=-1.0", "max_input_age = -1.0"),
    ],
)
def test_node_with_bad_parameter_exits_with_one_line(module, param, expected):
    proc = subprocess.run(
        [sys.executable, "-m", module, "--ros-args", "-p", param],
        capture_output=True,
        text=True,
        timeout=120,
        env=_env(),
        check=False,
    )
    lines = [ln for ln in proc.stderr.strip().splitlines() if not ln.startswith("pybullet")]
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and expected in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr
