"""One run of the force-feedback paper's polishing simulation (Fig. 2), ROS-free, in lockstep
simulated time: :func:`run_polishing`.

The closed loop is :func:`ffmpc_core.runner.run_scenario`, the one loop of every experiment;
the scenario around it is :class:`ffmpc_core.polishing_loop.PolishingLoop` (sensing, faults,
actuation, log) with the controllers :class:`~ffmpc_core.polishing_loop.MpcStage` and
:class:`~ffmpc_core.polishing_loop.LowLevelStage`, and the plant is the PyBullet scene of
:func:`sim_bridge.scenes.simulated_robot`. One plant cycle (``plant.time_step``, 1 ms by default)
does, in this order:

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

Faults (``faults=[Fault("mpc-dropout", 0.6, 0.05)]`` or ``["mpc-dropout@0.6+0.05"]``, see
``ffmpc_core.faults``) change what the CONTROLLERS read or get, never the plant or the random
streams (the sensing models still draw every cycle, so a faulty run and its fault-free twin see
the same noise): an MPC dropout skips the solve; a sensor dropout skips the solve and hands the
low level the last measurement received; a torque spike replaces the τ̂ the PID and a
torque-feedback MPC read; a NaN wrench replaces the λ̂ they read (the log keeps the sensor's own
λ̂). An input the MPC needs that is non-finite or implausible (``ffmpc_core.plausibility``), an
MPC that raises, or a command the low level refuses engages the safe hold on that cycle
(``LowLevelController.engage_hold``). Whatever the faults, the results carry
``max_velocity_ratio`` and ``max_torque_ratio`` (per joint, max over the run of |q̇|/limit with
the plant's q̇, and |τ^m|/limit with the motor torque the controller commands),
``max_applied_torque_ratio`` (the same with the torque the simulated actuation applies, eq 31:
its gain error a ∈ [0.8, 1.2], offset, friction and noise can take a saturated command past the
limit, which no controller can prevent and a real drive's current limit would clip) and
``safe_hold_s`` (time spent in the safe hold, s); ``safety_log`` holds their time series (not
part of ``log``, which the node graph reproduces).

The robot's reflexes (``plant.reflex``, on by default; :mod:`ffmpc_core.reflex`): the plant is
stepped through :class:`~ffmpc_core.reflex.ReflexPlant`. A measured value over a data-sheet limit
the robot stops on (the iiwa: q, q̇) stops it: from the next cycle on, the drives brake it to
rest and hold it, the controllers' commands are ignored (the loop runs on, its log still holds
what they asked for), and the run is **aborted**: ``aborted`` and ``reflex`` (which limit, which
joint, the value, the ratio, when; the largest ratio of each kind) in the results. With the
reflex off nothing is stopped, and ``reflex`` reports the raw excess and the crossing that
would have stopped the robot.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ffmpc_core import runner as closed_loop
from ffmpc_core.faults import RUNNER_KINDS, Fault, faults_from, require_kinds
from ffmpc_core.lowlevel import LowLevelMode
from ffmpc_core.metrics import PolishingMetrics, limit_ratios
from ffmpc_core.mpc import ModelPredictiveController
from ffmpc_core.polishing import (
    PolishingLog,
    RunDraws,
    command_delay,
    force_pipeline,
    joint_sensing_model,
    lowlevel_controller,
    mpc_config,
    mpc_schedule,
    polishing_push_metrics,
    polishing_run_metrics,
    resolve_command_delay,
    scenario_robot,
    spawn_generators,
    steps_per_mpc_period,
)
from ffmpc_core.polishing_loop import LowLevelStage, MpcStage, PolishingLoop
from ffmpc_core.robots import RobotModel
from ffmpc_core.runner import LockstepClock
from ffmpc_core.scenario import Scenario
from ffmpc_core.tasks import GuardedTask
from sim_bridge.scenes import simulated_robot

__all__ = ["RunResult", "run_polishing"]

_HOLD_MODES = (int(LowLevelMode.HOLD), int(LowLevelMode.FALLBACK))

#: Overrides of a polishing scenario that remove what an MPC's δo prediction cannot know (joint
#: friction, actuation bias and noise, sensing noise and delays, the actuation delay; the table's
#: tilt, stiffness and friction stay): a run whose prediction error is its model's.
PREDICTABLE_PLANT: dict[str, object] = {
    "plant.actuation_random_bias": False,
    "plant.actuation_noise_fraction": 0.0,
    "plant.static_friction": 0.0,
    "plant.viscous_friction": 0.0,
    "plant.actuation_delay_cycles": 0,
    "joint_sensor.position_noise_std": 0.0,
    "joint_sensor.velocity_noise_std": 0.0,
    "joint_sensor.delay_cycles": 0,
}


@dataclass
class RunResult:
    """Outcome of one run: metrics from the true and from the measured normal force, the draws,
    the time series (``log``), timing statistics, and the safety figures (module docstring):
    ``max_velocity_ratio`` / ``max_torque_ratio`` per joint, ``safe_hold_s`` (s), the MPC
    solves that raised (``mpc_failures``; the hold took over; among them
    ``constraint_failures``, solutions refused for breaking a hard constraint), the commands
    the velocity guard
    dropped (``velocity_guard_trips``, None with the guard off), the faults injected, and
    ``safety_log`` (t s; v rad/s and tau_applied N·m per joint; mode, the ``LowLevelMode`` of
    each cycle); ``solve_log``: per MPC solve, t (s) and state, the x̂ it started from (with a
    δo, the state it predicted at t + δo; ``MpcCommand.state``)."""

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
    max_velocity_ratio: np.ndarray = field(default_factory=lambda: np.zeros(0))
    max_torque_ratio: np.ndarray = field(default_factory=lambda: np.zeros(0))
    max_applied_torque_ratio: np.ndarray = field(default_factory=lambda: np.zeros(0))
    safe_hold_s: float = 0.0
    mpc_failures: int = 0
    constraint_failures: int = 0
    #: solves whose x̂ lay beyond a hard constraint's bound (relaxed for that solve)
    relaxed_solves: int = 0
    velocity_guard_trips: int | None = None
    faults: tuple[Fault, ...] = ()
    safety_log: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    solve_log: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    command_delay: float = 0.0  # δo of the run, s (pid.delay_cycles plant steps)
    #: Experiment 3.3, per push: true-force E_λ (N), E_P (mm), max |λ| (N) during and after it
    #: (:func:`ffmpc_core.polishing.polishing_push_metrics`); empty without a push.
    push_metrics: list[dict] = field(default_factory=list)
    #: The robot's reflexes (:meth:`ffmpc_core.reflex.RobotReflex.report`); empty if not run.
    reflex: dict = field(default_factory=dict)
    #: The guarded approach (``task.approach_speed`` > 0, :class:`ffmpc_core.tasks.GuardedTask`):
    #: the task time the MPC detected the contact, s (None: never, or no guarded approach), and
    #: whether the descent reached its bound without a contact (the contact phases never
    #: started: the tool held in free space; the metrics then cover the whole run).
    contact_time: float | None = None
    contact_missed: bool = False

    @property
    def aborted(self) -> bool:
        """The robot stopped itself (a reflex): the run was aborted."""
        return bool(self.reflex.get("aborted", False))

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
            "max_velocity_ratio": [float(x) for x in self.max_velocity_ratio],
            "max_torque_ratio": [float(x) for x in self.max_torque_ratio],
            "max_applied_torque_ratio": [float(x) for x in self.max_applied_torque_ratio],
            "safe_hold_s": self.safe_hold_s,
            "mpc_failures": self.mpc_failures,
            "constraint_failures": self.constraint_failures,
            "relaxed_solves": self.relaxed_solves,
            "faults": [str(f) for f in self.faults],
            "command_delay_s": self.command_delay,
            "aborted": self.aborted,
            "reflex": self.reflex,
            "contact_time_s": self.contact_time,
            "contact_missed": self.contact_missed,
            **({"push_true": self.push_metrics} if self.push_metrics else {}),
            **(
                {"velocity_guard_trips": self.velocity_guard_trips}
                if self.velocity_guard_trips is not None
                else {}
            ),
        }


def _median(values: list[float] | list[int]) -> float:
    return float(np.median(values)) if values else 0.0


def prediction_offsets(result: RunResult, robot: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    """How far each solve's δo prediction landed from the robot: per solve at t (s), the distance
    (m) in the world's horizontal plane between the contact frame at the state the solve started
    from (``solve_log``: predicted for t + δo) and the true contact frame at t + δo (``log``).
    Solves whose t + δo lies past the run's end are left out."""
    times, positions = result.log["t"], result.log["ee_position"]
    step = times[1] - times[0] if times.size > 1 else 1.0
    kept, offsets = [], []
    for t, state in zip(result.solve_log["t"], result.solve_log["state"], strict=True):
        k = round((t + result.command_delay - times[0]) / step)
        if k < times.size:
            tool = robot.contact_placement(state[: robot.nq]).translation
            kept.append(t)
            offsets.append(float(np.linalg.norm((tool - positions[k])[:2])))
    return np.array(kept), np.array(offsets)


def run_polishing(
    scenario: Scenario,
    duration: float | None = None,
    faults: Iterable[Fault | str] | None = None,
) -> RunResult:
    """Run one scenario in lockstep simulated time and return its metrics and log.

    Args:
        scenario: the experiment (its ``seed`` seeds every random draw of the run).
        duration: simulated time, s (default: the task's full duration).
        faults: faults to inject (``Fault`` or ``KIND@T[+DURATION]``; module docstring).
    """
    wall_start = time.perf_counter()
    faults = faults_from(faults)
    require_kinds(faults, RUNNER_KINDS, "the ROS-free runner")
    robot = scenario_robot(scenario)  # carrying the tool, if any (the cell's load data)
    # mpc.command_delay: measured → time this MPC here (the studies resolve it beforehand).
    scenario, _ = resolve_command_delay(scenario, robot)
    # One generator per device, spawned in a fixed order; the ROS nodes spawn the same ones.
    draw_rng, joint_rng, force_rng, act_rng, calibration_rng = spawn_generators(scenario.seed)
    sim = simulated_robot(scenario, robot, draw_rng, act_rng)
    draws, task, actuation = sim.draws, sim.task, sim.actuation
    duration = task.duration if duration is None else duration
    dt = scenario.plant.time_step
    config = mpc_config(scenario)

    lowlevel = lowlevel_controller(scenario, robot)
    mpc = ModelPredictiveController(robot, config, mpc_schedule(task, scenario))
    clock = LockstepClock.for_duration(dt, duration)
    log = PolishingLog(clock.steps, robot, task)
    loop = PolishingLoop(
        robot,
        config.contact,
        joint_sensing_model(scenario, robot.nv, joint_rng),
        force_pipeline(scenario, robot, force_rng, calibration_rng, time.time()),
        actuation,
        log,
        steps_per_mpc_period(scenario),
        faults,
        initial_torque=robot.gravity(robot.q_nominal),  # the motors hold the robot at start
        disturbance=sim.push_if_due,
    )
    mpc_stage = MpcStage(mpc, robot)
    with sim.plant as plant:
        stages: list[closed_loop.Controller[Any, Any]] = [mpc_stage, LowLevelStage(lowlevel)]
        closed_loop.run_scenario(loop, sim.reflex_plant, stages, clock)
        normal = plant.table_normal

    metrics_true, metrics_measured = polishing_run_metrics(log.arrays, task, normal)
    pushes = polishing_push_metrics(log.arrays, scenario, task, normal)
    return RunResult(
        scenario=scenario.name,
        formulation=config.ocp.formulation,
        pid_enabled=scenario.pid.enabled,
        seed=scenario.seed,
        draws=draws,
        metrics_true=metrics_true,
        metrics_measured=metrics_measured,
        log=log.arrays,
        wall_time=time.perf_counter() - wall_start,
        solve_time_median=_median(mpc_stage.solve_times),
        iterations_median=_median(mpc_stage.iterations),
        max_velocity_ratio=limit_ratios(loop.trace_v, robot.velocity_limit)[0],
        max_torque_ratio=limit_ratios(loop.trace_tau, robot.torque_limit)[0],
        max_applied_torque_ratio=limit_ratios(loop.trace_applied, robot.torque_limit)[0],
        safe_hold_s=float(np.sum(np.isin(loop.trace_mode, _HOLD_MODES)) * dt),
        mpc_failures=mpc_stage.failures,
        constraint_failures=mpc_stage.constraint_failures,
        relaxed_solves=mpc_stage.relaxed_solves,
        velocity_guard_trips=lowlevel.velocity_guard_trips if scenario.pid.velocity_guard else None,
        faults=faults,
        safety_log={
            "t": log.arrays["t"],
            "v": loop.trace_v,
            "tau_motor": loop.trace_tau,
            "tau_applied": loop.trace_applied,
            "mode": loop.trace_mode,
        },
        solve_log={
            "t": np.array([t for t, _ in mpc_stage.solve_states]),
            "state": np.array([x for _, x in mpc_stage.solve_states]),
        },
        command_delay=round(command_delay(scenario), 12),
        push_metrics=pushes,
        reflex=sim.reflex_plant.reflex.report(),
        contact_time=task.detected_at if isinstance(task, GuardedTask) else None,
        contact_missed=isinstance(task, GuardedTask)
        and task.contact_missed(mpc.task_time(duration)),
    )
