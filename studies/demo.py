"""``ffmpc demo`` (``make demo``): what the stack does today, in about half a minute.

1. Each of the three MPC formulations presses the iiwa's tool and holds 50 N in closed loop with
   its own dynamics (perfect model): force reached, held error, solve time.
2. The force-feedback MPC polishes in PyBullet with the paper's imperfections (table tilt,
   actuation bias, friction, noise, sensing and OCP delays, torque PID), through the ROS 2 node
   graph (plant, joint and F/T sensor models, MPC, PID: separate processes, lockstep), and the
   same run through the ROS-free runner: the study's metrics, which must agree.
"""

from __future__ import annotations

import numpy as np

from ffmpc_core.config import FORMULATIONS, OcpConfig
from ffmpc_core.metrics import PolishingMetrics
from ffmpc_core.model_plant import run_model_closed_loop
from ffmpc_core.mpc import MpcConfig
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_core.selfcheck import require_sound_dynamics
from ffmpc_core.tasks import PolishingTask
from studies.polishing import run_polishing


def run_demo(seed: int = 0) -> int:
    robot = load_robot("iiwa")
    require_sound_dynamics(robot)
    p0 = robot.contact_placement(robot.q_nominal).translation
    task = PolishingTask.pressing(p0)
    print("1) Perfect model: each MPC against its own dynamics, ramp to 50 N in 0.3 s, hold 0.5 s")
    print(
        f"   {'formulation':16} {'force at end N':>14} {'max |err| held N':>17} "
        f"{'solve median ms':>16} {'iterations max':>15}"
    )
    for formulation in FORMULATIONS:
        log = run_model_closed_loop(
            robot, MpcConfig(ocp=OcpConfig(formulation=formulation)), task, task.duration
        )
        a = log.arrays()
        held = a["t"] > task.duration - 0.3
        err = np.abs(a["force"][held, -1] - 50.0).max()
        print(
            f"   {formulation:16} {a['force'][-1, -1]:>14.2f} {err:>17.3f} "
            f"{np.median(a['solve_time']) * 1e3:>16.2f} {max(a['iterations']):>15d}"
        )

    scenario = load_scenario("polishing", {"seed": seed})
    print(
        f"\n2) PyBullet polishing, force-feedback MPC, scenario '{scenario.name}', seed {seed}: "
        "50 N, 14 cm circle at 3 rad/s, tilt and actuation bias drawn from the seed, noise, "
        "delays, torque PID"
    )
    from ffmpc_ros.bringup import GraphOptions, run_graph  # rclpy loads only here

    graph = run_graph(scenario, GraphOptions(single_process=False))
    print(
        f"   ROS 2 graph, separate node processes, lockstep: simulated {graph.sim_time:.2f} s in "
        f"{graph.wall_time:.1f} s wall (real-time factor {graph.real_time_factor:.2f}), "
        f"start-up {graph.startup_time:.1f} s"
    )
    _print_metrics(graph.metrics_true, graph.metrics_measured)
    result = run_polishing(scenario)
    print(
        f"   ROS-free runner, same scenario and seed: {result.wall_time:.1f} s wall, table tilt "
        f"{np.rad2deg(result.draws.tilt_angle):+.2f} deg (unknown to the controller), "
        f"MPC solve median {result.solve_time_median * 1e3:.2f} ms"
    )
    _print_metrics(result.metrics_true, result.metrics_measured)
    same = result.metrics_true == graph.metrics_true
    print(f"   graph and runner metrics identical: {same}")
    return 0 if same else 1


def _print_metrics(true: PolishingMetrics, measured: PolishingMetrics) -> None:
    for label, m in (("true normal force", true), ("measured force", measured)):
        print(
            f"     from the {label:17}: E_P = {m.position_mae_mm:.2f} mm, "
            f"E_lambda = {m.force_mae:.2f} N, lambda_max = {m.max_force:.1f} N, "
            f"t_break = {m.contact_break_percent:.2f} %, E_tau = {m.torque_mae:.2f} N.m"
        )
