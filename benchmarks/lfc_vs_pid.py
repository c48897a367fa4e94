"""The MPC executed by the linear_feedback_controller's law against ffmpc's normal graph: the same
scenario, seed and MPC, two low levels (README, "MPC on a ros2_control robot").

* normal: the default graph (``mpc/command`` → ffmpc's torque PID → ``pid/motor_torque``);
* lfc: ros2_control's terms (``linear_feedback_controller/control`` → the LFC-law node,
  τ = τ_ff + K·(x₀ ⊖ x) at 1 kHz → ``effort_controller/commands``).

Both lockstep, single process; prints the true-force metrics of each run and their differences.

    python benchmarks/lfc_vs_pid.py [--seeds 0 1 2] [--duration 0 (the task's)]
"""

from __future__ import annotations

import argparse
import time

from ffmpc_core.scenario import load_scenario
from ffmpc_ros.bringup import GraphOptions, run_graph

NAMES = ("force_mae", "position_mae_mm", "max_force", "contact_break_percent", "torque_mae")


def _run(seed: int, duration: float | None, low_level: str) -> tuple[dict, dict, float]:
    scenario = load_scenario("polishing", {"seed": seed})
    interfaces = "ffmpc" if low_level == "pid" else "ros2_control"
    start = time.perf_counter()
    graph = run_graph(
        scenario,
        GraphOptions(
            duration=duration,
            single_process=True,
            timeout=3600,
            interfaces=interfaces,
            low_level=low_level,
        ),
    )
    safety = {
        "max_velocity_ratio": max(graph.safety["max_velocity_ratio"]),
        "safe_hold_s": graph.safety["safe_hold_s"],
        "rejected": sum(sum(v.values()) for v in graph.safety["rejected_messages"].values() if v),
    }
    return graph.metrics_true.to_dict(), safety, time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--duration", type=float, default=0.0, help="s (0: the task's)")
    args = parser.parse_args()
    duration = args.duration or None
    print("seed  graph   " + "  ".join(f"{n:>21}" for n in NAMES) + "  max|v|/limit  hold_s  rej")
    for seed in args.seeds:
        rows = {name: _run(seed, duration, name) for name in ("pid", "lfc")}
        for name, (metrics, safety, wall) in rows.items():
            values = "  ".join(f"{metrics[n]:>21.4f}" for n in NAMES)
            print(
                f"{seed:>4}  {('normal' if name == 'pid' else 'lfc'):<6}  {values}  "
                f"{safety['max_velocity_ratio']:>12.3f}  {safety['safe_hold_s']:>6.3f}  "
                f"{safety['rejected']:>3}   ({wall:.0f} s wall)"
            )
        ref, lfc = rows["pid"][0], rows["lfc"][0]
        diffs = "  ".join(f"{lfc[n] - ref[n]:>+21.4f}" for n in NAMES)
        print(f"{seed:>4}  {'lfc-n':<6}  {diffs}")


if __name__ == "__main__":
    main()
