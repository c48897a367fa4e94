"""``ffmpc study compare``: studies run the same way, side by side (studies/compare.py)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_ros.cli import main
from studies.compare import cell_summary, compare, over_limit

ROOT = Path(__file__).resolve().parents[1]
IMPACT = ROOT / "benchmarks" / "results" / "impact_study" / "results.json"
FORMS = ["classical", "torque_feedback", "force_feedback"]


def _run(form: str, seed: int, force_mae: float, **extra) -> dict:
    return {
        "formulation": form,
        "pid_enabled": True,
        "seed": seed,
        "delta_o_setting": "0.0",
        "aborted": False,
        "max_velocity_ratio": [0.5] * 7,
        "max_torque_ratio": [0.5] * 7,
        "metrics_true": {"force_mae": force_mae, "position_mae_mm": 2.0, "max_force": 60.0},
        **extra,
    }


def _paper(engine: str, mae: dict[str, float], seeds=(1, 2)) -> dict:
    runs = [_run(f, s, mae[f] + 0.1 * s) for f in FORMS for s in seeds]
    study = {"grid": {"command_delays": ["0.0"]}, "runs": runs, "failures": []}
    return {
        "kind": "paper",
        "seeds": list(seeds),
        "formulations": FORMS,
        "command_delays": [0.0],
        "plant_engine": engine,
        "command_line": f"ffmpc study paper --plant {engine}",
        "source": {"commit": "0123456789abcdef"},
        "overrides": {},
        "sections": {"simulation": {"study": study}},
    }


def _write(tmp_path: Path, name: str, doc: dict) -> Path:
    path = tmp_path / name / "results.json"
    path.parent.mkdir()
    path.write_text(json.dumps(doc))
    return path


def test_a_cell_averages_the_runs_that_were_not_aborted_and_counts_the_rest():
    runs = [
        _run("classical", 1, 2.0),
        _run("classical", 2, 4.0, max_velocity_ratio=[1.2] + [0.5] * 6),
        _run("classical", 3, 100.0, aborted=True, max_torque_ratio=[1.01] + [0.5] * 6),
    ]
    runs[2]["metrics_true"]["max_force"] = 140.0
    cell = cell_summary(runs)
    assert cell["force_mae"] == pytest.approx(3.0)  # the aborted run's 100 N is left out
    assert cell["max_force"] == 140.0  # but its λmax counts
    assert (cell["runs"], cell["aborted"], cell["over_limit"]) == (3, 1, 2)
    assert not over_limit(runs[0]) and over_limit(runs[1]) and over_limit(runs[2])


def test_two_paper_studies_side_by_side_with_the_order_of_each(tmp_path):
    a = _write(
        tmp_path,
        "a",
        _paper("pybullet", {"classical": 5, "torque_feedback": 3, "force_feedback": 1}),
    )
    b = _write(
        tmp_path, "b", _paper("mujoco", {"classical": 4, "torque_feedback": 6, "force_feedback": 2})
    )
    table = compare([a, b.parent])  # a directory is read as its results.json
    row = next(line for line in table.splitlines() if "| TF |" in line)
    cells = [c.strip() for c in row.strip("|").split("|")]
    # seeds 1, 2: E_λ = base + 0.15 on average, both studies in one row
    assert cells[:4] == ["Table III", "on", "0 ms", "TF"]
    assert cells[4:8] == ["3.15", "2.00", "60.0", "0 / 0"]
    assert cells[8:12] == ["6.15", "2.00", "60.0", "0 / 0"]
    assert "pybullet FF < TF < C · mujoco FF < C < TF" in table
    doc = _paper("mujoco", {"classical": 4, "torque_feedback": 6, "force_feedback": 2})
    for run in doc["sections"]["simulation"]["study"]["runs"]:
        run["aborted"] = run["aborted"] or run["formulation"] == "torque_feedback"
    table = compare([a, _write(tmp_path, "c", doc)])
    assert "mujoco FF < C (TF: every run aborted)" in table
    assert "- **mujoco**: mujoco, `ffmpc study paper --plant mujoco`\n" in table


def test_studies_of_other_seeds_or_kinds_are_refused(tmp_path):
    mae = {"classical": 5, "torque_feedback": 3, "force_feedback": 1}
    a = _write(tmp_path, "a", _paper("pybullet", mae))
    b = _write(tmp_path, "b", _paper("mujoco", mae, seeds=(1, 3)))
    with pytest.raises(ConfigError, match="differs from study 1 in 'seeds'"):
        compare([a, b])
    with pytest.raises(ConfigError, match="cannot compare a paper study with an impact study"):
        compare([a, IMPACT])
    with pytest.raises(ConfigError, match="1 labels for 2 results files"):
        compare([a, a], ["one"])


def test_two_impact_studies_side_by_side(tmp_path):
    doc = json.loads(IMPACT.read_text())
    other = copy.deepcopy(doc)
    other["config"]["engine"] = "mujoco"
    other["runs"][0]["pre_impact_velocity"] = 0.3
    other["runs"][0]["violations"]["total"] = 2
    table = compare([IMPACT, _write(tmp_path, "m", other)], ["PyBullet", "MuJoCo"])
    first = doc["runs"][0]
    row = next(line for line in table.splitlines() if line.startswith("| maximal+admittance"))
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[:3] == [
        "maximal+admittance",
        first["strategy"],
        f"{first['pre_impact_velocity']:.3f}",
    ]
    assert cells[8] == "0.300" and cells[12] == "2"
    assert "Penetration bound z̄ kept by the planner: PyBullet 30.0 mm · MuJoCo 30.0 mm." in table
    other["runs"].pop()
    with pytest.raises(ConfigError, match="ran different runs"):
        compare([IMPACT, _write(tmp_path, "n", other)])


def test_the_cli_prints_and_writes_the_table_and_never_overwrites(tmp_path, capsys):
    mae = {"classical": 5, "torque_feedback": 3, "force_feedback": 1}
    a = _write(tmp_path, "a", _paper("pybullet", mae))
    b = _write(tmp_path, "b", _paper("mujoco", mae))
    out = tmp_path / "table.md"
    assert main(["study", "compare", str(a), str(b), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert out.read_text() in printed and "| Table III | on | 0 ms |" in printed
    assert main(["study", "compare", str(a), str(b), "--out", str(out)]) == 2
    assert "exists; never overwritten without --force" in capsys.readouterr().err
    out.write_text("old")
    assert main(["study", "compare", str(a), str(b), "--out", str(out), "--force"]) == 0
    assert out.read_text() != "old"


def test_polishing_studies_are_compared_as_their_one_table(tmp_path):
    paper = _paper("pybullet", {"classical": 5, "torque_feedback": 3, "force_feedback": 1})
    study = paper["sections"]["simulation"]["study"]
    polishing = {
        "kind": "polishing",
        "grid": {"formulations": FORMS, "seeds": [1, 2], "command_delays": ["0.0"]},
        "runs": study["runs"],
        "failures": [],
        "plant_engine": "mujoco",
        "command_line": "ffmpc study polishing --plant mujoco",
    }
    a = _write(tmp_path, "a", {**polishing, "plant_engine": "pybullet"})
    table = compare([a, _write(tmp_path, "b", polishing)])
    assert "| Table III | on | 0 ms | FF | 1.15 | 2.00 | 60.0 | 0 / 0 | 1.15 |" in table
    with pytest.raises(ConfigError, match="differs from study 1 in 'seeds'"):
        compare(
            [a, _write(tmp_path, "c", {**polishing, "grid": {**polishing["grid"], "seeds": [1]}})]
        )
