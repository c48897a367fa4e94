"""Speed of the ROS 2 node graph: real-time factor in lockstep (multi-process and
single-process, against the ROS-free runner on the same scenario) and the deadlines of the
real-time mode.

Real-time factor = simulated time / wall time of the stepping (from the plant's first step to
its last; start-up excluded, reported apart). Sensor-to-torque latency = wall time from the
plant publishing the state of cycle k to the plant receiving the motor torque of cycle k
(through joint sensor → [MPC] → PID), measured by the plant node.

    python benchmarks/bench_graph.py [--formulation classical] [--duration 1.0]
"""

from __future__ import annotations

import argparse
import os
import platform
import time

from ffmpc_core.scenario import load_scenario
from ffmpc_ros.bringup import GraphOptions, run_graph
from studies.polishing import run_polishing


def _latency(status: dict) -> str:
    ms = {k: 1e3 * status[f"latency_{k}"] for k in ("mean", "p50", "p99", "max")}
    return (
        f"latency mean {ms['mean']:.2f} ms, p50 {ms['p50']:.2f} ms, p99 {ms['p99']:.2f} ms, "
        f"max {ms['max']:.2f} ms over {status['latency_count']:.0f} commands"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="polishing")
    parser.add_argument("--formulation", default="classical")
    parser.add_argument("--duration", type=float, default=1.0, help="simulated s (lockstep)")
    parser.add_argument("--rt-duration", type=float, default=1.0, help="simulated s (real time)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    scenario = load_scenario(
        args.scenario, {"mpc.formulation": args.formulation, "seed": args.seed}
    )
    print(
        f"bench_graph: {args.scenario}, {args.formulation}, seed {args.seed}; "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores"
    )
    start = time.perf_counter()
    runner = run_polishing(scenario, duration=args.duration)
    wall = time.perf_counter() - start
    print(
        f"runner (ROS-free)        : {args.duration:.2f} s simulated in {wall:.2f} s "
        f"-> real-time factor {args.duration / wall:.3f}"
    )
    for single in (False, True):
        result = run_graph(scenario, GraphOptions(duration=args.duration, single_process=single))
        same = (result.metrics_true, result.metrics_measured) == (
            runner.metrics_true,
            runner.metrics_measured,
        )
        label = "single-process" if single else "multi-process "
        print(
            f"graph lockstep {label}: {args.duration:.2f} s simulated in {result.wall_time:.2f} s "
            f"-> real-time factor {result.real_time_factor:.3f} (start-up "
            f"{result.startup_time:.1f} s); metrics equal to the runner: {same}"
        )
        print(f"    {_latency(result.plant_status)}")
    result = run_graph(scenario, GraphOptions(duration=args.rt_duration, lockstep=False))
    t = result.timing
    print(
        f"graph real time (ffmpc_ros.realtime, default scheduling): {args.rt_duration:.2f} s in "
        f"{result.wall_time:.2f} s wall; deadlines met MPC "
        f"{t['deadline_met_fraction']['mpc']:.4f}, loop {t['deadline_met_fraction']['loop']:.4f}; "
        f"cycle latency p50 {t['latency_p50_ms']:.3f} ms, p99 {t['latency_p99_ms']:.3f} ms, "
        f"max {t['latency_max_ms']:.3f} ms; fallback {t['fallback_time_s']:.3f} s "
        "(python benchmarks/bench_realtime.py compares execution models)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
