"""``ffmpc study paper`` (studies/paper.py) and what it is made of: the paired comparison with the
Wilcoxon signed-rank test (studies.study.paired_comparison), one grid per δo
(``--command-delays``), and the push windows of Experiment 3.3 (ffmpc_core.metrics).

The CLI runs are smoke runs (0.2 s of simulated time: 54 runs of ~0.15 s each, in-process)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import wilcoxon

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.metrics import push_phase_metrics, push_phase_windows
from ffmpc_core.scenario import PAPER_SCHEDULE, load_scenario
from ffmpc_ros.cli import main
from studies import study
from studies.paper import SECTIONS, paper_specs
from studies.study import (
    RunSpec,
    execute_run,
    grid_specs,
    paired_comparison,
    parse_cell,
    parse_markdown_table,
    polishing_tables,
    resolve_command_delays,
    run_key,
)


# --------------------------------------------------------------------------- paired comparison
def _run(form: str, seed: int, force: float, position: float, pid: bool = True) -> dict:
    metrics = {
        "position_mae_mm": position,
        "force_mae": force,
        "max_force": 60.0,
        "contact_break_percent": 0.0,
        "torque_mae": 1.0,
    }
    return {
        "formulation": form,
        "pid_enabled": pid,
        "seed": seed,
        "metrics_true": metrics,
        "metrics_measured": {**metrics, "force_mae": force + 0.5},
    }


def _doc(runs: list[dict], failures: list[dict], seeds: list[int]) -> dict:
    return {
        "scenario": "polishing",
        "command_line": "test",
        "wall_time_s": 1.0,
        "workers": 1,
        "grid": {
            "formulations": ["classical", "torque_feedback", "force_feedback"],
            "pid_enabled": [True],
            "seeds": seeds,
        },
        "runs": runs,
        "failures": failures,
    }


#: Hand-made E_λ (N), E_P (mm) per seed: force-feedback, classical, torque-feedback.
FF = {s: (2.0 + 0.1 * s, 3.0 + 0.05 * s) for s in range(8)}
CL = {s: (10.0 + 0.7 * s * (-1) ** s, 6.0 + 0.3 * s) for s in range(8)}
TF = {s: (2.0 + 0.1 * s, 3.0 + 0.05 * s + 0.2 * (s - 3.5)) for s in range(8)}


def test_paired_comparison_pairs_by_seed_and_gives_scipys_wilcoxon() -> None:
    runs = [_run("force_feedback", s, *FF[s]) for s in range(8) if s != 5]  # ff seed 5 failed
    runs += [_run("classical", s, *CL[s]) for s in range(8) if s != 2]  # classical seed 2 failed
    runs += [_run("torque_feedback", s, *TF[s]) for s in range(8)]
    runs += [_run("classical", s, 99.0, 99.0, pid=False) for s in range(8)]  # other PID mode
    runs.reverse()  # pairing is by seed, not by position
    doc = _doc(runs, [], list(range(8)))
    pairs = paired_comparison(doc, pid=True)
    assert set(pairs) == {"classical", "torque_feedback"}

    # Force-feedback − classical: only the seeds where both succeeded.
    seeds = [0, 1, 3, 4, 6, 7]
    assert pairs["classical"]["seeds"] == seeds
    for i, metric in enumerate(("force_mae", "position_mae_mm")):
        d = np.array([FF[s][i] - CL[s][i] for s in seeds])
        got = pairs["classical"][metric]
        np.testing.assert_allclose(got["differences"], d, rtol=0, atol=1e-12)
        assert got["mean"] == pytest.approx(d.mean()) and got["std"] == pytest.approx(d.std())
        expected = wilcoxon(d, zero_method="wilcox", alternative="two-sided")
        assert got["n"] == 6
        assert got["statistic"] == pytest.approx(float(expected.statistic))
        assert got["p_value"] == pytest.approx(float(expected.pvalue))
        assert got["note"] == ""  # 6 pairs: no small-sample note
    # Every classical E_P is higher: all 6 differences negative, exact two-sided p = 2/2^6.
    assert pairs["classical"]["position_mae_mm"]["p_value"] == pytest.approx(2 / 64)

    # Force-feedback − torque-feedback: E_λ differences all zero → scipy's p = 1, stated.
    tf = pairs["torque_feedback"]
    assert tf["seeds"] == [0, 1, 2, 3, 4, 6, 7]
    assert tf["force_mae"]["differences"] == [0.0] * 7
    assert tf["force_mae"]["p_value"] == 1.0 and "all differences 0" in tf["force_mae"]["note"]
    d = np.array([FF[s][1] - TF[s][1] for s in tf["seeds"]])
    expected = wilcoxon(d, zero_method="wilcox", alternative="two-sided")
    assert tf["position_mae_mm"]["p_value"] == pytest.approx(float(expected.pvalue))

    # The table shows the same numbers and says how many pairs.
    text = "\n".join(study.paired_table(doc, True, "### Paired"))
    table = parse_markdown_table(text, "### Paired")
    row = table["Force-feedback − Classical"]
    assert row["pairs"] == "6"
    mean, std = parse_cell(row["ΔE_λ (N)"])
    assert mean == pytest.approx(pairs["classical"]["force_mae"]["mean"], abs=0.006)
    assert std == pytest.approx(pairs["classical"]["force_mae"]["std"], abs=0.006)
    assert float(row["p (E_P)"]) == pytest.approx(2 / 64, rel=1e-3)
    assert table["Force-feedback − Torque-feedback"]["pairs"] == "7"
    assert "E_λ: all differences 0" in table["Force-feedback − Torque-feedback"]["note"]
    assert "fewer than 6 pairs can never give p < 0.05" in text


def test_fewer_than_six_pairs_are_flagged_and_no_pair_gives_no_test() -> None:
    runs = [_run("force_feedback", s, *FF[s]) for s in range(3)]
    runs += [_run("classical", s, *CL[s]) for s in range(3)]
    pairs = paired_comparison(_doc(runs, [], [0, 1, 2]), pid=True)
    force = pairs["classical"]["force_mae"]
    d = [FF[s][0] - CL[s][0] for s in range(3)]
    assert force["p_value"] == pytest.approx(float(wilcoxon(d).pvalue))
    assert force["note"] == "n < 6: p >= 2/2^n = 0.25"
    assert pairs["torque_feedback"]["seeds"] == []  # no torque-feedback run succeeded
    assert pairs["torque_feedback"]["force_mae"]["p_value"] is None
    assert pairs["torque_feedback"]["force_mae"]["note"] == "no pair"


# --------------------------------------------------------------------------- δo grids
def test_command_delays_make_one_grid_per_delta_o_and_refuse_a_second_setting() -> None:
    specs = grid_specs("polishing", ["classical"], [True], [0, 1], 0.1, command_delays=[0, 0.005])
    assert [(s.delta_o_setting, s.seed) for s in specs] == [
        ("0.0", 0),
        ("0.0", 1),
        ("0.005", 0),
        ("0.005", 1),
    ]
    assert [s.load().pid.delay_cycles for s in specs] == [0, 0, 5, 5]  # δo in plant steps
    with pytest.raises(ConfigError, match="give it once"):
        grid_specs(
            "polishing",
            ["classical"],
            [True],
            [0],
            overrides={"mpc.command_delay": 0.0},
            command_delays=[0.005],
        )
    with pytest.raises(ConfigError, match="repeat"):
        grid_specs("polishing", ["classical"], [True], [0], command_delays=[0.005, 0.005])


def test_measured_delays_of_several_formulations_resolve_without_timing_again() -> None:
    specs = grid_specs(
        "polishing",
        ["classical", "force_feedback"],
        [True],
        [0],
        0.1,
        {"mpc.command_delay": "measured"},
    )
    resolved, records = resolve_command_delays(
        specs, measured={"classical": 0.0021, "force_feedback": 0.0004}
    )
    assert [s.command_delay for s in resolved] == [0.003, 0.001]  # rounded up to 1 ms steps
    assert records["force_feedback"]["measured_step_median_s"] == 0.0004


def test_tables_per_delta_o_from_the_documents_runs() -> None:
    runs = []
    for setting, shift in (("0.0", 0.0), ("0.005", 1.0)):
        for s in range(2):
            for form, table in (("force_feedback", FF), ("classical", CL)):
                run = _run(form, s, table[s][0] + shift, table[s][1])
                runs.append({**run, "delta_o_setting": setting})
    doc = _doc(runs, [], [0, 1])
    doc["grid"]["formulations"] = ["classical", "force_feedback"]
    doc["grid"]["command_delays"] = ["0.0", "0.005"]
    text = polishing_tables(doc)
    for setting, label, shift in (("0.0", "0 ms", 0.0), ("0.005", "5 ms", 1.0)):
        assert f"## δo = {label} (`mpc.command_delay: {setting}`)" in text
        table = parse_markdown_table(
            text, f"#### Table III — with low-level torque PID (true force, δo = {label})"
        )
        expected = np.mean([FF[s][0] + shift for s in range(2)])
        assert parse_cell(table["E_λ (N)"]["Force-feedback"])[0] == pytest.approx(
            expected, abs=0.006
        )
        assert f"#### Paired comparison, Table III (true force, δo = {label})" in text


# --------------------------------------------------------------------------- push windows
def test_push_windows_during_and_after_each_push_on_a_synthetic_log() -> None:
    windows = push_phase_windows([(2.0, 0.2), (1.0, 0.1)], recovery=0.5, end=2.35)
    assert windows == [
        {"during": (1.0, 1.1), "after": (1.1, 1.6)},
        {"during": (2.0, pytest.approx(2.2)), "after": (pytest.approx(2.2), 2.35)},
    ]
    assert push_phase_windows([(1.0, 0.1), (1.3, 0.1)], 0.5)[0]["after"] == (1.1, 1.3)  # next push
    with pytest.raises(InputError):
        push_phase_windows([(1.0, -0.1)])

    # 1 kHz log: 50 N reference; during [1.0, 1.1) the force is 70 N and the tool is 4 mm off
    # along the table (x) and 9 mm along the normal (z, not counted in E_P); after, 55 N and 1 mm.
    t = np.arange(0, 2000) * 1e-3
    force = np.full(t.size, 50.0)
    error = np.zeros((t.size, 3))
    during = (t >= 1.0 - 1e-9) & (t < 1.1 - 1e-9)
    after = (t >= 1.1 - 1e-9) & (t < 1.6 - 1e-9)
    force[during], error[during] = 70.0, (0.004, 0.0, 0.009)
    force[after], error[after] = 55.0, (0.0, 0.001, 0.0)
    reference = np.tile([0.5, 0.0, 0.3], (t.size, 1))
    normal = np.array([0.0, 0.0, 1.0])
    first = windows[0]
    got = push_phase_metrics(t, reference + error, reference, normal, force, 50.0, first["during"])
    assert got.samples == 100
    assert got.force_mae == pytest.approx(20.0) and got.max_force == pytest.approx(70.0)
    assert got.position_mae_mm == pytest.approx(4.0)
    got = push_phase_metrics(t, reference + error, reference, normal, force, 50.0, first["after"])
    assert got.samples == 500
    assert got.force_mae == pytest.approx(5.0) and got.position_mae_mm == pytest.approx(1.0)
    # A phase after the end of the log: no sample, no number.
    late = push_phase_metrics(t, reference, reference, normal, force, 50.0, (5.0, 5.2))
    assert late.samples == 0 and late.force_mae is None and late.max_force is None


#: The push scenario, shortened: contact at once, the circle from 0.15 s, a 0.05 s push at 0.2 s.
SHORT_PUSH = {
    **PAPER_SCHEDULE,  # no touch phase, the circle stepped
    "task.still": 0.0,
    "task.reach": 0.05,
    "task.force_ramp": 0.1,
    "task.start_height": 0.0,
    "plant.push_time": 0.2,
    "plant.push_duration": 0.05,
    "plant.push_rise_time": 0.01,  # the scenario's 0.05 s does not fit twice in 0.05 s
    "plant.push_force": [0.0, 80.0, 0.0],
}


def test_a_push_run_reports_its_push_windows_and_has_its_own_cache_key() -> None:
    from ffmpc_core.polishing import build_task
    from ffmpc_core.robots import load_robot
    from sim_bridge.scenes import polishing_plant_config
    from studies.polishing import run_polishing

    spec = RunSpec("push", "force_feedback", True, 0, 0.4, tuple(SHORT_PUSH.items()))
    scenario = spec.load()
    result = run_polishing(scenario, spec.duration)
    (push,) = result.summary()["push_true"]
    assert push["during"]["start"] == 0.2 and push["during"]["end"] == pytest.approx(0.25)
    assert push["during"]["samples"] == 50
    # After: to the end of the run (the circle is cut there), last cycle included.
    log = result.log
    assert push["after"]["end"] == pytest.approx(log["t"][-1] + 0.0005)
    assert push["after"]["samples"] == int(np.sum(log["t"] >= 0.25 - 1e-9))

    # The same numbers computed here from the run's log: true force, tangential error.
    task = build_task(scenario, load_robot(scenario.robot))
    normal = polishing_plant_config(scenario, task, result.draws.tilt_angle).table.normal
    for phase in ("during", "after"):
        window = push[phase]
        mask = (log["t"] >= window["start"]) & (log["t"] < window["end"])
        error = log["ee_position"][mask] - log["ee_reference"][mask]
        tangential = error - np.outer(error @ normal, normal)
        force = log["force_true"][mask]
        assert window["samples"] == int(mask.sum())
        assert window["force_mae"] == pytest.approx(
            np.mean(np.abs(force - log["force_reference"][mask]))
        )
        assert window["position_mae_mm"] == pytest.approx(
            1e3 * np.mean(np.linalg.norm(tangential, axis=1))
        )
        assert window["max_force"] == pytest.approx(np.max(np.abs(force)))
    assert push["during"]["max_force"] > 5.0  # in contact during the push

    # Without the push: no push windows in the summary, and the run differs in that window
    # (80 N along y moves the tool: measured 9.0 vs 7.3 mm on seed 0).
    quiet = RunSpec(
        "push", "force_feedback", True, 0, 0.4, (*SHORT_PUSH.items(), ("plant.push_enabled", False))
    )
    assert "push_true" not in execute_run(quiet).summary
    quiet_log = run_polishing(quiet.load(), quiet.duration).log
    window = push["during"]
    mask = (quiet_log["t"] >= window["start"]) & (quiet_log["t"] < window["end"])
    error = quiet_log["ee_position"][mask] - quiet_log["ee_reference"][mask]
    tangential = error - np.outer(error @ normal, normal)  # same draws: same tilt, same normal
    quiet_ep = 1e3 * np.mean(np.linalg.norm(tangential, axis=1))
    assert abs(window["position_mae_mm"] - quiet_ep) > 1.0
    assert run_key(spec) != run_key(quiet)
    assert "push_metrics" in spec.key_document() and "push_metrics" not in quiet.key_document()


def test_the_perfect_table_scenario_is_polishing_without_tilt() -> None:
    perfect, base = load_scenario("perfect_table"), load_scenario("polishing")
    assert perfect.plant.random_tilt_deg == 0.0 and perfect.plant.table_tilt_deg == 0.0
    assert base.plant.random_tilt_deg == 6.0
    for section in ("task", "mpc", "pid", "joint_sensor", "ft_sensor"):
        assert getattr(perfect, section) == getattr(base, section), section


# --------------------------------------------------------------------------- ffmpc study paper
PAPER = ["study", "paper", "--seeds", "2", "--duration", "0.2", "--workers", "1", "--no-progress"]


def test_paper_study_writes_every_section_and_a_resumed_run_reads_the_cache(
    tmp_path, capsys
) -> None:
    out = tmp_path / "paper"
    assert main([*PAPER, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    figures = [s.figure_file for s in SECTIONS if s.figure_file is not None]
    assert figures == [
        "fig4_experiment_1.png",
        "fig6_experiment_2.png",
        "fig7_experiment_3_1.png",
        "fig8_experiment_3_2.png",
        "fig9_experiment_3_3.png",
    ]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["cache", "paper.md", "results.json", *figures]
    )
    text = (out / "paper.md").read_text()
    doc = json.loads((out / "results.json").read_text())
    assert text in printed
    # The figures: PNG files of the first seed's runs, each linked under its section.
    assert doc["plot_seed"] == 0
    assert doc["figures"] == {s.key: s.figure_file for s in SECTIONS if s.figure_file}
    for name in figures:
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        assert f"]({name})" in text and name in printed
    specs = paper_specs([0, 1], duration=0.2, plot_seed=0)
    plotted = [(key, s.seed) for key, group in specs.items() for s in group if s.plot]
    assert sorted(plotted) == sorted((f, 0) for f in doc["figures"] for _ in range(3))
    assert list(doc["sections"]) == [s.key for s in SECTIONS]
    for section in SECTIONS:
        assert f"## {section.title}" in text
        entry = doc["sections"][section.key]
        assert entry["scenario"] == section.scenario
        assert entry["study"]["grid"]["seeds"] == [0, 1]
        assert (
            entry["weights"]["force_feedback"]
            == load_scenario(section.scenario).mpc.weights["force_feedback"]
        )
        assert f"Scenario `{section.scenario}`" in text
    assert "SMOKE RUN" in text and "seeds 0–1" in text
    assert doc["execution"] == {
        "cached": 0,
        "executed": 54,
        "cluster": "in-process",
        "cache_dir": str(out / "cache"),
    }
    assert doc["wall_time_s"] > 0 and f"wall time {doc['wall_time_s']:.1f} s" in text

    # Tables II–IV at δo = 0 and 5 ms, each beside the paper's numbers, with the paired test.
    sim = doc["sections"]["simulation"]["study"]
    assert sim["grid"]["command_delays"] == ["0.0", "0.005"]
    assert {(r["delta_o_setting"], r["command_delay_s"]) for r in sim["runs"]} == {
        ("0.0", 0.0),
        ("0.005", 0.005),
    }
    assert len(sim["runs"]) == 2 * 2 * 3 * 2
    for label in ("0 ms", "5 ms"):
        table = parse_markdown_table(
            text, f"#### Table III — with torque PID (true force, δo = {label})"
        )
        assert table["E_λ (N)"]["Force-feedback (paper)"] == "2.04 ± 0.01"
        assert table["E_P (mm)"]["Classical (paper)"] == "7.94 ± 1.43"
        title = f"#### Table IV — no-PID minus PID, per seed (true force, δo = {label})"
        table = parse_markdown_table(text, title)
        assert table["ΔE_λ (N)"]["Torque-feedback (paper)"] == "21.55 ± 4.95"
        title = f"#### Paired comparison, Table II (true force, δo = {label})"
        paired = parse_markdown_table(text, title)
        assert paired["Force-feedback − Classical"]["pairs"] == "2"
    assert set(sim["paired_comparison"]) == {"0.0", "0.005"}

    # The experiments, beside the paper's tables where it prints them.
    expected = {
        "experiment_1": ("E_λ (N)", "Classical (paper)", "2.76"),
        "experiment_2": ("E_λ (N)", "Force-feedback (paper)", "1.70 ± 0.15"),
        "experiment_3_1": ("E_P (mm)", "Torque-feedback (paper)", "3.37 ± 0.28"),
        "experiment_3_2": ("E_λ (N)", "Classical (paper)", "9.00 ± 1.61"),
        "experiment_3_3": ("E_λ (N)", "Classical (paper)", "–"),
    }
    for key, (row, column, value) in expected.items():
        title = next(s.title for s in SECTIONS if s.key == key)
        part = text[text.index(f"## {title}") :]
        table = parse_markdown_table(part, "### With torque PID")
        assert table[row][column] == value, key
        runs = doc["sections"][key]["study"]["runs"]
        assert len(runs) == 6 and all(r["pid_enabled"] for r in runs)
        cell = table["E_P (mm)"]["Force-feedback"]
        ff = [
            r["metrics_true"]["position_mae_mm"]
            for r in runs
            if r["formulation"] == "force_feedback"
        ]
        assert parse_cell(cell)[0] == pytest.approx(np.mean(ff), abs=0.006)
    push = parse_markdown_table(text, "### During and after the push")
    assert list(push) == [
        f"{m}, {phase} push"
        for phase in ("during", "after")
        for m in ("E_λ (N)", "E_P (mm)", "max λ (N)")
    ]
    push_runs = doc["sections"]["experiment_3_3"]["study"]["runs"]
    assert all(len(r["push_true"]) == 1 for r in push_runs)
    # 0.2 s runs end before the push at 2 s: no sample in its windows, said so.
    assert push["E_λ (N), during push"]["Force-feedback"] == "n/a"
    assert doc["sections"]["experiment_2"]["paper"]["V"]["Force (N)"]["classical"] == "9.31 ± 0.79"
    assert doc["sections"]["experiment_3_3"]["paper"] is None

    # The same command again (--force on the finished directory): every run from the cache.
    assert main([*PAPER, "--out", str(out), "--force"]) == 0
    again = json.loads((out / "results.json").read_text())
    assert again["execution"]["cached"] == 54 and again["execution"]["executed"] == 0
    assert "54 from the cache, 0 run" in capsys.readouterr().out
    for key in doc["sections"]:
        before = [_no_timing(r) for r in doc["sections"][key]["study"]["runs"]]
        after = [_no_timing(r) for r in again["sections"][key]["study"]["runs"]]
        assert after == before, key


def _no_timing(run: dict) -> dict:
    return {k: v for k, v in run.items() if k not in ("wall_time_s", "solve_time_median_s")}


def test_paper_study_refuses_bad_flags_before_any_run(tmp_path, capsys) -> None:
    out = tmp_path / "bad"
    argv = [*PAPER, "--out", str(out)]
    assert main([*argv, "--set", "mpc.command_delay=0"]) == 2
    assert "--command-delays" in capsys.readouterr().err
    assert main([*argv, "--command-delays", "0.005", "0.005"]) == 2
    assert "repeat" in capsys.readouterr().err
    assert main([*argv, "--set", "task.speed=1"]) == 2
    assert main([*argv, "--plot-seed", "5"]) == 2
    assert "--plot-seed 5" in capsys.readouterr().err
    assert not out.exists()


def test_set_file_overrides_come_before_set_and_are_checked(tmp_path) -> None:
    """``--set-file`` (a YAML mapping NAME: VALUE, e.g. the tuned weights) gives the same
    overrides as ``--set``; ``--set`` wins; a bad file or name is a ConfigError."""
    import argparse

    from studies.cli import _polishing_overrides

    tuned = tmp_path / "tuned.yaml"
    tuned.write_text(
        "mpc.weights.classical.force_phase: 2.5\nmpc.weights.classical.ee_rotation: 9\n"
    )
    args = argparse.Namespace(set_file=[str(tuned)], set=["mpc.weights.classical.ee_rotation=3"])
    assert _polishing_overrides(args) == {
        "mpc.weights.classical.force_phase": 2.5,
        "mpc.weights.classical.ee_rotation": 3,
    }
    shipped = Path(__file__).resolve().parents[1] / "benchmarks/results/tune/train1000-1002"
    weights = _polishing_overrides(
        argparse.Namespace(set_file=[str(shipped / "speed_penalty/tuned_weights.yaml")], set=None)
    )
    assert len(weights) == 17 and weights["mpc.weights.force_feedback.force_rate"] == 1.491e-08
    for text, what in (("- 1\n- 2\n", "mapping"), ("task.speed: 1\n", "task.speed")):
        tuned.write_text(text)
        with pytest.raises(ConfigError, match=what):
            _polishing_overrides(argparse.Namespace(set_file=[str(tuned)], set=None))
