"""Timing of the impact planner cycle: the same as ``ffmpc bench impact`` (the logic lives in
:mod:`studies.bench_impact`). Usage:

    python benchmarks/bench_impact.py [--cycles 1000] [--warmup 50] [--sim-duration 1.2]
                                      [--json FILE]
"""

from __future__ import annotations

import argparse
import sys

from studies.bench_impact import run_bench_impact


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--cycles", type=int, default=1000)
    parser.add_argument("--warmup", type=int, default=50)
    parser.add_argument("--sim-duration", type=float, default=1.2)
    parser.add_argument("--json")
    return run_bench_impact(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
