"""The ROS-free closed loop of the paper's simulation study (Fig. 2), in lockstep simulated time.

One plant cycle (``plant.time_step``, 1 ms by default) does, in this order:

1. read the true plant state at t;
2. sensing (eq 30, 32): q̂, q̇̂, λ̂ = true values δs cycles ago + noise;
3. every ``mpc.period`` (500 Hz): the MPC solves from (q̂, q̇̂, λ̂ or τ̂) and gives τ*;
4. the low-level loop (``ffmpc_core.lowlevel.LowLevelController``, the same class as the ROS
   PID node) sets τ^d: with the MPC on time, τ* (and with ``riccati_feedback`` τ* + G·(x̂ −
   x̂_solve) on the cycles in between) — its hold/blend/fallback never engage; the torque PID
   (eq 33) turns τ^d (delayed by δo) and the last measured torque τ̂ into τ^m;
5. actuation (eq 31): τ̂ = a·τ^m(t − δs) + b − friction + noise, applied to the plant and
   measured (it is what the next cycle's PID and torque-feedback MPC see);
6. the plant advances one step.

Nothing reads a clock and every random number comes from generators seeded by the scenario's
seed, so a run is a pure function of (scenario, seed). The ROS node graph reproduces this order.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field

import numpy as np

from ffmpc_core.errors import ConfigError  # noqa: F401  (re-exported for callers)
from ffmpc_core.lowlevel import LowLevelMeasurement
from ffmpc_core.metrics import PolishingMetrics
from ffmpc_core.mpc import ModelPredictiveController, MpcMeasurement
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import Scenario
from ffmpc_core.study import (
    RunDraws,
    StudyLog,
    actuation_model,
    build_task,
    command_delay,
    draw_run,
    force_sensing_model,
    joint_sensing_model,
    lowlevel_controller,
    measured_force,
    mpc_config,
    resolve_command_delay,
    spawn_generators,
    steps_per_mpc_period,
    study_metrics,
)
from sim_bridge.plant import Plant, PlantConfig, TableConfig


@dataclass
class RunResult:
    """Outcome of one run: metrics from the true and from the measured normal force, the draws,
    the time series (``log``), and timing statistics."""

    scenario: str
    formulation: str
    pid_enabled: bool
    seed: int
    draws: RunDraws
    metrics_true: PolishingMetrics
    metrics_measured: PolishingMetrics
    log: dict[str, np.ndarray] = field(repr=False)
    wall_time: float = 0.0
    solve_time_median: float = 0.0
    iterations_median: float = 0.0
    command_delay: float = 0.0  # δo of the run, s (pid.delay_cycles plant steps)

    def summary(self) -> dict:
        """A JSON-friendly dict without the time series."""
        return {
            "scenario": self.scenario,
            "formulation": self.formulation,
            "pid_enabled": self.pid_enabled,
            "seed": self.seed,
            "tilt_deg": float(np.rad2deg(self.draws.tilt_angle)),
            "actuation_gain": list(self.draws.actuation_gain),
            "actuation_offset": list(self.draws.actuation_offset),
            "metrics_true": self.metrics_true.to_dict(),
            "metrics_measured": self.metrics_measured.to_dict(),
            "wall_time_s": self.wall_time,
            "solve_time_median_s": self.solve_time_median,
            "iterations_median": self.iterations_median,
            "command_delay_s": self.command_delay,
        }


def plant_config(scenario: Scenario, task, tilt: float) -> PlantConfig:
    """Table tilted by θ about an axis through the circle centre (or the contact point)."""
    p = scenario.plant
    pivot = task.circle_center() if hasattr(task, "circle_center") else task.contact_position
    table = TableConfig(
        surface_point=tuple(pivot),
        tilt_angle=tilt,
        tilt_axis=p.table_tilt_axis,
        stiffness=p.table_stiffness,
        damping=p.table_damping,
        lateral_friction=p.table_friction,
    )
    return PlantConfig(time_step=p.time_step, table=table)


def run_scenario(scenario: Scenario, duration: float | None = None) -> RunResult:
    """Run one scenario in lockstep simulated time and return its metrics and log.

    Args:
        scenario: the experiment (its ``seed`` seeds every random draw of the run).
        duration: simulated time, s (default: the task's full duration).
    """
    wall_start = time.perf_counter()
    robot = load_robot(scenario.robot)
    # mpc.command_delay: measured → time this MPC here (the studies resolve it beforehand).
    scenario, _ = resolve_command_delay(scenario, robot)
    # One generator per device, spawned in a fixed order; the ROS nodes spawn the same ones.
    draw_rng, joint_rng, force_rng, act_rng = spawn_generators(scenario.seed)
    draws = draw_run(scenario, robot, draw_rng)
    task = build_task(scenario, robot)
    duration = task.duration if duration is None else duration
    dt = scenario.plant.time_step
    every = steps_per_mpc_period(scenario)
    config = mpc_config(scenario)
    contact = config.contact

    joint_sensing = joint_sensing_model(scenario, robot.nv, joint_rng)
    force_sensing = force_sensing_model(scenario, force_rng)
    actuation = actuation_model(scenario, robot, draws, act_rng)
    lowlevel = lowlevel_controller(scenario, robot)
    mpc = ModelPredictiveController(robot, config, task)
    p = scenario.plant
    push_steps = int(round(p.push_duration / dt))
    push_at = int(round(p.push_time / dt)) if p.push_enabled else -1

    steps = int(round(duration / dt))
    log = StudyLog(steps, robot, task)
    solve_times, iterations = [], []
    with Plant(robot, plant_config(scenario, task, draws.tilt_angle)) as plant:
        plant.reset(robot.q_nominal)
        tau_hat = robot.gravity(robot.q_nominal)  # the motors hold the robot at start
        for k in range(steps):
            t = k * dt
            if k == push_at:
                plant.apply_external_push(np.array(p.push_force), push_steps)
            s = plant.state()
            q_hat, v_hat, _ = joint_sensing.step(s.q, s.v)
            f_hat = force_sensing.step(measured_force(s.wrench_world, contact))
            if k % every == 0:
                meas = MpcMeasurement(q=q_hat, v=v_hat, force=f_hat, torque=tau_hat)
                command = mpc.step(meas, t)
                solve_times.append(command.solve_time)
                iterations.append(command.iterations)
                lowlevel.set_command(command, t)
            # Hold / blend / track / fallback + PID (eq 33): with the MPC on time this is the
            # plain scheme (τ* on solve cycles; τ* or τ* + G·Δx in between).
            out = lowlevel.step(LowLevelMeasurement(q_hat, v_hat, tau_hat, f_hat), t)
            tau_hat = actuation.step(out.motor_torque, s.v)
            plant.step(tau_hat)
            log.record(
                k, t, s.q, s.normal_force, f_hat[-1], out.desired_torque, tau_hat, out.motor_torque
            )
        normal = plant.table_normal

    metrics_true, metrics_measured = study_metrics(log.arrays, task, normal)
    return RunResult(
        scenario=scenario.name,
        formulation=config.formulation,
        pid_enabled=scenario.pid.enabled,
        seed=scenario.seed,
        draws=draws,
        metrics_true=metrics_true,
        metrics_measured=metrics_measured,
        log=log.arrays,
        wall_time=time.perf_counter() - wall_start,
        solve_time_median=float(np.median(solve_times)) if solve_times else 0.0,
        iterations_median=float(np.median(iterations)) if iterations else 0.0,
        command_delay=round(command_delay(scenario), 12),
    )


__all__ = [
    "RunResult",
    "RunDraws",
    "run_scenario",
    "build_task",
    "draw_run",
    "measured_force",
    "mpc_config",
    "plant_config",
    "spawn_generators",
    "asdict",
]
