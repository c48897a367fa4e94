"""The polishing simulation's building blocks (the force-feedback paper's study, Fig. 2),
shared by the ROS-free run (``studies.polishing``, on :mod:`ffmpc_core.polishing_loop`) and the
ROS nodes.

Every device of the simulation (the random draws, the joint sensor, the force sensor, the actuation)
owns one ``numpy.random.Generator`` spawned from the scenario seed in a fixed order
(:func:`spawn_generators`), and every object of the loop is built from a
:class:`~ffmpc_core.scenario.Scenario` by one function here. ``studies.polishing`` and the nodes of
``ffmpc_ros``/``ffmpc_ros.plant_node`` call the same functions, so both paths run the same numbers.

:class:`PolishingLog` and :func:`polishing_run_metrics` are the one place where a run's time
series become the paper's metrics (eq 34–35, Tables II–IV), for the runner and for the ROS graph
alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pinocchio as pin

from ffmpc_core.actuation import ActuationModel, ActuationParams
from ffmpc_core.errors import ConfigError
from ffmpc_core.ft_calibration import (
    CalibrationNoise,
    FtCalibration,
    calibration_poses,
    check_calibration,
    load_calibration,
    startup_calibration,
)
from ffmpc_core.lowlevel import LowLevelConfig, LowLevelController
from ffmpc_core.metrics import (
    PUSH_RECOVERY_WINDOW,
    PolishingMetrics,
    polishing_metrics,
    push_phase_metrics,
    push_phase_windows,
)
from ffmpc_core.mpc import MpcConfig
from ffmpc_core.robots import RobotModel, ToolLoad, load_robot, with_tool_load
from ffmpc_core.scenario import COMMAND_DELAY_MEASURED, COMMAND_DELAY_PID, Scenario
from ffmpc_core.sensing import ForceSensingModel, JointSensingModel
from ffmpc_core.sensing import measured_force as measured_force  # (its home until issue 27)
from ffmpc_core.tasks import (
    ForceSquareTask,
    GuardedApproach,
    GuardedTask,
    LiveTask,
    PolishingTask,
)
from ffmpc_core.wrist_ft import (
    ContactForceSensing,
    WristCompensator,
    WristForceSensing,
    WristSensorModel,
)

#: The task schedules of a scenario (:func:`build_task`).
PolishingSchedule = PolishingTask | ForceSquareTask | GuardedTask

#: The devices owning a generator, in spawn order (see :func:`spawn_generators`); the wrist
#: F/T sensor's calibration run draws from ``ft_calibration`` (its joint and sensor readings).
DEVICES = ("draws", "joint_sensor", "force_sensor", "actuation", "ft_calibration")


@dataclass(frozen=True)
class RunDraws:
    """The random quantities of one run, drawn from the scenario seed (reported with results)."""

    tilt_angle: float  # rad
    actuation_gain: tuple[float, ...]
    actuation_offset: tuple[float, ...]  # N·m


def spawn_generators(seed: int) -> list[np.random.Generator]:
    """The run's generators, in this order: draws (tilt, bias), joint sensor, force sensor,
    actuation, F/T calibration. Each device (and its ROS node) owns one; same seed → same
    streams (a device added at the end leaves the others' streams unchanged)."""
    return np.random.default_rng(seed).spawn(len(DEVICES))


def device_generator(seed: int, device: str) -> np.random.Generator:
    """The generator of one device (one of :data:`DEVICES`), from :func:`spawn_generators`."""
    if device not in DEVICES:
        raise ConfigError(f"unknown device {device!r}; devices: {DEVICES}")
    return spawn_generators(seed)[DEVICES.index(device)]


def steps_per_mpc_period(scenario: Scenario) -> int:
    """mpc.period in plant steps (ConfigError unless a whole number >= 1)."""
    every = scenario.mpc.ocp.period / scenario.plant.time_step
    if abs(every - round(every)) > 1e-9 or round(every) < 1:
        raise ConfigError("mpc.period must be a whole number of plant steps")
    return int(round(every))


def build_task(scenario: Scenario, robot: RobotModel) -> PolishingSchedule:
    """The task schedule and the believed table point for a scenario.

    The tool starts at ``robot.q_nominal``; the controller believes the table is horizontal,
    ``task.start_height`` below the start position, and the circle starts right below it.
    With ``task.approach_speed`` > 0 the schedule is a guarded approach
    (:class:`~ffmpc_core.tasks.GuardedTask`): its contact phases start when the MPC measures
    the contact. A new object per call: a run's MPC, log and metrics must share one.
    """
    timed = _timed_task(scenario, robot)
    task = scenario.task
    if task.approach_speed <= 0.0:
        return timed
    approach = GuardedApproach(task.approach_speed, task.approach_depth, task.contact_force)
    return GuardedTask(timed, approach)


def _timed_task(scenario: Scenario, robot: RobotModel) -> PolishingTask | ForceSquareTask:
    """The time-based schedule of :func:`build_task` (the contact phases at fixed times)."""
    task = scenario.task
    start = robot.contact_placement(robot.q_nominal).translation.copy()
    contact = start - np.array([0.0, 0.0, task.start_height])
    weights = scenario.mpc.phase_weights()
    common: dict[str, Any] = dict(
        start_position=start,
        contact_position=contact,
        still=task.still,
        reach=task.reach,
        clearance=task.approach_clearance,
        touch=task.touch,
        touch_force=task.touch_force,
        force_ramp=task.force_ramp,
        weights=weights,
    )
    if task.name == "polishing":
        # the ramps travel ω·circle_ramp less than the plain circle: the phase is that much longer
        circle = task.circles * 2.0 * np.pi / task.angular_velocity + task.circle_ramp
        return PolishingTask(
            normal_force=task.normal_force,
            circle_radius=task.circle_radius,
            angular_velocity=task.angular_velocity,
            circle=circle,
            stop=task.stop,
            ee_z_weight_in_contact=task.ee_z_weight_in_contact,
            circle_ramp=task.circle_ramp,
            **common,
        )
    return ForceSquareTask(
        low_force=task.low_force,
        high_force=task.high_force,
        period=task.square_period,
        cycles=task.square_cycles,
        **common,
    )


def mpc_schedule(task: PolishingSchedule, scenario: Scenario) -> LiveTask:
    """The MPC's schedule: ``task`` (:func:`build_task`) with the scenario's position offset
    ``mpc.position_offset`` (m, world frame; the plant's table does not move), changeable while
    it runs (:class:`~ffmpc_core.tasks.LiveTask`: the MPC node's live parameters)."""
    return LiveTask(task, scenario.mpc.position_offset)


def draw_run(scenario: Scenario, robot: RobotModel, rng: np.random.Generator) -> RunDraws:
    """Table tilt θ and actuation bias (a, b) of a run (paper VI-C: random per run)."""
    plant = scenario.plant
    tilt = np.deg2rad(plant.table_tilt_deg)
    if plant.random_tilt_deg > 0:
        tilt = np.deg2rad(rng.uniform(-plant.random_tilt_deg, plant.random_tilt_deg))
    gain, offset = plant.actuation.draw_bias(rng, robot.nv)
    return RunDraws(float(tilt), tuple(map(float, gain)), tuple(map(float, offset)))


def mpc_config(scenario: Scenario, real_time: bool = False) -> MpcConfig:
    """The MPC's parameters; with ``mpc.delay_compensation`` it plans for t + δo.

    δo = ``pid.delay_cycles`` plant steps; ``mpc.command_delay: measured`` must have been
    resolved first (:func:`resolve_command_delay`). ``mpc.constraints.max_solve_time`` (a
    wall-clock cap) is passed for a real-time run only (``real_time``): a lockstep run's solves
    never depend on the CPU's speed.
    """
    m = scenario.mpc
    if m.command_delay == COMMAND_DELAY_MEASURED:
        raise ConfigError(
            "mpc.command_delay is 'measured': resolve it first (resolve_command_delay; the "
            "studies and `ffmpc run` do)"
        )
    return MpcConfig(
        ocp=m.ocp,
        contact=m.contact,
        weights=m.cost_weights(),
        backend=m.backend,
        torque_state=m.torque_state,
        position_observer_time=m.position_observer_time,
        constraints=m.constraints if real_time else replace(m.constraints, max_solve_time=0.0),
        command_delay=command_delay(scenario) if m.delay_compensation else 0.0,
    )


def command_delay(scenario: Scenario) -> float:
    """δo of a (resolved) scenario, s: ``pid.delay_cycles`` plant steps."""
    return scenario.pid.delay_cycles * scenario.plant.time_step


def measure_mpc_step_time(scenario: Scenario, robot: RobotModel, steps: int = 60) -> float:
    """Median wall time of the scenario's MPC step on this machine, s (the calibration of
    ``mpc.command_delay: measured``).

    The MPC of the scenario (formulation, horizon, Δt, weights, contact; δo as
    ``pid.delay_cycles`` so that its predictor is timed too) runs ``steps`` steps in closed loop
    against its own dynamics (:mod:`ffmpc_core.model_plant`), pressing and circling from the
    nominal posture (in contact, where solves are the hardest); the cold first step is left
    out. The whole step is timed (state, references, warm start, solve): it is what delays a
    command.
    """
    from ffmpc_core.model_plant import run_model_closed_loop

    if steps < 2:
        raise ConfigError(f"the calibration needs at least 2 MPC steps, got {steps}")
    provisional = replace(scenario, mpc=replace(scenario.mpc, command_delay=COMMAND_DELAY_PID))
    config = mpc_config(provisional)
    p0 = robot.contact_placement(robot.q_nominal).translation
    task = PolishingTask.pressing(p0, force_ramp=0.1, circle=10.0, stop=0.0)
    log = run_model_closed_loop(robot, config, task, duration=steps * config.ocp.period)
    return float(np.median(log.step_time[1:]))


def resolve_command_delay(
    scenario: Scenario,
    robot: RobotModel | None = None,
    measured: float | None = None,
    steps: int = 60,
) -> tuple[Scenario, dict]:
    """The scenario with δo settled, and a record of it for the results.

    ``mpc.command_delay``: "pid" and fixed values are returned as they are; "measured" becomes
    the median MPC step time (``measured``, s, or :func:`measure_mpc_step_time` with ``steps``)
    rounded UP to a whole number of plant steps (so lockstep stays exact), which sets
    ``pid.delay_cycles``. The record: ``setting``, ``delta_o_s`` (δo used, s),
    ``delay_cycles`` and, when measured, ``measured_step_median_s`` and ``calibration_steps``.
    """
    setting = scenario.mpc.command_delay
    dt = scenario.plant.time_step
    record: dict = {"setting": setting}
    if setting == COMMAND_DELAY_MEASURED:
        if measured is None:
            robot = robot or load_robot(scenario.robot)
            measured = measure_mpc_step_time(scenario, robot, steps)
            record["calibration_steps"] = steps
        if not (np.isfinite(measured) and measured >= 0.0):
            raise ConfigError(f"measured MPC step time must be finite and >= 0 s, got {measured}")
        cycles = int(math.ceil(measured / dt - 1e-9))  # 0.004 / 0.001 is 4.000000000000001
        if cycles * dt < measured:
            cycles += 1
        horizon = scenario.mpc.ocp.horizon * scenario.mpc.ocp.dt
        if scenario.mpc.delay_compensation and cycles * dt >= horizon:
            raise ConfigError(
                f"measured δo {measured * 1e3:.2f} ms rounds up to {cycles * dt * 1e3:.0f} ms, "
                f"not shorter than the MPC horizon N·Δt = {horizon * 1e3:.0f} ms"
            )
        scenario = scenario.with_overrides({"mpc.command_delay": round(cycles * dt, 12)})
        record["measured_step_median_s"] = float(measured)
    record["delay_cycles"] = scenario.pid.delay_cycles
    record["delta_o_s"] = round(command_delay(scenario), 12)
    return scenario, record


def tool_load(scenario: Scenario) -> ToolLoad:
    """The tool on the flange (``plant.tool_mass``, ``plant.tool_center_of_mass``)."""
    p = scenario.plant
    return ToolLoad(p.tool_mass, p.tool_center_of_mass)


def scenario_robot(scenario: Scenario) -> RobotModel:
    """The controllers' robot model: the scenario's robot carrying its tool (the cell's load
    data, :func:`~ffmpc_core.robots.with_tool_load`); the bare robot without a tool."""
    return with_tool_load(load_robot(scenario.robot), tool_load(scenario))


def wrist_sensor_model(
    scenario: Scenario, robot: RobotModel, rng: np.random.Generator
) -> WristSensorModel:
    """The wrist F/T sensor of ``ft_sensor.model: wrist`` (bias, δs, σ_f, σ_m) carrying the
    scenario's tool; ``robot``: the bare robot (kinematics)."""
    fs = scenario.ft_sensor
    return WristSensorModel(
        robot,
        tool_load(scenario),
        fs.bias,
        fs.delay_cycles,
        fs.force_noise_std,
        fs.moment_noise_std,
        scenario.plant.time_step,
        rng,
        inertial=fs.inertial_wrench,
    )


def tool_calibration(
    scenario: Scenario,
    sensor: WristSensorModel,
    rng: np.random.Generator,
    now: float,
) -> FtCalibration | None:
    """The checked calibration of the wrist sensor (``ft_sensor.calibration``): "startup" runs
    the calibration poses now (:func:`~ffmpc_core.ft_calibration.startup_calibration`, drawing
    from ``rng``), "file" loads ``calibration_file``; "none" gives None. CalibrationError, with
    the reason, for a stale, foreign or implausible one. ``now``: UNIX time, s."""
    fs = scenario.ft_sensor
    if fs.calibration == "none":
        return None
    robot = sensor.robot
    poses = calibration_poses(robot)
    if fs.calibration == "file":
        calibration = load_calibration(fs.calibration_file)
    else:
        noise = CalibrationNoise(
            fs.force_noise_std,
            fs.moment_noise_std,
            scenario.joint_sensor.position_noise_std,
            fs.calibration_samples,
        )
        calibration = startup_calibration(sensor, poses, noise, rng, now)
    check_calibration(calibration, robot, poses, tool_load(scenario), fs.calibration_max_age, now)
    return calibration


def wrist_compensator(
    scenario: Scenario, robot: RobotModel, calibration: FtCalibration | None
) -> WristCompensator:
    """The force node's compensation with ``calibration`` (None: ``calibration: none``, the
    raw reading only moved to the contact frame); ``robot``: the bare robot (kinematics)."""
    dt, inertial = scenario.plant.time_step, scenario.ft_sensor.inertial_wrench
    if calibration is None:
        return WristCompensator(robot, np.zeros(6), 0.0, np.zeros(3), dt, enabled=False)
    bias, mass, com = calibration.bias, calibration.mass, calibration.center_of_mass
    return WristCompensator(robot, bias, mass, com, dt, inertial=inertial)


def force_pipeline(
    scenario: Scenario,
    robot: RobotModel,
    rng: np.random.Generator,
    calibration_rng: np.random.Generator,
    now: float,
) -> ContactForceSensing | WristForceSensing:
    """What the loop reads λ̂ through (``ft_sensor.model``): the paper's sensor (eq 32), or the
    wrist sensor with the calibration of :func:`tool_calibration` compensated by the measured
    joint state (the raw reading with ``calibration: none``). ``rng``: the force sensor's
    generator, ``calibration_rng``: the ``ft_calibration`` device's; ``robot``: the robot (its
    kinematics; a tool in its model is not used); ``now``: UNIX time, s."""
    contact = scenario.mpc.contact
    if scenario.ft_sensor.model == "contact":
        return ContactForceSensing(force_sensing_model(scenario, rng), contact)
    sensor = wrist_sensor_model(scenario, robot, rng)
    calibration = tool_calibration(scenario, sensor, calibration_rng, now)
    return WristForceSensing(sensor, wrist_compensator(scenario, robot, calibration), contact)


def joint_sensing_model(scenario: Scenario, nv: int, rng: np.random.Generator) -> JointSensingModel:
    """Eq 30: the joint sensor of the ``joint_sensor`` section (δs, σ_q, σ_q̇)."""
    return JointSensingModel(scenario.joint_sensor, nv, rng)


def force_sensing_model(scenario: Scenario, rng: np.random.Generator) -> ForceSensingModel:
    """Eq 32: the force sensor (δs, σ_λ of ``ft_sensor``), sized by the MPC's contact."""
    fs = scenario.ft_sensor
    dim = scenario.mpc.contact.dimension
    return ForceSensingModel(fs.delay_cycles, fs.force_noise_std, dim, rng)


def actuation_model(
    scenario: Scenario, robot: RobotModel, draws: RunDraws, rng: np.random.Generator
) -> ActuationModel:
    """Eq 31 of the ``plant`` section's actuation, with the run's drawn bias (a, b) and σ_τ
    scaled by the robot's torque limits."""
    params = ActuationParams.from_config(
        scenario.plant.actuation,
        robot.torque_limit,
        np.array(draws.actuation_gain),
        np.array(draws.actuation_offset),
    )
    return ActuationModel(params, rng)


def lowlevel_config(scenario: Scenario) -> LowLevelConfig:
    """The low-level loop's parameters: the ``pid`` section as it is, with the MPC's
    formulation, period, force dimension and Riccati feedback."""
    m = scenario.mpc
    return LowLevelConfig(
        formulation=m.ocp.formulation,
        force_dimension=m.contact.dimension,
        riccati_feedback=m.riccati_feedback,
        mpc_period=m.ocp.period,
        pid=scenario.pid,
    )


def lowlevel_controller(scenario: Scenario, robot: RobotModel) -> LowLevelController:
    """The low-level loop (hold/blend/track/fallback) around the scenario's torque PID (eq 33,
    scaled by the robot's torque limits)."""
    return LowLevelController.from_config(
        robot, lowlevel_config(scenario), scenario.plant.time_step
    )


class PolishingLog:
    """The time series of one run, one row per plant cycle k (t = k·time_step).

    Arrays: t (s); ee_position, ee_reference (m, world); force_true (N, along the true table
    normal), force_measured (N, last entry of λ̂), force_reference (N); tau_desired τ^d,
    tau_measured τ̂ (the actuation output of the cycle), tau_motor τ^m (N·m).
    """

    FIELDS = (
        "t",
        "ee_position",
        "ee_reference",
        "force_true",
        "force_measured",
        "force_reference",
        "tau_desired",
        "tau_measured",
        "tau_motor",
    )

    def __init__(self, steps: int, robot: RobotModel, task: PolishingSchedule) -> None:
        if steps < 1:
            raise ConfigError(f"a run needs at least one cycle, got {steps}")
        nv = robot.nv
        self.steps = steps
        self.robot = robot
        self.task = task
        self._data = robot.create_data()
        self.arrays: dict[str, np.ndarray] = {
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

    def record(
        self,
        k: int,
        t: float,
        q_true: np.ndarray,
        force_true: float,
        force_measured: float,
        tau_desired: np.ndarray,
        tau_measured: np.ndarray,
        tau_motor: np.ndarray,
    ) -> None:
        """Row k: the contact-frame position from the TRUE q (pinocchio FK), the references of
        the task at t, and the given signals."""
        log, robot = self.arrays, self.robot
        pin.framesForwardKinematics(robot.model, self._data, q_true)
        log["t"][k] = t
        log["ee_position"][k] = self._data.oMf[robot.contact_frame_id].translation
        log["ee_reference"][k] = self.task.ee_position(t)
        log["force_true"][k] = force_true
        log["force_measured"][k] = force_measured
        log["force_reference"][k] = self.task.force(t)
        log["tau_desired"][k] = tau_desired
        log["tau_measured"][k] = tau_measured
        log["tau_motor"][k] = tau_motor

    def replay_contact(self, every: int) -> float | None:
        """A guarded approach recorded away from its MPC (the graph's metrics node, the
        real-time loop): detect the contact from the logged measured force at the MPC's ticks
        (every ``every`` cycles, :meth:`GuardedTask.replay`) and write the references of every
        row again with the phases shifted to it. Returns the detection time (s; None: none,
        or a time-based task, whose log is left as it is)."""
        task = self.task
        if not isinstance(task, GuardedTask):
            return None
        log = self.arrays
        detected = task.replay(log["t"], log["force_measured"], every)
        for k, t in enumerate(log["t"]):
            log["ee_reference"][k] = task.ee_position(float(t))
            log["force_reference"][k] = task.force(float(t))
        return detected


def polishing_run_metrics(
    log: dict[str, np.ndarray], task: PolishingSchedule, table_normal: np.ndarray
) -> tuple[PolishingMetrics, PolishingMetrics]:
    """The metrics from the TRUE and from the MEASURED normal force, over the task's evaluation
    window (the circle; the whole run if the run ends before it)."""
    window = task.in_circle(log["t"])
    start, end = (log["t"][window][[0, -1]]) if window.any() else (None, None)

    def metrics(force: np.ndarray) -> PolishingMetrics:
        return polishing_metrics(
            log["t"],
            log["ee_position"],
            log["ee_reference"],
            table_normal,
            force,
            log["force_reference"],
            desired_torque=log["tau_desired"],
            measured_torque=log["tau_measured"],
            start=start,
            end=end,
        )

    return metrics(log["force_true"]), metrics(log["force_measured"])


def polishing_push_metrics(
    log: dict[str, np.ndarray],
    scenario: Scenario,
    task: PolishingSchedule,
    table_normal: np.ndarray,
    recovery: float = PUSH_RECOVERY_WINDOW,
) -> list[dict[str, Any]]:
    """Experiment 3.3: per external push of the scenario (``plant.push_*``; [] without one),
    E_λ (N, TRUE normal force), E_P (mm) and max |λ| (N) DURING the push and over the
    ``recovery`` s AFTER it (cut at the end of the task's evaluation window), as
    ``{"during": {...}, "after": {...}}`` of :class:`ffmpc_core.metrics.PushPhaseMetrics`."""
    plant = scenario.plant
    if not plant.push_enabled:
        return []
    t = log["t"]
    window = task.in_circle(t)
    # Half-open phases: the last cycle of the evaluation window is inside.
    end = float(t[window][-1]) + 0.5 * plant.time_step if window.any() else None
    phases = push_phase_windows([(plant.push_time, plant.push_duration)], recovery, end)
    out = []
    for push in phases:
        out.append(
            {
                name: push_phase_metrics(
                    t,
                    log["ee_position"],
                    log["ee_reference"],
                    table_normal,
                    log["force_true"],
                    log["force_reference"],
                    bounds,
                ).to_dict()
                for name, bounds in push.items()
            }
        )
    return out
