"""How far the MPC's δo prediction lands from the real tool, and how far the tool lags the
circle, with and without the table's friction in the predictor (README, "The delay predictor and
the table's friction").

Per run (``polishing`` scenario, PyBullet, ROS-free runner) it prints E_λ (N), E_P (mm), the mean
distance in the table plane between the tool at each solve's predicted state and the real tool
δo later (mm, over the circle), the time shift of the reference that fits the tool best (the
lag, ms) and the largest joint speed over its limit. ``--clean`` removes what the predictor
cannot know (joint friction, actuation bias and noise, sensing noise and delays, actuation
delay), so the prediction error left is the model's.

    python benchmarks/predictor_friction.py --seeds 100 --clean
    python benchmarks/predictor_friction.py --seeds 100 101 102 103 104 --workers 2 \
        --set-file benchmarks/results/tune/train1000-1002/speed_penalty/tuned_weights.yaml
"""

from __future__ import annotations

import argparse
import itertools
from concurrent.futures import ProcessPoolExecutor
from typing import Any

import numpy as np
import yaml

from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from studies.polishing import PREDICTABLE_PLANT, prediction_offsets, run_polishing

MAX_LAG_MS = 60


def one_run(overrides: dict[str, Any]) -> dict[str, float]:
    """One run's figures (module docstring)."""
    scenario = load_scenario("polishing", overrides)
    result = run_polishing(scenario)
    log = result.log
    t, position, reference = log["t"], log["ee_position"][:, :2], log["ee_reference"][:, :2]
    dt = scenario.plant.time_step
    circle = np.flatnonzero((t > 1.2) & (t < t[-1] - 0.6))
    solves, offsets = prediction_offsets(result, load_robot(scenario.robot))
    ahead = offsets[(solves > t[circle[0]]) & (solves < t[circle[-1]])]
    fits = [
        np.mean(np.linalg.norm(position[circle] - reference[circle - lag], axis=1))
        for lag in range(MAX_LAG_MS)
    ]
    return {
        "force_mae": result.metrics_true.force_mae,
        "position_mae_mm": result.metrics_true.position_mae_mm,
        "prediction_ahead_mm": 1e3 * float(np.mean(ahead)) if ahead.size else float("nan"),
        "lag_ms": float(np.argmin(fits)) * dt * 1e3,
        "max_velocity_ratio": float(np.max(result.max_velocity_ratio)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[100])
    parser.add_argument(
        "--formulations", nargs="+", default=["classical", "torque_feedback", "force_feedback"]
    )
    parser.add_argument("--friction", type=float, nargs="+", default=[0.0, 0.5])
    parser.add_argument("--command-delay", type=float, default=0.005, help="δo, s")
    parser.add_argument("--clean", action="store_true", help="the predictor's unknowns removed")
    parser.add_argument("--set-file", help="YAML NAME: VALUE overrides (e.g. tuned weights)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    parser.add_argument("--workers", type=int, default=1)
    args = parser.parse_args()
    base: dict[str, Any] = dict(PREDICTABLE_PLANT) if args.clean else {}
    if args.set_file:
        with open(args.set_file) as f:
            base.update(yaml.safe_load(f))
    for item in args.set:
        name, _, value = item.partition("=")
        base[name] = yaml.safe_load(value)
    grid = list(itertools.product(args.formulations, args.friction, args.seeds))
    jobs = [
        {
            **base,
            "mpc.formulation": form,
            "mpc.contact.friction_coefficient": mu,
            "mpc.command_delay": args.command_delay,
            "seed": seed,
        }
        for form, mu, seed in grid
    ]
    with ProcessPoolExecutor(args.workers) as pool:
        results = list(pool.map(one_run, jobs))
    print(
        f"δo = {1e3 * args.command_delay:g} ms, seeds {args.seeds}, "
        f"{'clean plant' if args.clean else 'full simulation'}; means over the seeds"
    )
    print("| formulation | μ | E_λ (N) | E_P (mm) | prediction ahead (mm) | lag (ms) | runs over |")
    print("|---|---|---|---|---|---|---|")
    for form, mu in itertools.product(args.formulations, args.friction):
        rows = [r for (f, m, _), r in zip(grid, results, strict=True) if (f, m) == (form, mu)]

        def mean(key: str, rows: list[dict[str, float]] = rows) -> float:
            return float(np.mean([r[key] for r in rows]))

        over = sum(r["max_velocity_ratio"] > 1.0 for r in rows)
        largest = max(r["max_velocity_ratio"] for r in rows)
        print(
            f"| {form} | {mu:g} | {mean('force_mae'):.2f} | {mean('position_mae_mm'):.2f} | "
            f"{mean('prediction_ahead_mm'):.2f} | {mean('lag_ms'):.1f} | "
            f"{over}/{len(rows)} ({largest:.2f}) |"
        )


if __name__ == "__main__":
    main()
