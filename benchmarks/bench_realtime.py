"""Execution models of the real-time mode (ffmpc_ros.realtime) on this machine, measured.

Runs ``polishing`` on the wall clock (MPC 500 Hz, loop 1 kHz) once per configuration of the
scheduling — normal or SCHED_FIFO, processes pinned to one core each or not — and prints, per
run, the fraction of MPC and loop deadlines met, the loop's cycle latency (p50/p99/max), the
MPC's measurement-to-command latency (p50/p99) and solve time (p50), and the time in fallback;
then the lockstep force error of the same scenario for reference. Every figure is measured
in this run; the machine's load is printed with them (shared machines are noisy: compare
configurations within one run).

    python benchmarks/bench_realtime.py [--duration 3] [--set mpc.formulation=classical]...
"""

from __future__ import annotations

import argparse
import os

from ffmpc_core.scenario import load_scenario
from ffmpc_ros.bringup import GraphOptions, run_graph
from ffmpc_ros.cli_args import parse_overrides
from studies.polishing import run_polishing

CONFIGS = (
    ("normal, not pinned", None, 0),
    ("normal, pinned", "auto", 0),
    ("SCHED_FIFO 80, not pinned", None, 80),
    ("SCHED_FIFO 80, pinned (default)", "auto", 80),
)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=3.0, help="simulated s per run")
    parser.add_argument("--scenario", default="polishing")
    parser.add_argument("--set", action="append", metavar="NAME=VALUE", default=[])
    parser.add_argument("--repeats", type=int, default=1, help="runs per configuration")
    args = parser.parse_args()
    scenario = load_scenario(args.scenario, parse_overrides(args.set))
    print(
        f"{args.scenario} {' '.join(args.set)} ({scenario.mpc.ocp.formulation}), "
        f"{args.duration:.1f} s per run, {os.cpu_count()} CPUs, load average "
        f"{' '.join(f'{x:.1f}' for x in os.getloadavg())}"
    )
    header = (
        f"{'configuration':34s} {'MPC met':>8s} {'loop met':>8s} {'cycle p50/p99/max ms':>22s} "
        f"{'MPC lat p50/p99 ms':>19s} {'solve p50':>9s} {'fallback s':>10s} {'E_λ N':>7s}"
    )
    print(header)
    for label, cpus, priority in CONFIGS:
        for _ in range(args.repeats):
            r = run_graph(
                scenario,
                GraphOptions(duration=args.duration, lockstep=False, cpus=cpus, priority=priority),
            )
            t = r.timing
            m = t["mpc"]
            fr = t["deadline_met_fraction"]

            def f(x, fmt=".3f"):
                return "n/a" if x is None else format(x, fmt)

            print(
                f"{label:34s} {f(fr['mpc'], '.4f'):>8s} {f(fr['loop'], '.4f'):>8s} "
                f"{f(t['latency_p50_ms'])}/{f(t['latency_p99_ms'])}/{f(t['latency_max_ms']):>7s} "
                f"{f(m['latency_p50_ms'])}/{f(m['latency_p99_ms']):>8s} "
                f"{f(m['solve_p50_ms']):>9s} {t['fallback_time_s']:10.3f} "
                f"{r.metrics_true.force_mae:7.2f}"
            )
    lock = run_polishing(scenario, duration=args.duration)
    print(
        f"lockstep (ROS-free runner, equal to the lockstep graph): E_λ "
        f"{lock.metrics_true.force_mae:.2f} N, E_P {lock.metrics_true.position_mae_mm:.2f} mm; "
        f"load average now {' '.join(f'{x:.1f}' for x in os.getloadavg())}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
