"""The studies' commands of ``ffmpc``: ``ffmpc study polishing|force-square|impact|explore``,
``ffmpc tune`` and ``ffmpc bench impact``.

They are registered as entry points (pyproject.toml ``[project.entry-points]``, groups
``ffmpc.command`` and ``ffmpc.bench``) and found by ``ffmpc_ros.cli`` through
:mod:`ffmpc_ros.cli_extensions`, as ros2cli finds its command extensions: the command line
(``ffmpc_ros``, one layer down) never imports :mod:`studies`. Building the parsers imports
nothing heavy; each command imports its study when it runs.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ffmpc_core.errors import ConfigError
from ffmpc_ros.cli_args import (
    STUDY_FORMULATIONS,
    add_plant_argument,
    existing_file,
    new_path,
    nonnegative_float,
    nonnegative_int,
    output_file,
    positive_float,
    positive_int,
    seed_int,
    with_plant_engine,
)
from ffmpc_ros.cli_args import parse_overrides as _parse_overrides
from ffmpc_ros.cli_extensions import CommandExtension

__all__ = ["BenchImpactVerb", "StudyCommand", "TuneCommand"]

#: The ``add_subparsers()`` action of ``ffmpc study``.
SubParsers = argparse._SubParsersAction  # argparse has no public name for it


# -- ffmpc study polishing | force-square ------------------------------------------------------
def _plot_seed(args: argparse.Namespace) -> int:
    """The seed whose runs are plotted: ``--plot-seed`` (one of the study's seeds, else a
    ConfigError before any run) or the first seed."""
    if args.plot_seed is None:
        return int(args.first_seed)
    if not args.first_seed <= args.plot_seed < args.first_seed + args.seeds:
        raise ConfigError(
            f"--plot-seed {args.plot_seed}: expected one of the seeds "
            f"{args.first_seed}..{args.first_seed + args.seeds - 1}"
        )
    return int(args.plot_seed)


def _cmd_study(args: argparse.Namespace) -> int:
    import shlex

    from ffmpc_core.scenario import load_scenario

    kind = "polishing" if args.study == "polishing" else "force_square"
    overrides = _polishing_overrides(args)
    load_scenario(args.scenario or kind, overrides)  # refuse a bad scenario before any import
    _check_execution_arguments(args)  # before any run (studies.study does not load PyBullet)
    use_cache = not args.no_cache
    plot_seed = _plot_seed(args)
    from studies.study import default_out_dir, grid_specs, run_study

    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    pid_modes = {"on": [True], "off": [False], "both": [True, False]}[args.pid]
    specs = grid_specs(
        args.scenario or kind,
        args.formulations,
        pid_modes,
        seeds,
        duration=args.duration,
        overrides=overrides,
        plot_seed=plot_seed,
        command_delays=getattr(args, "command_delays", None),
    )
    out = args.out or default_out_dir(kind)
    report = run_study(
        kind,
        specs,
        out,
        workers=args.workers,
        force=args.force,
        command_line=shlex.join(["ffmpc", *args.argv]),
        progress=not args.no_progress,
        scheduler=args.scheduler,
        cache=use_cache,
        cache_dir=args.cache_dir,
        fresh=args.fresh,
    )
    print(report.tables)
    if kind == "force_square":
        from studies.study import LABELS, aggregate

        for pid in pid_modes:
            maes = []
            for form in args.formulations:
                cell = aggregate(report.document, form, pid, "true")
                value = "failed" if cell is None else f"{cell['force_mae_mean']:.2f} N"
                maes.append(f"{LABELS[form]} {value}")
            print(f"normal-force MAE ({'PID' if pid else 'no PID'}): " + ", ".join(maes))
    failures = report.document["failures"]
    execution = report.document["execution"]
    print(
        f"{len(report.document['runs'])} runs, {len(failures)} failed "
        f"({execution['cached']} from the cache, {execution['executed']} run: "
        f"{execution['cluster']}, {report.document['workers']} worker(s)), wall time "
        f"{report.document['wall_time_s']:.1f} s"
    )
    for f in failures:
        pid_state = "on" if f["pid_enabled"] else "off"
        print(f"  FAILED {f['formulation']} pid={pid_state} seed={f['seed']}: {f['error']}")
    print("files:")
    for path in report.files:
        print(f"  {path}")
    return 0 if report.document["runs"] else 1


def _add_set_argument(p: argparse.ArgumentParser, what: str, example: str) -> None:
    """``--set NAME=VALUE`` (repeatable), ``--set-file FILE``, ``--plant`` and
    ``--no-progress`` of the polishing studies."""
    add_plant_argument(p)
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help=f"scenario override, {what} (repeatable), e.g. {example}",
    )
    p.add_argument(
        "--set-file",
        action="append",
        type=existing_file,
        metavar="FILE",
        help="overrides from a YAML mapping NAME: VALUE (repeatable; --set wins), e.g. the "
        "tuned weights benchmarks/results/tune/train1000-1002/speed_penalty/tuned_weights.yaml",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _polishing_overrides(args: argparse.Namespace) -> dict:
    """The overrides of ``--set-file`` files (in order), ``--set``, each checked by the scenario
    schema (ConfigError naming the file or the pair), then ``--plant``."""
    import json

    items: list[str] = []
    for path in args.set_file or []:
        doc = _read_set_file(path)
        items += [f"{name}={json.dumps(value)}" for name, value in doc.items()]
    return with_plant_engine(
        _parse_overrides(items + list(args.set or [])), getattr(args, "plant", None)
    )


def _read_set_file(path: str | Path) -> dict:
    """A ``--set-file`` (or ``--start-from``) YAML mapping NAME: VALUE, read as ROS 2 reads values
    (1e4 is a number); ConfigError naming the file when it is not one."""
    import yaml

    from ffmpc_core.values import load_yaml

    try:
        doc = load_yaml(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError, ConfigError) as exc:
        raise ConfigError(f"{path}: not a readable YAML file ({exc})") from None
    if not isinstance(doc, dict) or not all(isinstance(k, str) for k in doc):
        raise ConfigError(f"{path}: expected a mapping NAME: VALUE")
    return doc


def _add_execution_arguments(p: argparse.ArgumentParser, cache_dir: bool = False) -> None:
    """Where a study's runs go (studies.execute): ``--workers``, ``--scheduler``, ``--out`` and
    its resume, ``--force``, ``--fresh``, ``--no-cache`` (and ``--cache-dir``); the same for
    every study."""
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="worker processes of a local Dask cluster (default: all CPUs; 1: in this process)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run on a running Dask cluster, e.g. tcp://127.0.0.1:8786 (its workers need ffmpc)",
    )
    p.add_argument(
        "--out",
        help="output directory, must not exist (default benchmarks/results/...); an interrupted "
        "study's directory (cache/, no results.json) is resumed",
    )
    p.add_argument("--force", action="store_true", help="write into an existing --out")
    p.add_argument(
        "--fresh", action="store_true", help="run every run again (results still go to the cache)"
    )
    p.add_argument("--no-cache", action="store_true", help="neither read nor write the run cache")
    if cache_dir:
        p.add_argument(
            "--cache-dir",
            metavar="DIR",
            help="run cache directory, one JSON file per finished run (default OUT/cache)",
        )


def _check_execution_arguments(args: argparse.Namespace) -> None:
    """Refuse conflicting or unusable execution flags before any run (and before PyBullet)."""
    from studies.execute import check_output_dir, worker_count

    worker_count(args.workers, args.scheduler)
    if args.out:
        check_output_dir(args.out, args.force, resume=not args.no_cache and not args.fresh)


def command_delay_value(text: str) -> float | str:
    """A δo of ``--command-delays``: seconds >= 0 or "measured" (argparse type)."""
    if text.strip() == "measured":
        return "measured"
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected seconds >= 0 or 'measured', got {text!r}"
        ) from None
    if not (value >= 0.0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"expected seconds >= 0 or 'measured', got {text!r}")
    return value


def _add_command_delays_argument(p: argparse.ArgumentParser, default: list | None) -> None:
    p.add_argument(
        "--command-delays",
        nargs="+",
        type=command_delay_value,
        default=default,
        metavar="DELTA_O",
        help="OCP delays δo to run, s or 'measured': one grid per value (each the override "
        "mpc.command_delay=VALUE), tables per δo"
        + (f" (default {' '.join(map(str, default))})" if default else "")
        + "; excludes --set mpc.command_delay",
    )


def _cmd_study_paper(args: argparse.Namespace) -> int:
    import shlex

    from ffmpc_core.scenario import load_scenario

    overrides = _polishing_overrides(args)
    if "mpc.command_delay" in overrides:
        raise ConfigError("--set mpc.command_delay: give the δo values with --command-delays")
    load_scenario("polishing", overrides)  # refuse a bad override before any import
    _check_execution_arguments(args)
    plot_seed = _plot_seed(args)
    from studies.paper import run_paper
    from studies.study import default_out_dir

    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    report = run_paper(
        args.out or default_out_dir("paper"),
        seeds,
        formulations=args.formulations,
        command_delays=args.command_delays,
        duration=args.duration,
        overrides=overrides,
        workers=args.workers,
        scheduler=args.scheduler,
        force=args.force,
        cache=not args.no_cache,
        cache_dir=args.cache_dir,
        fresh=args.fresh,
        command_line=shlex.join(["ffmpc", *args.argv]),
        progress=not args.no_progress,
        plot_seed=plot_seed,
    )
    print(report.text)
    doc = report.document
    sections = doc["sections"].values()
    runs = sum(len(s["study"]["runs"]) for s in sections)
    failed = sum(len(s["study"]["failures"]) for s in sections)
    execution = doc["execution"]
    print(
        f"{runs + failed} runs in {len(doc['sections'])} sections, {failed} failed "
        f"({execution['cached']} from the cache, {execution['executed']} run: "
        f"{execution['cluster']}, {doc['workers']} worker(s)), wall time "
        f"{doc['wall_time_s']:.1f} s"
    )
    print("files:")
    for path in report.files:
        print(f"  {path}")
    return 0 if runs else 1


def _add_paper_study_parser(study_sub: SubParsers) -> None:
    """``ffmpc study paper``: every table of the force-feedback paper, one report."""
    from ffmpc_core.config import FORMULATIONS

    p = study_sub.add_parser(
        "paper",
        help="every table of the force-feedback paper (II-VII, Experiments 1-3), one report",
        description="Runs, as one batch on one Dask cluster: the simulation study (Tables "
        "II-IV, PID off and on, one grid per --command-delays value, with the paired "
        "force-feedback comparison and Wilcoxon p), Experiment 1 (force_square), Experiment 2 "
        "(Table V, perfect_table), 3.1 (Table VI, tilt), 3.2 (Table VII, polishing_fast) and 3.3 "
        "(push: errors during and after the push), the experiments with the torque PID. Writes "
        "paper.md (each table beside the paper's printed values) and results.json into --out; "
        "every run is cached, so the same command resumes.",
    )
    p.add_argument("--seeds", type=positive_int, default=20, help="number of seeds (default 20)")
    p.add_argument("--first-seed", type=seed_int, default=0, help="first seed (default 0)")
    p.add_argument(
        "--duration",
        type=positive_float,
        help="simulated time per run, s (default: each scenario's task; shorter = smoke run)",
    )
    p.add_argument(
        "--formulations",
        nargs="+",
        choices=STUDY_FORMULATIONS,
        default=list(FORMULATIONS),
        help="controllers (default: all three)",
    )
    p.add_argument(
        "--plot-seed",
        type=seed_int,
        help="seed of the figures (Fig. 4, 6-9: every controller, torque PID; default: first)",
    )
    _add_command_delays_argument(p, [0.0, 0.005])
    _add_execution_arguments(p, cache_dir=True)
    _add_set_argument(
        p, "applied to every section", "mpc.weights.torque_feedback.joint_velocity=1.0"
    )
    p.set_defaults(study_main=_cmd_study_paper)


def _cmd_study_compare(args: argparse.Namespace) -> int:
    from studies.compare import compare

    table = compare(args.results, args.labels)
    if args.out is not None:
        out = Path(args.out)
        if out.exists() and not args.force:
            raise ConfigError(f"--out {args.out}: exists; never overwritten without --force")
        out.write_text(table)
    print(table)
    return 0


def _add_compare_parser(study_sub: SubParsers) -> None:
    """``ffmpc study compare``: studies run the same way on two plants, side by side."""
    p = study_sub.add_parser(
        "compare",
        help="two or more studies of one kind side by side (e.g. PyBullet vs MuJoCo)",
        description="Reads the results.json of two or more paper studies (or impact studies) "
        "run with the same seeds and settings, e.g. with --plant pybullet and --plant mujoco, "
        "and prints one markdown table: per experiment, PID, delta_o and MPC, E_lambda, E_P, "
        "lambda_max, aborted runs and runs over a joint limit for each study, and the MPCs' "
        "order in E_lambda (impact: pre-impact velocity, contact time, penetration, peak "
        "force, violations per run). Refuses studies that differ in seeds or settings.",
    )
    p.add_argument("results", nargs="+", help="results.json files (or their directories)")
    p.add_argument("--labels", nargs="+", help="column labels (default: each plant engine)")
    p.add_argument("--out", help="also write the table to this markdown file")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    p.set_defaults(study_main=_cmd_study_compare)


def _add_study_arguments(p: argparse.ArgumentParser, seeds: int, pid: str) -> None:
    p.add_argument("--scenario", help="shipped scenario name or path to a scenario file")
    p.add_argument(
        "--seeds", type=positive_int, default=seeds, help=f"number of seeds (default {seeds})"
    )
    p.add_argument("--first-seed", type=seed_int, default=0, help="first seed (default 0)")
    _add_execution_arguments(p, cache_dir=True)
    p.add_argument(
        "--duration", type=positive_float, help="simulated time per run, s (default: task)"
    )
    p.add_argument(
        "--formulations",
        nargs="+",
        choices=STUDY_FORMULATIONS,
        default=list(STUDY_FORMULATIONS),
        help="controllers to compare (default: all three)",
    )
    p.add_argument(
        "--pid", choices=("on", "off", "both"), default=pid, help=f"torque PID (default {pid})"
    )
    p.add_argument("--plot-seed", type=seed_int, help="seed shown in the figures (default: first)")
    _add_set_argument(p, "dotted name", "mpc.weights.force_feedback.force_phase=5")
    p.set_defaults(study_main=_cmd_study)


# -- ffmpc study impact | explore, ffmpc tune --------------------------------------------------
#: ``ffmpc study impact`` flags (argparse dest) → the scenario names they set (shorthands).
IMPACT_SHORTHANDS = {
    "dice_stiffness": "plant.dice_stiffness",
    "dice_damping": "plant.dice_damping",
    "duration": "duration",
    "replan_period": "replan_period",
    "strategy": "strategy",
    "prior_stiffness": "planner.prior_stiffness",
    "prior_damping": "planner.prior_damping",
    "target_force": "target_force",
    "plant": "plant.engine",
}
#: ``ffmpc study explore`` flags (argparse dest) → the scenario names they set (shorthands).
EXPLORE_SHORTHANDS = {
    "sine_cycles": "sine_cycles",
    "impact_velocities": "impact_velocities",
    "approach_speed": "approach_speed",
}


def _cmd_tune(args: argparse.Namespace) -> int:
    from ffmpc_ros.preflight import check_output
    from studies.tune import Objective, tune

    if args.out is not None:
        check_output(args.out, what="--out")
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    objective = Objective(
        position_weight=args.position_weight,
        break_penalty=args.break_penalty,
        force_limit=args.force_limit,
        force_penalty=args.force_penalty,
        velocity_penalty=args.velocity_penalty,
    )
    result = tune(
        args.scenario or ["polishing"],
        args.formulation,
        seeds,
        args.trials,
        args.storage,
        study_name=args.study_name,
        jobs=args.jobs,
        sampler_seed=args.sampler_seed,
        objective=objective,
        duration=args.duration,
        out=args.out,
        overrides=_parse_overrides(args.set),
        workers=args.workers,
        scheduler=args.scheduler,
        cache_dir=args.cache_dir,
        start_from=[_read_set_file(path) for path in args.start_from or []],
    )
    resumed = len(result.values) - result.trials_run
    print(
        f"ffmpc tune {args.formulation}: {len(result.values)} trials in {args.storage} "
        f"({resumed} resumed), training seeds {seeds[0]}-{seeds[-1]}"
    )
    print(f"  first trial (the scenario's weights): J = {result.values[0]:.4f}")
    print(f"  best: J = {result.best_value:.4f}")
    for name, value in result.best_weights.items():
        print(f"    mpc.weights.{args.formulation}.{name} = {value:.6g}")
    if result.out is not None:
        print(f"  written: {result.out}")
    return 0


def _add_tune_arguments(p: argparse.ArgumentParser) -> None:
    """``ffmpc tune``'s flags (studies/tune.py: Optuna search of one controller's cost weights)."""
    p.add_argument("formulation", choices=STUDY_FORMULATIONS)
    p.add_argument(
        "--scenario",
        action="append",
        help="shipped scenario name or a path (repeatable: J is the mean over every scenario "
        "and seed; default polishing)",
    )
    p.add_argument(
        "--start-from",
        action="append",
        type=existing_file,
        metavar="FILE",
        help="a YAML mapping NAME: VALUE (e.g. an earlier search's tuned_weights.yaml) whose "
        "mpc.weights.<formulation>.* a new search tries right after the scenario's own "
        "(repeatable)",
    )
    p.add_argument("--seeds", type=positive_int, default=3, help="number of training seeds")
    p.add_argument(
        "--first-seed",
        type=seed_int,
        default=1000,
        help="first training seed (default 1000: disjoint from the studies' 0-19)",
    )
    p.add_argument("--trials", type=positive_int, default=20, help="trials to add (default 20)")
    p.add_argument("--jobs", type=positive_int, default=1, help="trials at a time (default 1)")
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="worker processes of a local Dask cluster running each trial's seeds (default: all "
        "CPUs; 1: in this process)",
    )
    p.add_argument(
        "--scheduler",
        metavar="ADDRESS",
        help="run the trials' runs on a running Dask cluster, e.g. tcp://127.0.0.1:8786",
    )
    p.add_argument(
        "--cache-dir",
        metavar="DIR",
        help="run cache shared by the trials (and studies): a run already done is read back",
    )
    p.add_argument(
        "--storage",
        default="tune.db",
        help="Optuna storage: an SQLite file path or an RDB URL (default tune.db)",
    )
    p.add_argument("--study-name", help="search name in the storage (default SCENARIO-FORM)")
    p.add_argument("--sampler-seed", type=seed_int, default=0, help="TPE sampler seed")
    p.add_argument(
        "--position-weight", type=nonnegative_float, default=0.5, help="W, N/mm (default 0.5)"
    )
    p.add_argument(
        "--break-penalty", type=nonnegative_float, default=10.0, help="N per %% of contact lost"
    )
    p.add_argument(
        "--force-limit", type=nonnegative_float, default=150.0, help="lambda_max limit, N"
    )
    p.add_argument(
        "--force-penalty", type=nonnegative_float, default=1.0, help="N per N above the limit"
    )
    p.add_argument(
        "--velocity-penalty",
        type=nonnegative_float,
        default=50.0,
        help="N per unit of max |joint speed|/limit above 1 (default 50)",
    )
    p.add_argument("--duration", type=positive_float, help="simulated time per run, s")
    p.add_argument("--out", type=new_path, help="scenario file to write with the best weights")
    p.add_argument(
        "--set", action="append", default=[], metavar="NAME=VALUE", help="scenario override"
    )


def _study_overrides(args: argparse.Namespace, params: dict, shorthands: dict) -> dict:
    """The dotted-name overrides of a study: its shorthand flags, then ``--set`` (checked
    against the study's schema ``params``; a name given both ways is refused)."""
    overrides = {}
    for dest, name in shorthands.items():
        if getattr(args, dest, None) is not None:
            overrides[name] = getattr(args, dest)
    for name, value in _parse_overrides(args.set, schema=params).items():
        if name in overrides:
            flag = "--" + next(d for d, n in shorthands.items() if n == name).replace("_", "-")
            raise ConfigError(f"--set {name}: also given by {flag}; give it once")
        overrides[name] = value
    return overrides


def _cmd_study_impact(args: argparse.Namespace) -> int:
    import shlex

    _check_execution_arguments(args)  # before importing PyBullet
    from ffmpc_core.impact.scenario import IMPACT_SCHEMA, load_impact_config
    from studies.impact_study import (
        default_out_dir,
        recall_object,
        remember_object,
        run_impact_study,
    )

    overrides = _study_overrides(args, IMPACT_SCHEMA.params, IMPACT_SHORTHANDS)
    if args.strategies and "strategy" in overrides:
        raise ConfigError("--strategies runs each strategy given: no --strategy with it")
    if args.memory is not None:
        recalled = recall_object(args.memory, args.object, overrides)
        if recalled:
            print(f"recalled for {args.object!r} from {args.memory}: {recalled}")
        overrides = {**overrides, **recalled}
    config = load_impact_config(args.scenario or "impact", overrides)
    runs = tuple(tuple(name.split("+")) for name in args.runs)
    result = run_impact_study(
        config,
        runs=runs,
        out_dir=args.out or default_out_dir(),
        force=args.force,
        progress=not args.no_progress,
        command_line=shlex.join(["ffmpc", *getattr(args, "argv", [])]),
        strategies=tuple(args.strategies) if args.strategies else None,
        workers=args.workers,
        scheduler=args.scheduler,
        cache=not args.no_cache,
        fresh=args.fresh,
    )
    print(result.table)
    print(f"wall time {result.wall_time:.1f} s; files:")
    for path in result.files:
        print(f"  {path}")
    if args.memory is not None:
        kept = remember_object(args.memory, args.object, result.runs, config)
        if kept is not None:
            print(f"remembered for {args.object!r} in {args.memory}: {kept.describe()}")
    refused = [r for r in result.runs if r.refusal]
    for r in refused:
        print(f"ffmpc study impact: {r.name} refused: {r.refusal}", file=sys.stderr)
    if refused:
        return 2
    failed = [r for r in result.runs if r.violations.total or not r.contact_time >= 0.0]
    return 1 if failed else 0


#: ``ffmpc study impact --strategy/--strategies`` (ffmpc_core.impact.scenario.STRATEGIES).
STRATEGY_CHOICES = ("strike_first", "touch_first", "prior")


def _add_impact_study_parser(study_sub: SubParsers) -> None:
    """``ffmpc study impact``: the safe-maximal-impact experiment (Dehio & Kheddar, Fig. 4)."""
    runs = ("maximal+admittance", "maximal+ff_mpc", "baseline+admittance", "baseline+ff_mpc")
    p = study_sub.add_parser(
        "impact",
        help="safe maximal impact on a soft dice vs a near-zero-velocity baseline (Fig. 4)",
        description="The Panda, 0.46 m above a soft dice simulated in PyBullet (or MuJoCo: --plant "
        "mujoco), approaches it "
        "either at the maximal safe pre-impact velocity (eq 9-14, every cycle) or with the "
        "baseline (static target, near-zero contact velocity), then regulates 60 N with the "
        "paper's admittance controller or hands over to the force-feedback MPC with the "
        "stiffness and damping learned online (eq 19-21). Prints pre-impact velocity, contact "
        "time, time to a steady force, peak force and penetration, joint-limit violations and "
        "the learned material per run; writes table.md, results.json and impact_fig4.png. "
        "By default (--strategy strike_first) the maximal approach's first contact is the "
        "task's impact, at the bound safe for every plausible material (faster where the "
        "known surface rules a contact out); the learner sharpens the model from the impact "
        "and the regulation, and a force target the (worst-case) learned material cannot hold "
        "within the penetration bound is refused in contact (retract and hold). Exit 1 if a "
        "run never touched the dice or broke a limit, 2 on bad input or a refused target "
        "(the reason on stderr).",
    )
    _add_execution_arguments(p)
    p.add_argument(
        "--duration", type=positive_float, default=None, help="simulated s per run (default 4)"
    )
    p.add_argument(
        "--replan-period",
        type=nonnegative_float,
        help="s between eq 9-14 solves of the maximal approach (default 0: every 1 ms cycle); "
        "= --set replan_period=S",
    )
    p.add_argument("--runs", nargs="+", choices=runs, default=list(runs), help="runs to do")
    p.add_argument(
        "--dice-stiffness",
        type=positive_float,
        metavar="K",
        help="true stiffness of the simulated dice, N/m (default 3000; the prior stays 2400)",
    )
    p.add_argument(
        "--dice-damping",
        type=nonnegative_float,
        metavar="B",
        help="true damping of the simulated dice, N.s/m (default 20; the prior stays 15)",
    )
    p.add_argument(
        "--target-force", type=positive_float, help="force to hold after contact, N (60)"
    )
    p.add_argument(
        "--strategy",
        choices=STRATEGY_CHOICES,
        help="maximal approach: strike_first (the first contact is the task's impact, at the "
        "bound safe for every material still plausible; the target decided in contact), "
        "touch_first (touch, learn, retract, strike) or prior (plan from the prior as if it "
        "were the truth: the paper's scheme); = --set strategy=S",
    )
    p.add_argument(
        "--strategies",
        nargs="+",
        choices=STRATEGY_CHOICES,
        metavar="S",
        help="run the maximal approach once per strategy (one table; the baseline once)",
    )
    p.add_argument(
        "--memory",
        metavar="FILE",
        help="object memory (JSON): the strike-first strategy starts from the interval a "
        "previous run learned on --object (if FILE has one), and this run's learned interval "
        "is kept there for the next",
    )
    p.add_argument("--object", default="dice", help="the object's name in --memory (default dice)")
    p.add_argument("--prior-stiffness", type=positive_float, help="planner's prior stiffness, N/m")
    p.add_argument("--prior-damping", type=nonnegative_float, help="planner's prior damping, N.s/m")
    add_plant_argument(p)
    _add_study_config_arguments(p, "impact", "plant.dice_stiffness=4800")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    p.set_defaults(study_main=_cmd_study_impact)


def _add_study_config_arguments(p: argparse.ArgumentParser, study: str, example: str) -> None:
    """``--scenario`` and ``--set`` of a study configured by its own dataclass tree."""
    p.add_argument(
        "--scenario",
        help=f"shipped scenario name or path to a scenario file (default {study}: "
        f"ffmpc_core/scenarios/{study}.yaml); the other flags are shorthands for --set",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help=f"scenario override, dotted name (repeatable), e.g. {example}",
    )


def _add_explore_study_parser(study_sub: SubParsers) -> None:
    """``ffmpc study explore``: the contact learner's exploration (Dehio & Kheddar, Sec. V-VI)."""

    def run(args: argparse.Namespace) -> int:
        from ffmpc_core.impact.scenario import EXPLORATION_SCHEMA, load_exploration_config
        from studies.exploration import format_checkpoints, format_summary, run_exploration_study
        from studies.study import default_out_dir

        _check_execution_arguments(args)
        overrides = _study_overrides(args, EXPLORATION_SCHEMA.params, EXPLORE_SHORTHANDS)
        cfg = load_exploration_config(args.scenario or "explore", overrides)
        out = args.out or default_out_dir("explore")
        runs = run_exploration_study(
            tuple(args.materials),
            cfg,
            progress=not args.no_progress,
            out_dir=out,
            force=args.force,
            workers=args.workers,
            scheduler=args.scheduler,
            cache=not args.no_cache,
            fresh=args.fresh,
        )
        for r in runs:
            print("\n" + format_checkpoints(r))
        print("\nFinal relative errors vs the truth set in PyBullet:\n")
        print(format_summary(runs))
        print(f"\nfiles: {out}/tables.md, {out}/results.json")
        bad = [r for r in runs if r.violations.total or not r.final.covers(r.material)]
        return 1 if bad else 0

    p = study_sub.add_parser(
        "explore",
        help="learn a soft object's stiffness and damping online (Sec. V, eq 19-21)",
        description="The Panda finds the surface of a soft object simulated in PyBullet by a "
        "guarded approach, then tracks the exploration motion (a sinusoidal penetration, then "
        "impacts at 0.15-0.35 m/s) inside the joint-limit QP while the recursive learner "
        "(eq 19-21) is fed (z, z-dot, f). Prints the estimate, its confidence (2 standard "
        "errors + the bound of the surface error) and the error vs the truth after the "
        "sinusoid and after each impact, per material. Exit 1 if a joint limit was broken or "
        "an interval misses the truth.",
    )
    p.add_argument(
        "--materials",
        nargs="+",
        choices=("foam", "dice", "rubber"),
        default=["foam", "dice", "rubber"],
        help="objects to explore (default: all three)",
    )
    p.add_argument("--sine-cycles", type=positive_int, help="sine periods (default 4)")
    p.add_argument(
        "--impact-velocities",
        type=positive_float,
        nargs="+",
        help="pre-impact velocities, m/s (default: each material's, 0.15-0.35)",
    )
    p.add_argument(
        "--approach-speed",
        type=positive_float,
        help="guarded approach, m/s (default 0.005)",
    )
    _add_study_config_arguments(p, "explore", "gains.position=300")
    _add_execution_arguments(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(study_main=run)


# -- ffmpc bench impact ----------------------------------------------------------------------
def _cmd_bench_impact(args: argparse.Namespace) -> int:
    from studies.bench_impact import run_bench_impact

    return run_bench_impact(args)


# -- the extensions ----------------------------------------------------------------------------
class StudyCommand(CommandExtension):
    """``ffmpc study``: the simulated studies (entry point ``study`` of ``ffmpc.command``)."""

    help = "simulated studies: the papers' tables and figures"
    description = (
        "Simulated studies that write results.json, tables and figures: the "
        "force-feedback paper's polishing study and Experiment 1 (grids of closed-loop runs, "
        "formulations x torque PID x seeds, in parallel worker processes), and the impact "
        "paper's experiments."
    )
    verb_dest = "study"

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        study_sub = parser.add_subparsers(dest="study", required=True)
        polishing = study_sub.add_parser(
            "polishing",
            help="Tables II-IV and Figs. 6-9 (VI-C)",
            description="The polishing study of VI-C: each seed draws a table tilt and an "
            "actuation bias; every controller runs with and without the torque PID. Prints "
            "Tables II-IV (from the true normal force, then from the measured one) and writes "
            "results.json, tables.md and two figures into --out.",
        )
        _add_study_arguments(polishing, seeds=20, pid="both")
        _add_command_delays_argument(polishing, None)
        square = study_sub.add_parser(
            "force-square",
            help="Experiment 1 (VII-B): square force signal, Fig. 4",
            description="Experiment 1 of VII-B: the three controllers track a square "
            "normal-force reference (with the torque PID, one seed by default); prints each "
            "controller's normal-force MAE and writes results.json, tables.md and a Fig. 4-like "
            "plot.",
        )
        _add_study_arguments(square, seeds=1, pid="on")
        _add_paper_study_parser(study_sub)
        _add_impact_study_parser(study_sub)
        _add_explore_study_parser(study_sub)
        _add_compare_parser(study_sub)

    def main(self, args: argparse.Namespace) -> int:
        return int(args.study_main(args) or 0)


class TuneCommand(CommandExtension):
    """``ffmpc tune``: Optuna search of one controller's cost weights (studies/tune.py)."""

    help = "search one controller's cost weights with Optuna (resumable)"
    description = (
        "Search the cost weights of one MPC formulation on training seeds with "
        "Optuna (seeded TPE sampler, trials kept in an RDB storage so that a search resumes, "
        "--jobs trials at a time). Objective per run: E_lambda + W x E_P (N, mm) + penalties "
        "for contact breaks and lambda_max above a limit; the mean over the seeds is minimised. "
        "The first trial of a new search is the scenario's own weights. Writes the best weights "
        "into a copy of the scenario file (--out)."
    )

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        _add_tune_arguments(parser)

    def main(self, args: argparse.Namespace) -> int:
        return _cmd_tune(args)


class BenchImpactVerb(CommandExtension):
    """``ffmpc bench impact`` (entry point ``impact`` of ``ffmpc.bench``): the impact planner's
    cycle time (studies/bench_impact.py)."""

    help = "impact planner cycle time (eq 9-14 + learner), DAQP vs the OSQP reference"
    description = (
        "Runs the impact study's maximal approach in PyBullet, then replays its "
        "pre-contact states through the planner cycle (learner update, eq 9-11 mapping, eq 14) "
        "with DAQP and with the old OSQP pipeline, interleaved in the same run; prints median, "
        "p90, p99, their ratio and the solver failures."
    )

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--cycles", type=positive_int, default=1000, help="timed planner cycles"
        )
        parser.add_argument(
            "--warmup", type=nonnegative_int, default=50, help="untimed first cycles"
        )
        parser.add_argument(
            "--sim-duration",
            type=positive_float,
            default=1.2,
            help="simulated seconds of the study's approach to take the problems from",
        )
        parser.add_argument("--json", type=output_file, help="write the figures to this JSON file")
        parser.add_argument("--force", action="store_true", help="replace an existing --json")

    def main(self, args: argparse.Namespace) -> int:
        _check_json(args)
        return _cmd_bench_impact(args)


def _check_json(args: argparse.Namespace) -> None:
    """A bench's ``--json``: a new file in a writable directory (an existing one with --force),
    checked before the bench runs (ffmpc_ros.preflight)."""
    from ffmpc_ros.preflight import check_output

    if args.json is not None:
        check_output(args.json, force=args.force, what="--json")


class DemoCommand(CommandExtension):
    """``ffmpc demo`` (``make demo``; entry point ``demo`` of ``ffmpc.command``): the demo of
    studies/demo.py."""

    help = "run the main demo"
    description = (
        "Run the main demo: the three MPC formulations hold 50 N in closed loop with their own "
        "dynamics, then the force-feedback MPC polishes in PyBullet with the paper's "
        "imperfections, through the ROS 2 node graph and the ROS-free run; prints forces, solve "
        "times and the study's metrics (exit 1 if the graph and the run disagree)."
    )

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--seed", type=seed_int, default=0)
        parser.set_defaults(needs_ros=True)  # the node graph: ROS_DOMAIN_ID checked first

    def main(self, args: argparse.Namespace) -> int:
        from studies.demo import run_demo

        return run_demo(seed=args.seed)


class BenchMpcVerb(CommandExtension):
    """``ffmpc bench mpc`` (entry point ``mpc`` of ``ffmpc.bench``): studies/bench_mpc.py."""

    help = "MPC step and solve time per formulation"
    description = (
        "Median and p90 MPC step time (references, warm start and solve), median solve time, "
        "iterations and iteration-cap hits of each formulation on the iiwa, at N=5, dt=3 ms and "
        "N=20, dt=10 ms, with and without its hard constraints, and the ratios to crocoddyl's "
        "built-in classical contact model on the same problem and of the constrained solve to "
        "the unconstrained one, measured in the same run."
    )

    def add_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--solves", type=positive_int, default=200, help="MPC steps per case")
        parser.add_argument("--seed", type=seed_int, default=0)
        parser.add_argument(
            "--cases",
            nargs="+",
            metavar="CASE[:N]",
            help="cases to run: a formulation (classical, torque_feedback, force_feedback; with "
            "its constraints), FORMULATION_unconstrained, FORMULATION_python, "
            "force_feedback_capped; optionally restricted to one configuration with :5 or :20 "
            "(default: every case but the Python ones of classical and torque_feedback); the "
            "reference always runs in each configuration used",
        )
        parser.add_argument(
            "--json", metavar="FILE", type=output_file, help='also write {"cases": [...]} to FILE'
        )
        parser.add_argument("--force", action="store_true", help="replace an existing --json")

    def main(self, args: argparse.Namespace) -> int:
        from studies.bench_mpc import run_bench_mpc

        _check_json(args)
        return run_bench_mpc(args)
