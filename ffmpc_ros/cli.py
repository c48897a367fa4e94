"""``ffmpc``: the one command-line entry point. Every subcommand has ``--help``.

Subcommands import what they need lazily, so ``ffmpc check`` works even where ROS or PyBullet
would fail to load.
"""

from __future__ import annotations

import argparse
import sys

from ffmpc_core.errors import FfmpcError


def _cmd_check(args: argparse.Namespace) -> int:
    import numpy as np

    from ffmpc_core.robots import ROBOT_NAMES, load_robot
    from ffmpc_core.selfcheck import (
        check_crocoddyl_dynamics,
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
    for robot_name in ROBOT_NAMES:
        result = check_crocoddyl_dynamics(load_robot(robot_name), rng, samples=args.samples)
        verdict = "ok" if result.ok else "FAILED"
        print(
            f"crocoddyl free dynamics vs pin.aba on {robot_name}: max |Δq̈| = "
            f"{result.max_error:.2e} rad/s² over {result.samples} states "
            f"(tolerance {result.tolerance:g}): {verdict}"
        )
        status |= 0 if result.ok else 1
    return status


def _cmd_bench_mpc(args: argparse.Namespace) -> int:
    from ffmpc_core.bench_mpc import run_bench_mpc

    return run_bench_mpc(args)


def _cmd_demo(args: argparse.Namespace) -> int:
    from sim_bridge.demo import run_demo

    return run_demo(seed=args.seed)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
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
    check.add_argument("--samples", type=int, default=20, help="random states per robot")
    check.add_argument("--seed", type=int, default=0, help="seed of the random states")
    check.set_defaults(func=_cmd_check)

    demo = sub.add_parser(
        "demo",
        help="run the main demo",
        description="Run the main demo: the three MPC formulations hold 50 N in closed loop with "
        "their own dynamics, then the force-feedback MPC polishes in PyBullet with the paper's "
        "imperfections; prints forces, solve times and the study's metrics.",
    )
    demo.add_argument("--seed", type=int, default=0)
    demo.set_defaults(func=_cmd_demo)

    bench = sub.add_parser("bench", help="benchmarks that print their figures")
    bench_sub = bench.add_subparsers(dest="bench", required=True)
    bench_mpc = bench_sub.add_parser(
        "mpc",
        help="MPC solve time per formulation",
        description="Median and p90 solve time and iterations of each formulation on the iiwa, "
        "at N=5, dt=3 ms and N=20, dt=10 ms, and the ratio to crocoddyl's built-in classical "
        "contact model on the same problem, measured in the same run.",
    )
    bench_mpc.add_argument("--solves", type=int, default=200, help="solves per configuration")
    bench_mpc.add_argument("--seed", type=int, default=0)
    bench_mpc.set_defaults(func=_cmd_bench_mpc)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except FfmpcError as exc:
        print(f"ffmpc {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
