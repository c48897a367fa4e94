"""``ffmpc bag``: info, play, plot, metrics, rerun, recover and record.

:func:`add_bag_parser` registers the subcommand on the ``ffmpc`` parser; every command imports
what it needs when it runs (building the parser imports nothing heavy).
"""

from __future__ import annotations

import argparse
import json


def _cmd_info(args: argparse.Namespace) -> int:
    from ffmpc_ros.bag.reader import BagReader

    with BagReader(args.bag) as bag:
        if args.json:
            print(
                json.dumps(
                    {
                        "path": str(bag.path),
                        "folder": None if bag.folder is None else str(bag.folder),
                        "size_bytes": bag.file_size,
                        "duration_s": bag.duration,
                        "start_ns": bag.start_time,
                        "end_ns": bag.end_time,
                        "messages": bag.message_count,
                        "topics": {
                            t.topic: {"type": t.type, "count": t.count} for t in bag.topics.values()
                        },
                        "parameters": sorted(bag.parameters),
                        "recovery": vars(bag.recovery) | {"describe": bag.recovery.describe()},
                    },
                    indent=2,
                )
            )
        else:
            print(bag.describe())
        return 0 if bag.recovery.complete else 3


def _output(path: str, args: argparse.Namespace, what: str) -> None:
    """An output of a bag command checked before anything runs (ffmpc_ros.preflight); with
    --force an existing file is removed just before it is written anew."""
    from ffmpc_ros import preflight

    preflight.check_output(path, force=args.force, what=what)
    preflight.check_distinct([(what, path)], [getattr(args, "bag", None)])


def _cmd_recover(args: argparse.Namespace) -> int:
    from ffmpc_ros import preflight
    from ffmpc_ros.bag.reader import recover_bag

    _output(args.out, args, "out")
    preflight.replace_forced(args.out, args.force)
    report = recover_bag(args.bag, args.out)
    print(f"{args.bag}: {report.describe()}")
    print(f"wrote {args.out}: {report.messages} messages")
    return 0


def usable_bag(path: str, command: str) -> int:
    """The number of messages of a complete bag that holds some: a truncated bag (a recorder
    killed mid-run) or an empty one is refused with what it holds (BagError, exit 2), so that
    ``play`` and ``rerun`` never report a success over a part of a run or over nothing."""
    from ffmpc_ros.bag.errors import BagError
    from ffmpc_ros.bag.reader import BagReader

    with BagReader(path) as bag:
        recovery = bag.recovery
        if not recovery.complete:
            raise BagError(
                f"{path}: TRUNCATED ({recovery.reason}): only {recovery.messages} readable "
                f"messages in {recovery.chunks} complete chunks; nothing {command} (`ffmpc bag "
                f"recover {path} OUT.mcap` copies them into a complete bag)"
            )
        if bag.message_count == 0:
            raise BagError(f"{path}: holds no message (0 messages); nothing {command}")
        return int(bag.message_count)


def _cmd_play(args: argparse.Namespace) -> int:
    from ffmpc_ros.bag.player import parse_remaps, play_bag

    remap = parse_remaps(args.remap or [])
    recorded = usable_bag(args.bag, "played")
    report = play_bag(
        args.bag,
        rate=args.rate,
        topics=args.topics,
        remap=remap,
        clock_rate=args.clock,
        delay=args.delay,
    )
    print(f"{report.describe()} ({recorded} messages in the bag)")
    return 0


def _cmd_metrics(args: argparse.Namespace) -> int:
    from ffmpc_ros.bag.analysis import bag_study

    study = bag_study(args.bag)
    summary = study.summary()
    if args.json:
        print(json.dumps(summary | {"matches_recorded": study.matches_recorded}, indent=2))
        return 0 if study.metrics_true is not None else 1
    if study.metrics_true is None or study.metrics_measured is None:  # (both or neither)
        print(
            f"{args.bag}: {study.recorded_cycles} of {study.cycles} cycles complete in the bag; "
            "no metrics (a truncated bag: plot it, or recover it)"
        )
        return 1
    print(f"{args.bag}: {study.formulation}, seed {study.seed}, {study.cycles} cycles")
    for label, m in (("true", study.metrics_true), ("measured", study.metrics_measured)):
        d = m.to_dict()
        print(
            f"  from the {label} force: E_P {d['position_mae_mm']:.3f} mm, "
            f"E_λ {d['force_mae']:.3f} N, λmax {d['max_force']:.2f} N, "
            f"t_break {d['contact_break_percent']:.1f} %, E_τ {d['torque_mae']}"
        )
    match = study.matches_recorded
    if match is not None:
        print(f"  equal to the /metrics/summary recorded in the bag: {match}")
    return 0


def _cmd_plot(args: argparse.Namespace) -> int:
    from ffmpc_ros.bag.analysis import bag_study, plot_study

    out = args.out or (str(args.bag).removesuffix(".mcap") + ".png")
    _output(out, args, "--out")
    study = bag_study(args.bag)
    from ffmpc_ros import preflight

    preflight.replace_forced(out, args.force)
    print(f"wrote {plot_study(study, out)}")
    return 0


def _cmd_rerun(args: argparse.Namespace) -> int:
    from ffmpc_ros.bag.rerun import RerunTolerance, rerun_node
    from ffmpc_ros.cli_args import parse_overrides

    tolerance = RerunTolerance(args.rtol, args.atol)
    overrides = parse_overrides(args.set, node_names=True)
    usable_bag(args.bag, "re-run")
    report = rerun_node(
        args.bag,
        args.node,
        overrides,
        timeout=args.timeout,
        tolerance=tolerance,
    )
    ok = report.identical if args.exact else report.ok
    if args.json:
        print(
            json.dumps(
                {
                    "node": report.node,
                    "identical": report.identical,
                    "reproduced": report.reproduced,
                    "same_machine": report.same_machine,
                    "ok": ok,
                    "tolerance": {"relative": tolerance.relative, "absolute": tolerance.absolute},
                    "cycles": report.cycles,
                    "compared": report.compared,
                    "shortfall": report.shortfall(),
                    "overrides": report.overrides,
                    "outputs": [
                        vars(c)
                        | {"ignored": list(c.ignored), "exact": c.exact, "reproduced": c.reproduced}
                        for c in report.outputs
                    ],
                },
                indent=2,
                default=float,
            )
        )
    else:
        print(report.describe())
    return 0 if ok else 1


def _cmd_record(args: argparse.Namespace) -> int:
    from ffmpc_ros import preflight
    from ffmpc_ros.bag.recorder import record_bag

    preflight.check_output(args.bag, force=args.force, what="bag")
    preflight.replace_forced(args.bag, args.force)
    recorder = record_bag(
        args.bag,
        topics=args.topics,
        duration=args.duration,
        use_sim_time=not args.wall_clock,
        writer_options={"flush_interval": args.flush_interval},
    )
    total = sum(recorder.received.values())
    print(f"recorded {total} messages on {len(recorder.received)} topics into {args.bag}")
    for topic, n in sorted(recorder.received.items()):
        print(f"  {topic}: {n}")
    return 0


def add_bag_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``ffmpc bag`` and its subcommands on the ``ffmpc`` subparsers."""
    from ffmpc_ros.cli_args import new_path, nonnegative_float, positive_float

    bag = sub.add_parser(
        "bag",
        help="bags of runs (one .mcap file or a rosbag2 folder): info, play, plot, metrics, "
        "rerun, recover, record",
        description="Bags are rosbag2-compatible MCAP files (ros2 bag, Foxglove, rosbags and "
        "mcap-ros2-support read them); `ffmpc run SCENARIO --record PATH` records a run with "
        "every topic and every node's parameters.",
    )
    bag_sub = bag.add_subparsers(dest="bag_command", required=True)

    p = bag_sub.add_parser(
        "info",
        help="topics, types, counts, duration, integrity",
        description="Print what a bag holds (like `ros2 bag info`), and for a truncated bag "
        "(a recorder killed mid-run) how much of it is readable. Exit 3 for a truncated bag.",
    )
    p.add_argument("bag")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=_cmd_info)

    p = bag_sub.add_parser(
        "play",
        help="republish a bag with its original timing",
        description="Republish the recorded messages at their recorded times (divided by "
        "--rate), /clock included, so nodes with use_sim_time follow the bag.",
    )
    p.add_argument("bag")
    p.add_argument("--rate", type=positive_float, default=1.0, help="speed factor (default 1)")
    p.add_argument("--topics", nargs="+", help="recorded topics to play (default: all)")
    p.add_argument(
        "--remap", action="append", metavar="FROM:=TO", help="publish a topic under another name"
    )
    p.add_argument(
        "--clock",
        type=positive_float,
        metavar="HZ",
        help="publish the bag's clock (/clock, or /NS/clock for a namespaced run) from the bag "
        "time at HZ instead",
    )
    p.add_argument(
        "--delay", type=nonnegative_float, default=0.5, help="wall s before the first message"
    )
    p.set_defaults(func=_cmd_play, needs_ros=True)

    p = bag_sub.add_parser(
        "plot",
        help="normal force, force reference and position error over time (PNG)",
        description="Rebuild the run's log from the bag with the metrics node's code and plot "
        "the true and measured normal force, the force reference and the tangential position "
        "error.",
    )
    p.add_argument("bag")
    p.add_argument("--out", type=new_path, help="PNG path, must not exist (default: BAG with .png)")
    p.add_argument("--force", action="store_true", help="replace an existing PNG")
    p.set_defaults(func=_cmd_plot, needs_ros=True)

    p = bag_sub.add_parser(
        "metrics",
        help="the study metrics computed from a bag",
        description="Feed the recorded topics to the metrics node (with the parameters it ran "
        "with, from the bag) and print the study metrics (E_P, E_λ, λmax, t_break, E_τ), and "
        "whether they equal the summary recorded in the bag.",
    )
    p.add_argument("bag")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=_cmd_metrics, needs_ros=True)

    p = bag_sub.add_parser(
        "rerun",
        help="feed one node the recorded inputs and compare its outputs",
        description="Rebuild one node with the parameters it ran with (plus --set changes), feed "
        "it the recorded inputs in lockstep and compare its outputs with the recorded ones, "
        "field by field. Exit 0 when they are bit-identical (on the machine that recorded the "
        "bag) or equal within the tolerance (elsewhere: other CPUs and BLAS kernels change the "
        "last bits), 1 when they differ.",
    )
    p.add_argument("bag")
    p.add_argument(
        "--node",
        default="mpc",
        choices=("mpc", "pid", "joint_sensor", "ft_sensor"),
        help="node to re-run (default mpc)",
    )
    p.add_argument(
        "--set",
        action="append",
        metavar="NAME=VALUE",
        help="parameter change, scenario or node name (repeatable), e.g. "
        "mpc.weights.force_feedback.force_phase=5",
    )
    p.add_argument(
        "--timeout", type=positive_float, default=10.0, help="wall s to wait at any one step"
    )
    p.add_argument(
        "--rtol",
        type=nonnegative_float,
        default=1e-6,
        help="relative tolerance per field (default 1e-6)",
    )
    p.add_argument(
        "--atol",
        type=nonnegative_float,
        default=1e-9,
        help="absolute tolerance per field (default 1e-9)",
    )
    p.add_argument(
        "--exact", action="store_true", help="require bit-identical outputs on any machine"
    )
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=_cmd_rerun, needs_ros=True)

    p = bag_sub.add_parser(
        "recover",
        help="copy what is readable of a truncated bag into a complete one",
        description="Read a bag up to its last complete chunk and write it as a new, complete "
        "bag that every MCAP tool opens.",
    )
    p.add_argument("bag")
    p.add_argument(
        "out", type=new_path, help="new bag path (must not exist; .mcap: a file, else a folder)"
    )
    p.add_argument("--force", action="store_true", help="replace an existing bag FILE")
    p.set_defaults(func=_cmd_recover)

    p = bag_sub.add_parser(
        "record",
        help="record a live graph (every topic, or --topics)",
        description="Record every topic of the graph on this ROS domain, with every node's "
        "parameters, until Ctrl-C or --duration wall seconds.",
    )
    p.add_argument(
        "bag", type=new_path, help="new bag path (must not exist; .mcap: a file, else a folder)"
    )
    p.add_argument("--topics", nargs="+", help="topics to record (default: all)")
    p.add_argument("--force", action="store_true", help="replace an existing bag FILE")
    p.add_argument("--duration", type=positive_float, help="wall seconds to record")
    p.add_argument("--wall-clock", action="store_true", help="log times on the system clock")
    p.add_argument(
        "--flush-interval",
        type=positive_float,
        default=1.0,
        help="wall s between chunk flushes: at most this much is lost if killed (default 1)",
    )
    p.set_defaults(func=_cmd_record, needs_ros=True)
