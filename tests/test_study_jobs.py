"""The impact study and the exploration on the run engine (studies.execute): a running Dask
scheduler with two workers gives the in-process results, and a study whose results were lost
resumes from its cache without running again."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest
from dask_helpers import running_cluster

from ffmpc_core.impact.scenario import ExplorationConfig, ImpactStudyConfig
from ffmpc_ros.cli import main
from studies.exploration import run_exploration_study
from studies.impact_study import run_impact_study

#: Short exploration: one sine period and one impact per material (~3 s simulated each).
EXPLORE = replace(ExplorationConfig(), sine_cycles=1, impact_velocities=(0.2,))
#: Short impact runs: the baseline touches the dice at 1.43 s.
IMPACT = replace(ImpactStudyConfig(), duration=1.6)
IMPACT_RUNS = (("baseline", "admittance"), ("maximal", "admittance"))


def _runs(path) -> list[dict]:
    """The runs of a results.json without their wall times."""
    runs = json.loads(path.read_text())["runs"]
    return [{k: v for k, v in r.items() if k != "wall_time"} for r in runs]


@pytest.fixture(scope="module")
def in_process(tmp_path_factory):
    """Both studies in this process (workers=1): the results every other way must reproduce."""
    out = tmp_path_factory.mktemp("in_process")
    explore = run_exploration_study(
        ("dice", "rubber"), EXPLORE, progress=False, out_dir=out / "explore", workers=1
    )
    impact = run_impact_study(IMPACT, IMPACT_RUNS, out / "impact", progress=False, workers=1)
    return out, explore, impact


def test_a_running_scheduler_gives_the_in_process_runs_of_both_studies(in_process, tmp_path):
    out, explore, impact = in_process
    with running_cluster(tmp_path, workers=2) as address:
        remote = run_exploration_study(
            ("dice", "rubber"),
            EXPLORE,
            progress=False,
            out_dir=tmp_path / "explore",
            scheduler=address,
        )
        remote_impact = run_impact_study(
            IMPACT, IMPACT_RUNS, tmp_path / "impact", progress=False, scheduler=address
        )
    assert _runs(tmp_path / "explore" / "results.json") == _runs(out / "explore" / "results.json")
    assert _runs(tmp_path / "impact" / "results.json") == _runs(out / "impact" / "results.json")
    execution = json.loads((tmp_path / "impact" / "results.json").read_text())["execution"]
    assert execution["cluster"] == address and execution["executed"] == 2
    assert execution["workers"] == 2
    # the figures' series came back from the workers too
    assert remote_impact.runs[0].log["force"].shape == impact.runs[0].log["force"].shape
    assert [r.final.estimate for r in remote] == [r.final.estimate for r in explore]
    # the learner really learned (the runs are not empty shells)
    assert all(r.final.covers(r.material) for r in remote)


def test_a_study_whose_results_were_lost_resumes_from_its_cache(in_process):
    out, explore, impact = in_process
    before = _runs(out / "impact" / "results.json")
    (out / "impact" / "results.json").unlink()  # as if killed before the end
    again = run_impact_study(IMPACT, IMPACT_RUNS, out / "impact", progress=False, workers=1)
    doc = json.loads((out / "impact" / "results.json").read_text())
    assert doc["execution"]["executed"] == 0 and doc["execution"]["cached"] == 2
    assert _runs(out / "impact" / "results.json") == before
    assert again.table == impact.table
    (out / "explore" / "results.json").unlink()
    resumed = run_exploration_study(
        ("dice", "rubber"), EXPLORE, progress=False, out_dir=out / "explore", workers=1
    )
    doc = json.loads((out / "explore" / "results.json").read_text())
    assert doc["execution"]["executed"] == 0 and doc["execution"]["cached"] == 2
    assert [r.summary() for r in resumed] == [r.summary() for r in explore]
    # a changed setting is a new run, not a cached one
    stiffer = replace(IMPACT, dice=replace(IMPACT.dice, stiffness=3300.0))
    run_impact_study(
        stiffer, IMPACT_RUNS[:1], out / "impact", progress=False, workers=1, force=True
    )
    doc = json.loads((out / "impact" / "results.json").read_text())
    assert doc["execution"]["executed"] == 1


def test_the_impact_command_takes_set_and_resumes_from_its_cache(tmp_path, capsys):
    out = tmp_path / "impact"
    argv = ["study", "impact", "--set", "plant.dice_stiffness=3300", "--runs"]
    argv += ["baseline+admittance", "--duration", "1.6", "--workers", "1", "--out", str(out)]
    assert main(argv) == 0
    first = capsys.readouterr()
    doc = json.loads((out / "results.json").read_text())
    assert doc["config"]["dice"]["stiffness"] == 3300.0
    assert doc["execution"]["executed"] == 1 and doc["runs"][0]["contact_time"] > 1.0
    assert main(argv) == 2  # a finished study is not overwritten
    assert "already exists" in capsys.readouterr().err
    (out / "results.json").unlink()
    assert main(argv) == 0
    again = capsys.readouterr()
    assert "1 runs: 1 from the cache" in again.err
    table = [line for line in first.out.splitlines() if line.startswith("| baseline")]
    assert table and table == [
        line for line in again.out.splitlines() if line.startswith("| baseline")
    ]
