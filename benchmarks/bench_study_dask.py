"""Wall time of one small polishing study in this process vs on a Dask LocalCluster.

The same grid (``--seeds`` seeds × three formulations × PID on/off, ``--duration`` s each, the
scenario's default when omitted) runs ``--repeats`` times each way, alternating, with no run
cache: in this process (``workers=1``, the reference) and on a LocalCluster of ``--workers``
spawned workers (cluster start-up included). Prints each wall time, the medians, their ratio,
and whether the runs (without their timings) are identical. Wall time: on a shared machine it
counts the waiting for a core too, so say what else ran.

    python benchmarks/bench_study_dask.py [--seeds 2] [--duration 1.0] [--workers 2]
"""

from __future__ import annotations

import argparse
import statistics
import time

from studies.study import execute_specs, grid_specs

FORMULATIONS = ("classical", "torque_feedback", "force_feedback")
#: Summary entries that are wall-clock measurements, not results.
TIMING = ("wall_time_s", "solve_time_median_s")


def _results(batch) -> list[dict]:
    return [
        {k: v for k, v in o.summary.items() if k not in TIMING} if o.ok else {"error": o.error}
        for o in batch.outcomes
    ]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=2, help="seeds of the grid")
    parser.add_argument("--duration", type=float, default=None, help="simulated s per run")
    parser.add_argument("--workers", type=int, default=2, help="LocalCluster workers")
    parser.add_argument("--repeats", type=int, default=1, help="timed studies each way")
    args = parser.parse_args()
    specs = grid_specs(
        "polishing", FORMULATIONS, (True, False), range(args.seeds), duration=args.duration
    )
    walls: dict[str, list[float]] = {"in-process": [], "LocalCluster": []}
    results: dict[str, list[dict]] = {}
    for _ in range(args.repeats):
        for name, workers in (("in-process", 1), ("LocalCluster", args.workers)):
            start = time.perf_counter()
            batch = execute_specs(specs, workers, progress=False)
            walls[name].append(time.perf_counter() - start)
            results[name] = _results(batch)
            print(
                f"{name:13} {len(specs)} runs, {batch.workers} worker(s): {walls[name][-1]:.1f} s"
            )
    local = statistics.median(walls["in-process"])
    cluster = statistics.median(walls["LocalCluster"])
    print(
        f"median wall time: in-process {local:.1f} s, LocalCluster({args.workers}) "
        f"{cluster:.1f} s, ratio in-process/cluster {local / cluster:.2f}"
    )
    same = results["in-process"] == results["LocalCluster"]
    print(f"runs identical (timings aside): {same}")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
