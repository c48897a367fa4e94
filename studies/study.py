"""The paper's simulation study (VI-C: Tables II–IV, Figs. 6–9) and Experiment 1 (VII-B).

A study is a grid of closed-loop runs — formulations × torque PID on/off × seeds — each run being
``run_polishing(load_scenario(name, overrides))`` with the overrides ``mpc.formulation``,
``pid.enabled`` and ``seed`` (the seed draws the table tilt θ and the actuation bias (a, b), the
same for every controller). A run is a pure function of its :class:`RunSpec`. Runs go to Dask
(``distributed``): a ``LocalCluster`` of spawned single-thread worker processes by default
(PyBullet clients and crocoddyl objects must never be forked mid-state), or the workers of a
running scheduler (``scheduler=``, ``--scheduler``); ``workers=1`` runs in this process. A worker
sends back the run's ``summary()`` and, for the one seed that is plotted, a downsampled log —
never the full time series. Each finished run is cached on disk under a key of its fully
resolved scenario (:func:`run_key`, :class:`RunCache`), so an interrupted study resumes.

Outputs, in a directory that must not exist yet (unless ``force``):

* ``results.json`` — every run's summary, failures, the grid, the command line, the package
  versions, the scenario's parameters, the wall time and how many runs came from the cache;
* ``cache/<key>.json`` — one finished run each (the default cache directory);
* ``tables.md`` — Tables II (no PID) and III (PID) in the paper's layout, Table IV (ΔE_λ, ΔE_τ =
  no-PID − PID per seed), computed from the TRUE normal force along the tilted table normal, then
  the same tables from the MEASURED force (what the controllers see);
* PNG figures like the paper's Figs. 6–9 (normal force vs reference and tangential position
  error over time, one seed, three controllers), or Fig. 4 for Experiment 1.

A run that raises (a diverging controller: non-finite state, solver failure) is recorded as a
failure with its error and left out of the aggregates; the tables say how many runs each cell
has and list the failures. A run the robot's own reflexes aborted (``plant.reflex``, on by
default: a joint over a data-sheet limit the robot stops on; ``ffmpc_core.reflex``) is counted
in its cell ("4/5 (1 aborted)"), left out of the aggregates and paired comparisons, and listed
with its event under "Aborted runs"; a study run with ``--set plant.reflex=false`` says so
under the tables, and its counts are of the runs that would have been aborted.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import platform
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ffmpc_core.config import FORMULATIONS
from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_core.metrics import PolishingMetrics, summarize
from ffmpc_core.scenario import Scenario, load_scenario, resolve_scenario_path, scenario_parameters
from studies.execute import (
    CACHE_SCHEMA,
    RunBatch,
    RunCache,
    RunOutcome,
    canonical_json,
    check_output_dir,
    execute_jobs,
    job_key,
    prepare_output_dir,
    study_cache,
    write_atomic,
    write_json,
)
from studies.reflexes import aborted_count, reflex_note, reflexes_enabled

if TYPE_CHECKING:
    from distributed import Client
    from matplotlib.axes import Axes

    from studies.polishing import RunResult

#: Column titles of the paper's tables, per formulation.
LABELS = {
    "classical": "Classical",
    "torque_feedback": "Torque-feedback",
    "force_feedback": "Force-feedback",
}
#: Plot colours per formulation.
COLORS = {"classical": "tab:blue", "torque_feedback": "tab:orange", "force_feedback": "tab:green"}
#: Sampling period of the logs kept for the figures, s.
PLOT_STEP = 0.002
#: Signals of a downsampled plot log (t in s, forces in N, tangential error in mm).
PLOT_SIGNALS = ("t", "force_true", "force_measured", "force_reference", "tangential_error_mm")

#: The paper's Tables II–IV (VI-C) and Experiment 1 MAEs (VII-B), for comparison only.
PAPER_TABLES: dict[str, dict[str, tuple[str, ...]]] = {
    "II": {
        "classical": ("5.75 ± 0.06", "25.52 ± 4.09", "59.36", "0.51"),
        "torque_feedback": ("2.44 ± 0.01", "33.98 ± 4.42", "105.57", "32.75"),
        "force_feedback": ("4.59 ± 0.01", "10.55 ± 4.40", "110.95", "0.00"),
    },
    "III": {
        "classical": ("7.94 ± 1.43", "15.21 ± 5.70", "185.75", "0.00"),
        "torque_feedback": ("3.87 ± 0.65", "12.44 ± 4.16", "211.00", "0.00"),
        "force_feedback": ("3.07 ± 0.01", "2.04 ± 0.01", "111.97", "0.00"),
    },
    "IV": {
        "classical": ("10.31 ± 6.85", "2.24 ± 0.08"),
        "torque_feedback": ("21.55 ± 4.95", "2.20 ± 0.07"),
        "force_feedback": ("8.51 ± 1.87", "1.95 ± 0.26"),
    },
}
PAPER_FORCE_SQUARE_MAE = {"classical": 2.76, "torque_feedback": 2.70, "force_feedback": 2.16}


#: The paper's hardware tables (VII-C, VII-D): "Force (N)" and "Position (mm)" MAE, mean ± std
#: over 10 circles of one run (ours: over the seeds). Experiment 3.3 prints no numbers (Fig. 9).
PAPER_TABLES.update(
    {
        "V": {
            "classical": ("9.31 ± 0.79", "6.48 ± 0.21"),
            "torque_feedback": ("4.28 ± 0.63", "3.23 ± 0.12"),
            "force_feedback": ("1.70 ± 0.15", "3.10 ± 0.11"),
        },
        "VI": {
            "classical": ("9.49 ± 1.59", "7.04 ± 0.43"),
            "torque_feedback": ("9.67 ± 0.61", "3.37 ± 0.28"),
            "force_feedback": ("2.12 ± 0.37", "3.34 ± 0.11"),
        },
        "VII": {
            "classical": ("9.00 ± 1.61", "10.85 ± 0.12"),
            "torque_feedback": ("11.40 ± 1.45", "5.41 ± 0.12"),
            "force_feedback": ("1.84 ± 0.32", "5.29 ± 0.03"),
        },
    }
)
#: Version of the push windows a push run's summary holds (part of its cache key).
PUSH_METRICS_VERSION = 1
#: The scenario parameter of δo.
DELTA_O = "mpc.command_delay"


def delta_o_text(value: Any) -> str | None:
    """A ``mpc.command_delay`` value as the text that labels its grid: seconds as ``repr`` of
    the float ("0.0", "0.005"), "measured" and "pid" as they are; None stays None."""
    if value is None:
        return None
    if isinstance(value, str) and value.strip() in ("measured", "pid"):
        return value.strip()
    try:
        return repr(float(value))
    except (TypeError, ValueError):
        raise ConfigError(
            f"mpc.command_delay = {value!r}: expected seconds, 'measured' or 'pid'"
        ) from None


def delta_o_label(setting: str | None) -> str:
    """``δo = 5 ms`` for "0.005", ``δo measured`` ..., for table titles."""
    if setting is None:
        return "δo of the scenario"
    if setting in ("measured", "pid"):
        return f"δo = {setting}"
    return f"δo = {float(setting) * 1e3:g} ms"


#: Exceptions that mean "this run diverged" (recorded as a failure, the study goes on).
DIVERGENCE_ERRORS: tuple[type[BaseException], ...] = (
    FfmpcError,
    ArithmeticError,
    ValueError,
    RuntimeError,
    np.linalg.LinAlgError,
)


# --------------------------------------------------------------------------- runs
def _freeze(value: Any) -> Any:
    """Lists (nested too) as tuples, so that an override value is hashable."""
    return tuple(_freeze(v) for v in value) if isinstance(value, list | tuple) else value


def _thaw(value: Any) -> Any:
    """Tuples back to the lists a scenario file would hold."""
    return [_thaw(v) for v in value] if isinstance(value, tuple) else value


@dataclass(frozen=True)
class RunSpec:
    """One run of a study: a scenario (shipped name or path) with the grid's overrides.

    ``overrides`` are extra dotted-name overrides applied to every run of the study (as
    ``(name, value)`` pairs, so the spec stays hashable and picklable); ``plot`` asks the worker
    to send back a log downsampled to ``plot_step`` (s); ``command_delay`` is the δo (s) that
    :func:`resolve_command_delays` measured for the spec's formulation.
    """

    scenario: str
    formulation: str
    pid_enabled: bool
    seed: int
    duration: float | None = None
    overrides: tuple[tuple[str, Any], ...] = ()
    plot: bool = False
    plot_step: float = PLOT_STEP
    #: δo resolved by the study for ``mpc.command_delay: measured`` (s), else None.
    command_delay: float | None = None

    def __post_init__(self) -> None:
        # Hashable whatever the caller passed: list values (``--set axis=[1, 0, 0]``) become
        # tuples here and lists again in :meth:`scenario_overrides`.
        frozen = tuple((str(k), _freeze(v)) for k, v in self.overrides)
        object.__setattr__(self, "overrides", frozen)

    def scenario_overrides(self) -> dict[str, Any]:
        out = {k: _thaw(v) for k, v in self.overrides}
        out.update(
            {
                "mpc.formulation": self.formulation,
                "pid.enabled": self.pid_enabled,
                "seed": self.seed,
            }
        )
        if self.command_delay is not None:
            out["mpc.command_delay"] = self.command_delay
        return out

    def load(self) -> Scenario:
        """The run's scenario (ConfigError on a bad file or override)."""
        return load_scenario(self.scenario, self.scenario_overrides())

    def key_document(self) -> dict[str, Any]:
        """The fully resolved scenario (the file's parameters with every override, formulation,
        PID mode, seed and δo applied), the duration (s) and what the run sends back (plot step,
        s, or none): :class:`studies.execute.Job`."""
        scenario = self.load()
        doc = {
            "scenario_name": scenario.name,
            "scenario": scenario_parameters(scenario),
            "duration_s": self.duration,
            "plot_step_s": self.plot_step if self.plot else None,
        }
        if scenario.plant.push_enabled:  # the summary holds the push windows (Experiment 3.3)
            doc["push_metrics"] = PUSH_METRICS_VERSION
        return doc

    @property
    def delta_o_setting(self) -> str | None:
        """The run's ``mpc.command_delay`` override as text ("0.005", "measured"), None when the
        scenario's own setting is used (see :func:`grid_specs` ``command_delays``)."""
        return delta_o_text(dict(self.overrides).get(DELTA_O))

    def description(self) -> dict[str, Any]:
        return {
            "scenario": self.scenario,
            "formulation": self.formulation,
            "pid_enabled": self.pid_enabled,
            "seed": self.seed,
            "duration_s": self.duration,
            "overrides": dict(self.overrides),
            "command_delay_s": self.command_delay,
        }

    @property
    def label(self) -> str:
        return f"{self.formulation} pid={'on' if self.pid_enabled else 'off'} seed={self.seed}"

    @property
    def cost_rank(self) -> int:
        """The slowest formulations first."""
        return {"force_feedback": 0, "torque_feedback": 1}.get(self.formulation, 2)


def plot_log(result: RunResult, scenario: Scenario, step: float) -> dict[str, np.ndarray]:
    """The signals of :data:`PLOT_SIGNALS` from a run's log, one sample every ``step`` s.

    The tangential error is ‖(I − n nᵀ)(p − p̄)‖ in mm, n the TRUE (tilted) table normal, as E_P;
    ``window`` holds the [start, end] of the metrics window (s; NaN when empty).
    """
    from ffmpc_core.polishing import build_task
    from ffmpc_core.robots import load_robot
    from ffmpc_core.tasks import GuardedTask
    from sim_bridge.scenes import polishing_plant_config as plant_config

    log = result.log
    dt = scenario.plant.time_step
    every = max(1, int(round(step / dt)))
    task = build_task(scenario, load_robot(scenario.robot))
    if isinstance(task, GuardedTask):  # the run's contact phases, shifted by its detection
        task.restore_detection(result.contact_time)
    table = plant_config(scenario, task, result.draws.tilt_angle).table
    assert table is not None  # plant_config always builds the tilted table
    normal = table.normal
    error = log["ee_position"] - log["ee_reference"]
    tangential = error - np.outer(error @ normal, normal)
    full = {
        "t": log["t"],
        "force_true": log["force_true"],
        "force_measured": log["force_measured"],
        "force_reference": log["force_reference"],
        "tangential_error_mm": 1e3 * np.linalg.norm(tangential, axis=1),
    }
    out = {name: np.array(values[::every]) for name, values in full.items()}
    window = task.in_circle(log["t"])
    out["window"] = log["t"][window][[0, -1]] if window.any() else np.array([np.nan, np.nan])
    return out


def execute_run(spec: RunSpec) -> RunOutcome:
    """Run one spec (in a worker or in-process).

    A run that diverges — non-finite states or measurements (InputError), a solver failure, a
    numerical error from numpy/pinocchio/crocoddyl/PyBullet — is returned as a failure. A
    configuration error, and programming errors (NameError, TypeError, ...), propagate: they
    are not results.
    """
    import pybullet

    from studies.polishing import run_polishing

    scenario = spec.load()
    try:
        result = run_polishing(scenario, spec.duration)
    except ConfigError:
        raise
    except (*DIVERGENCE_ERRORS, pybullet.error) as exc:
        return RunOutcome(spec, error=f"{type(exc).__name__}: {exc}")
    logs = plot_log(result, scenario, spec.plot_step) if spec.plot else None
    return RunOutcome(spec, summary=result.summary(), plot_log=logs)


def resolve_command_delays(
    specs: Sequence[RunSpec], steps: int = 60, measured: dict[str, float] | None = None
) -> tuple[list[RunSpec], dict[str, dict]]:
    """Settle δo (``mpc.command_delay``) of every spec, once per formulation.

    With ``mpc.command_delay: measured`` the MPC of each formulation is timed on this machine
    (:func:`ffmpc_core.polishing.resolve_command_delay`, ``steps`` MPC steps, in this process,
    before any run starts) and its specs get the measured δo, rounded up to the plant step;
    ``measured`` (``{formulation: MPC step time, s}``, e.g. from an interrupted start of the
    same study) is used instead of timing again.
    Returns the specs and ``{formulation: record}`` (``delta_o_s`` is the δo the runs used).
    """
    from ffmpc_core.polishing import resolve_command_delay

    records: dict[str, dict] = {}
    resolved: dict[tuple, float | None] = {}
    out = []
    for spec in specs:
        key = (spec.scenario, spec.overrides, spec.formulation)
        if key not in resolved:
            known = (measured or {}).get(spec.formulation)
            scenario, record = resolve_command_delay(spec.load(), measured=known, steps=steps)
            was_measured = record["setting"] == "measured"
            resolved[key] = record["delta_o_s"] if was_measured else None
            records.setdefault(spec.formulation, record)
        out.append(replace(spec, command_delay=resolved[key]))
    return out, records


def _measured_delays_path(cache: RunCache, specs: Sequence[RunSpec]) -> Path:
    """Where a study keeps the MPC step times it measured for ``mpc.command_delay: measured``:
    one file per (scenario, overrides) of the grid, in the cache directory."""
    context = canonical_json([specs[0].scenario, [list(kv) for kv in specs[0].overrides]])
    digest = hashlib.sha256(context.encode("utf-8")).hexdigest()[:16]
    return cache.directory / f"measured_mpc_step_time_{digest}.json"


def _load_measured_delays(cache: RunCache, specs: Sequence[RunSpec]) -> dict[str, float]:
    """``{formulation: MPC step time, s}`` measured by an earlier start of the study (or {})."""
    try:
        doc = json.loads(_measured_delays_path(cache, specs).read_text(encoding="utf-8"))
    except (FileNotFoundError, json.JSONDecodeError):
        return {}
    return {str(k): float(v) for k, v in doc.items()} if isinstance(doc, dict) else {}


def _save_measured_delays(
    cache: RunCache, specs: Sequence[RunSpec], records: dict[str, dict], known: dict[str, float]
) -> None:
    """Keep the measured MPC step times so that a resumed study gives its runs the same δo
    (the same cache keys) instead of timing the MPC again."""
    times = dict(known)
    for formulation, record in records.items():
        if "measured_step_median_s" in record:
            times[formulation] = float(record["measured_step_median_s"])
    if times:
        cache.directory.mkdir(parents=True, exist_ok=True)
        write_atomic(_measured_delays_path(cache, specs), canonical_json(times) + "\n")


def validate_specs(specs: Sequence[RunSpec]) -> None:
    """Load each distinct scenario of the grid once: a bad file or override fails now, before
    any run (ConfigError)."""
    if not specs:
        raise ConfigError("a study needs at least one run")
    distinct = {(s.scenario, s.overrides, s.formulation, s.pid_enabled): s for s in specs}
    for spec in distinct.values():
        spec.load()


def run_key(spec: RunSpec, versions: dict[str, str | None] | None = None) -> str:
    """The cache key of a polishing run (:func:`studies.execute.job_key` of the spec)."""
    return job_key(spec, versions)


def execute_specs(
    specs: Sequence[RunSpec],
    workers: int | None = None,
    progress: bool = True,
    runner: Callable[[RunSpec], RunOutcome] = execute_run,
    *,
    scheduler: str | None = None,
    cache: RunCache | None = None,
    fresh: bool = False,
    announce: Callable[[str], None] | None = None,
    client: Client | None = None,
) -> RunBatch:
    """Check the grid (:func:`validate_specs`), then :func:`studies.execute.execute_jobs` with
    ``runner`` (default :func:`execute_run`)."""
    validate_specs(specs)
    return execute_jobs(
        specs,
        runner,
        workers,
        progress,
        scheduler=scheduler,
        cache=cache,
        fresh=fresh,
        announce=announce,
        client=client,
    )


def run_specs(
    specs: Sequence[RunSpec],
    workers: int | None = None,
    progress: bool = True,
    runner: Callable[[RunSpec], RunOutcome] = execute_run,
    *,
    scheduler: str | None = None,
    cache: RunCache | None = None,
    fresh: bool = False,
) -> list[RunOutcome]:
    """Run every spec and return the outcomes in the order of ``specs`` (see
    :func:`execute_specs` for the arguments: ``workers`` > 1 is a Dask LocalCluster, ``1`` this
    process, ``scheduler`` a running Dask cluster)."""
    return execute_specs(
        specs, workers, progress, runner, scheduler=scheduler, cache=cache, fresh=fresh
    ).outcomes


def grid_specs(
    scenario: str,
    formulations: Sequence[str],
    pid_modes: Sequence[bool],
    seeds: Sequence[int],
    duration: float | None = None,
    overrides: dict[str, Any] | None = None,
    plot_seed: int | None = None,
    command_delays: Sequence[float | str] | None = None,
) -> list[RunSpec]:
    """The runs of a study: every (PID mode, formulation, seed), the ``plot_seed`` ones plotted.

    ``command_delays``: one grid per value, each with the override ``mpc.command_delay`` = the
    value (s, or "measured"); the tables then come per δo (:func:`polishing_tables`).
    """
    if command_delays is not None:
        if not command_delays:
            raise ConfigError("command_delays: give at least one value")
        if DELTA_O in (overrides or {}):
            raise ConfigError(
                f"{DELTA_O} is given both as an override and by the command delays; give it once"
            )
        settings = [delta_o_text(v) for v in command_delays]
        if len(set(settings)) != len(settings):
            raise ConfigError(f"command delays repeat a value: {list(command_delays)}")
        return [
            spec
            for value in command_delays
            for spec in grid_specs(
                scenario,
                formulations,
                pid_modes,
                seeds,
                duration,
                {**(overrides or {}), DELTA_O: value},
                plot_seed,
            )
        ]
    bad = [f for f in formulations if f not in FORMULATIONS]
    if bad or not formulations:
        raise ConfigError(f"formulations must be among {FORMULATIONS}, got {list(formulations)}")
    if not seeds or not pid_modes:
        raise ConfigError("a study needs at least one seed and one PID mode")
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise ConfigError(f"duration must be > 0 s, got {duration}")
    extra = tuple(sorted((overrides or {}).items()))
    reserved = {"mpc.formulation", "pid.enabled", "seed"} & {k for k, _ in extra}
    if reserved:
        raise ConfigError(f"{sorted(reserved)} are set by the study grid, not by overrides")
    return [
        RunSpec(
            scenario=scenario,
            formulation=form,
            pid_enabled=pid,
            seed=int(seed),
            duration=duration,
            overrides=extra,
            plot=plot_seed is not None and int(seed) == plot_seed,
        )
        for pid in pid_modes
        for form in formulations
        for seed in seeds
    ]


# --------------------------------------------------------------------------- results
def source_state() -> dict[str, Any]:
    """The git commit of the ffmpc sources that ran, and the files modified since (read-only
    git queries; empty when not in a git checkout)."""
    import subprocess

    root = Path(__file__).resolve().parent.parent

    def git(*args: str) -> str | None:
        try:
            done = subprocess.run(
                ["git", "-C", str(root), *args], capture_output=True, text=True, timeout=10
            )
        except (OSError, subprocess.TimeoutExpired):
            return None
        return done.stdout if done.returncode == 0 else None

    commit = git("rev-parse", "HEAD")
    if commit is None:
        return {}
    status = git("status", "--porcelain", "--untracked-files=no") or ""
    return {
        "commit": commit.strip(),
        "modified": [line[3:] for line in status.splitlines() if line.strip()],
    }


def study_document(
    kind: str,
    specs: Sequence[RunSpec],
    outcomes: Sequence[RunOutcome],
    *,
    command_line: str,
    workers: int,
    wall_time: float,
    command_delays: dict[str, dict] | None = None,
    execution: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The content of ``results.json``: the grid, every run, failures, versions, timing, the
    δo each formulation ran with (``command_delay``, see :func:`resolve_command_delays`) and
    how the runs were obtained (``execution``: cached vs run, cluster, cache directory)."""
    from ffmpc_core.selfcheck import installed_versions

    first = specs[0]
    scenario = first.load()
    # One grid per δo (grid_specs command_delays): each run and failure says which.
    settings = list(dict.fromkeys(s.delta_o_setting for s in specs))
    per_delta = settings != [None] and all(isinstance(v, str) for v in settings)

    def tagged(record: dict, spec: RunSpec) -> dict:
        return {**record, "delta_o_setting": spec.delta_o_setting} if per_delta else record

    runs = [tagged(o.summary, o.spec) for o in outcomes if o.summary is not None]
    failures = [
        tagged(
            {
                "formulation": o.spec.formulation,
                "pid_enabled": o.spec.pid_enabled,
                "seed": o.spec.seed,
                "error": o.error,
            },
            o.spec,
        )
        for o in outcomes
        if not o.ok
    ]
    grid: dict[str, Any] = {
        "formulations": list(dict.fromkeys(s.formulation for s in specs)),
        "pid_enabled": list(dict.fromkeys(s.pid_enabled for s in specs)),
        "seeds": list(dict.fromkeys(s.seed for s in specs)),
    }
    overrides = dict(first.overrides)
    if per_delta:
        grid["command_delays"] = settings
        if len(settings) > 1:  # one grid per δo: the runs say which; one δo stays an override
            overrides.pop(DELTA_O, None)
    doc = {
        "kind": kind,
        "scenario": scenario.name,
        "scenario_file": str(resolve_scenario_path(first.scenario)),
        "plant_engine": scenario.plant.engine,
        "overrides": overrides,
        "duration_s": first.duration,
        "grid": grid,
        "command_line": command_line,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "wall_time_s": wall_time,
        "workers": workers,
        "execution": execution or {},
        "source": source_state(),
        "versions": {
            "python": platform.python_version(),
            "platform": platform.platform(),
            **installed_versions(),
        },
        "metrics_note": (
            "metrics_true: the plant's true normal force along the tilted table normal; "
            "metrics_measured: the measured force the controllers see (sensor noise and delay). "
            "E_P uses the true table normal in both. Window: the circle phase (polishing) or "
            "the square signal (force_square)."
        ),
        "command_delay": command_delays or {},
        "scenario_parameters": scenario_parameters(
            scenario.with_overrides({"seed": 0, "mpc.formulation": first.formulation})
        ),
        "runs": runs,
        "failures": failures,
    }
    doc["paired_comparison"] = {
        delta_key(setting): {
            ("III" if pid else "II"): paired_comparison(sub, pid) for pid in grid["pid_enabled"]
        }
        for setting, sub in delta_o_groups(doc)
    }
    return doc


def delta_key(setting: str | None) -> str:
    """The key of a δo group in ``results.json`` ("scenario" for the scenario's own δo)."""
    return "scenario" if setting is None else setting


def delta_o_groups(doc: dict) -> list[tuple[str | None, dict]]:
    """The study per δo: ``[(setting, the document with that δo's runs and failures only)]``;
    one ``(None, doc)`` for a study without ``command_delays``."""
    settings = doc["grid"].get("command_delays")
    if not settings:
        return [(None, doc)]
    out = []
    for setting in settings:
        sub = dict(doc)
        sub["runs"] = [r for r in doc["runs"] if r.get("delta_o_setting") == setting]
        sub["failures"] = [f for f in doc["failures"] if f.get("delta_o_setting") == setting]
        out.append((setting, sub))
    return out


#: The two metrics of the paired comparison: run-summary name, table label.
PAIRED_METRICS = (("force_mae", "ΔE_λ (N)"), ("position_mae_mm", "ΔE_P (mm)"))
#: How the paired test is called (stated in the tables).
WILCOXON_CALL = "scipy.stats.wilcoxon(d, zero_method='wilcox', alternative='two-sided')"


def wilcoxon_test(differences: Sequence[float]) -> dict[str, Any]:
    """The Wilcoxon signed-rank test of paired differences d (two-sided, :data:`WILCOXON_CALL`).

    Returns ``n`` (pairs), ``statistic``, ``p_value`` and ``note``. What scipy does, stated:
    zero differences are dropped (zero_method 'wilcox'); with no zero or tie it uses the exact
    distribution, so the smallest two-sided p of n pairs is 2/2ⁿ (n = 5: 0.0625: fewer than 6
    pairs can never reach p < 0.05); with every difference zero scipy returns p = 1 (it warns
    of a 0/0, silenced here). No pair: no test (None). A scipy that refuses the data (older
    versions raise on all-zero differences) gives None with its message as the note.
    """
    import warnings

    from scipy.stats import wilcoxon

    d = np.asarray(differences, dtype=float)
    n = int(d.size)
    if n == 0:
        return {"n": 0, "statistic": None, "p_value": None, "note": "no pair"}
    notes = []
    if n < 6:
        notes.append(f"n < 6: p >= 2/2^n = {2.0 / 2**n:.3g}")
    if np.all(d == 0.0):
        notes.append("all differences 0")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            result = wilcoxon(d, zero_method="wilcox", alternative="two-sided")
    except ValueError as exc:
        return {"n": n, "statistic": None, "p_value": None, "note": f"scipy: {exc}"}
    return {
        "n": n,
        "statistic": float(result.statistic),
        "p_value": float(result.pvalue),
        "note": "; ".join(notes),
    }


def paired_comparison(
    doc: dict, pid: bool, source: str = "true", reference: str = "force_feedback"
) -> dict[str, dict[str, Any]]:
    """Per seed, ``reference`` (the force-feedback MPC) minus each other controller, for E_λ (N)
    and E_P (mm), PID mode ``pid``, from the ``source`` force ("true" or "measured").

    Only the seeds where both runs succeeded (no failure, no reflex abort) are paired. Returns
    ``{other formulation: {"seeds": [...], "force_mae": {"differences", "mean", "std",
    **wilcoxon_test}, "position_mae_mm": {...}}}`` (std: numpy's, ddof 0, as the tables' other std).
    """
    forms = doc["grid"]["formulations"]
    if reference not in forms:
        return {}
    ref = {r["seed"]: r for r in _select(doc["runs"], reference, pid)}
    out: dict[str, dict[str, Any]] = {}
    for other in forms:
        if other == reference:
            continue
        them = {r["seed"]: r for r in _select(doc["runs"], other, pid)}
        seeds = sorted(set(ref) & set(them))
        entry: dict[str, Any] = {"seeds": seeds}
        for metric, _label in PAIRED_METRICS:
            diffs = [
                ref[s][f"metrics_{source}"][metric] - them[s][f"metrics_{source}"][metric]
                for s in seeds
            ]
            mean, std = _mean_std(diffs)
            entry[metric] = {"differences": diffs, "mean": mean, "std": std, **wilcoxon_test(diffs)}
        out[other] = entry
    return out


def _p_text(p: float | None) -> str:
    return "n/a" if p is None else f"{p:.4g}"


def paired_table(doc: dict, pid: bool, title: str, source: str = "true") -> list[str]:
    """Markdown of :func:`paired_comparison`: one row per other controller."""
    pairs = paired_comparison(doc, pid, source)
    if not pairs:
        return []
    header = ["", "pairs", "ΔE_λ (N)", "p (E_λ)", "ΔE_P (mm)", "p (E_P)", "note"]
    rows = []
    for other, entry in pairs.items():
        force, position = entry["force_mae"], entry["position_mae_mm"]
        notes: list[str] = []
        for short, result in (("E_λ", force), ("E_P", position)):
            for part in filter(None, result["note"].split("; ")):
                text = part if part.startswith("n < 6") else f"{short}: {part}"
                if text not in notes:
                    notes.append(text)
        rows.append(
            [
                f"Force-feedback − {LABELS[other]}",
                str(len(entry["seeds"])),
                _pm(force["mean"], force["std"]),
                _p_text(force["p_value"]),
                _pm(position["mean"], position["std"]),
                _p_text(position["p_value"]),
                "; ".join(notes) or "-",
            ]
        )
    total = len(doc["grid"]["seeds"])
    return [
        title,
        "",
        *_table(header, rows),
        "",
        f"Per seed, force-feedback minus the other controller ({source} force; negative: the "
        f"force-feedback MPC has the lower error); mean ± std over the pairs. Only seeds where "
        f"both runs succeeded (neither failed nor aborted by a reflex) are paired (pairs out of "
        f"{total} seeds). p: Wilcoxon signed-rank, "
        f"paired, two-sided, `{WILCOXON_CALL}`: zero differences are dropped; without zeros or "
        "ties the p is exact, at least 2/2ⁿ for n pairs, so fewer than 6 pairs can never give "
        "p < 0.05; all differences 0 → scipy returns p = 1.",
        "",
    ]


def _metrics(run: dict, source: str) -> PolishingMetrics:
    return PolishingMetrics(**run[f"metrics_{source}"])


def _cell(runs: Sequence[dict], formulation: str, pid: bool) -> list[dict]:
    """Every run of one table cell (formulation, PID mode), aborted ones included."""
    return [r for r in runs if r["formulation"] == formulation and r["pid_enabled"] == pid]


def _select(runs: Sequence[dict], formulation: str, pid: bool) -> list[dict]:
    """The runs of one cell that the aggregates use: those a reflex did not abort (an aborted
    run's robot stopped itself mid-task; it is counted, not averaged)."""
    return [r for r in _cell(runs, formulation, pid) if not r.get("aborted", False)]


def _pm(mean: float | None, std: float | None) -> str:
    return "n/a" if mean is None else f"{mean:.2f} ± {std:.2f}"


def aggregate(doc: dict, formulation: str, pid: bool, source: str) -> dict | None:
    """``summarize()`` of the runs of one cell (``source`` "true" or "measured"), or None."""
    runs = _select(doc["runs"], formulation, pid)
    return summarize([_metrics(r, source) for r in runs]) if runs else None


def delta_per_seed(doc: dict, formulation: str, source: str) -> dict[str, list[float]]:
    """Table IV: ΔE_λ (N) and ΔE_τ (N·m) = no-PID − PID, per seed run in both modes."""
    off = {r["seed"]: r for r in _select(doc["runs"], formulation, False)}
    on = {r["seed"]: r for r in _select(doc["runs"], formulation, True)}
    seeds = sorted(set(off) & set(on))
    out: dict[str, list[float]] = {"seeds": seeds, "force_mae": [], "torque_mae": []}
    for seed in seeds:
        a, b = off[seed][f"metrics_{source}"], on[seed][f"metrics_{source}"]
        out["force_mae"].append(a["force_mae"] - b["force_mae"])
        if a["torque_mae"] is not None and b["torque_mae"] is not None:
            out["torque_mae"].append(a["torque_mae"] - b["torque_mae"])
    return out


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def _counts(doc: dict, forms: Sequence[str], pid: bool) -> str:
    """ "Classical 4/5 (1 aborted), ...": the runs each aggregate uses out of the seeds, and the
    runs a reflex aborted (with the reflexes off: "would have aborted")."""
    total = len(doc["grid"]["seeds"])
    parts = []
    for f in forms:
        cell = _cell(doc["runs"], f, pid)
        used = len(_select(doc["runs"], f, pid))
        crossed = aborted_count([r.get("reflex") for r in cell])
        off = reflexes_enabled([r.get("reflex") for r in cell]) is False
        note = f" ({crossed} {'would have aborted' if off else 'aborted'})" if crossed else ""
        parts.append(f"{LABELS[f]} {used}/{total}{note}")
    return ", ".join(parts)


def aborted_section(doc: dict, title: str = "") -> list[str]:
    """The runs the robot's reflexes aborted (left out of every aggregate), each with its
    event, and whether the reflexes were on (:func:`studies.reflexes.reflex_note`)."""
    reports = [r.get("reflex") for r in doc["runs"]]
    lines = [f"## Aborted runs{title} (the robot's own reflexes; left out of every aggregate)", ""]
    lines += [reflex_note(reports), ""]
    for r in doc["runs"]:
        event = (r.get("reflex") or {}).get("event")
        if event is None:
            continue
        pid = "on" if r["pid_enabled"] else "off"
        delta = f", {delta_o_label(r['delta_o_setting'])}" if "delta_o_setting" in r else ""
        lines.append(
            f"- {LABELS[r['formulation']]}, PID {pid}{delta}, seed {r['seed']}: {event['message']}"
        )
    return lines + [""]


def polishing_tables(doc: dict) -> str:
    """``tables.md`` of a polishing study: Tables II–IV from the true, then the measured force,
    with the paired comparison (:func:`paired_table`) under Tables II–III from the true force;
    once per δo for a study with ``command_delays``."""
    forms = doc["grid"]["formulations"]
    delays = doc["grid"].get("command_delays")
    lines = [
        f"# Polishing study — scenario `{doc['scenario']}`",
        "",
        f"{len(doc['grid']['seeds'])} seeds ({_seed_range(doc['grid']['seeds'])}); each seed "
        "draws the table tilt θ ~ U(±θmax) and the actuation bias (a, b), the same for every "
        f"controller. Command: `{doc['command_line']}`. Wall time {doc['wall_time_s']:.0f} s "
        f"on {doc['workers']} worker(s). Plant simulator (`plant.engine`): "
        f"{doc.get('plant_engine', 'pybullet')}.",
        "",
        "Aggregation as the paper: E_P, E_λ mean ± std over the seeds; λmax and t_break the max "
        "over the seeds (eq 34–35); metrics over the circle phase.",
        "",
    ]
    if delays:
        lines += [
            "One grid per OCP delay δo (`mpc.command_delay`: "
            + ", ".join(f"`{d}`" for d in delays)
            + "), the same seeds.",
            "",
        ]
    for setting, sub in delta_o_groups(doc):
        if delays:
            lines += [f"## {delta_o_label(setting)} (`mpc.command_delay: {setting}`)", ""]
        lines += polishing_body(sub, level=3 if delays else 2, delta=setting)
    lines += aborted_section(doc)
    lines += _failures_section(doc)
    lines += _paper_section(forms)
    return "\n".join(lines) + "\n"


def table_cells(doc: dict, forms: Sequence[str], pid: bool, source: str) -> list[list[str]]:
    """The rows of a Table II/III (E_P, E_λ, λmax, t_break; one column per formulation)."""
    cells = {f: aggregate(doc, f, pid, source) for f in forms}
    return [
        ["E_P (mm)"]
        + [
            _pm(c["position_mae_mm_mean"], c["position_mae_mm_std"]) if c else "n/a"
            for c in cells.values()
        ],
        ["E_λ (N)"]
        + [_pm(c["force_mae_mean"], c["force_mae_std"]) if c else "n/a" for c in cells.values()],
        ["λmax (N)"] + [f"{c['max_force']:.2f}" if c else "n/a" for c in cells.values()],
        ["t_break (%)"]
        + [f"{c['contact_break_percent']:.2f}" if c else "n/a" for c in cells.values()],
    ]


def polishing_body(doc: dict, level: int = 2, delta: str | None = None) -> list[str]:
    """Tables II–IV of one δo (true force, then measured), headings at ``level``."""
    forms = doc["grid"]["formulations"]
    modes = doc["grid"]["pid_enabled"]
    h2, h3 = "#" * level, "#" * (level + 1)
    suffix = "" if delta is None else f", {delta_o_label(delta)}"
    lines: list[str] = []
    sources = (
        ("true", "TRUE normal force (the plant's, along the tilted table normal)"),
        ("measured", "MEASURED force (what the controllers see: noise, delay, world-z axis)"),
    )
    for source, description in sources:
        lines += [f"{h2} Metrics from the {description}", ""]
        for number, pid in (("II", False), ("III", True)):
            if pid not in modes:
                continue
            what = "with" if pid else "without"
            title = f"{h3} Table {number} — {what} low-level torque PID ({source} force{suffix})"
            lines += [title, ""]
            lines += _table(["", *(LABELS[f] for f in forms)], table_cells(doc, forms, pid, source))
            lines += ["", f"Runs: {_counts(doc, forms, pid)}.", ""]
            if source == "true":
                lines += paired_table(
                    doc, pid, f"{h3} Paired comparison, Table {number} ({source} force{suffix})"
                )
        if set(modes) >= {True, False}:
            lines += [f"{h3} Table IV — no-PID minus PID, per seed ({source} force{suffix})", ""]
            deltas = {f: delta_per_seed(doc, f, source) for f in forms}
            rows = [
                ["ΔE_λ (N)"] + [_pm(*_mean_std(d["force_mae"])) for d in deltas.values()],
                ["ΔE_τ (N m)"] + [_pm(*_mean_std(d["torque_mae"])) for d in deltas.values()],
            ]
            lines += _table(["", *(LABELS[f] for f in forms)], rows)
            pairs = ", ".join(f"{LABELS[f]} {len(d['seeds'])}" for f, d in deltas.items())
            lines += ["", f"Seed pairs: {pairs}.", ""]
    return lines


def _mean_std(values: Sequence[float]) -> tuple[float | None, float | None]:
    if not values:
        return None, None
    return float(np.mean(values)), float(np.std(values))


def _seed_range(seeds: Sequence[int]) -> str:
    seeds = list(seeds)
    if seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"seeds {seeds[0]}–{seeds[-1]}" if len(seeds) > 1 else f"seed {seeds[0]}"
    return "seeds " + ", ".join(map(str, seeds))


def _failures_section(doc: dict) -> list[str]:
    failures = doc["failures"]
    lines = ["## Failed runs (left out of every aggregate)", ""]
    if not failures:
        return lines + ["None.", ""]
    for f in failures:
        pid = "on" if f["pid_enabled"] else "off"
        delta = f", {delta_o_label(f['delta_o_setting'])}" if "delta_o_setting" in f else ""
        lines.append(
            f"- {LABELS[f['formulation']]}, PID {pid}{delta}, seed {f['seed']}: {f['error']}"
        )
    return lines + [""]


def _paper_section(forms: Sequence[str]) -> list[str]:
    lines = ["## The paper's values (Kleff et al., Tables II–IV), for comparison", ""]
    for number, title in (("II", "without PID"), ("III", "with PID")):
        rows = [
            [name] + [PAPER_TABLES[number][f][i] for f in forms]
            for i, name in enumerate(("E_P (mm)", "E_λ (N)", "λmax (N)", "t_break (%)"))
        ]
        lines += [f"Table {number} ({title}):", ""]
        lines += _table(["", *(LABELS[f] for f in forms)], rows) + [""]
    rows = [
        [name] + [PAPER_TABLES["IV"][f][i] for f in forms]
        for i, name in enumerate(("ΔE_λ (N)", "ΔE_τ (N m)"))
    ]
    lines += ["Table IV:", ""] + _table(["", *(LABELS[f] for f in forms)], rows) + [""]
    return lines


def force_square_report(doc: dict) -> str:
    """``tables.md`` of Experiment 1: normal-force MAE per controller (true and measured)."""
    forms = doc["grid"]["formulations"]
    lines = [
        f"# Experiment 1 (VII-B): force square signal — scenario `{doc['scenario']}`",
        "",
        f"{_seed_range(doc['grid']['seeds'])}; command `{doc['command_line']}`; wall time "
        f"{doc['wall_time_s']:.0f} s. MAE of the normal force over the square signal, mean ± std "
        "over the seeds.",
        "",
    ]
    for pid in doc["grid"]["pid_enabled"]:
        rows = []
        for source in ("true", "measured"):
            cells = [aggregate(doc, f, pid, source) for f in forms]
            rows.append(
                [f"E_λ (N), {source} force"]
                + [_pm(c["force_mae_mean"], c["force_mae_std"]) if c else "n/a" for c in cells]
            )
        rows.append(["paper (hardware)"] + [f"{PAPER_FORCE_SQUARE_MAE[f]:.2f}" for f in forms])
        lines += [f"## {'With' if pid else 'Without'} torque PID", ""]
        lines += _table(["", *(LABELS[f] for f in forms)], rows)
        lines += ["", f"Runs: {_counts(doc, forms, pid)}.", ""]
    lines += aborted_section(doc)
    lines += _failures_section(doc)
    return "\n".join(lines) + "\n"


_CELL = re.compile(r"^(-?\d+(?:\.\d+)?)(?: ± (\d+(?:\.\d+)?))?$")


def parse_markdown_table(text: str, title_prefix: str) -> dict[str, dict[str, str]]:
    """Read back the table under the heading starting with ``title_prefix``:
    ``{row name: {column title: cell}}`` (for tests and tools)."""
    lines = text.splitlines()
    start = next((i for i, s in enumerate(lines) if s.startswith(title_prefix)), None)
    if start is None:
        raise ConfigError(f"no table titled {title_prefix!r}")
    i = start + 1
    while i < len(lines) and not lines[i].startswith("|"):
        i += 1
    header = [c.strip() for c in lines[i].strip("|").split("|")]
    out: dict[str, dict[str, str]] = {}
    for row in lines[i + 2 :]:
        if not row.startswith("|"):
            break
        cells = [c.strip() for c in row.strip("|").split("|")]
        out[cells[0]] = dict(zip(header[1:], cells[1:], strict=True))
    return out


def parse_cell(cell: str) -> tuple[float, float | None]:
    """``"5.75 ± 0.06"`` → (5.75, 0.06); ``"59.36"`` → (59.36, None)."""
    match = _CELL.match(cell.strip())
    if not match:
        raise ConfigError(f"not a table number: {cell!r}")
    return float(match.group(1)), None if match.group(2) is None else float(match.group(2))


# --------------------------------------------------------------------------- figures
def _figure_outcomes(outcomes: Sequence[RunOutcome], pid: bool) -> list[RunOutcome]:
    return [o for o in outcomes if o.plot_log is not None and o.spec.pid_enabled == pid]


def _shade_window(log: dict[str, np.ndarray], axes: Sequence[Axes]) -> None:
    """Grey band over the metrics window (circle phase or square signal)."""
    start, end = log["window"]
    if np.isfinite(start):
        for i, ax in enumerate(axes):
            ax.axvspan(start, end, color="0.9", zorder=0, label=None if i else "metrics window")


def plot_polishing(
    outcomes: Sequence[RunOutcome],
    pid: bool,
    path: Path,
    title: str,
    spans: Sequence[tuple[float, float]] = (),
    span_label: str = "",
) -> bool:
    """Figs. 6–9 style: (a) true normal force vs reference, (b) tangential position error, for
    the plotted seed of every controller; ``spans`` ([start, end] in s, e.g. the pushes of
    Experiment 3.3) are shaded and labelled ``span_label``. Returns False when no run of that
    mode was plotted."""
    chosen = _figure_outcomes(outcomes, pid)
    if not chosen:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_f, ax_p) = plt.subplots(2, 1, figsize=(7.5, 5.5), sharex=True, dpi=100)
    ref_drawn = False
    for o in chosen:
        log, form = o.plot_log, o.spec.formulation
        assert log is not None  # _figure_outcomes keeps the plotted runs only
        if not ref_drawn:
            ax_f.plot(log["t"], log["force_reference"], "k--", lw=1.0, label="reference")
            ref_drawn = True
        ax_f.plot(log["t"], log["force_true"], color=COLORS[form], lw=0.8, label=LABELS[form])
        ax_p.plot(
            log["t"], log["tangential_error_mm"], color=COLORS[form], lw=0.8, label=LABELS[form]
        )
    first = chosen[0].plot_log
    assert first is not None
    _shade_window(first, (ax_f, ax_p))
    for k, (start, end) in enumerate(spans):
        for i, ax in enumerate((ax_f, ax_p)):
            label = span_label if i == 0 and k == 0 and span_label else None
            ax.axvspan(start, end, color="tab:orange", alpha=0.25, zorder=0, label=label)
    ax_f.set_ylabel("normal force λ (N)")
    ax_f.set_title(title, fontsize=9)
    ax_f.legend(loc="upper left", fontsize=8, ncol=4)
    ax_f.grid(alpha=0.3)
    ax_p.set_ylabel("tangential position error (mm)")
    ax_p.set_xlabel("time (s)")
    ax_p.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


def plot_force_square(outcomes: Sequence[RunOutcome], path: Path, title: str) -> bool:
    """Fig. 4 style: true normal force of each controller vs the square reference."""
    chosen = [o for o in outcomes if o.plot_log is not None]
    if not chosen:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 3.5), dpi=100)
    log = chosen[0].plot_log
    assert log is not None  # chosen holds the plotted runs only
    ax.plot(log["t"], log["force_reference"], "k--", lw=1.0, label="reference")
    for o in chosen:
        form = o.spec.formulation
        pid = "" if o.spec.pid_enabled else " (no PID)"
        assert o.plot_log is not None
        ax.plot(
            o.plot_log["t"],
            o.plot_log["force_true"],
            color=COLORS[form],
            lw=0.8,
            label=LABELS[form] + pid,
        )
    _shade_window(log, (ax,))
    ax.set_xlabel("time (s)")
    ax.set_ylabel("normal force λ (N)")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper left", fontsize=8, ncol=4)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return True


# --------------------------------------------------------------------------- whole studies
@dataclass
class StudyReport:
    """What a study produced: the results document, its tables and the files written."""

    out_dir: Path
    document: dict
    tables: str
    files: list[Path]
    outcomes: list[RunOutcome] = field(repr=False)


def run_study(
    kind: str,
    specs: Sequence[RunSpec],
    out_dir: str | os.PathLike,
    *,
    workers: int | None = None,
    force: bool = False,
    command_line: str = "",
    progress: bool = True,
    scheduler: str | None = None,
    cache: bool = True,
    cache_dir: str | os.PathLike | None = None,
    fresh: bool = False,
) -> StudyReport:
    """Run a grid of specs and write ``results.json``, ``tables.md`` and the figures.

    Args:
        kind: "polishing" (Tables II–IV, Figs. 6–9) or "force_square" (Experiment 1, Fig. 4).
        out_dir: created here; an existing one is refused unless ``force``, or unless it holds
            an interrupted study (``cache/``, no ``results.json``): that one is resumed.
        workers, scheduler: see :func:`execute_specs` (LocalCluster, in-process, or a running
            Dask scheduler).
        cache: keep each finished run in ``cache_dir`` (default ``out_dir/cache``) and read the
            runs already there instead of running them; ``fresh`` runs them all again.
    """
    if kind not in ("polishing", "force_square"):
        raise ConfigError(f"unknown study kind {kind!r}")
    validate_specs(specs)
    out = prepare_output_dir(out_dir, force, resume=cache and not fresh)
    run_cache = study_cache(out, cache, cache_dir)
    start = time.perf_counter()
    measured = {}
    if run_cache is not None and not fresh:
        measured = _load_measured_delays(run_cache, specs)
    specs, delays = resolve_command_delays(specs, measured=measured)
    if run_cache is not None:
        _save_measured_delays(run_cache, specs, delays, measured)
    batch = execute_specs(
        specs, workers, progress, scheduler=scheduler, cache=run_cache, fresh=fresh
    )
    outcomes = batch.outcomes
    wall = time.perf_counter() - start
    doc = study_document(
        kind,
        specs,
        outcomes,
        command_line=command_line,
        workers=batch.workers,
        wall_time=wall,
        command_delays=delays,
        execution=batch.execution(run_cache),
    )
    files = [out / "results.json", out / "tables.md"]
    write_json(files[0], doc)
    seed = next((o.spec.seed for o in outcomes if o.plot_log is not None), None)
    if kind == "polishing":
        tables = polishing_tables(doc)
        for pid, name in ((True, "fig_polishing_pid.png"), (False, "fig_polishing_nopid.png")):
            title = (
                f"{doc['scenario']}, seed {seed}, {'with' if pid else 'no'} torque PID — "
                "top: true normal force, bottom: tangential position error"
            )
            if plot_polishing(outcomes, pid, out / name, title):
                files.append(out / name)
    else:
        tables = force_square_report(doc)
        title = f"Experiment 1 — force square, {doc['scenario']}, seed {seed} (true normal force)"
        if plot_force_square(outcomes, out / "fig_force_square.png", title):
            files.append(out / "fig_force_square.png")
    files[1].write_text(tables, encoding="utf-8")
    return StudyReport(out, doc, tables, files, list(outcomes))


def default_out_dir(kind: str) -> Path:
    """``benchmarks/results/<kind>_study/<UTC time>`` under the current directory."""
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return Path("benchmarks") / "results" / f"{kind}_study" / stamp


__all__ = [
    "RunSpec",
    "RunOutcome",
    "RunBatch",
    "RunCache",
    "CACHE_SCHEMA",
    "run_key",
    "execute_specs",
    "write_atomic",
    "check_output_dir",
    "StudyReport",
    "execute_run",
    "run_specs",
    "resolve_command_delays",
    "grid_specs",
    "run_study",
    "prepare_output_dir",
    "study_document",
    "polishing_tables",
    "force_square_report",
    "aggregate",
    "delta_per_seed",
    "parse_markdown_table",
    "parse_cell",
    "plot_log",
    "default_out_dir",
]
