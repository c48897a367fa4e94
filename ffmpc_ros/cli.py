"""``ffmpc``: the one command-line entry point. Every subcommand has ``--help``.

Subcommands import what they need lazily, so ``ffmpc check`` works even where ROS or PyBullet
would fail to load. The commands of the layer above (``ffmpc study ...``, ``ffmpc tune``,
``ffmpc bench impact``: ``studies/cli.py``) are entry points found at start-up
(:mod:`ffmpc_ros.cli_extensions`, as ros2cli's command extensions): this package never imports
``studies``.
"""

from __future__ import annotations

import argparse
import os
import sys
from types import FrameType
from typing import TYPE_CHECKING

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_ros.cli_args import (
    PLANT_ENGINE_PARAMETER,
    STUDY_FORMULATIONS,
    add_plant_argument,
    finite_float,
    new_path,
    nonnegative_int,
    output_file,
    port_int,
    positive_float,
    positive_int,
    seed_int,
    with_plant_engine,
)
from ffmpc_ros.cli_args import parse_overrides as _parse_overrides
from ffmpc_ros.cli_extensions import BENCH_GROUP, COMMAND_GROUP, add_extension_parsers
from ffmpc_ros.discovery import check_ros_environment, ensure_local_discovery

if TYPE_CHECKING:
    from ffmpc_core.scenario import Scenario

#: Exit status of every malformed input (argparse's own for syntax errors).
EXIT_USAGE = 2
#: Exit status of ``ffmpc run`` when the robot's own reflex stopped it (a data-sheet limit it
#: stops on, or commands missing; ``ffmpc_core.reflex``) in a run without an injected fault:
#: the run was aborted, as on the real robot. With ``--fault``, a reflex stop is a safe
#: outcome (exit 0, said on stderr).
EXIT_ABORTED = 3
#: Default port of ``ffmpc run --view`` (ffmpc_ros.view.DEFAULT_PORT).
VIEW_PORT = 8765
#: The commands of this package; an entry point of ``ffmpc.command`` may not take these names.
BUILT_IN_COMMANDS = ("check", "bench", "run", "bag", "launch")


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

    from ffmpc_ros import preflight
    from ffmpc_ros.impact_graph import run_impact_graph
    from ffmpc_ros.topics import normalize_namespace

    given = [flag for dest, flag in POLISHING_ONLY.items() if getattr(args, dest, None)]
    if given:
        raise ConfigError(f"{', '.join(given)}: polishing-graph options (not for ffmpc run impact)")
    overrides = list(args.set or [])  # the study's defaults (strategy strike_first)
    if args.plant is not None:
        if any(item.partition("=")[0].strip() == PLANT_ENGINE_PARAMETER for item in overrides):
            raise ConfigError(f"--plant and --set {PLANT_ENGINE_PARAMETER}: give one")
        overrides.append(f"{PLANT_ENGINE_PARAMETER}={args.plant}")
    if args.duration is not None:
        overrides.append(f"duration={args.duration!r}")
    try:
        namespace = normalize_namespace(args.namespace)
    except ConfigError as exc:
        raise ConfigError(f"--namespace: {exc}") from None
    _check_run_outputs(args, [])
    from ffmpc_ros.impact_graph import impact_node_parameters

    impact_node_parameters(  # the study's overrides, checked before any node starts
        args.approach or "maximal",
        args.regulation or "admittance",
        "impact",
        overrides,
        args.record is not None,
        namespace,
    )
    preflight.replace_forced(args.record, args.force)
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
    event = result.reflex_event
    if event is not None:
        head = "ABORTED: the robot stopped itself" if result.aborted else "reflex off"
        print(f"{head}: {event['message']}", file=sys.stderr)
    if result.aborted:
        return EXIT_ABORTED
    return 0 if result.safe else 1


def _run_options(args: argparse.Namespace) -> dict:
    """``ffmpc run`` (polishing graph): every option checked, before anything starts
    (ConfigError, one line): the scenario and its overrides, the real-time and view options,
    the faults against the graph and the run's duration, the per-node parameters, the output
    paths. Returns the keyword arguments of ``run_graph`` that need checking."""
    from ffmpc_core.faults import parse_fault
    from ffmpc_core.scenario import load_scenario
    from ffmpc_ros import preflight
    from ffmpc_ros.graph_nodes import NODES
    from ffmpc_ros.topics import normalize_namespace

    given = [flag for dest, flag in IMPACT_ONLY.items() if getattr(args, dest, None)]
    if given:
        raise ConfigError(f"{', '.join(given)}: options of ffmpc run impact only")
    overrides = with_plant_engine(_parse_overrides(args.set), args.plant)
    if args.formulation:
        overrides["mpc.formulation"] = args.formulation
    if args.seed is not None:
        overrides["seed"] = args.seed
    scenario = load_scenario(args.scenario, overrides)
    cpus: str | tuple[int, int] | None = "auto"
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
    if args.view and args.real_time:
        raise ConfigError("--view is a lockstep option (the real-time loop has no view)")
    if args.real_time and (args.single_process or args.record):
        raise ConfigError("--single-process and --record are lockstep options (not --real-time)")
    faults = [parse_fault(text) for text in args.fault or []]
    node_ros_args = _node_ros_args(args.node_param or [], args)
    for flag, value in (
        ("--stall-timeout", args.stall_timeout),
        ("--start-timeout", args.start_timeout),
    ):
        if value <= 0:
            raise ConfigError(f"{flag} must be > 0 s, got {value}")
    try:
        namespace = normalize_namespace(args.namespace)
    except ConfigError as exc:
        raise ConfigError(f"--namespace: {exc}") from None
    duration = args.duration if args.duration is not None else _task_duration(scenario)
    preflight.check_faults(
        faults,
        duration=duration,
        nodes=NODES,
        single_process=args.single_process,
        lockstep=not args.real_time,
    )
    windows = [tuple(w) for w in args.fault_window or []]
    preflight.check_fault_windows(windows, duration)
    _check_run_outputs(args, [args.scenario])
    if args.view:
        from ffmpc_ros.view import check_port_free

        check_port_free("127.0.0.1", args.view_port)
    return {
        "scenario": scenario,
        "faults": faults,
        "node_ros_args": node_ros_args,
        "namespace": namespace,
        "cpus": cpus,
        "fault_windows": windows,
    }


def _task_duration(scenario: Scenario) -> float:
    """The simulated s of the scenario's task (what a run without --duration lasts)."""
    from ffmpc_core.polishing import build_task
    from ffmpc_core.robots import load_robot

    return float(build_task(scenario, load_robot(scenario.robot)).duration)


def _node_ros_args(items: list[str], args: argparse.Namespace) -> dict[str, list[str]]:
    """``--node-param NODE:NAME:=VALUE`` as ROS arguments per node, each value checked by the
    node's own rules (:func:`ffmpc_ros.params.check_node_parameter`) before any node starts."""
    import yaml

    from ffmpc_core.values import load_yaml
    from ffmpc_ros.graph_nodes import NODES
    from ffmpc_ros.params import check_node_parameter

    real_time_foreign = args.real_time and any(not i.startswith("mpc:") for i in items)
    if items and (args.single_process or real_time_foreign):
        raise ConfigError(
            "--node-param needs the multi-process graph (with --real-time: the mpc node's only)"
        )
    out: dict[str, list[str]] = {}
    for item in items:
        node, sep, assignment = item.partition(":")
        name, eq, text = assignment.partition(":=")
        if not sep or not eq or not name:
            raise ConfigError(f"--node-param expects NODE:NAME:=VALUE, got {item!r}")
        if node not in NODES:
            raise ConfigError(
                f"--node-param {item!r}: no node {node!r} (nodes: {', '.join(NODES)})"
            )
        try:  # as rcl reads `-p NAME:=VALUE` (a list of one type, ffmpc_core.values)
            check_node_parameter(node, name, load_yaml(text))
        except yaml.YAMLError:
            raise ConfigError(f"--node-param {item!r}: {text!r} is not a YAML value") from None
        except ConfigError as exc:
            raise ConfigError(f"--node-param {item!r}: {exc}") from None
        out.setdefault(node, []).extend(["-p", assignment])
    return out


def _check_run_outputs(args: argparse.Namespace, inputs: list[str]) -> None:
    """``--json`` and ``--record``: new paths in writable directories (an existing one only with
    --force, then a file), neither the other nor an input."""
    from ffmpc_ros import preflight

    for flag, path in (("--json", args.json), ("--record", args.record)):
        if path is not None:
            preflight.check_output(path, force=args.force, what=flag)
    preflight.check_distinct((("--json", args.json), ("--record", args.record)), inputs)


def _cmd_run(args: argparse.Namespace) -> int:
    import json
    import shlex

    from ffmpc_ros import preflight
    from ffmpc_ros.bringup import GraphOptions, run_graph

    if args.scenario == "impact":
        return _cmd_run_impact(args)
    checked = _run_options(args)
    scenario = checked["scenario"]
    if args.view:
        print(
            f"live view: Foxglove WebSocket server on ws://127.0.0.1:{args.view_port} until "
            "the run ends (Foxglove: Open connection > Foxglove WebSocket; layout "
            f"{_view_layout()})",
            file=sys.stderr,
            flush=True,
        )
    if scenario.mpc.command_delay == "measured":
        from ffmpc_core.polishing import resolve_command_delay

        scenario, record = resolve_command_delay(scenario)
        print(
            f"mpc.command_delay measured: δo = {record['delta_o_s'] * 1e3:.0f} ms",
            file=sys.stderr,
            flush=True,
        )
    preflight.replace_forced(args.record, args.force)
    result = run_graph(
        scenario,
        GraphOptions(
            faults=checked["faults"],
            allow_foreign=args.allow_foreign_publishers,
            stall_timeout=args.stall_timeout,
            start_timeout=args.start_timeout,
            node_ros_args=checked["node_ros_args"],
            duration=args.duration,
            single_process=args.single_process,
            lockstep=not args.real_time,
            timeout=args.timeout,
            quiet=not args.verbose,
            record=args.record,
            fault_windows=checked["fault_windows"],
            cpus=checked["cpus"],
            priority=args.priority,
            view=args.view_port if args.view else None,
            view_wait=args.view_wait,
            namespace=checked["namespace"],
            interfaces=args.interfaces,
            low_level=args.low_level,
        ),
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

    def shown(value: float | None, fmt: str) -> str:
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
    return _run_verdict(summary, result.reflex_event, result.aborted, failures, limits)


def _run_verdict(
    summary: dict, event: dict | None, aborted: bool, failures: list[str], limits: list[str]
) -> int:
    """The exit status of ``ffmpc run`` (printing the reflex and fault lines): a run a reflex
    aborted → :data:`EXIT_ABORTED`, unless faults were injected (a reflex stop is then a safe
    outcome: 0); a fault run is judged on its safety (timing failures reported), others on
    timing and limits (1)."""
    if event is not None:
        head = "ABORTED: the robot stopped itself" if aborted else "reflex off"
        print(f"{head}: {event['message']}", file=sys.stderr)
    if summary.get("faults"):
        ratios = (max(summary["max_velocity_ratio"]), max(summary["max_torque_ratio"]))
        if aborted:
            assert event is not None
            verdict = f"handled safely: the robot's own {event['kind']} reflex stopped it"
        else:
            verdict = "broke a joint limit" if limits else "handled safely"
        print(
            f"faults {', '.join(f['fault'] for f in summary['faults'])}: {verdict} (max "
            f"|q̇|/limit {ratios[0]:.3f}, max |τ|/limit {ratios[1]:.3f}, safe hold "
            f"{summary['safe_hold_s']:.3f} s)",
            file=sys.stderr,
        )
        if failures:  # the verdict of a fault run is its safety
            print(
                "(timing failures of a fault run are reported, not the exit status)",
                file=sys.stderr,
            )
        return 1 if limits and not aborted else 0
    if aborted:
        return EXIT_ABORTED
    return 1 if failures or limits else 0


def _cmd_run_guarded(args: argparse.Namespace) -> int:
    """``ffmpc run`` with clean stops: Ctrl-C (SIGINT) and SIGTERM stop every node, close the
    bag and print one line (exit 130 and 143). The handler only records the request; the
    bring-up's loop raises ``RunInterrupted`` outside every ROS callback."""
    import signal

    from ffmpc_ros.bringup import RunInterrupted, request_stop

    def terminate(signum: int, _frame: FrameType | None) -> None:
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

    bench = sub.add_parser("bench", help="benchmarks that print their figures")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    add_extension_parsers(bench_sub, BENCH_GROUP, reserved=bench_sub.choices)

    # ffmpc study, ffmpc tune, ...: the commands of the packages above (studies/cli.py)
    add_extension_parsers(sub, COMMAND_GROUP, reserved=BUILT_IN_COMMANDS)
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
        "--fault-window. The robot's own reflexes are on (plant.reflex): a joint over a "
        f"data-sheet limit it stops on, or commands missing, stops it and aborts the run: exit "
        f"{EXIT_ABORTED} (with --fault: a safe outcome, exit 0); the JSON has 'aborted' and "
        "'reflex'.",
    )
    run.add_argument(
        "scenario",
        help="a shipped scenario name or a scenario YAML path; 'impact': the safe-maximal-impact "
        "experiment (Dehio & Kheddar 2020) as a node graph (dice plant, sensors, impact planner, "
        "contact learner, impact controller; ffmpc_ros/impact_graph.py) with --approach, "
        "--regulation, --set (impact-study names and defaults: strategy strike_first), --duration, "
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
    add_plant_argument(run)
    run.add_argument(
        "--seed",
        type=seed_int,
        default=None,
        help="scenario seed (impact: recorded only — the impact run draws no random number)",
    )
    run.add_argument("--set", action="append", metavar="NAME=VALUE", help="scenario override")
    run.add_argument("--timeout", type=positive_float, default=3600.0, help="wall-time limit, s")
    run.add_argument(
        "--force",
        action="store_true",
        help="replace an existing --json or --record FILE (a directory is never replaced)",
    )
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
        type=port_int,
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
        type=finite_float,
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
        "exit 1 when a joint limit was broken, 0 when the robot's own reflex stopped it (a "
        "safe outcome) (ffmpc_ros/fault_injector.py)",
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
        "--interfaces",
        choices=("ffmpc", "ros2_control"),
        default="ffmpc",
        help="the topics between MPC, low level and plant: ffmpc's own (default) or "
        "ros2_control's terms (linear_feedback_controller_msgs Control/Sensor, the effort "
        "command topic effort_controller/commands, joint_states; lockstep only)",
    )
    run.add_argument(
        "--low-level",
        choices=("pid", "lfc"),
        default="pid",
        help="the low-level node: ffmpc's torque PID (default) or lfc, the "
        "linear_feedback_controller's law tau = ff + K (x0 - x) (needs --interfaces ros2_control)",
    )
    run.add_argument(
        "--allow-foreign-publishers",
        action="store_true",
        help="start even if other nodes already publish on the graph's topics (default: "
        "refuse, naming them)",
    )
    run.add_argument(
        "--stall-timeout",
        type=positive_float,
        default=30.0,
        help="lockstep: stop when no plant cycle came for this many wall s (default 30)",
    )
    run.add_argument(
        "--start-timeout",
        type=positive_float,
        default=180.0,
        help="lockstep: stop when the first plant cycle has not come this many wall s after the "
        "start (default 180)",
    )
    run.add_argument(
        "--node-param",
        action="append",
        metavar="NODE:NAME:=VALUE",
        help="multi-process: one more ROS parameter of one node (after the generated file); "
        "shared parameters that then differ between nodes stop the run before it starts; "
        "--real-time: the mpc node's only (e.g. mpc:real_time_iterations:=0)",
    )
    run.set_defaults(func=_cmd_run_guarded, needs_ros=True)
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
    # an extension's sub-command (ffmpc study impact) names its dest (cli_extensions)
    for sub in ("bench", "bag_command", getattr(args, "verb_dest_", None)):
        if sub and getattr(args, sub, None):
            words.append(getattr(args, sub))
    prog = " ".join(words)
    try:
        if getattr(args, "needs_ros", False):  # before anything starts (ffmpc_ros.preflight)
            check_ros_environment()
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
