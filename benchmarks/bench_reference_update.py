"""Cost of the MPC step outside the solve: the nodes' reference updates and the warm start.

For each formulation at N = 5, Δt = 3 ms and N = 20, Δt = 10 ms (iiwa, the pressing-and-circling
task of ``ffmpc bench mpc``), the MPC takes one real step, then its reference update
(``_update_references``: the schedule writes every node's reference, the nodes update in place)
and its warm start are timed ``--steps`` times at successive instants. Times are the calling
thread's CPU time (``time.thread_time``), medians in ms: on a shared machine they measure the
work, not the waiting for a core. Run it on two checkouts to compare them.

    python benchmarks/bench_reference_update.py [--steps 300]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from ffmpc_core.config import OcpConfig
from ffmpc_core.model_plant import ModelPlant
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig
from ffmpc_core.robots import load_robot
from ffmpc_core.tasks import PolishingTask

CONFIGURATIONS = ((5, 0.003), (20, 0.010))
FORMULATIONS = ("classical", "torque_feedback", "force_feedback")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=300, help="timed updates per case")
    args = parser.parse_args()
    robot = load_robot("iiwa")
    p0 = robot.contact_placement(robot.q_nominal).translation
    print(f"{'formulation':16} {'N':>3} {'update ms':>9} {'warm start ms':>13}  (thread CPU time)")
    for formulation in FORMULATIONS:
        for horizon, dt in CONFIGURATIONS:
            config = MpcConfig(ocp=OcpConfig(formulation=formulation, horizon=horizon, dt=dt))
            task = PolishingTask.pressing(p0, force_ramp=0.1, circle=10.0, stop=0.0)
            mpc = ModelPredictiveController(robot, config, task)
            plant = ModelPlant(robot, formulation, config.contact)
            plant.reset(robot.q_nominal)
            measurement = plant.measurement()
            mpc.step(measurement, 0.0)
            update, warm = [], []
            for k in range(args.steps):
                t = config.ocp.period * (k + 1)
                x0 = mpc.predict(mpc.state_from(measurement), t)
                a = time.thread_time()
                mpc._update_references(t)
                b = time.thread_time()
                mpc._warm_start(x0, t)
                c = time.thread_time()
                update.append(b - a)
                warm.append(c - b)
                mpc._prev_t = t
            print(
                f"{formulation:16} {horizon:>3} {np.median(update) * 1e3:>9.3f} "
                f"{np.median(warm) * 1e3:>13.3f}"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
