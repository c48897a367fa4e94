"""The polishing study's closed loop (Fig. 2) as a scenario and two controllers of
:func:`ffmpc_core.runner.run_scenario`.

* :class:`PolishingLoop` (the scenario): sensing (eq 30, 32: q̂, q̇̂, λ̂ = true values δs
  cycles ago + noise; or the wrist F/T sensor compensated with q̂,
  :class:`~ffmpc_core.wrist_ft.WristForceSensing`), the injected faults (they change only
  what the controllers read), the actuation (eq 31: τ̂ = a·τ^m(t − δs) + b − friction +
  noise, applied to the plant and measured: the next cycle's PID and torque-feedback MPC read
  it), the external push, the run's log
  (:class:`~ffmpc_core.polishing.PolishingLog`) and its safety traces.
* :class:`MpcStage`: every ``mpc.period`` the MPC solves from the reading if its inputs are
  plausible, else (or when the solve raises) it asks for the safe hold.
* :class:`LowLevelStage`: the low-level loop (:class:`~ffmpc_core.lowlevel.LowLevelController`,
  the same class as the ROS PID node): hold / blend / track / fallback and the torque PID (eq 33).

Nothing here imports a simulator: the plant is any :class:`~ffmpc_core.plant.Plant` whose state
has ``q``, ``v``, ``wrench_world`` and ``normal_force`` (the PyBullet plant of ``sim_bridge``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ffmpc_core.actuation import ActuationModel
from ffmpc_core.config import ContactConfig
from ffmpc_core.constraints import ConstraintViolationError
from ffmpc_core.errors import FfmpcError, InputError
from ffmpc_core.faults import Fault, active_kinds
from ffmpc_core.lowlevel import LowLevelController, LowLevelMeasurement, LowLevelOutput
from ffmpc_core.mpc import ModelPredictiveController, MpcCommand, MpcMeasurement
from ffmpc_core.plausibility import check_force, torque_plausible
from ffmpc_core.polishing import PolishingLog
from ffmpc_core.robots import RobotModel
from ffmpc_core.sensing import JointSensingModel
from ffmpc_core.wrist_ft import ForcePipeline

__all__ = ["LowLevelStage", "MpcDecision", "MpcStage", "PolishingLoop", "PolishingReading"]


class PolishingPlantState(Protocol):
    """What the loop reads of the plant: q rad, q̇ rad/s, the wrench on the tool ([f; m], N and
    N·m, world axes) and the normal force on the table, N."""

    @property
    def q(self) -> np.ndarray:
        """Joint positions, rad."""
        ...

    @property
    def v(self) -> np.ndarray:
        """Joint velocities, rad/s."""
        ...

    @property
    def wrench_world(self) -> np.ndarray:
        """Wrench on the tool, [f; m] in N and N·m, world axes."""
        ...

    @property
    def normal_force(self) -> float:
        """Normal force on the table along its true normal, N."""
        ...


@dataclass(frozen=True)
class PolishingReading:
    """What the controllers read at one cycle.

    Attributes:
        q, v: q̂ rad, q̇̂ rad/s. torque: τ̂ N·m. force: λ̂ N (contact frame).
        force_ok: λ̂ is plausible (``ffmpc_core.plausibility.check_force``).
        solve: this cycle is an MPC tick with fresh sensors and no MPC dropout.
        force_sensor: the force sensor's own λ̂ of the cycle (N; the log keeps it, not a fault's).
    """

    q: np.ndarray
    v: np.ndarray
    torque: np.ndarray
    force: np.ndarray
    force_ok: bool
    solve: bool
    force_sensor: np.ndarray


@dataclass(frozen=True)
class MpcDecision:
    """The MPC stage's output: the reading passed on, the new command (None: no solve this
    cycle, or a hold) and whether the safe hold must engage."""

    reading: PolishingReading
    command: MpcCommand | None
    hold: bool


class MpcStage:
    """The MPC side of Fig. 2 (a :class:`~ffmpc_core.runner.Controller`): on a solve cycle the
    MPC solves from (q̂, q̇̂, λ̂ or τ̂) if the input its formulation needs is plausible; an
    implausible input or a solve that raises asks for the safe hold. Counts the failures (among
    them ``constraint_failures``: solutions that broke a hard constraint beyond its tolerance,
    :class:`~ffmpc_core.constraints.ConstraintViolationError`) and keeps the solve times (s),
    SQP iterations, and each solve's time t (s) with the state x̂ it started from
    (``solve_states``: with a δo, the prediction at t + δo)."""

    def __init__(self, mpc: ModelPredictiveController, robot: RobotModel) -> None:
        self.mpc = mpc
        self.robot = robot
        self.formulation = mpc.config.ocp.formulation
        self.failures = 0
        self.constraint_failures = 0
        self.relaxed_solves = 0  # solves from an x̂ beyond a bound (relaxed bounds)
        self.solve_times: list[float] = []
        self.iterations: list[int] = []
        self.solve_states: list[tuple[float, np.ndarray]] = []

    def reset(self) -> None:
        """Reset the MPC and forget the counts and logs."""
        self.mpc.reset()
        self.failures = 0
        self.constraint_failures = 0
        self.relaxed_solves = 0
        self.solve_times.clear()
        self.iterations.clear()
        self.solve_states.clear()

    def step(self, reading: PolishingReading, t: float, /) -> MpcDecision:
        """Solve on a solve cycle (t in s) or pass the reading on; ask for the safe hold on an
        implausible input or a failed solve."""
        if not reading.solve:
            return MpcDecision(reading, None, False)
        needs_ok = (self.formulation != "force_feedback" or reading.force_ok) and (
            self.formulation != "torque_feedback"
            or torque_plausible(reading.torque, self.robot.torque_limit)
        )
        command = None
        if needs_ok:
            meas = MpcMeasurement(
                q=reading.q, v=reading.v, force=reading.force, torque=reading.torque
            )
            try:
                command = self.mpc.step(meas, t)
            except ConstraintViolationError:
                command = None
                self.failures += 1
                self.constraint_failures += 1
            except FfmpcError:
                command = None
                self.failures += 1
        if command is None:
            return MpcDecision(reading, None, True)  # an implausible input or a failed solve
        self.solve_times.append(command.solve_time)
        self.iterations.append(command.iterations)
        self.relaxed_solves += command.relaxed
        self.solve_states.append((t, command.state))
        return MpcDecision(reading, command, False)


class LowLevelStage:
    """The low-level loop of Fig. 2 (a :class:`~ffmpc_core.runner.Controller`): takes the MPC
    stage's decision (hold, or a new τ* it may refuse: a bad torque engages the safe hold), then
    hold / blend / track / fallback + the torque PID (eq 33). An implausible λ̂ reaches it as
    missing: it holds the newest plausible one for ``force_hold_time``, then sends τ* without
    feedback (:class:`~ffmpc_core.lowlevel.LowLevelConfig`)."""

    def __init__(self, lowlevel: LowLevelController) -> None:
        self.lowlevel = lowlevel

    def reset(self) -> None:
        """Reset the low-level controller (PID, safe hold, blend)."""
        self.lowlevel.reset()

    def step(self, decision: MpcDecision, t: float, /) -> LowLevelOutput:
        """The motor torque of this cycle (t in s) from the MPC's decision: a new command, the
        safe hold, or the one in force."""
        if decision.hold:
            self.lowlevel.engage_hold()
        elif decision.command is not None:
            try:
                self.lowlevel.set_command(decision.command, t)
            except InputError:
                pass  # refused; a bad torque has engaged the safe hold
        r = decision.reading
        force = r.force if r.force_ok else None
        return self.lowlevel.step(LowLevelMeasurement(r.q, r.v, r.torque, force), t)


class PolishingLoop:
    """The polishing run's scenario (:class:`~ffmpc_core.runner.LoopScenario`; module
    docstring).

    Args:
        robot: the robot model.
        contact: the MPC's contact model (which components of the wrench λ̂ holds).
        joint_sensing, force_sensing, actuation: the run's device models (each drawing from its
            own generator: they draw every cycle, faults or not); ``force_sensing`` reads λ̂
            from the plant's state and this cycle's q̂ (:func:`ffmpc_core.polishing.force_pipeline`).
        log: the run's log (one row per cycle).
        mpc_every: plant cycles per MPC period.
        faults: the faults to inject (they change what the controllers read, never the plant).
        initial_torque: τ̂ before the first cycle, N·m (the motors hold the robot at start).
        disturbance: called with k before the plant's step k (the external push).
    """

    def __init__(
        self,
        robot: RobotModel,
        contact: ContactConfig,
        joint_sensing: JointSensingModel,
        force_sensing: ForcePipeline,
        actuation: ActuationModel,
        log: PolishingLog,
        mpc_every: int,
        faults: Sequence[Fault] = (),
        initial_torque: np.ndarray | None = None,
        disturbance: Callable[[int], None] | None = None,
    ) -> None:
        self.robot = robot
        self.contact = contact
        self.joint_sensing = joint_sensing
        self.force_sensing = force_sensing
        self.actuation = actuation
        self.log = log
        self.mpc_every = mpc_every
        self.faults = tuple(faults)
        self.disturbance = disturbance
        nv, steps = robot.nv, log.steps
        self.tau_hat = robot.gravity(robot.q_nominal) if initial_torque is None else initial_torque
        self._received: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        #: Safety traces per cycle: true q̇ (rad/s), τ^m (N·m), applied τ̂ (N·m), low-level mode.
        self.trace_v = np.zeros((steps, nv))
        self.trace_tau = np.zeros((steps, nv))
        self.trace_applied = np.zeros((steps, nv))
        self.trace_mode = np.zeros(steps, dtype=int)

    def measure(self, k: int, t: float, state: PolishingPlantState, /) -> PolishingReading:
        """What the controllers read at cycle k (t in s): the sensing models of eq 30 and 32
        applied to the plant's state, with the injected faults."""
        active = active_kinds(self.faults, t) if self.faults else {}
        q_hat, v_hat = self.joint_sensing.step(state.q, state.v)
        f_hat = self.force_sensing.measure(state.q, state.v, state.wrench_world, q_hat, v_hat)
        # What the controllers read this cycle (faults change only this).
        tau_read, f_read = self.tau_hat, f_hat
        if "torque-spike" in active:
            tau_read = np.full(self.robot.nv, active["torque-spike"].value)
        if "nan-wrench" in active:
            f_read = np.full_like(f_hat, np.nan)
        sensors_fresh = "sensor-dropout" not in active or self._received is None
        if sensors_fresh:
            self._received = (q_hat, v_hat, tau_read, f_read)
        assert self._received is not None  # the first cycle always reads fresh sensors
        q_read, v_read, tau_read, f_read = self._received
        try:
            check_force(f_read)
            force_ok = True
        except InputError:
            force_ok = False
        solve = k % self.mpc_every == 0 and sensors_fresh and "mpc-dropout" not in active
        return PolishingReading(q_read, v_read, tau_read, f_read, force_ok, solve, f_hat)

    def actuate(
        self, k: int, t: float, state: PolishingPlantState, command: LowLevelOutput, /
    ) -> np.ndarray:
        """The joint torque the plant applies at cycle k: the actuation model of eq 31 on the
        motor torque (N·m)."""
        self.tau_hat = self.actuation.step(command.motor_torque, state.v)
        if self.disturbance is not None:
            self.disturbance(k)
        return self.tau_hat

    def record(
        self,
        k: int,
        t: float,
        state: PolishingPlantState,
        measurement: PolishingReading,
        command: LowLevelOutput,
        joint_input: np.ndarray | None,
        /,
    ) -> None:
        """Log cycle k into the run's :class:`~ffmpc_core.polishing.PolishingLog`."""
        assert joint_input is not None  # the polishing loop never ends early
        self.log.record(
            k,
            t,
            state.q,
            state.normal_force,
            measurement.force_sensor[-1],
            command.desired_torque,
            joint_input,
            command.motor_torque,
        )
        self.trace_v[k], self.trace_tau[k] = state.v, command.motor_torque
        self.trace_mode[k] = int(command.mode)
        self.trace_applied[k] = joint_input
