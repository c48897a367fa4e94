"""The ROS-free closed loop of the paper's simulation study (Fig. 2), in lockstep simulated time.

One plant cycle (``plant.time_step``, 1 ms by default) does, in this order:

1. read the true plant state at t;
2. sensing (eq 30, 32): q̂, q̇̂, λ̂ = true values δs cycles ago + noise;
3. every ``mpc.period`` (500 Hz): the MPC solves from (q̂, q̇̂, λ̂ or τ̂) and gives τ^d;
   with ``riccati_feedback`` the cycles in between use τ^d + G·(x̂ − x̂_solve);
4. the torque PID (eq 33) turns τ^d (delayed by δo) and the last measured torque τ̂ into τ^m;
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
import pinocchio as pin

from ffmpc_core.actuation import ActuationModel, ActuationParams
from ffmpc_core.config import ContactConfig
from ffmpc_core.errors import ConfigError
from ffmpc_core.metrics import PolishingMetrics, polishing_metrics
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig, MpcMeasurement
from ffmpc_core.pid import TorquePid, TorquePidGains
from ffmpc_core.robots import RobotModel, load_robot
from ffmpc_core.scenario import Scenario
from ffmpc_core.sensing import ForceSensingModel, SensingModel, SensingParams
from ffmpc_core.tasks import ForceSquareTask, PhaseWeights, PolishingTask
from sim_bridge.plant import Plant, PlantConfig, TableConfig


@dataclass(frozen=True)
class RunDraws:
    """The random quantities of one run, drawn from the scenario seed (reported with results)."""

    tilt_angle: float  # rad
    actuation_gain: tuple[float, ...]
    actuation_offset: tuple[float, ...]  # N·m


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
        }


def spawn_generators(seed: int) -> list[np.random.Generator]:
    """The run's generators, in this order: draws (tilt, bias), joint sensor, force sensor,
    actuation. Each device (and its ROS node) owns one; same seed → same streams."""
    return np.random.default_rng(seed).spawn(4)


def build_task(scenario: Scenario, robot: RobotModel):
    """The task schedule and the believed table point for a scenario.

    The tool starts at ``robot.q_nominal``; the controller believes the table is horizontal,
    ``task.start_height`` below the start position, and the circle starts right below it.
    """
    task = scenario.task
    start = robot.contact_placement(robot.q_nominal).translation.copy()
    contact = start - np.array([0.0, 0.0, task.start_height])
    mpc = scenario.mpc
    weights = PhaseWeights(
        free_ee_position=mpc.phase_weight("ee_position_phase", PhaseWeights.free_ee_position),
        contact_ee_position=mpc.phase_weight("ee_position_phase", 1e3),
        force=mpc.phase_weight("force_phase", PhaseWeights.force),
    )
    common = dict(
        start_position=start,
        contact_position=contact,
        still=task.still,
        reach=task.reach,
        force_ramp=task.force_ramp,
        weights=weights,
    )
    if task.name == "polishing":
        circle = task.circles * 2.0 * np.pi / task.angular_velocity
        return PolishingTask(
            normal_force=task.normal_force,
            circle_radius=task.circle_radius,
            angular_velocity=task.angular_velocity,
            circle=circle,
            stop=task.stop,
            **common,
        )
    return ForceSquareTask(
        low_force=task.low_force,
        high_force=task.high_force,
        period=task.square_period,
        cycles=task.square_cycles,
        **common,
    )


def draw_run(scenario: Scenario, robot: RobotModel, rng: np.random.Generator) -> RunDraws:
    """Table tilt θ and actuation bias (a, b) of a run (paper VI-C: random per run)."""
    plant = scenario.plant
    tilt = np.deg2rad(plant.table_tilt_deg)
    if plant.random_tilt_deg > 0:
        tilt = np.deg2rad(rng.uniform(-plant.random_tilt_deg, plant.random_tilt_deg))
    if plant.actuation_random_bias:
        params = ActuationParams.with_random_bias(rng, robot.torque_limit)
        gain, offset = params.gain, params.offset
    else:
        gain, offset = np.ones(robot.nv), np.zeros(robot.nv)
    return RunDraws(float(tilt), tuple(map(float, gain)), tuple(map(float, offset)))


def mpc_config(scenario: Scenario) -> MpcConfig:
    m = scenario.mpc
    return MpcConfig(
        formulation=m.formulation,
        horizon=m.horizon,
        dt=m.dt,
        period=m.period,
        contact=m.contact,
        weights=m.cost_weights(),
        cutoff_frequency=m.cutoff_frequency,
        max_iterations=m.max_iterations,
        kkt_tolerance=m.kkt_tolerance,
        command_delay=scenario.pid.delay_cycles * scenario.plant.time_step
        if m.delay_compensation
        else 0.0,
    )


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


def measured_force(wrench_world: np.ndarray, contact: ContactConfig) -> np.ndarray:
    """The MPC's force from the tool wrench (world axes): 1-D → the world-z component
    (LOCAL_WORLD_ALIGNED normal, config.py's convention), 3-D → the world force."""
    if contact.frame_type != "LOCAL_WORLD_ALIGNED":
        raise ConfigError("the runner feeds world-aligned forces; use LOCAL_WORLD_ALIGNED")
    if contact.dimension == 1:
        return wrench_world[contact.normal_axis : contact.normal_axis + 1].copy()
    return wrench_world[:3].copy()


def run_scenario(scenario: Scenario, duration: float | None = None) -> RunResult:
    """Run one scenario in lockstep simulated time and return its metrics and log.

    Args:
        scenario: the experiment (its ``seed`` seeds every random draw of the run).
        duration: simulated time, s (default: the task's full duration).
    """
    wall_start = time.perf_counter()
    robot = load_robot(scenario.robot)
    # One generator per device, spawned in a fixed order; the ROS nodes spawn the same ones.
    draw_rng, joint_rng, force_rng, act_rng = spawn_generators(scenario.seed)
    draws = draw_run(scenario, robot, draw_rng)
    task = build_task(scenario, robot)
    duration = task.duration if duration is None else duration
    dt = scenario.plant.time_step
    every = scenario.mpc.period / dt
    if abs(every - round(every)) > 1e-9 or round(every) < 1:
        raise ConfigError("mpc.period must be a whole number of plant steps")
    every = int(round(every))
    config = mpc_config(scenario)
    contact = config.contact
    nv = robot.nv

    js, fs = scenario.joint_sensor, scenario.ft_sensor
    joint_sensing = SensingModel(
        SensingParams(
            delay_cycles=js.delay_cycles,
            position_noise_std=js.position_noise_std,
            velocity_noise_std=js.velocity_noise_std,
        ),
        nv,
        0,
        joint_rng,
    )
    force_sensing = ForceSensingModel(
        fs.delay_cycles, fs.force_noise_std, contact.dimension, force_rng
    )
    p = scenario.plant
    actuation = ActuationModel(
        ActuationParams(
            gain=np.array(draws.actuation_gain),
            offset=np.array(draws.actuation_offset),
            torque_noise_std=p.actuation_noise_fraction * robot.torque_limit,
            delay_cycles=p.actuation_delay_cycles,
            static_friction=p.static_friction,
            viscous_friction=p.viscous_friction,
            friction_velocity=p.friction_velocity,
        ),
        act_rng,
    )
    pid_cfg = scenario.pid
    pid = TorquePid(
        TorquePidGains.default(
            robot.torque_limit, pid_cfg.kp, pid_cfg.ki, pid_cfg.kd, pid_cfg.integral_fraction
        ),
        dt,
        delay_cycles=pid_cfg.delay_cycles,
        enabled=pid_cfg.enabled,
    )
    mpc = ModelPredictiveController(robot, config, task)
    push_steps = int(round(p.push_duration / dt))
    push_at = int(round(p.push_time / dt)) if p.push_enabled else -1

    steps = int(round(duration / dt))
    log = {
        "t": np.zeros(steps),
        "ee_position": np.zeros((steps, 3)),
        "ee_reference": np.zeros((steps, 3)),
        "force_true": np.zeros(steps),
        "force_measured": np.zeros(steps),
        "force_reference": np.zeros(steps),
        "tau_desired": np.zeros((steps, nv)),
        "tau_measured": np.zeros((steps, nv)),
        "tau_motor": np.zeros((steps, nv)),
    }
    solve_times, iterations = [], []
    data = robot.create_data()
    with Plant(robot, plant_config(scenario, task, draws.tilt_angle)) as plant:
        plant.reset(robot.q_nominal)
        tau_hat = robot.gravity(robot.q_nominal)  # the motors hold the robot at start
        tau_desired = tau_hat.copy()
        command = None
        for k in range(steps):
            t = k * dt
            if k == push_at:
                plant.apply_external_push(np.array(p.push_force), push_steps)
            s = plant.state()
            q_hat, v_hat, _ = joint_sensing.step(s.q, s.v)
            f_hat = force_sensing.step(measured_force(s.wrench_world, contact))
            meas = MpcMeasurement(q=q_hat, v=v_hat, force=f_hat, torque=tau_hat)
            if k % every == 0:
                command = mpc.step(meas, t)
                solve_times.append(command.solve_time)
                iterations.append(command.iterations)
                tau_desired = command.torque
            elif scenario.mpc.riccati_feedback:
                dx = mpc.state_from(meas) - command.state
                tau_desired = robot.clip_torque(command.torque + command.feedback_gain @ dx)
            tau_motor = robot.clip_torque(pid.step(tau_hat, tau_desired, t))
            tau_hat = actuation.step(tau_motor, s.v)
            plant.step(tau_hat)

            pin.framesForwardKinematics(robot.model, data, s.q)
            log["t"][k] = t
            log["ee_position"][k] = data.oMf[robot.contact_frame_id].translation
            log["ee_reference"][k] = task.ee_position(t)
            log["force_true"][k] = s.normal_force
            log["force_measured"][k] = f_hat[-1]
            log["force_reference"][k] = task.force(t)
            log["tau_desired"][k] = tau_desired
            log["tau_measured"][k] = tau_hat
            log["tau_motor"][k] = tau_motor
        normal = plant.table_normal

    window = task.in_circle(log["t"])
    start, end = (log["t"][window][[0, -1]]) if window.any() else (None, None)

    def metrics(force: np.ndarray) -> PolishingMetrics:
        return polishing_metrics(
            log["t"],
            log["ee_position"],
            log["ee_reference"],
            normal,
            force,
            log["force_reference"],
            desired_torque=log["tau_desired"],
            measured_torque=log["tau_measured"],
            start=start,
            end=end,
        )

    return RunResult(
        scenario=scenario.name,
        formulation=config.formulation,
        pid_enabled=pid_cfg.enabled,
        seed=scenario.seed,
        draws=draws,
        metrics_true=metrics(log["force_true"]),
        metrics_measured=metrics(log["force_measured"]),
        log=log,
        wall_time=time.perf_counter() - wall_start,
        solve_time_median=float(np.median(solve_times)) if solve_times else 0.0,
        iterations_median=float(np.median(iterations)) if iterations else 0.0,
    )


__all__ = ["RunResult", "RunDraws", "run_scenario", "build_task", "draw_run", "asdict"]
