"""Every malformed command line of issue 28, run as a user runs it (the installed ``ffmpc`` and
node executables, as subprocesses): refused with exit 2 and ONE line on stderr that says why,
before anything started (nothing on stdout: no run summary, no ``[launch] started``), and no
file of the work directory changed (no output overwritten, nothing half-written)."""

from __future__ import annotations

import pytest
from bad_input_helpers import Result, copy_bag, run_cases

#: Where nothing can be written, even by root: /proc takes no new file.
UNWRITABLE = "/proc/ffmpc_bad_input"
#: A fault that refuses the run after everything before it was accepted (it proves a value
#: earlier on the command line was read, without starting a graph).
LATE = ["--fault", "mpc-dropout@5", "--duration", "0.05"]
LATE_REFUSAL = "fault mpc-dropout@5: starts at 5 s, after the run ends (0.05 s simulated)"

#: id: (argv, extra environment, text of the one error line)
CASES: dict[str, tuple[list[str], dict[str, str], str]] = {
    # -- 2: bags that hold less than a run -------------------------------------------------
    "bag-rerun-truncated": (
        ["ffmpc", "bag", "rerun", "trunc.mcap"],
        {},
        "trunc.mcap: TRUNCATED (ends inside a CHUNK record): only {messages} readable messages",
    ),
    "bag-play-truncated": (
        ["ffmpc", "bag", "play", "trunc.mcap"],
        {},
        "only {messages} readable messages in {chunks} complete chunks; nothing played",
    ),
    "bag-rerun-truncated-to-nothing": (
        ["ffmpc", "bag", "rerun", "trunc0.mcap"],
        {},
        "only 0 readable messages in 0 complete chunks; nothing re-run",
    ),
    "bag-play-empty": (
        ["ffmpc", "bag", "play", "empty.mcap"],
        {},
        "empty.mcap: holds no message (0 messages); nothing played",
    ),
    "bag-rerun-empty": (["ffmpc", "bag", "rerun", "empty.mcap"], {}, "holds no message"),
    "bag-recover-exists": (
        ["ffmpc", "bag", "recover", "trunc.mcap", "existing.mcap"],
        {},
        "out existing.mcap: exists; never overwritten (--force replaces it)",
    ),
    "bag-plot-exists": (
        ["ffmpc", "bag", "plot", "run.mcap", "--out", "existing.json"],
        {},
        "--out existing.json: exists; never overwritten",
    ),
    "bag-record-exists": (
        ["ffmpc", "bag", "record", "existing.mcap", "--duration", "1"],
        {},
        "bag existing.mcap: exists; never overwritten",
    ),
    "bag-record-unwritable": (
        ["ffmpc", "bag", "record", f"{UNWRITABLE}.mcap"],
        {},
        f"bag {UNWRITABLE}.mcap: cannot write in '/proc'",
    ),
    # -- 3: outputs: never overwritten, unwritable refused first ---------------------------
    "run-json-exists": (
        ["ffmpc", "run", "polishing", "--duration", "0.05", "--json", "existing.mcap"],
        {},
        "--json existing.mcap: exists; never overwritten (--force replaces it)",
    ),
    "run-json-unwritable": (
        ["ffmpc", "run", "polishing", "--duration", "0.05", "--json", f"{UNWRITABLE}.json"],
        {},
        f"--json {UNWRITABLE}.json: cannot write in '/proc'",
    ),
    "run-record-unwritable": (
        ["ffmpc", "run", "polishing", "--duration", "0.05", "--record", f"{UNWRITABLE}.mcap"],
        {},
        f"--record {UNWRITABLE}.mcap: cannot write in '/proc'",
    ),
    "run-record-exists": (
        ["ffmpc", "run", "polishing", "--record", "existing.mcap"],
        {},
        "--record existing.mcap: exists; never overwritten",
    ),
    "run-record-directory-force": (
        ["ffmpc", "run", "polishing", "--record", "outdir", "--force"],
        {},
        "--record outdir: a directory exists there; never replaced",
    ),
    "run-json-is-the-scenario": (
        ["ffmpc", "run", "sci.yaml", "--json", "sci.yaml", "--force"],
        {},
        "--json sci.yaml: the same file as the input sci.yaml",
    ),
    "run-impact-json-exists": (
        ["ffmpc", "run", "impact", "--json", "existing.json"],
        {},
        "--json existing.json: exists; never overwritten",
    ),
    # -- 4: numbers as ROS 2 writes them ---------------------------------------------------
    "set-1e4-is-a-number": (
        ["ffmpc", "run", "polishing", "--set", "mpc.contact.stiffness=1e4", *LATE],
        {},
        LATE_REFUSAL,
    ),
    "set-1e+09-is-the-bound": (
        ["ffmpc", "run", "polishing", "--set", "mpc.contact.stiffness=1e+09", *LATE],
        {},
        LATE_REFUSAL,
    ),
    "set-1e+10-is-out-of-range": (
        ["ffmpc", "run", "polishing", "--set", "mpc.contact.stiffness=1e+10"],
        {},
        "mpc.contact.stiffness = 10000000000.0: expected a number in [0, 1e+09] N/m",
    ),
    "set-inf-refused-by-the-range": (
        ["ffmpc", "run", "polishing", "--set", "task.normal_force=.inf"],
        {},
        "task.normal_force = inf: expected a number in [0, 500] N",
    ),
    "set-recovery-time-negative": (
        ["ffmpc", "run", "polishing", "--set", "mpc.constraints.recovery_time=-1"],
        {},
        "mpc.constraints.recovery_time = -1: expected a number in [0.0001, 10] s",
    ),
    "scenario-file-1e4-is-a-number": (["ffmpc", "run", "sci.yaml", *LATE], {}, LATE_REFUSAL),
    "duration-5e-2": (
        ["ffmpc", "run", "polishing", "--fault", "mpc-dropout@5", "--duration", "5e-2"],
        {},
        LATE_REFUSAL,
    ),
    "scenario-file-mixed-list": (
        ["ffmpc", "run", "mixed.yaml"],
        {},
        "a list mixes double, integer values (ROS 2 refuses it",
    ),
    # -- 5: nonsense refused before the run ------------------------------------------------
    "run-empty-scenario": (
        ["ffmpc", "run", "empty.yaml"],
        {},
        "empty.yaml: an empty scenario (no parameter)",
    ),
    "run-partial-scenario": (
        ["ffmpc", "run", "partial.yaml"],
        {},
        "partial.yaml: a partial scenario (no section /**, plant, joint_sensor, ft_sensor, pid)",
    ),
    "run-fault-unknown-node": (
        ["ffmpc", "run", "polishing", "--fault", "node-kill:nonexistent@0.01", *LATE[2:]],
        {},
        "fault node-kill:nonexistent@0.01: no node 'nonexistent' in this graph",
    ),
    "run-fault-after-the-end": (["ffmpc", "run", "polishing", *LATE], {}, LATE_REFUSAL),
    "run-fault-window-after-the-end": (
        ["ffmpc", "run", "polishing", "--fault-window", "5", "6", "--duration", "0.05"],
        {},
        "--fault-window 5 6: starts after the run ends (0.05 s)",
    ),
    "run-fault-real-time": (
        ["ffmpc", "run", "polishing", "--real-time", "--fault", "nan-wrench@0.1"],
        {},
        "nan-wrench is not supported in real time",
    ),
    "run-node-param-unknown-name": (
        ["ffmpc", "run", "polishing", "--node-param", "mpc:horizn:=3"],
        {},
        "horizn = 3: node mpc has no such parameter",
    ),
    "run-node-param-bad-value": (
        ["ffmpc", "run", "polishing", "--node-param", "pid:kp:=-1.0"],
        {},
        "kp = -1.0: expected a number in [0, 100]",
    ),
    "run-node-param-no-value": (
        ["ffmpc", "run", "polishing", "--node-param", "mpc:horizon"],
        {},
        "--node-param expects NODE:NAME:=VALUE, got 'mpc:horizon'",
    ),
    "run-node-param-not-yaml": (
        ["ffmpc", "run", "polishing", "--node-param", "mpc:horizon:=[1"],
        {},
        "'[1' is not a YAML value",
    ),
    "study-empty-scenario": (
        ["ffmpc", "study", "polishing", "--scenario", "empty.yaml"],
        {},
        "empty.yaml: an empty scenario",
    ),
    "study-out-unwritable": (
        ["ffmpc", "study", "polishing", "--out", f"{UNWRITABLE}/study"],
        {},
        "cannot write in '/proc'",
    ),
    "run-approach-speed-negative": (
        ["ffmpc", "run", "polishing", "--set", "task.approach_speed=-1"],
        {},
        "task.approach_speed = -1: expected a number in [0, 1] m/s",
    ),
    "run-contact-force-zero": (
        ["ffmpc", "run", "polishing", "--set", "task.contact_force=0"],
        {},
        "task.contact_force = 0: expected a number in [0.001, 500] N",
    ),
    "run-push-rise-longer-than-half": (
        ["ffmpc", "run", "push", "--set", "plant.push_rise_time=0.15"],
        {},
        "plant.push_rise_time = 0.15: expected at most half of plant.push_duration (0.2 s)",
    ),
    "run-negative-free-space-weight": (
        ["ffmpc", "run", "polishing", "--set", "mpc.weights.force_feedback.ee_position_free=-3"],
        {},
        "mpc.weights.force_feedback.ee_position_free = -3: expected a number >= 0",
    ),
    "tune-start-from-without-weights": (
        ["ffmpc", "tune", "classical", "--start-from", "existing.json"],
        {},
        "no searched mpc.weights.classical.* weight in the starting point (['keep'])",
    ),
    "tune-scenario-twice": (
        ["ffmpc", "tune", "classical", "--scenario", "polishing", "--scenario", "polishing"],
        {},
        "a training scenario is given twice: ['polishing', 'polishing']",
    ),
    "study-compare-missing": (
        ["ffmpc", "study", "compare", "nowhere.json", "existing.json"],
        {},
        "nowhere.json: no such results file",
    ),
    "study-compare-not-a-study": (
        ["ffmpc", "study", "compare", "existing.json", "existing.json"],
        {},
        "existing.json: not the results.json of a paper or impact study",
    ),
    "study-compare-one-file": (
        ["ffmpc", "study", "compare", "existing.json"],
        {},
        "compare needs two results files or more",
    ),
    "tune-out-exists": (
        ["ffmpc", "tune", "classical", "--out", "existing.json"],
        {},
        "--out existing.json: exists; never overwritten",
    ),
    "bench-json-exists": (
        ["ffmpc", "bench", "mpc", "--json", "existing.json"],
        {},
        "--json existing.json: exists; never overwritten",
    ),
    # -- 6: the environment ----------------------------------------------------------------
    "env-domain-abc": (
        ["ffmpc", "run", "polishing"],
        {"ROS_DOMAIN_ID": "abc"},
        "ROS_DOMAIN_ID='abc': expected an integer in [0, 232]",
    ),
    "env-domain-999": (
        ["ffmpc", "run", "polishing"],
        {"ROS_DOMAIN_ID": "999"},
        "ROS_DOMAIN_ID='999': expected an integer in [0, 232]",
    ),
    "env-discovery-range": (
        ["ffmpc", "bag", "play", "run.mcap"],
        {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LAN"},
        "ROS_AUTOMATIC_DISCOVERY_RANGE='LAN': expected one of OFF, LOCALHOST, SUBNET",
    ),
    "env-launch-domain": (
        ["ffmpc", "launch", "polishing.launch.yaml"],
        {"ROS_DOMAIN_ID": "-1"},
        "ROS_DOMAIN_ID='-1'",
    ),
    "env-node-executable": (
        ["ffmpc-mpc"],
        {"ROS_DOMAIN_ID": "999"},
        "ffmpc-mpc: error: ROS_DOMAIN_ID='999'",
    ),
    # -- ffmpc launch: the nodes' own checks, before any node starts -----------------------
    "launch-duration-text": (
        ["ffmpc", "launch", "polishing.launch.yaml", "duration:=abc"],
        {},
        "node plant: duration = 'abc': expected a number",
    ),
    "launch-formulation": (
        ["ffmpc", "launch", "polishing.launch.yaml", "formulation:=rigid"],
        {},
        "node mpc: formulation = 'rigid': expected one of",
    ),
    "launch-partial-scenario": (
        ["ffmpc", "launch", "polishing.launch.yaml", "scenario:={root}/partial.yaml"],
        {},
        "partial.yaml: a partial scenario",
    ),
    "launch-log-dir-has-files": (
        ["ffmpc", "launch", "polishing.launch.yaml", "--log-dir", "outdir"],
        {},
        "--log-dir outdir: holds files; never overwritten",
    ),
    "launch-timeout-nan": (
        ["ffmpc", "launch", "polishing.launch.yaml", "--timeout", "nan"],
        {},
        "argument --timeout: expected a finite number, got 'nan'",
    ),
}


@pytest.fixture(scope="module")
def results(workdir) -> dict[str, Result]:
    cases = {
        cid: ([a.replace("{root}", str(workdir)) for a in argv], env)
        for cid, (argv, env, _) in CASES.items()
    }
    return run_cases(cases, workdir)


@pytest.mark.parametrize("case", list(CASES))
def test_refused_with_one_line_before_anything_starts(case, results, truncated_counts):
    argv, _, template = CASES[case]
    expected = template.format(**truncated_counts) if case.endswith("-truncated") else template
    got = results[case]
    lines = got.stderr.strip().splitlines()
    assert got.code == 2, (got.code, got.stderr[-2000:])
    assert len(lines) == 1, got.stderr
    assert lines[0].startswith(f"{argv[0]}") and ": error: " in lines[0], lines[0]
    assert expected in lines[0], lines[0]
    assert got.stdout == "", got.stdout  # no summary, no [launch] line: nothing ran
    assert got.changed == (), got.changed


def test_rerun_fails_when_it_compared_nothing(workdir):
    """A complete bag whose MPC outputs were not recorded: the re-run feeds the inputs and
    compares nothing, which is a failure (exit 1) saying so, not "IDENTICAL"; the same bag with
    its outputs passes and says how many messages it compared."""
    keep_inputs = {"/clock", "/joint_sensor/joint_states", "/ft_sensor/wrench"}
    inputs_only = copy_bag(
        workdir / "run.mcap", workdir / "inputs_only.mcap", keep_inputs.__contains__, 20_000_000
    )
    whole = copy_bag(workdir / "run.mcap", workdir / "short.mcap", lambda t: True, 20_000_000)
    got = run_cases(
        {
            "nothing": (["ffmpc", "bag", "rerun", inputs_only.name], {}),
            "short": (["ffmpc", "bag", "rerun", whole.name], {}),
        },
        workdir,
    )
    nothing, short = got["nothing"], got["short"]
    assert nothing.code == 1, nothing.stderr
    verdict = nothing.stdout.strip().splitlines()[-1]
    assert verdict.startswith("FAILED: the re-run checked less than the recording holds")
    assert "nothing compared" in verdict and "IDENTICAL" not in nothing.stdout
    assert short.code == 0, short.stdout + short.stderr
    assert "compared 20 recorded output messages on 2 topics" in short.stdout, short.stdout
    assert short.stdout.strip().splitlines()[-1] == "outputs IDENTICAL to the recording"
