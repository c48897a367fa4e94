"""Studies on Dask and the run cache (studies.study, ``ffmpc study ... --scheduler``).

The same short runs as tests/test_study.py (0.3 s of simulated time, contact at once, circle
from 0.15 s). One reference study runs in this process without a cache; a LocalCluster of two
workers, a scheduler with two workers started here as ``dask`` subprocesses, and a study killed
mid-way then restarted must all give the same ``results.json`` runs.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
from dask_helpers import free_port, running_cluster
from test_study import SHORT, SHORT_SET  # the short study setup, once

from ffmpc_core.errors import ConfigError
from ffmpc_ros.cli import main
from studies import execute
from studies.study import (
    RunCache,
    RunOutcome,
    RunSpec,
    check_output_dir,
    execute_specs,
    grid_specs,
    run_key,
    run_study,
    write_atomic,
)

#: Two seeds, the three formulations, PID on: six runs.
STUDY = ["study", "polishing", "--seeds", "2", "--pid", "on", "--duration", "0.3", *SHORT_SET]
ROOT = Path(__file__).resolve().parent.parent
#: Summary entries that are wall-clock measurements, not results.
TIMING = ("wall_time_s", "solve_time_median_s")


def _runs(out: Path) -> list[dict]:
    """The runs of a results.json without their timings, in grid order."""
    doc = json.loads((out / "results.json").read_text())
    assert doc["failures"] == []
    runs = [{k: v for k, v in r.items() if k not in TIMING} for r in doc["runs"]]
    return sorted(runs, key=lambda r: (r["formulation"], r["seed"]))


def _execution(out: Path) -> dict:
    return json.loads((out / "results.json").read_text())["execution"]


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> list[dict]:
    """The study in this process, no cache: the runs every other way must reproduce."""
    out = tmp_path_factory.mktemp("reference") / "study"
    assert main([*STUDY, "--workers", "1", "--no-cache", "--no-progress", "--out", str(out)]) == 0
    assert not (out / "cache").exists()
    execution = _execution(out)
    assert execution == {"cached": 0, "executed": 6, "cluster": "in-process", "cache_dir": None}
    runs = _runs(out)
    assert len(runs) == 6 and all(r["metrics_true"]["max_force"] > 5.0 for r in runs)
    return runs


def test_a_local_cluster_of_two_workers_gives_the_runs_of_the_in_process_study(
    reference, tmp_path, capsys
) -> None:
    out = tmp_path / "local"
    assert main([*STUDY, "--workers", "2", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert _runs(out) == reference
    doc = json.loads((out / "results.json").read_text())
    assert doc["workers"] == 2
    assert doc["execution"]["cluster"] == "LocalCluster"
    assert doc["execution"]["cached"] == 0 and doc["execution"]["executed"] == 6
    assert len(list((out / "cache").glob("*.json"))) == 6
    # The cluster and its dashboard (bound to this machine) are announced on stderr.
    assert "Dask LocalCluster at tcp://127.0.0.1:" in captured.err
    assert "dashboard: http://127.0.0.1:" in captured.err
    assert "(0 from the cache, 6 run: LocalCluster, 2 worker(s))" in captured.out


def test_a_running_scheduler_with_two_workers_gives_the_same_runs(reference, tmp_path) -> None:
    from distributed import Client

    with running_cluster(tmp_path, workers=2) as address:
        out = tmp_path / "remote"
        assert main([*STUDY, "--scheduler", address, "--no-progress", "--out", str(out)]) == 0
        assert _runs(out) == reference
        doc = json.loads((out / "results.json").read_text())
        assert doc["execution"]["cluster"] == address and doc["workers"] == 2
        assert doc["execution"]["executed"] == 6
        # The workers ran the study without importing ROS.
        with Client(address, timeout="60s") as client:
            loaded = client.run(eval, "'rclpy' in __import__('sys').modules")
            assert len(loaded) == 2 and set(loaded.values()) == {False}


def test_a_killed_study_resumes_from_its_cache_without_rerunning_finished_runs(
    reference, tmp_path
) -> None:
    out = tmp_path / "killed"
    argv = [*STUDY, "--workers", "1", "--out", str(out)]
    cache = out / "cache"
    proc = subprocess.Popen(
        [sys.executable, "-m", "ffmpc_ros.cli", *argv, "--no-progress"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 240
        while len(list(cache.glob("*.json"))) < 2:
            assert proc.poll() is None, "the study ended before it could be killed"
            assert time.monotonic() < deadline, "no run finished in 240 s"
            time.sleep(0.05)
    finally:
        proc.kill()  # SIGKILL: no clean-up of any kind
        proc.wait()
    assert not (out / "results.json").exists()
    finished = len(list(cache.glob("*.json")))
    assert 2 <= finished < 6
    for entry in cache.glob("*.json"):  # whole entries only
        json.loads(entry.read_text())

    # The same command again: an interrupted study's directory is resumed, not refused.
    assert main([*argv, "--no-progress"]) == 0
    assert _execution(out)["cached"] == finished
    assert _execution(out)["executed"] == 6 - finished
    assert _runs(out) == reference

    # Finished now: the same command is refused; --force reads every run from the cache,
    # --force --fresh runs them all again.
    with pytest.raises(ConfigError, match="already exists"):
        check_output_dir(out, force=False, resume=True)
    assert main([*argv, "--no-progress", "--force"]) == 0
    assert _execution(out)["cached"] == 6 and _execution(out)["executed"] == 0
    assert _execution(out)["cluster"] == "none (every run from the cache)"
    assert _runs(out) == reference


# --------------------------------------------------------------------------- cache, fast
def _fake_summary(spec: RunSpec) -> dict:
    """A deterministic stand-in for a run's summary (the cache logic does not look inside)."""
    return {"seed": spec.seed, "formulation": spec.formulation, "value": spec.seed / 7.0}


class _Counting:
    """A runner that counts its calls (in-process runs only)."""

    def __init__(self) -> None:
        self.calls: list[RunSpec] = []

    def __call__(self, spec: RunSpec) -> RunOutcome:
        self.calls.append(spec)
        if spec.seed == 2:
            return RunOutcome(spec, error="InputError: diverged")
        return RunOutcome(spec, summary=_fake_summary(spec))


def test_the_cache_reads_finished_runs_back_and_runs_only_the_others(tmp_path) -> None:
    specs = grid_specs("polishing", ["classical", "force_feedback"], [True], [0, 1, 2], 0.1)
    cache = RunCache(tmp_path / "cache")
    first = _Counting()
    batch = execute_specs(specs[:4], 1, False, first, cache=cache)
    assert (batch.cached, batch.executed, len(first.calls)) == (0, 4, 4)
    assert len(list(cache.directory.glob("*.json"))) == 4

    again = _Counting()
    batch = execute_specs(specs, 1, False, again, cache=cache)
    assert (batch.cached, batch.executed) == (4, 2)
    assert again.calls == list(specs[4:])
    assert [o.spec for o in batch.outcomes] == list(specs)
    assert [o.cached for o in batch.outcomes] == [True] * 4 + [False] * 2
    expected = [None if s.seed == 2 else _fake_summary(s) for s in specs]
    assert [o.summary for o in batch.outcomes] == expected
    # A failure is a result too (a pure function of the spec): cached, not run again.
    failed = [o for o in batch.outcomes if not o.ok]
    assert [o.spec.seed for o in failed] == [2, 2] and failed[0].error == "InputError: diverged"
    assert execute_specs(specs, 1, False, _Counting(), cache=cache).executed == 0

    # fresh: every run again; no cache: nothing read or written.
    fresh = _Counting()
    assert execute_specs(specs, 1, False, fresh, cache=cache, fresh=True).executed == 6
    assert len(fresh.calls) == 6
    uncached = _Counting()
    assert execute_specs(specs, 1, False, uncached).executed == 6

    # An unreadable or foreign entry is run again (and replaced by a whole one).
    key = run_key(specs[0])
    cache.path(key).write_text('{"key": "')
    other = cache.path(run_key(specs[1]))
    other.write_text(json.dumps({"key": "not-this-one"}))
    redo = _Counting()
    assert execute_specs(specs, 1, False, redo, cache=cache).executed == 2
    assert redo.calls == list(specs[:2])
    assert json.loads(cache.path(key).read_text())["key"] == key


def test_the_run_key_changes_with_everything_that_changes_a_result() -> None:
    base = grid_specs("polishing", ["classical"], [True], [0], 0.3, SHORT)[0]
    key = run_key(base)
    assert len(key) == 32 and run_key(replace(base)) == key
    variants = [
        replace(base, seed=1),
        replace(base, formulation="force_feedback"),
        replace(base, pid_enabled=False),
        replace(base, duration=0.4),
        replace(base, overrides=(*base.overrides, ("plant.table_stiffness", 12345.0))),
        replace(base, command_delay=0.004),
        replace(base, plot=True),
        replace(base, scenario="tilt"),
    ]
    keys = {run_key(v) for v in variants}
    assert key not in keys and len(keys) == len(variants)
    # The same scenario given by path or by name is the same run.
    from ffmpc_core.scenario import resolve_scenario_path

    assert run_key(replace(base, scenario=str(resolve_scenario_path("polishing")))) == key


def test_atomic_writes_leave_the_old_file_or_the_new_one(tmp_path, monkeypatch) -> None:
    path = tmp_path / "entry.json"
    write_atomic(path, "old\n")

    def crash(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(KeyboardInterrupt):
        write_atomic(path, "new\n")
    assert path.read_text() == "old\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["entry.json"]


def test_bad_cluster_requests_are_refused(tmp_path, monkeypatch) -> None:
    specs = grid_specs("polishing", ["classical"], [True], [0], 0.1)
    with pytest.raises(ConfigError, match="exclude each other"):
        execute_specs(specs, 2, False, _Counting(), scheduler="tcp://127.0.0.1:1")
    argv = [*STUDY, "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"]
    assert main([*argv, "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
    monkeypatch.setattr(execute, "SCHEDULER_TIMEOUT_S", 1.0)
    with pytest.raises(ConfigError, match="cannot reach the Dask scheduler"):
        execute_specs(specs, None, False, _Counting(), scheduler=f"tcp://127.0.0.1:{free_port()}")


def test_a_resumed_study_reuses_the_measured_mpc_step_time_so_its_runs_stay_cached(
    tmp_path,
) -> None:
    short = {"task.still": 0.0, "task.reach": 0.02, "mpc.command_delay": "measured"}
    short |= {"mpc.horizon": 20, "mpc.dt": 0.01}  # room for a slow step on a loaded machine
    specs = grid_specs("polishing", ["classical"], [True], [0], duration=0.05, overrides=short)
    out = tmp_path / "out"
    first = run_study("polishing", specs, out, workers=1, progress=False)
    assert first.document["execution"]["executed"] == 1
    (out / "results.json").unlink()  # as if killed before the end
    again = run_study("polishing", specs, out, workers=1, progress=False)
    assert again.document["execution"] == {
        **first.document["execution"],
        "cached": 1,
        "executed": 0,
        "cluster": "none (every run from the cache)",
    }
    record = again.document["command_delay"]["classical"]
    assert record["delta_o_s"] == first.document["command_delay"]["classical"]["delta_o_s"]
    assert (
        record["measured_step_median_s"]
        == (first.document["command_delay"]["classical"]["measured_step_median_s"])
    )


def test_a_run_spec_is_hashable_even_with_list_overrides() -> None:
    axis = {"plant.table_tilt_axis": [1.0, 0.0, 0.0]}
    spec = grid_specs("polishing", ["classical"], [True], [0], 0.1, axis)[0]
    assert spec.overrides == (("plant.table_tilt_axis", (1.0, 0.0, 0.0)),)
    assert {spec: 1}[replace(spec)] == 1
    assert spec.scenario_overrides()["plant.table_tilt_axis"] == [1.0, 0.0, 0.0]
    assert spec.load().plant.table_tilt_axis == (1.0, 0.0, 0.0)
    other = replace(spec, overrides=(("plant.table_tilt_axis", (0.0, 1.0, 0.0)),))
    assert run_key(other) != run_key(spec)
