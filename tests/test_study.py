"""The simulation study (studies.study, ``ffmpc study``): Dask vs in-process determinism,
output files, tables vs the JSON runs, failures, and the shipped scenario files.

Runs are short (0.3 s of simulated time with contact and circle from 0.15 s on) so the whole
file stays well under a minute.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from ffmpc_core.config import FORMULATIONS
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.metrics import PolishingMetrics, summarize
from ffmpc_core.polishing import draw_run
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import PAPER_SCHEDULE, load_scenario
from ffmpc_ros.cli import main
from studies import study
from studies.study import (
    RunSpec,
    execute_run,
    grid_specs,
    parse_cell,
    parse_markdown_table,
    prepare_output_dir,
    run_specs,
)

#: Contact at once and the circle from t = 0.15 s: a 0.3 s run has a 0.15 s metrics window.
SHORT = {
    **PAPER_SCHEDULE,  # no touch phase, the circle stepped
    "task.still": 0.0,
    "task.reach": 0.05,
    "task.force_ramp": 0.1,
    "task.start_height": 0.0,
}
SHORT_SET = [arg for k, v in SHORT.items() for arg in ("--set", f"{k}={v}")]
LABELS = study.LABELS
ROWS = ("E_P (mm)", "E_λ (N)", "λmax (N)", "t_break (%)")


def _comparable(summary: dict) -> dict:
    return {k: v for k, v in summary.items() if k not in ("wall_time_s", "solve_time_median_s")}


def test_a_two_run_study_gives_the_same_numbers_on_a_dask_cluster_and_in_process() -> None:
    specs = [
        RunSpec("polishing", "force_feedback", True, 3, 0.3, tuple(SHORT.items()), plot=True),
        RunSpec("polishing", "classical", False, 4, 0.3, tuple(SHORT.items())),
    ]
    pooled = run_specs(specs, workers=2, progress=False)
    local = run_specs(specs, workers=1, progress=False)
    # workers=2: a Dask LocalCluster of two spawned processes; outcomes come back in the order
    # of the specs.
    assert [o.spec for o in pooled] == specs
    for a, b in zip(pooled, local, strict=True):
        assert a.ok and b.ok, (a.error, b.error)
        assert _comparable(a.summary) == _comparable(b.summary)
    assert pooled[0].summary["metrics_true"]["max_force"] > 5.0  # contact happened
    # Only the plotted run ships a (downsampled) log back from the cluster.
    assert pooled[1].plot_log is None
    log = pooled[0].plot_log
    assert set(log) == {*study.PLOT_SIGNALS, "window"}
    assert log["t"].size == 150 and np.allclose(np.diff(log["t"]), study.PLOT_STEP)
    np.testing.assert_array_equal(log["force_true"], local[0].plot_log["force_true"])
    assert log["window"][0] == pytest.approx(0.15, abs=1.5e-3)  # first sample of the circle


def _check_table(text: str, title: str, cells: dict[str, dict | None]) -> None:
    """Every cell of a Table II/III is present and equals summarize() to the printed 2 decimals."""
    table = parse_markdown_table(text, title)
    assert list(table) == list(ROWS)
    for form, agg in cells.items():
        expected = {
            "E_P (mm)": (agg["position_mae_mm_mean"], agg["position_mae_mm_std"]),
            "E_λ (N)": (agg["force_mae_mean"], agg["force_mae_std"]),
            "λmax (N)": (agg["max_force"], None),
            "t_break (%)": (agg["contact_break_percent"], None),
        }
        for row, (mean, std) in expected.items():
            got_mean, got_std = parse_cell(table[row][LABELS[form]])
            assert got_mean == pytest.approx(mean, abs=0.0051), (title, row, form)
            if std is None:
                assert got_std is None
            else:
                assert got_std == pytest.approx(std, abs=0.0051), (title, row, form)


def test_study_cli_writes_files_refuses_to_overwrite_and_tables_match_the_runs(
    tmp_path, capsys
) -> None:
    out = tmp_path / "study"
    argv = ["study", "polishing", "--seeds", "2", "--workers", "1", "--duration", "0.3"]
    argv += ["--out", str(out), "--no-progress", *SHORT_SET]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    names = sorted(p.name for p in out.iterdir())
    assert names == [
        "cache",  # one JSON file per finished run (tests/test_study_dask.py)
        "fig_polishing_nopid.png",
        "fig_polishing_pid.png",
        "results.json",
        "tables.md",
    ]
    for png in ("fig_polishing_nopid.png", "fig_polishing_pid.png"):
        data = (out / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and 10_000 < len(data) < 400_000
    doc = json.loads((out / "results.json").read_text())
    text = (out / "tables.md").read_text()
    assert text in printed and str(out / "tables.md") in printed

    # The JSON holds every run of the grid, with what is needed to reproduce it.
    assert doc["failures"] == []
    assert len(doc["runs"]) == 2 * 3 * 2
    assert {(r["formulation"], r["pid_enabled"], r["seed"]) for r in doc["runs"]} == {
        (f, p, s) for f in FORMULATIONS for p in (True, False) for s in (0, 1)
    }
    assert doc["command_line"].startswith("ffmpc study polishing --seeds 2")
    assert doc["versions"]["crocoddyl"] and doc["versions"]["pin"]
    assert doc["overrides"] == SHORT and doc["duration_s"] == 0.3
    assert doc["wall_time_s"] > 0
    # Same seed → same draws for every controller (the paper's paired comparison).
    for seed in (0, 1):
        tilts = {r["tilt_deg"] for r in doc["runs"] if r["seed"] == seed}
        assert len(tilts) == 1
    assert "TRUE normal force" in text and "MEASURED force" in text

    # Tables II–III, true and measured: every cell equals summarize() of the JSON runs a reflex
    # did not abort (these 0.05 s reaches drive some seed-0 runs over the iiwa 14's velocity
    # limits: the robot stopped itself; those are counted, not averaged).
    completed = [r for r in doc["runs"] if not r["aborted"]]
    assert all(r["reflex"]["enabled"] for r in doc["runs"])
    for form in FORMULATIONS:
        for pid in (False, True):
            cell = [r for r in doc["runs"] if r["formulation"] == form and r["pid_enabled"] == pid]
            aborted = sum(r["aborted"] for r in cell)
            count = f"{LABELS[form]} {len(cell) - aborted}/2" + (
                f" ({aborted} aborted)" * bool(aborted)
            )
            assert count in text, count
    for source in ("true", "measured"):
        for number, pid, what in (("II", False, "without"), ("III", True, "with")):
            cells = {}
            for form in FORMULATIONS:
                runs = [
                    PolishingMetrics(**r[f"metrics_{source}"])
                    for r in completed
                    if r["formulation"] == form and r["pid_enabled"] == pid
                ]
                cells[form] = summarize(runs)
            title = f"### Table {number} — {what} low-level torque PID ({source} force)"
            _check_table(text, title, cells)

        # Table IV: per-seed differences no-PID − PID, mean ± std, computed independently.
        table = parse_markdown_table(text, f"### Table IV — no-PID minus PID, per seed ({source}")
        for form in FORMULATIONS:
            by = {
                (r["pid_enabled"], r["seed"]): r[f"metrics_{source}"]
                for r in completed
                if r["formulation"] == form
            }
            pairs = [s for s in (0, 1) if (False, s) in by and (True, s) in by]
            for row, key in (("ΔE_λ (N)", "force_mae"), ("ΔE_τ (N m)", "torque_mae")):
                diffs = [by[(False, s)][key] - by[(True, s)][key] for s in pairs]
                mean, std = parse_cell(table[row][LABELS[form]])
                assert mean == pytest.approx(np.mean(diffs), abs=0.0051)
                assert std == pytest.approx(np.std(diffs), abs=0.0051)

    # A second run into the same directory is refused before any run; nothing is touched.
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    assert main(argv) == 2
    assert "already exists" in capsys.readouterr().err
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before


def test_output_directory_is_refused_unless_forced(tmp_path) -> None:
    path = tmp_path / "out"
    assert prepare_output_dir(path) == path and path.is_dir()
    with pytest.raises(ConfigError, match="already exists"):
        prepare_output_dir(path)
    (path / "keep.txt").write_text("x")
    assert prepare_output_dir(path, force=True) == path
    assert (path / "keep.txt").read_text() == "x"
    (tmp_path / "file").write_text("x")
    with pytest.raises(ConfigError, match="not a directory"):
        prepare_output_dir(tmp_path / "file", force=True)


def test_a_diverging_run_is_recorded_and_left_out_while_a_bug_propagates(monkeypatch) -> None:
    import studies.polishing as polishing

    real = polishing.run_polishing

    def diverge_on_seed_2(scenario, duration=None):
        if scenario.seed == 2:
            raise InputError("measurement q is not finite: [nan ...]")
        return real(scenario, duration)

    # (seeds 1 and 2: seed 0 of these short classical runs crosses A5's velocity limit on its
    # own and is aborted by the robot's reflex)
    monkeypatch.setattr(polishing, "run_polishing", diverge_on_seed_2)
    specs = grid_specs("polishing", ["classical"], [False], [1, 2], 0.3, SHORT)
    outcomes = run_specs(specs, workers=1, progress=False)
    assert outcomes[0].ok and not outcomes[1].ok
    assert outcomes[1].error.startswith("InputError: measurement q is not finite")
    doc = study.study_document(
        "polishing", specs, outcomes, command_line="test", workers=1, wall_time=1.0
    )
    assert len(doc["runs"]) == 1
    assert doc["failures"] == [
        {"formulation": "classical", "pid_enabled": False, "seed": 2, "error": outcomes[1].error}
    ]
    text = study.polishing_tables(doc)
    assert "Runs: Classical 1/2." in text
    assert "- Classical, PID off, seed 2: InputError" in text
    table = parse_markdown_table(text, "### Table II — without low-level torque PID (true")
    only = PolishingMetrics(**doc["runs"][0]["metrics_true"])
    assert parse_cell(table["E_λ (N)"]["Classical"]) == pytest.approx(
        (only.force_mae, 0.0), abs=6e-3
    )

    def bug(scenario, duration=None):
        raise NameError("name 'SensingModel' is not defined")

    monkeypatch.setattr(polishing, "run_polishing", bug)
    with pytest.raises(NameError):
        execute_run(specs[0])


#: A 100 N push on the tool for 50 ms at 0.05 s: joint A5 over its velocity limit at 0.052 s.
PUSH = {
    "plant.push_enabled": True,
    "plant.push_time": 0.05,
    "plant.push_force": (0.0, 100.0, 0.0),
    "plant.push_duration": 0.05,
}


@pytest.mark.parametrize("reflex", [True, False])
def test_a_run_the_reflex_aborts_is_counted_listed_and_left_out(monkeypatch, reflex) -> None:
    """Seed 2 pushed over a velocity limit: with the reflexes on (the default) the tables count
    it as aborted ("1/2 (1 aborted)"), list its event and average seed 1 only; with
    ``plant.reflex=false`` nothing is aborted, both runs are averaged, and the tables say the
    reflexes were off and which run would have been aborted. (Seeds 1 and 2: seed 0 of these
    short classical runs crosses A5's velocity limit on its own, 1.006×, at 0.155 s.)"""
    import studies.polishing as polishing

    real = polishing.run_polishing

    def push_seed_2(scenario, duration=None):
        return real(scenario.with_overrides(PUSH) if scenario.seed == 2 else scenario, duration)

    monkeypatch.setattr(polishing, "run_polishing", push_seed_2)
    overrides = {**SHORT, "plant.reflex": reflex}
    specs = grid_specs("polishing", ["classical"], [False], [1, 2], 0.3, overrides)
    outcomes = run_specs(specs, workers=1, progress=False)
    doc = study.study_document(
        "polishing", specs, outcomes, command_line="test", workers=1, wall_time=1.0
    )
    runs = {r["seed"]: r for r in doc["runs"]}
    assert runs[2]["aborted"] is reflex and not runs[1]["aborted"]
    assert runs[2]["reflex"]["event"]["kind"] == "velocity" and runs[1]["reflex"]["event"] is None
    text = study.polishing_tables(doc)
    table = parse_markdown_table(text, "### Table II — without low-level torque PID (true")
    averaged = [1] if reflex else [1, 2]
    expected = np.mean([runs[k]["metrics_true"]["force_mae"] for k in averaged])
    assert parse_cell(table["E_λ (N)"]["Classical"])[0] == pytest.approx(expected, abs=6e-3)
    if reflex:
        assert "Runs: Classical 1/2 (1 aborted)." in text
        assert "`ffmpc_core.reflex`): 1 of 2 runs." in text  # the line under the tables
        assert "- Classical, PID off, seed 2: velocity reflex at t = 0.05" in text
    else:
        assert "Runs: Classical 2/2 (1 would have aborted)." in text
        assert "Reflexes OFF (`plant.reflex: false`)" in text and "1 of 2 runs would" in text
        assert "reflex off: the robot went on (it would have stopped here)" in text


def test_grid_rejects_bad_requests() -> None:
    with pytest.raises(ConfigError, match="formulations"):
        grid_specs("polishing", ["rigid"], [True], [0])
    with pytest.raises(ConfigError, match="set by the study grid"):
        grid_specs("polishing", ["classical"], [True], [0], overrides={"seed": 3})
    with pytest.raises(ConfigError, match="duration"):
        grid_specs("polishing", ["classical"], [True], [0], duration=-1.0)
    with pytest.raises(ConfigError, match="unknown scenario parameter"):
        run_specs(grid_specs("polishing", ["classical"], [True], [0], 0.1, {"task.speed": 1}))
    with pytest.raises(ConfigError, match="no scenario"):
        run_specs(grid_specs("no_such_scenario", ["classical"], [True], [0], 0.1))
    with pytest.raises(ConfigError, match="workers"):
        run_specs(grid_specs("polishing", ["classical"], [True], [0], 0.1), workers=0)


def test_shipped_scenarios_are_what_their_names_say() -> None:
    robot = load_robot("iiwa")
    base = load_scenario("polishing")
    fast = load_scenario("polishing_fast")
    assert fast.task.angular_velocity == 6.0 and base.task.angular_velocity == 3.0
    assert fast.plant.random_tilt_deg == base.plant.random_tilt_deg == 6.0

    tilt = load_scenario("tilt")
    for seed in range(5):
        rng = np.random.default_rng(seed)
        assert draw_run(tilt, robot, rng).tilt_angle == pytest.approx(math.radians(6.0))
    assert len({draw_run(base, robot, np.random.default_rng(s)).tilt_angle for s in range(5)}) == 5

    push = load_scenario("push")
    assert push.plant.push_enabled and push.task.angular_velocity == 6.0
    assert np.linalg.norm(push.plant.push_force) > 0 and push.plant.push_duration > 0
    assert push.plant.random_tilt_deg == 0.0 and push.plant.table_tilt_deg == 0.0
    circle_start = push.task.still + push.task.reach + push.task.force_ramp
    circle_end = circle_start + push.task.circles * 2 * math.pi / push.task.angular_velocity
    assert circle_start < push.plant.push_time < push.plant.push_time + push.plant.push_duration
    assert push.plant.push_time + push.plant.push_duration < circle_end

    square = load_scenario("force_square")
    assert square.task.name == "force_square"
    assert square.task.low_force < square.task.high_force
    # Everything else is the polishing study's setup (same controllers, noise and PID).
    for section in ("mpc", "pid", "joint_sensor", "ft_sensor"):
        for other in (fast, tilt, push, square):
            assert getattr(other, section) == getattr(base, section), (other.name, section)


def test_force_square_cli_prints_each_controllers_mae_and_saves_the_figure(
    tmp_path, capsys
) -> None:
    out = tmp_path / "square"
    shorter = [*SHORT_SET, "--set", "task.square_period=0.2", "--set", "task.square_cycles=1"]
    argv = ["study", "force-square", "--workers", "1", "--out", str(out), "--no-progress"]
    assert main([*argv, *shorter]) == 0
    printed = capsys.readouterr().out
    doc = json.loads((out / "results.json").read_text())
    assert doc["kind"] == "force_square" and doc["scenario"] == "force_square"
    assert {(r["formulation"], r["pid_enabled"], r["seed"]) for r in doc["runs"]} == {
        (f, True, 0) for f in FORMULATIONS
    }
    maes = {r["formulation"]: r["metrics_true"]["force_mae"] for r in doc["runs"]}
    line = next(s for s in printed.splitlines() if s.startswith("normal-force MAE (PID):"))
    for form, mae in maes.items():
        assert f"{LABELS[form]} {mae:.2f} N" in line
        assert 0.0 < mae < 50.0
    assert (out / "fig_force_square.png").read_bytes()[:4] == b"\x89PNG"
    table = parse_markdown_table((out / "tables.md").read_text(), "## With torque PID")
    assert parse_cell(table["paper (hardware)"]["Force-feedback"]) == (2.16, None)
