"""``ffmpc``: the one command-line entry point. Every subcommand has ``--help``.

Subcommands import what they need lazily, so ``ffmpc check`` works even where ROS or PyBullet
would fail to load.
"""

from __future__ import annotations

import argparse
import os
import sys

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_ros.cli_args import (
    new_path,
    nonnegative_float,
    nonnegative_int,
    output_file,
    positive_float,
    positive_int,
    seed_int,
)
from ffmpc_ros.cli_args import parse_overrides as _parse_overrides
from ffmpc_ros.discovery import ensure_local_discovery

#: ffmpc_core.config.FORMULATIONS, spelled out so that building the parser imports nothing heavy.
STUDY_FORMULATIONS = ("classical", "torque_feedback", "force_feedback")
#: Exit status of every malformed input (argparse's own for syntax errors).
EXIT_USAGE = 2
#: Default port of ``ffmpc run --view`` (ffmpc_ros.view.DEFAULT_PORT).
VIEW_PORT = 8765


class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (``ffmpc run: error: …``, no usage block), exit 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def _cmd_check(args: argparse.Namespace) -> int:
    import numpy as np

    from ffmpc_core.robots import ROBOT_NAMES, load_robot
    from ffmpc_core.selfcheck import (
        check_crocoddyl_dynamics,
        check_native_soft_contact,
        installed_versions,
        version_mismatches,
    )

    print("installed versions:")
    for name, version in installed_versions().items():
        print(f"  {name:20s} {version or 'MISSING'}")
    status = 0
    for name, (found, wanted) in version_mismatches().items():
        print(f"PIN MISMATCH: {name} is {found}, ffmpc requires {wanted}")
        status = 1
    rng = np.random.default_rng(args.seed)
    checks = (
        (check_crocoddyl_dynamics, "crocoddyl free dynamics vs pin.aba", "max |Δq̈|", " rad/s²"),
        (
            check_native_soft_contact,
            "native force-feedback model vs Python reference",
            "max relative |Δ(x⁺, Fx)|",
            "",
        ),
    )
    for robot_name in ROBOT_NAMES:
        for check, what, error, unit in checks:
            result = check(load_robot(robot_name), rng, samples=args.samples)
            print(
                f"{what} on {robot_name}: {error} = {result.max_error:.2e}{unit} over "
                f"{result.samples} states (tolerance {result.tolerance:g}): "
                f"{'ok' if result.ok else 'FAILED'}"
            )
            status |= 0 if result.ok else 1
    return status


def _cmd_bench_mpc(args: argparse.Namespace) -> int:
    from ffmpc_core.bench_mpc import run_bench_mpc

    return run_bench_mpc(args)


def _cmd_bench_impact(args: argparse.Namespace) -> int:
    from studies.bench_impact import run_bench_impact

    return run_bench_impact(args)


def _cmd_demo(args: argparse.Namespace) -> int:
    from ffmpc_ros.demo import run_demo

    return run_demo(seed=args.seed)


def _cmd_study(args: argparse.Namespace) -> int:
    import shlex

    from ffmpc_core.scenario import load_scenario

    kind = "polishing" if args.study == "polishing" else "force_square"
    overrides = _parse_overrides(args.set)
    load_scenario(args.scenario or kind, overrides)  # refuse a bad scenario before any import
    if args.scheduler is not None and args.workers is not None:
        raise ConfigError("--workers and --scheduler exclude each other (a cluster has workers)")
    use_cache = not args.no_cache
    if args.out:  # refused before any run (studies.study does not load PyBullet)
        from studies.study import check_output_dir

        check_output_dir(args.out, args.force, resume=use_cache and not args.fresh)
    if args.plot_seed is not None and not (
        args.first_seed <= args.plot_seed < args.first_seed + args.seeds
    ):
        raise ConfigError(
            f"--plot-seed {args.plot_seed}: expected one of the seeds "
            f"{args.first_seed}..{args.first_seed + args.seeds - 1}"
        )
    from studies.study import default_out_dir, grid_specs, run_study

    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    pid_modes = {"on": [True], "off": [False], "both": [True, False]}[args.pid]
    plot_seed = args.first_seed if args.plot_seed is None else args.plot_seed
    specs = grid_specs(
        args.scenario or kind,
        args.formulations,
        pid_modes,
        seeds,
        duration=args.duration,
        overrides=overrides,
        plot_seed=plot_seed,
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
        pid = "on" if f["pid_enabled"] else "off"
        print(f"  FAILED {f['formulation']} pid={pid} seed={f['seed']}: {f['error']}")
    print("files:")
    for path in report.files:
        print(f"  {path}")
    return 0 if report.document["runs"] else 1


def _add_study_arguments(p: argparse.ArgumentParser, seeds: int, pid: str) -> None:
    p.add_argument("--scenario", help="shipped scenario name or path to a scenario file")
    p.add_argument(
        "--seeds", type=positive_int, default=seeds, help=f"number of seeds (default {seeds})"
    )
    p.add_argument("--first-seed", type=seed_int, default=0, help="first seed (default 0)")
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
        "--cache-dir",
        metavar="DIR",
        help="run cache directory, one JSON file per finished run (default OUT/cache)",
    )
    p.add_argument(
        "--fresh", action="store_true", help="run every run again (results still go to the cache)"
    )
    p.add_argument("--no-cache", action="store_true", help="neither read nor write the run cache")
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
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help="scenario override, dotted name (repeatable), e.g. mpc.weights.force_feedback."
        "force_phase=5",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_study)


def _view_layout() -> str:
    from ffmpc_ros.ament import foxglove_layout_path

    return str(foxglove_layout_path())


#: ``ffmpc run`` options of the polishing graph only (argparse dest → flag).
POLISHING_ONLY = {
    "single_process": "--single-process",
    "real_time": "--real-time",
    "formulation": "--formulation",
    "view": "--view",
    "cpus": "--cpus",
    "priority": "--priority",
    "fault_window": "--fault-window",
    "fault": "--fault",
    "node_param": "--node-param",
}
#: ``ffmpc run`` options of the impact graph only (argparse dest → flag).
IMPACT_ONLY = {"approach": "--approach", "regulation": "--regulation"}


def _cmd_run_impact(args: argparse.Namespace) -> int:
    """``ffmpc run impact``: the impact experiment on the node graph (ffmpc_ros.impact_graph)."""
    import json
    import shlex

    from ffmpc_core.errors import ConfigError
    from ffmpc_ros.impact_graph import run_impact_graph
    from ffmpc_ros.topics import normalize_namespace

    given = [flag for dest, flag in POLISHING_ONLY.items() if getattr(args, dest, None)]
    if given:
        raise ConfigError(f"{', '.join(given)}: polishing-graph options (not for ffmpc run impact)")
    overrides = list(args.set or [])  # the study's defaults (strategy touch_first)
    if args.duration is not None:
        overrides.append(f"duration={args.duration!r}")
    try:
        namespace = normalize_namespace(args.namespace)
    except ConfigError as exc:
        raise ConfigError(f"--namespace: {exc}") from None
    result = run_impact_graph(
        args.approach or "maximal",
        args.regulation or "admittance",
        overrides=overrides,
        record=args.record,
        timeout=args.timeout,
        stall_timeout=args.stall_timeout,
        start_timeout=args.start_timeout,
        quiet=not args.verbose,
        namespace=namespace,
        allow_foreign=args.allow_foreign_publishers,
    )
    summary = result.summary()
    summary["seed"] = args.seed
    summary["command_line"] = shlex.join(["ffmpc", *args.argv])
    summary = json.loads(json.dumps(summary, default=float))
    print(json.dumps(summary, indent=2))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(summary, fh, indent=2)
    m = result.metrics
    print(
        f"impact graph {result.approach}+{result.regulation}: contact {m['contact_time']:.3f} s at "
        f"{m['pre_impact_velocity']:.3f} m/s, peak force {m['peak_force']:.1f} N, peak "
        f"penetration {1e3 * m['peak_penetration']:.1f} mm, final force {m['final_force']:.2f} N,"
        f" {m['violations'].total} limit violations; simulated {result.sim_time:.2f} s in "
        f"{result.wall_time:.1f} s wall: {'safe' if result.safe else 'NOT SAFE'}",
        file=sys.stderr,
    )
    return 0 if result.safe else 1


def _cmd_run(args: argparse.Namespace) -> int:
    import json
    import shlex

    from ffmpc_core.errors import ConfigError
    from ffmpc_core.scenario import load_scenario
    from ffmpc_ros.bringup import run_graph

    if args.scenario == "impact":
        return _cmd_run_impact(args)
    given = [flag for dest, flag in IMPACT_ONLY.items() if getattr(args, dest, None)]
    if given:
        raise ConfigError(f"{', '.join(given)}: options of ffmpc run impact only")
    overrides = _parse_overrides(args.set)
    if args.formulation:
        overrides["mpc.formulation"] = args.formulation
    if args.seed is not None:
        overrides["seed"] = args.seed
    scenario = load_scenario(args.scenario, overrides)
    cpus = "auto"
    if args.cpus == "none":
        cpus = None
    elif args.cpus is not None:
        try:
            loop_cpu, mpc_cpu = (int(c) for c in args.cpus.split(","))
        except ValueError:
            raise ConfigError(
                f"--cpus expects LOOP,MPC (two CPU numbers) or none, got {args.cpus!r}"
            ) from None
        cpus = (loop_cpu, mpc_cpu)
    if (args.cpus is not None or args.priority is not None) and not args.real_time:
        raise ConfigError("--cpus and --priority are real-time options (add --real-time)")
    if args.priority is not None and not 0 <= args.priority <= 99:
        raise ConfigError(f"--priority must be in 0..99, got {args.priority}")
    if (args.view_port != VIEW_PORT or args.view_wait) and not args.view:
        raise ConfigError("--view-port and --view-wait need --view")
    if args.view:
        if args.real_time:
            raise ConfigError("--view is a lockstep option (the real-time loop has no view)")
        from ffmpc_ros.view import check_port_free

        check_port_free("127.0.0.1", args.view_port)
        print(
            f"live view: Foxglove WebSocket server on ws://127.0.0.1:{args.view_port} until "
            "the run ends (Foxglove: Open connection > Foxglove WebSocket; layout "
            f"{_view_layout()})",
            file=sys.stderr,
            flush=True,
        )
    if scenario.mpc.command_delay == "measured":
        from ffmpc_core.study import resolve_command_delay

        scenario, record = resolve_command_delay(scenario)
        print(
            f"mpc.command_delay measured: δo = {record['delta_o_s'] * 1e3:.0f} ms",
            file=sys.stderr,
            flush=True,
        )
    from ffmpc_core.faults import parse_fault

    faults = [parse_fault(text) for text in args.fault or []]
    node_ros_args: dict[str, list[str]] = {}
    for item in args.node_param or []:
        node, sep, assignment = item.partition(":")
        if not sep or ":=" not in assignment:
            raise ConfigError(f"--node-param expects NODE:NAME:=VALUE, got {item!r}")
        node_ros_args.setdefault(node, []).extend(["-p", assignment])
    if args.stall_timeout <= 0:
        raise ConfigError(f"--stall-timeout must be > 0 s, got {args.stall_timeout}")
    from ffmpc_ros.topics import normalize_namespace

    try:
        namespace = normalize_namespace(args.namespace)
    except ConfigError as exc:
        raise ConfigError(f"--namespace: {exc}") from None
    result = run_graph(
        scenario,
        faults=faults,
        allow_foreign=args.allow_foreign_publishers,
        stall_timeout=args.stall_timeout,
        start_timeout=args.start_timeout,
        node_ros_args=node_ros_args,
        duration=args.duration,
        single_process=args.single_process,
        lockstep=not args.real_time,
        timeout=args.timeout,
        quiet=not args.verbose,
        record=args.record,
        fault_windows=[tuple(w) for w in args.fault_window or []],
        cpus=cpus,
        priority=args.priority,
        view=args.view_port if args.view else None,
        view_wait=args.view_wait,
        namespace=namespace,
    )
    summary = result.summary()
    summary["command_line"] = shlex.join(["ffmpc", *args.argv])
    print(json.dumps(summary, indent=2))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(summary, fh, indent=2)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
    t = result.timing or {}
    fractions = t.get("deadline_met_fraction") or {}

    def shown(value, fmt: str) -> str:
        return "n/a" if value is None else format(value, fmt)

    print(
        f"timing ({summary['mode']}): deadlines met MPC {shown(fractions.get('mpc'), '.4f')}, "
        f"loop {shown(fractions.get('loop'), '.4f')}; latency p50/p99/max "
        f"{shown(t.get('latency_p50_ms'), '.3f')}/{shown(t.get('latency_p99_ms'), '.3f')}/"
        f"{shown(t.get('latency_max_ms'), '.3f')} ms; fallback "
        f"{shown(t.get('fallback_time_s'), '.3f')} s",
        file=sys.stderr,  # stdout stays one JSON document
    )
    failures = result.timing_failures()
    for failure in failures:
        print(f"FAILED: {failure}", file=sys.stderr)
    limits = result.limit_failures()
    for failure in limits:
        print(f"FAILED: {failure}", file=sys.stderr)
    if summary.get("faults"):
        ratios = (max(summary["max_velocity_ratio"]), max(summary["max_torque_ratio"]))
        verdict = "broke a joint limit" if limits else "handled safely"
        print(
            f"faults {', '.join(f['fault'] for f in summary['faults'])}: {verdict} (max "
            f"|q̇|/limit {ratios[0]:.3f}, max |τ|/limit {ratios[1]:.3f}, safe hold "
            f"{summary['safe_hold_s']:.3f} s)",
            file=sys.stderr,
        )
    if summary.get("faults") and failures:  # the verdict of a fault run is its safety
        print("(timing failures of a fault run are reported, not the exit status)", file=sys.stderr)
        return 1 if limits else 0
    return 1 if failures or limits else 0


def _cmd_run_guarded(args: argparse.Namespace) -> int:
    """``ffmpc run`` with clean stops: Ctrl-C (SIGINT) and SIGTERM stop every node, close the
    bag and print one line (exit 130 and 143). The handler only records the request; the
    bring-up's loop raises ``RunInterrupted`` outside every ROS callback."""
    import signal

    from ffmpc_ros.bringup import RunInterrupted, request_stop

    def terminate(signum, _frame):
        for sig in (signal.SIGINT, signal.SIGTERM):  # one stop at a time: cleanup runs once
            signal.signal(sig, signal.SIG_IGN)
        if args.real_time:  # ffmpc_ros.realtime stops on KeyboardInterrupt
            raise KeyboardInterrupt
        request_stop(signum)

    signal.signal(signal.SIGINT, terminate)
    signal.signal(signal.SIGTERM, terminate)
    what = "every node stopped" + (f", bag {args.record} closed" if args.record else "")
    try:
        return _cmd_run(args)
    except RunInterrupted as stop:
        name = "SIGTERM" if stop.signum == signal.SIGTERM else "SIGINT"
        verb = "terminated" if stop.signum == signal.SIGTERM else "interrupted"
        print(f"ffmpc run: {verb} ({name}): {what}", file=sys.stderr)
        return 128 + int(stop.signum)
    except KeyboardInterrupt:
        print(f"ffmpc run: interrupted: {what}", file=sys.stderr)
        return 130


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
}
#: ``ffmpc study explore`` flags (argparse dest) → the scenario names they set (shorthands).
EXPLORE_SHORTHANDS = {
    "sine_cycles": "sine_cycles",
    "impact_velocities": "impact_velocities",
    "approach_speed": "approach_speed",
}


def _cmd_tune(args: argparse.Namespace) -> int:
    from studies.tune import Objective, tune

    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    objective = Objective(
        position_weight=args.position_weight,
        break_penalty=args.break_penalty,
        force_limit=args.force_limit,
        force_penalty=args.force_penalty,
    )
    result = tune(
        args.scenario,
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


def _add_tune_parser(sub) -> None:
    """``ffmpc tune``: Optuna search of one controller's cost weights (studies/tune.py)."""
    p = sub.add_parser(
        "tune",
        help="search one controller's cost weights with Optuna (resumable)",
        description="Search the cost weights of one MPC formulation on training seeds with "
        "Optuna (seeded TPE sampler, trials kept in an RDB storage so that a search resumes, "
        "--jobs trials at a time). Objective per run: E_lambda + W x E_P (N, mm) + penalties "
        "for contact breaks and lambda_max above a limit; the mean over the seeds is minimised. "
        "The first trial of a new search is the scenario's own weights. Writes the best weights "
        "into a copy of the scenario file (--out).",
    )
    p.add_argument("formulation", choices=STUDY_FORMULATIONS)
    p.add_argument("--scenario", default="polishing", help="shipped scenario name or a path")
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
    p.add_argument("--duration", type=positive_float, help="simulated time per run, s")
    p.add_argument("--out", type=new_path, help="scenario file to write with the best weights")
    p.add_argument(
        "--set", action="append", default=[], metavar="NAME=VALUE", help="scenario override"
    )
    p.set_defaults(func=_cmd_tune)


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

    if args.out and os.path.exists(args.out) and not args.force:  # before importing PyBullet
        raise ConfigError(f"{args.out} exists: choose another --out or pass --force to overwrite")
    from ffmpc_core.impact.scenario import IMPACT_SCHEMA, load_impact_config
    from studies.impact_study import default_out_dir, run_impact_study

    overrides = _study_overrides(args, IMPACT_SCHEMA.params, IMPACT_SHORTHANDS)
    config = load_impact_config(args.scenario or "impact", overrides)
    runs = tuple(tuple(name.split("+")) for name in args.runs)
    result = run_impact_study(
        config,
        runs=runs,
        out_dir=args.out or default_out_dir(),
        force=args.force,
        progress=not args.no_progress,
        command_line=shlex.join(["ffmpc", *getattr(args, "argv", [])]),
    )
    print(result.table)
    print(f"wall time {result.wall_time:.1f} s; files:")
    for path in result.files:
        print(f"  {path}")
    refused = [r for r in result.runs if r.refusal]
    for r in refused:
        print(f"ffmpc study impact: {r.name} refused: {r.refusal}", file=sys.stderr)
    if refused:
        return 2
    failed = [r for r in result.runs if r.violations.total or not r.contact_time >= 0.0]
    return 1 if failed else 0


def _add_impact_study_parser(study_sub) -> None:
    """``ffmpc study impact``: the safe-maximal-impact experiment (Dehio & Kheddar, Fig. 4)."""
    runs = ("maximal+admittance", "maximal+ff_mpc", "baseline+admittance", "baseline+ff_mpc")
    p = study_sub.add_parser(
        "impact",
        help="safe maximal impact on a soft dice vs a near-zero-velocity baseline (Fig. 4)",
        description="The Panda, 0.46 m above a soft dice simulated in PyBullet, approaches it "
        "either at the maximal safe pre-impact velocity (eq 9-14, every cycle) or with the "
        "baseline (static target, near-zero contact velocity), then regulates 60 N with the "
        "paper's admittance controller or hands over to the force-feedback MPC with the "
        "stiffness and damping learned online (eq 19-21). Prints pre-impact velocity, contact "
        "time, time to a steady force, peak force and penetration, joint-limit violations and "
        "the learned material per run; writes table.md, results.json and impact_fig4.png. "
        "By default (--strategy touch_first) the maximal approach first touches the dice at "
        "the bound safe for every plausible material, learns it, and strikes at the bound of "
        "the learned model; a force target the (worst-case) material cannot hold within the "
        "penetration bound is refused before the strike. Exit 1 if a run never touched the "
        "dice or broke a limit, 2 on bad input or a refused target (the reason on stderr).",
    )
    p.add_argument(
        "--out", help="output directory, must not exist (default benchmarks/results/...)"
    )
    p.add_argument("--force", action="store_true", help="write into an existing --out")
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
        choices=("touch_first", "prior"),
        help="maximal approach: touch, learn, then strike (default), or plan from the prior "
        "as if it were the truth (the paper's scheme)",
    )
    p.add_argument("--prior-stiffness", type=positive_float, help="planner's prior stiffness, N/m")
    p.add_argument("--prior-damping", type=nonnegative_float, help="planner's prior damping, N.s/m")
    _add_study_config_arguments(p, "impact", "plant.dice_stiffness=4800")
    p.add_argument("--no-progress", action="store_true", help="no progress lines")
    p.set_defaults(func=_cmd_study_impact)


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


def _add_explore_study_parser(study_sub) -> None:
    """``ffmpc study explore``: the contact learner's exploration (Dehio & Kheddar, Sec. V-VI)."""

    def run(args: argparse.Namespace) -> int:
        from ffmpc_core.impact.scenario import EXPLORATION_SCHEMA, load_exploration_config
        from studies.exploration import format_checkpoints, format_summary, run_exploration_study

        overrides = _study_overrides(args, EXPLORATION_SCHEMA.params, EXPLORE_SHORTHANDS)
        cfg = load_exploration_config(args.scenario or "explore", overrides)
        runs = run_exploration_study(tuple(args.materials), cfg, progress=not args.no_progress)
        for r in runs:
            print("\n" + format_checkpoints(r))
        print("\nFinal relative errors vs the truth set in PyBullet:\n")
        print(format_summary(runs))
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
    p.add_argument("--no-progress", action="store_true", help="no per-checkpoint lines")
    p.set_defaults(func=run)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="ffmpc",
        description="Force-feedback MPC and safe maximal impacts on soft contacts (ROS 2 Jazzy).",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    check = sub.add_parser(
        "check",
        help="print versions and check crocoddyl's dynamics against pin.aba",
        description="Print installed versions, flag pin mismatches, and compare crocoddyl's free "
        "forward dynamics with pin.aba on random states of every robot. Exit 1 on any failure.",
    )
    check.add_argument("--samples", type=positive_int, default=20, help="random states per robot")
    check.add_argument("--seed", type=seed_int, default=0, help="seed of the random states")
    check.set_defaults(func=_cmd_check)

    demo = sub.add_parser(
        "demo",
        help="run the main demo",
        description="Run the main demo: the three MPC formulations hold 50 N in closed loop with "
        "their own dynamics, then the force-feedback MPC polishes in PyBullet with the paper's "
        "imperfections; prints forces, solve times and the study's metrics.",
    )
    demo.add_argument("--seed", type=seed_int, default=0)
    demo.set_defaults(func=_cmd_demo)

    bench = sub.add_parser("bench", help="benchmarks that print their figures")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    bench_mpc = bench_sub.add_parser(
        "mpc",
        help="MPC step and solve time per formulation",
        description="Median and p90 MPC step time (references, warm start and solve), median "
        "solve time, iterations and iteration-cap hits of each formulation on the iiwa, at N=5, "
        "dt=3 ms and N=20, dt=10 ms, and the ratio to crocoddyl's built-in classical contact "
        "model on the same problem, measured in the same run.",
    )
    bench_mpc.add_argument("--solves", type=positive_int, default=200, help="MPC steps per case")
    bench_mpc.add_argument("--seed", type=seed_int, default=0)
    bench_mpc.add_argument(
        "--cases",
        nargs="+",
        metavar="FORMULATION[:N]",
        help="formulations to run (classical, torque_feedback, force_feedback), optionally "
        "restricted to one configuration with :5 or :20 (default: all); the reference always "
        "runs in each configuration used",
    )
    bench_mpc.add_argument(
        "--json", metavar="FILE", type=output_file, help='also write {"cases": [...]} to FILE'
    )
    bench_mpc.set_defaults(func=_cmd_bench_mpc)
    bench_impact = bench_sub.add_parser(
        "impact",
        help="impact planner cycle time (eq 9-14 + learner), DAQP vs the OSQP reference",
        description="Runs the impact study's maximal approach in PyBullet, then replays its "
        "pre-contact states through the planner cycle (learner update, eq 9-11 mapping, eq 14) "
        "with DAQP and with the old OSQP pipeline, interleaved in the same run; prints median, "
        "p90, p99, their ratio and the solver failures.",
    )
    bench_impact.add_argument(
        "--cycles", type=positive_int, default=1000, help="timed planner cycles"
    )
    bench_impact.add_argument(
        "--warmup", type=nonnegative_int, default=50, help="untimed first cycles"
    )
    bench_impact.add_argument(
        "--sim-duration",
        type=positive_float,
        default=1.2,
        help="simulated seconds of the study's approach to take the problems from",
    )
    bench_impact.add_argument(
        "--json", type=output_file, help="write the figures to this JSON file"
    )
    bench_impact.set_defaults(func=_cmd_bench_impact)

    study = sub.add_parser(
        "study",
        help="simulated studies: the papers' tables and figures",
        description="Simulated studies that write results.json, tables and figures: the "
        "force-feedback paper's polishing study and Experiment 1 (grids of closed-loop runs, "
        "formulations x torque PID x seeds, in parallel worker processes), and the impact "
        "paper's experiments.",
    )
    study_sub = study.add_subparsers(dest="study", required=True)
    polishing = study_sub.add_parser(
        "polishing",
        help="Tables II-IV and Figs. 6-9 (VI-C)",
        description="The polishing study of VI-C: each seed draws a table tilt and an actuation "
        "bias; every controller runs with and without the torque PID. Prints Tables II-IV "
        "(from the true normal force, then from the measured one) and writes results.json, "
        "tables.md and two figures into --out.",
    )
    _add_study_arguments(polishing, seeds=20, pid="both")
    square = study_sub.add_parser(
        "force-square",
        help="Experiment 1 (VII-B): square force signal, Fig. 4",
        description="Experiment 1 of VII-B: the three controllers track a square normal-force "
        "reference (with the torque PID, one seed by default); prints each controller's "
        "normal-force MAE and writes results.json, tables.md and a Fig. 4-like plot.",
    )
    _add_study_arguments(square, seeds=1, pid="on")
    _add_impact_study_parser(study_sub)
    _add_explore_study_parser(study_sub)
    _add_tune_parser(sub)
    run = sub.add_parser(
        "run",
        help="run a scenario on the ROS 2 node graph and print its metrics",
        description="Start the plant, joint-sensor, F/T-sensor, MPC and PID nodes (each its own "
        "process, or all in this one with --single-process) and a metrics node, run the "
        "scenario in lockstep simulated time and print the study metrics, computed with the "
        "same code as the ROS-free runner. --real-time runs the loop nodes (plant, sensors, "
        "PID) composed in one process at 1 kHz on the wall clock and the MPC node in another "
        "at its own rate (ffmpc_ros/realtime.py). Both modes print the fraction of MPC and "
        "loop deadlines met, latency percentiles and the time in fallback; exit 1 when more "
        "than 1 % of either kind of deadline was missed or the loop fell back outside a "
        "--fault-window.",
    )
    run.add_argument(
        "scenario",
        help="a shipped scenario name or a scenario YAML path; 'impact': the safe-maximal-impact "
        "experiment (Dehio & Kheddar 2020) as a node graph (dice plant, sensors, impact planner, "
        "contact learner, impact controller; ffmpc_ros/impact_graph.py) with --approach, "
        "--regulation, --set (impact-study names and defaults: strategy touch_first), --duration, "
        "--record, --json; exit 1 when a joint limit was broken",
    )
    run.add_argument(
        "--approach", choices=("maximal", "baseline"), default=None, help="impact: approach"
    )
    run.add_argument(
        "--regulation",
        choices=("admittance", "ff_mpc"),
        default=None,
        help="impact: regulation after contact",
    )
    run.add_argument("--single-process", action="store_true", help="all nodes on one executor")
    run.add_argument(
        "--real-time", action="store_true", help="1 kHz loop and MPC on the wall clock"
    )
    run.add_argument(
        "--duration", type=positive_float, default=None, help="simulated s (default: task)"
    )
    run.add_argument("--formulation", choices=STUDY_FORMULATIONS, default=None)
    run.add_argument(
        "--seed",
        type=seed_int,
        default=None,
        help="scenario seed (impact: recorded only — the impact run draws no random number)",
    )
    run.add_argument("--set", action="append", metavar="NAME=VALUE", help="scenario override")
    run.add_argument("--timeout", type=positive_float, default=3600.0, help="wall-time limit, s")
    run.add_argument("--verbose", action="store_true", help="show the nodes' output")
    run.add_argument(
        "--record",
        metavar="PATH",
        type=new_path,
        help="record the run (every topic and parameter) to a bag: PATH.mcap is one MCAP file, "
        "any other PATH a rosbag2 folder (metadata.yaml + MCAP, as ros2 bag record writes)",
    )
    run.add_argument(
        "--view",
        action="store_true",
        help="lockstep: stream the run live to Foxglove (WebSocket on 127.0.0.1:--view-port): "
        "every topic, /tf, /robot_description, /view/markers, /mpc/prediction "
        "(ffmpc_ros/view.py; layout share/ffmpc_ros/foxglove/ffmpc_layout.json)",
    )
    run.add_argument(
        "--view-port",
        type=int,
        default=VIEW_PORT,
        help=f"port of the live view (default {VIEW_PORT}; a busy port is refused)",
    )
    run.add_argument(
        "--view-wait",
        action="store_true",
        help="start the run only once a Foxglove client subscribes to /plant/joint_states "
        "(--start-timeout still applies)",
    )
    run.add_argument(
        "--json",
        metavar="FILE",
        type=output_file,
        help="write the summary (metrics_true, metrics_measured, deadline_met_fraction, "
        "fallback_time_s, latency_p50/p99/max_ms, timing details) to FILE",
    )
    run.add_argument(
        "--cpus",
        metavar="LOOP,MPC",
        help="real time: pin the loop and the MPC process to these CPUs (default: the first "
        "two CPUs; 'none': no pinning)",
    )
    run.add_argument(
        "--priority",
        type=nonnegative_int,
        default=None,
        help="real time: SCHED_FIFO priority of both processes, 1-99 (default 80 where "
        "permitted: root or CAP_SYS_NICE; 0: normal scheduling)",
    )
    run.add_argument(
        "--fault-window",
        nargs=2,
        type=float,
        action="append",
        metavar=("START", "END"),
        help="simulated s of an injected fault: fallback inside it is excused (repeatable)",
    )
    run.add_argument(
        "--fault",
        action="append",
        metavar="KIND@T[+DURATION]",
        help="inject a fault at simulated T s for DURATION s (default: to the end), repeatable; "
        "kinds: mpc-dropout, sensor-dropout (the F/T sensor), future-stamp, nan-wrench, "
        "torque-spike, node-kill[:NODE] (default the MPC). Multi-process lockstep: all; "
        "--single-process: the message kinds; real time: none (exit 2). The JSON gains "
        "max_velocity_ratio, max_torque_ratio, safe_hold_s, faults and rejected_messages; "
        "exit 1 when a joint limit was broken (ffmpc_ros/fault_injector.py)",
    )
    run.add_argument(
        "--namespace",
        metavar="NS",
        default=None,
        help="run the whole graph under this ROS namespace (/arm1: topics /arm1/plant/..., "
        "clock /arm1/clock; every node, the recorder and the bring-up's own subscriptions): "
        "two graphs under different namespaces share one ROS domain (default: the root)",
    )
    run.add_argument(
        "--allow-foreign-publishers",
        action="store_true",
        help="start even if other nodes already publish on the graph's topics (default: "
        "refuse, naming them)",
    )
    run.add_argument(
        "--stall-timeout",
        type=float,
        default=30.0,
        help="lockstep: stop when no plant cycle came for this many wall s (default 30)",
    )
    run.add_argument(
        "--start-timeout",
        type=float,
        default=180.0,
        help="lockstep: stop when the first plant cycle has not come this many wall s after the "
        "start (default 180)",
    )
    run.add_argument(
        "--node-param",
        action="append",
        metavar="NODE:NAME:=VALUE",
        help="multi-process: one more ROS parameter of one node (after the generated file); "
        "shared parameters that then differ between nodes stop the run before it starts",
    )
    run.set_defaults(func=_cmd_run_guarded)
    from ffmpc_ros.bag.cli import add_bag_parser
    from ffmpc_ros.launch import add_launch_parser

    add_bag_parser(sub)
    add_launch_parser(sub)
    return parser


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text or type(exc).__name__


def main(argv: list[str] | None = None) -> int:
    """Run one ``ffmpc`` command. Malformed input (syntax, a bad value, a missing or existing
    file, a bag that is not a bag) → one line on stderr and exit 2, never a traceback; an
    unexpected failure → one line and exit 1 (``FFMPC_TRACEBACK=1`` shows the traceback)."""
    ensure_local_discovery()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse: --help (0) or a syntax error (2, already printed)
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    args.argv = list(sys.argv[1:] if argv is None else argv)
    words = ["ffmpc", args.command]
    for sub in ("study", "bench", "bag_command"):
        if getattr(args, sub, None):
            words.append(getattr(args, sub))
    prog = " ".join(words)
    try:
        return int(args.func(args) or 0)
    except (FfmpcError, OSError) as exc:  # bad input: a value, a path, a file's content
        print(f"{prog}: error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:  # a bug, not the input: say so on one line
        if os.environ.get("FFMPC_TRACEBACK"):
            raise
        print(
            f"{prog}: internal error: {type(exc).__name__}: {_one_line(exc)} "
            "(FFMPC_TRACEBACK=1 shows where)",
            file=sys.stderr,
        )
        return 1


if __name__ == "__main__":
    sys.exit(main())
