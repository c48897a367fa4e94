"""``ffmpc tune``: search one controller's cost weights with Optuna, the same way for all three.

The objective of a set of weights is the mean over the training scenarios and seeds of one
polishing run each (:func:`studies.polishing.run_polishing`, torque PID as in each scenario,
metrics from the true normal force over the circle phase; ``--scenario`` repeated searches one
set of weights for several scenarios at once, e.g. the slow and fast circles and the push),
each run a job of :func:`studies.execute.execute_jobs` (on the search's Dask cluster,
``--workers``/``--scheduler``, or in this process; cached with ``--cache-dir``):

    J = E_λ + W·E_P + P_break·t_break + P_force·max(0, λmax − λ_limit) + P_vel·max(0, r_v − 1)

with E_λ in N, E_P in mm, t_break in % and λmax in N, r_v the run's largest joint speed over its
limit (max over joints and the whole run of |q̇_j|/q̇_max,j) (:class:`Objective`; defaults:
W = 0.5 N/mm, P_break = 10 N per % of the circle out of contact, P_force = 1 per N above
λ_limit = 150 N, P_vel = 50 N per unit of r_v above 1: a search without it found weights that
track better by spinning the wrist at up to 3.4× its speed limit). A run that diverges, or that
the robot's own reflexes aborted (``plant.reflex``, on by default: a real robot would have
stopped it mid-task; ``ffmpc_core.reflex``), costs ``FAILED_RUN_COST``. A stored search
remembers its objective and is not resumed with another.

The search (seeded TPE sampler) keeps its trials in an Optuna RDB storage (an SQLite file by
default), so a search that is stopped resumes where it stood: the same ``--storage`` and
``--study-name`` load the trials already run, and ``--trials`` more are added. The first trial of
a new search is the (first) scenario's own weights, so the best trial is never worse than them;
``--start-from`` files (``--set-file`` mappings such as an earlier search's
``tuned_weights.yaml``) add their weights as the next trials. Trials
run ``--jobs`` at a time (Optuna threads). The best weights are written into a copy of the
scenario file (``--out``), under ``mpc.weights.<formulation>``.

The search space (:data:`SEARCH_SPACE`) is the same for the three formulations except the terms
a formulation does not have: the low-pass input weight c_w (eq 28) and the force-rate weight c_λ
(eq 29) belong to one formulation each.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import ANY_NAMESPACE, Scenario, load_scenario, resolve_scenario_path
from studies.execute import RunCache, dask_cluster

if TYPE_CHECKING:
    import optuna
    from distributed import Client
    from optuna.trial import FrozenTrial

#: Cost of a trial whose run failed (an FfmpcError), in the objective's units.
FAILED_RUN_COST = 1e4

#: name: (low, high, formulations) — log-uniform bounds of each searched weight
#: (``mpc.weights.<formulation>.<name>``; ``force_phase`` is c6, ``ee_position_phase`` c4).
#: The first searches (48 trials each) had c4 ≤ 1e4, ee_rotation ≤ 100, joint_velocity ≥ 1e-3
#: and ee_velocity ≥ 1e-2; their best trials came within a factor 2 of those bounds
#: (benchmarks/results/tune/train1000-1002), so the bounds were widened 10× for all three.
SEARCH_SPACE: dict[str, tuple[float, float, tuple[str, ...]]] = {
    "force_phase": (0.1, 10.0, ("classical", "torque_feedback", "force_feedback")),
    "ee_position_phase": (1e2, 1e5, ("classical", "torque_feedback", "force_feedback")),
    "joint_velocity": (1e-4, 1.0, ("classical", "torque_feedback", "force_feedback")),
    "ee_velocity": (1e-3, 10.0, ("classical", "torque_feedback", "force_feedback")),
    "ee_rotation": (0.1, 1e3, ("classical", "torque_feedback", "force_feedback")),
    "lowpass_input": (1e-6, 1e-2, ("torque_feedback",)),
    "force_rate": (1e-8, 1e-4, ("force_feedback",)),
}

#: Defaults of the weights the scenario files leave out (CostWeights' and the task's defaults).
_UNSET_DEFAULTS = {
    "force_phase": 1e-2,
    "ee_position_phase": 1e3,
    "joint_velocity": 1e-2,
    "ee_velocity": 1.0,
    "ee_rotation": 0.0,
    "lowpass_input": 1e-4,
    "force_rate": 1e-6,
}


@dataclass(frozen=True)
class Objective:
    """J = E_λ + position_weight·E_P + break_penalty·t_break + force_penalty·(λmax − force_limit)₊
    + velocity_penalty·(r_v − 1)₊ (N, N/mm, N/%, N/N, N, N per unit of r_v = max |q̇|/limit)."""

    position_weight: float = 0.5
    break_penalty: float = 10.0
    force_limit: float = 150.0
    force_penalty: float = 1.0
    velocity_penalty: float = 50.0

    def __post_init__(self) -> None:
        for name in (f.name for f in fields(self)):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ConfigError(f"objective {name} must be finite and >= 0, got {value}")

    def of(
        self,
        force_mae: float,
        position_mae_mm: float,
        break_percent: float,
        max_force: float,
        max_velocity_ratio: float = 0.0,
    ) -> float:
        """J of one run's metrics (``max_velocity_ratio``: max over joints and time of
        |q̇|/limit)."""
        return (
            force_mae
            + self.position_weight * position_mae_mm
            + self.break_penalty * break_percent
            + self.force_penalty * max(0.0, max_force - self.force_limit)
            + self.velocity_penalty * max(0.0, max_velocity_ratio - 1.0)
        )


@dataclass
class TuneResult:
    """The search after this call: its best weights and value, and the trial values in order."""

    formulation: str
    best_weights: dict[str, float]
    best_value: float
    values: list[float]  # every complete trial's J, in trial order (resumed ones first)
    trials_run: int  # trials added by this call
    out: Path | None


def searched_names(formulation: str) -> list[str]:
    """The weights searched for ``formulation`` (:data:`SEARCH_SPACE`)."""
    return [n for n, (_, _, forms) in SEARCH_SPACE.items() if formulation in forms]


def current_weights(scenario: Scenario, formulation: str) -> dict[str, float]:
    """The scenario's values of the searched weights (defaults where the file has none)."""
    values = scenario.mpc.weights.get(formulation, {})
    out = {}
    for name in searched_names(formulation):
        value = float(values.get(name, _UNSET_DEFAULTS[name]))
        low, high, _ = SEARCH_SPACE[name]
        out[name] = min(max(value, low), high)  # a 0 (term off) starts at the lower bound
    return out


def evaluate(
    scenario_names: str | Sequence[str],
    formulation: str,
    weights: dict[str, float],
    seeds: list[int],
    objective: Objective,
    duration: float | None = None,
    overrides: dict[str, Any] | None = None,
    *,
    pid_enabled: dict[str, bool] | None = None,
    client: Client | None = None,
    cache: RunCache | None = None,
) -> float:
    """Mean J over ``scenario_names`` × ``seeds`` of the runs with ``formulation`` and
    ``weights``: one polishing job per scenario and seed (:class:`studies.study.RunSpec`, PID as
    in its scenario) through :func:`studies.execute.execute_jobs`, on the Dask ``client``'s
    workers (None: in this process), reading and writing the run ``cache``. ``pid_enabled``:
    each scenario's (loaded when not given; a search passes it once)."""
    from studies.study import RunSpec, execute_specs

    names = _scenario_list(scenario_names)
    if pid_enabled is None:
        pid_enabled = {n: load_scenario(n, overrides or {}).pid.enabled for n in names}
    prefix = f"mpc.weights.{formulation}."
    settings = dict(overrides or {}) | {prefix + k: float(v) for k, v in weights.items()}
    specs = [
        RunSpec(
            name,
            formulation,
            pid_enabled[name],
            seed,
            duration,
            overrides=tuple(settings.items()),
        )
        for name in names
        for seed in seeds
    ]
    batch = execute_specs(specs, 1 if client is None else None, False, cache=cache, client=client)
    total = 0.0
    for outcome in batch.outcomes:
        if outcome.summary is None or outcome.summary.get("aborted", False):
            # the run diverged (its error is in the outcome) or the robot stopped itself
            total += FAILED_RUN_COST
            continue
        m = outcome.summary["metrics_true"]
        value = objective.of(
            m["force_mae"],
            m["position_mae_mm"],
            m["contact_break_percent"],
            m["max_force"],
            max(outcome.summary["max_velocity_ratio"], default=0.0),
        )
        total += value if math.isfinite(value) else FAILED_RUN_COST
    return total / len(specs)


def _scenario_list(scenario_names: str | Sequence[str]) -> list[str]:
    """The training scenarios as a list (one name or several; ConfigError for none or a
    repeated one)."""
    names = [scenario_names] if isinstance(scenario_names, str) else list(scenario_names)
    if not names:
        raise ConfigError("tune needs at least one training scenario")
    if len(set(names)) != len(names):
        raise ConfigError(f"a training scenario is given twice: {names}")
    return names


def start_weights(
    doc: dict[str, Any], formulation: str, base: dict[str, float]
) -> dict[str, float]:
    """A starting trial from a ``--set-file`` mapping (``mpc.weights.<formulation>.<name>:
    value``): its weights of ``formulation`` over ``base`` (the scenario's), each clipped to its
    search bounds. ConfigError when the mapping holds none of them."""
    prefix = f"mpc.weights.{formulation}."
    found = {k[len(prefix) :]: v for k, v in doc.items() if k.startswith(prefix)}
    names = searched_names(formulation)
    if not any(n in found for n in names):
        raise ConfigError(f"no searched {prefix}* weight in the starting point ({sorted(doc)})")
    out = dict(base)
    for name in names:
        if name in found:
            raw = found[name]
            number = isinstance(raw, int | float) and not isinstance(raw, bool)
            value = float(raw) if number else math.nan
            if not math.isfinite(value):
                raise ConfigError(f"{prefix}{name} = {raw!r}: not a finite number")
            low, high, _ = SEARCH_SPACE[name]
            out[name] = min(max(value, low), high)
    return out


def tune(
    scenario_name: str | Sequence[str],
    formulation: str,
    seeds: list[int],
    trials: int,
    storage: str,
    study_name: str | None = None,
    jobs: int = 1,
    sampler_seed: int = 0,
    objective: Objective | None = None,
    duration: float | None = None,
    out: str | Path | None = None,
    overrides: dict[str, Any] | None = None,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    cache_dir: str | Path | None = None,
    start_from: Sequence[dict[str, Any]] = (),
) -> TuneResult:
    """Run (or resume) the search and write the best weights to ``out`` (if given).

    Args:
        scenario_name: a shipped scenario name or a scenario file, or several (the objective
            is the mean over every scenario and seed; the first gives the starting weights, the
            default search name and the ``out`` file's base).
        formulation: the controller whose weights are searched.
        seeds: training seeds (keep them disjoint from the evaluation seeds).
        trials: trials to add in this call (≥ 1).
        storage: Optuna RDB URL (``sqlite:///tune.db``) or a path (made an SQLite URL).
        study_name: the search's name in the storage (default ``<scenario>-<formulation>``).
        jobs: trials run at a time.
        sampler_seed: seed of the TPE sampler (a resumed search adds the number of trials
            already stored, so that it does not draw the same points again).
        duration: simulated time per run, s (default: the task's).
        out: scenario file to write with the best weights (must not exist).
        overrides: dotted-name scenario overrides for every run.
        workers, scheduler: where each trial's runs go (:func:`studies.execute.dask_cluster`,
            one cluster for the whole search: a LocalCluster of ``workers`` processes, the
            workers of a running ``scheduler``, or this process with ``workers=1``).
        cache_dir: a run cache shared by the trials (and with studies): a run already done,
            the same scenario, weights, seed and duration, is read back, not run again.
        start_from: ``--set-file`` mappings whose weights of ``formulation``
            (:func:`start_weights`) a new search runs right after the scenario's own.
    """
    import optuna

    if not seeds:
        raise ConfigError("tune needs at least one training seed")
    if trials < 1 or jobs < 1:
        raise ConfigError("--trials and --jobs must be >= 1")
    out_path = Path(out) if out is not None else None
    if out_path is not None and out_path.exists():
        raise ConfigError(f"{out_path} exists: choose another --out")
    names_run = _scenario_list(scenario_name)
    scenarios = {n: load_scenario(n, overrides or {}) for n in names_run}
    scenario = scenarios[names_run[0]]
    if formulation not in SEARCH_SPACE["force_phase"][2]:
        raise ConfigError(f"unknown formulation {formulation!r}")
    objective = objective or Objective()
    own = current_weights(scenario, formulation)
    starts = [start_weights(doc, formulation, own) for doc in start_from]  # checked before any run
    url = storage if "://" in storage else f"sqlite:///{Path(storage).resolve()}"
    name = study_name or "+".join(s.name for s in scenarios.values()) + f"-{formulation}"
    optuna.logging.set_verbosity(optuna.logging.WARNING)

    def open_study(seed: int) -> optuna.Study:
        return optuna.create_study(
            study_name=name,
            storage=url,
            sampler=optuna.samplers.TPESampler(seed=seed),
            direction="minimize",
            load_if_exists=True,
        )

    study = open_study(sampler_seed)
    stated = {**asdict(objective), "training_seeds": list(seeds), "scenarios": names_run}
    stored = study.user_attrs.get("objective")
    if stored is not None and "scenarios" not in stored and len(names_run) == 1:
        stored = {**stored, "scenarios": names_run}  # a search stored before several scenarios
    if stored is None and not study.trials:
        study.set_user_attr("objective", stated)
    elif stored is not None and stored != stated:
        raise ConfigError(
            f"search {name!r} in {storage} was run with objective {stored}; this call states "
            f"{stated}: give another --study-name (trials of two objectives do not mix)"
        )
    if study.trials:
        # A resumed search: a sampler seeded as before would draw its first points again (TPE's
        # random start-up repeats them); seeded with the number of trials stored, it goes on.
        study = open_study(sampler_seed + len(study.trials))
    if not study.trials:  # a new search starts from the scenario's own weights
        study.enqueue_trial(own)
        for point in starts:
            study.enqueue_trial(point, skip_if_exists=True)
    names = searched_names(formulation)

    cache = None if cache_dir is None else RunCache(cache_dir)
    with dask_cluster(workers, scheduler) as client:

        def run_trial(trial: optuna.Trial) -> float:
            weights = {
                n: trial.suggest_float(n, SEARCH_SPACE[n][0], SEARCH_SPACE[n][1], log=True)
                for n in names
            }
            return evaluate(
                names_run,
                formulation,
                weights,
                seeds,
                objective,
                duration,
                overrides,
                pid_enabled={n: s.pid.enabled for n, s in scenarios.items()},
                client=client,
                cache=cache,
            )

        study.optimize(run_trial, n_trials=trials, n_jobs=jobs)
    complete = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    best = study.best_trial
    best_value = float(best.value) if best.value is not None else math.inf
    best_weights = {k: float(v) for k, v in best.params.items()}
    if out_path is not None:
        write_tuned_scenario(names_run[0], formulation, best_weights, out_path, best_value, seeds)
    return TuneResult(
        formulation=formulation,
        best_weights=best_weights,
        best_value=best_value,
        values=[float(t.value) for t in complete if t.value is not None],
        trials_run=trials,
        out=out_path,
    )


def first_completed(study: optuna.Study, budget: int) -> tuple[list[FrozenTrial], FrozenTrial]:
    """The first ``budget`` completed trials of a search (by trial number) and the best of them
    (lowest J): searches compared alike get the same budget however far each has run."""
    import optuna

    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    done = sorted(done, key=lambda t: t.number)[:budget]
    if not done:
        raise ConfigError(f"search {study.study_name!r} has no completed trial")
    return done, min(done, key=lambda t: math.inf if t.value is None else t.value)


def best_trial_report(
    study: optuna.Study, source: str, formulation: str, budget: int, trial0: str
) -> list[str]:
    """The lines of ``best_<formulation>.txt``: the best of the first ``budget`` completed
    trials (:func:`first_completed`), its weights as dotted names, J of trial 0 (``trial0``
    says what it tried) and of every trial; ``source`` names the storage."""
    done, best = first_completed(study, budget)
    return [
        f"search {study.study_name} ({source}): the first {len(done)} completed trials",
        f"  trial 0 ({trial0}): J = {done[0].value:.4f}",
        f"  best: trial {best.number}, J = {best.value:.4f}",
        *(f"    mpc.weights.{formulation}.{k} = {v:.6g}" for k, v in best.params.items()),
        f"  J per trial: {', '.join(f'{t.value:.3f}' for t in done)}",
    ]


def write_tuned_scenario(
    scenario_name: str,
    formulation: str,
    weights: dict[str, float],
    out: Path,
    value: float,
    seeds: list[int],
) -> None:
    """A copy of the scenario file with ``mpc.weights.<formulation>`` set to ``weights``; the
    copy loads (checked) before it is written."""
    source = resolve_scenario_path(scenario_name)
    doc = yaml.safe_load(source.read_text(encoding="utf-8"))
    # the file's own key of the mpc section: ``/**/mpc`` (the shipped files) or ``mpc``
    key = next((k for k in (ANY_NAMESPACE + "mpc", "mpc") if k in doc), ANY_NAMESPACE + "mpc")
    params = doc.setdefault(key, {}).setdefault("ros__parameters", {})
    table = params.setdefault("weights", {}).setdefault(formulation, {})
    table.update({k: float(np.float64(v)) for k, v in weights.items()})
    header = (
        f"# {source.name} with the {formulation} weights tuned by `ffmpc tune` (Optuna TPE) on\n"
        f"# training seeds {seeds}: objective {value:.4g} (E_lambda + weight x E_P + penalties).\n"
    )
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(header + yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
    try:
        load_scenario(tmp)  # the schema checks every value
    except ConfigError:
        tmp.unlink()
        raise
    tmp.replace(out)
