"""``ffmpc bench mpc``: solve time of each formulation, against crocoddyl's all-C++ classical model.

For every configuration (N = 5, Δt = 3 ms and N = 20, Δt = 10 ms, on the iiwa) each controller
runs in closed loop against its own dynamics (:mod:`ffmpc_core.model_plant`) through the same
pressing task — contact from t = 0, normal force ramped to 50 N and held, the tool drawing the
polishing circle — so every formulation solves the same sequence of problems from states it
really visits. The reference is the classical problem built from crocoddyl's C++ residuals only
(``builtin_residuals``), measured in the same run; ratios are medians over that median.
Figures are wall-clock on a shared machine: compare ratios, not absolute times, across runs.
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np

from ffmpc_core.model_plant import run_model_closed_loop
from ffmpc_core.mpc import MpcConfig
from ffmpc_core.robots import load_robot
from ffmpc_core.tasks import PolishingTask

CONFIGURATIONS = ((5, 0.003), (20, 0.010))
#: ``*_python``: the formulation with the Python reference action models (MpcConfig.backend);
#: the others use the default (native C++ where the formulation has one).
CASES = ("reference", "classical", "torque_feedback", "force_feedback", "force_feedback_python")


def _task(robot) -> PolishingTask:
    p0 = robot.contact_placement(robot.q_nominal).translation
    return PolishingTask.pressing(p0, force_ramp=0.1, circle=10.0, stop=0.0)


def bench_case(case: str, horizon: int, dt: float, solves: int) -> dict:
    """Closed-loop solves of one case; returns solve-time and iteration statistics."""
    robot = load_robot("iiwa")
    backend = "python" if case.endswith("_python") else "native"
    formulation = "classical" if case == "reference" else case.removesuffix("_python")
    config = MpcConfig(formulation=formulation, horizon=horizon, dt=dt, backend=backend)
    factory = None
    if case == "reference":
        from ffmpc_core.rigid_contact import make_rigid_contact_node

        def factory(terminal: bool):
            return make_rigid_contact_node(
                robot, config.contact, config.weights, dt, terminal, builtin_residuals=True
            )

    task = _task(robot)
    log = run_model_closed_loop(
        robot, config, task, duration=solves * config.period, node_factory=factory
    )
    times = np.asarray(log.solve_time[1:])  # the first solve starts cold
    iters = np.asarray(log.iterations[1:])
    return {
        "case": case,
        "horizon": horizon,
        "dt": dt,
        "solves": int(times.size),
        "median_ms": float(np.median(times) * 1e3),
        "p90_ms": float(np.percentile(times, 90) * 1e3),
        "iterations_median": float(np.median(iters)),
        "iterations_max": int(iters.max()),
        "final_force_N": float(log.force[-1][-1]),
    }


def run_bench_mpc(args: argparse.Namespace) -> int:
    print(
        f"ffmpc bench mpc — iiwa, {args.solves} closed-loop solves per case, "
        f"{platform.processor() or platform.machine()}, {time.strftime('%Y-%m-%d %H:%M')}"
    )
    header = (
        f"{'N':>3} {'dt ms':>5}  {'formulation':21} {'median ms':>9} {'p90 ms':>7} "
        f"{'iters med':>9} {'iters max':>9} {'ratio':>6} {'force N':>8}"
    )
    for horizon, dt in CONFIGURATIONS:
        print(header)
        rows = [bench_case(case, horizon, dt, args.solves) for case in CASES]
        ref = rows[0]["median_ms"]
        for r in rows:
            print(
                f"{horizon:>3} {dt * 1e3:>5.0f}  {r['case']:21} {r['median_ms']:>9.3f} "
                f"{r['p90_ms']:>7.3f} {r['iterations_median']:>9.1f} {r['iterations_max']:>9d} "
                f"{r['median_ms'] / ref:>6.2f} {r['final_force_N']:>8.2f}"
            )
        print()
    print(
        "ratio = median solve time / median of 'reference' (crocoddyl's all-C++ classical "
        "model, same task, same run). 'force N' = normal force at the end of the run."
    )
    return 0
