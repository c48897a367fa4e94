"""A plant made of an OCP formulation's own dynamics, integrated at a fine step.

This is the "perfect model" closed loop: no simulator, no noise, no delay. It checks that each
MPC formulation does what its model says it can (reach and hold a force) before the PyBullet
study adds everything the model does not know. The plant is one running node of the same
formulation, integrated at ``dt`` (1 ms by default):

* classical: (q, v) with a rigid contact, force = the KKT dual λ^r (eq 4), driven by τ;
* torque-feedback: (q, v, τ) with the low-pass actuation (eq 13), driven by the unfiltered input
  w (the MPC's first control), force = λ^r;
* force-feedback: (q, v, λ) with the visco-elastic contact (eq 18), driven by τ, force = λ.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, cast

import numpy as np

from ffmpc_core.config import ContactConfig, CostWeights, NodeReference
from ffmpc_core.errors import ConfigError
from ffmpc_core.mpc import (
    ModelPredictiveController,
    MpcCommand,
    MpcConfig,
    MpcMeasurement,
    OcpNode,
    Schedule,
)
from ffmpc_core.plant import Plant
from ffmpc_core.robots import RobotModel

if TYPE_CHECKING:
    from ffmpc_core.lowpass import LowPassNode
    from ffmpc_core.rigid_contact import RigidContactNode
    from ffmpc_core.soft_contact import SoftContactNode


class ContactSchedule(Schedule, Protocol):
    """A task schedule that also says when the plant is in contact (:mod:`ffmpc_core.tasks`)."""

    def in_contact(self, t: float) -> bool:
        """True when the task wants contact at time t (s)."""
        ...

    def force(self, t: float) -> float:
        """λ̄(t), N."""
        ...

    def ee_position(self, t: float) -> np.ndarray:
        """p̄(t), m, world frame."""
        ...


class ModelPlant:
    """One formulation's dynamics as a simulated plant (the :class:`~ffmpc_core.plant.Plant`
    shape, state :class:`~ffmpc_core.mpc.MpcMeasurement`).

    Args:
        robot: robot model.
        formulation: ``"classical"``, ``"torque_feedback"`` or ``"force_feedback"``.
        contact: contact model (K, B of the visco-elastic plant for force-feedback).
        dt: integration step, s.
        cutoff_frequency: low-pass actuation cut-off, Hz (torque-feedback).
    """

    def __init__(
        self,
        robot: RobotModel,
        formulation: str,
        contact: ContactConfig,
        dt: float = 1e-3,
        cutoff_frequency: float = 50.0,
    ) -> None:
        self.robot = robot
        self.formulation = formulation
        self.contact = contact
        self.dt = dt
        weights = CostWeights()
        self._node: RigidContactNode | LowPassNode | SoftContactNode
        if formulation == "classical":
            from ffmpc_core.rigid_contact import make_rigid_contact_node

            self._node = make_rigid_contact_node(robot, contact, weights, dt, False)
        elif formulation == "torque_feedback":
            from ffmpc_core.lowpass import make_lowpass_node

            self._node = make_lowpass_node(robot, contact, weights, dt, False, cutoff_frequency)
        elif formulation == "force_feedback":
            from ffmpc_core.soft_contact import make_soft_contact_node

            self._node = make_soft_contact_node(robot, contact, weights, dt, False)
        else:
            raise ConfigError(f"unknown formulation {formulation!r}")
        self._data = self._node.model.createData()
        self._in_contact: bool | None = None
        self.x = np.zeros(self._node.model.state.nx)
        self.force = np.zeros(contact.dimension)

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Start at rest (or at velocity v) with zero force and torque = gravity."""
        nv = self.robot.nv
        self.x[:] = 0.0
        self.x[:nv] = q
        self.x[nv : 2 * nv] = 0.0 if v is None else v
        if self.formulation == "torque_feedback":
            self.x[2 * nv :] = self.robot.gravity(q)
        self.force[:] = 0.0
        self._set_contact(False)

    def _set_contact(self, in_contact: bool) -> None:
        if in_contact == self._in_contact:
            return
        nc = self.contact.dimension
        ref = NodeReference(np.zeros(3), np.zeros(nc), 0.0, 0.0, in_contact)
        if self._node.set_reference(ref):
            self._data = self._node.model.createData()
        self._in_contact = in_contact

    def set_contact(self, in_contact: bool) -> None:
        """Switch the contact model on (the task wants contact) or off, from the next step."""
        self._set_contact(bool(in_contact))

    def step(self, control: np.ndarray, in_contact: bool | None = None) -> None:
        """Integrate one step with ``control`` (τ, or w for torque-feedback), N·m; with
        ``in_contact`` (True/False) the contact model is switched first, None keeps it."""
        if in_contact is not None:
            self._set_contact(in_contact)
        self._node.model.calc(self._data, self.x, np.asarray(control, float))
        if self.formulation == "force_feedback":
            self.x[:] = self._data.xnext
            self.force[:] = self.x[2 * self.robot.nv :]
        else:
            # the two rigid-contact formulations: λ comes from the node, not the state
            node = cast("RigidContactNode | LowPassNode", self._node)
            self.force[:] = node.contact_force(self._data)
            self.x[:] = self._data.xnext

    def state(self) -> MpcMeasurement:
        """The state after the last step (:class:`~ffmpc_core.plant.Plant`'s shape): q rad,
        v rad/s, the contact force N (and τ N·m for torque-feedback)."""
        return self.measurement()

    def measurement(self) -> MpcMeasurement:
        """The state as the MPC's measurement (no noise, no delay)."""
        nv = self.robot.nv
        torque = self.x[2 * nv :].copy() if self.formulation == "torque_feedback" else None
        return MpcMeasurement(
            q=self.x[:nv].copy(),
            v=self.x[nv : 2 * nv].copy(),
            force=self.force.copy(),
            torque=torque,
        )


@dataclass
class ClosedLoopLog:
    """Time series of a closed-loop run: rows per plant step, and per MPC step for
    ``iterations``, ``solve_time`` (s, the SQP solve alone), ``step_time`` (s, wall time of the
    whole ``ModelPredictiveController.step``: state, references, warm start, solve, command),
    ``converged``, ``qp_iterations`` (ADMM iterations of the last SQP iteration; 0 without
    constraints), ``constraint_violation`` (the solution's largest excess over a bound, a
    fraction of its limit) and ``screen_iterations`` (SQP iterations of an unconstrained screen
    that broke a bound: ``MpcCommand``)."""

    t: list[float] = field(default_factory=list)
    force: list[np.ndarray] = field(default_factory=list)
    force_reference: list[float] = field(default_factory=list)
    ee_position: list[np.ndarray] = field(default_factory=list)
    ee_reference: list[np.ndarray] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)
    solve_time: list[float] = field(default_factory=list)
    step_time: list[float] = field(default_factory=list)
    converged: list[bool] = field(default_factory=list)
    qp_iterations: list[int] = field(default_factory=list)
    constraint_violation: list[float] = field(default_factory=list)
    screen_iterations: list[int] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        """Every logged series as a numpy array, by field name (one row per cycle)."""
        return {k: np.asarray(v) for k, v in self.__dict__.items()}


class _TimedMpc:
    """The MPC as the model loop's controller: times each whole ``step`` (wall time, s) and logs
    its solver figures into the run's :class:`ClosedLoopLog`."""

    def __init__(self, mpc: ModelPredictiveController, log: ClosedLoopLog) -> None:
        self.mpc = mpc
        self.log = log

    def reset(self) -> None:
        self.mpc.reset()

    def step(self, measurement: MpcMeasurement, t: float, /) -> MpcCommand:
        start = time.perf_counter()
        command = self.mpc.step(measurement, t)
        self.log.step_time.append(time.perf_counter() - start)
        self.log.iterations.append(command.iterations)
        self.log.solve_time.append(command.solve_time)
        self.log.converged.append(command.converged)
        self.log.qp_iterations.append(command.qp_iterations)
        self.log.constraint_violation.append(command.constraint_violation)
        self.log.screen_iterations.append(command.screen_iterations)
        return command


class _ModelLoop:
    """The model loop's scenario (:class:`~ffmpc_core.runner.LoopScenario`): the MPC reads the
    plant's exact state; the plant gets τ (w, the low-pass input, for torque-feedback) with its
    contact switched as the task schedules it; the log row of cycle k is the state after its step,
    t_k + dt (written when cycle k + 1 reads it, and by :meth:`finish` for the last one)."""

    def __init__(
        self, plant: ModelPlant, schedule: ContactSchedule, log: ClosedLoopLog, robot: RobotModel
    ) -> None:
        self.plant = plant
        self.schedule = schedule
        self.log = log
        self.robot = robot
        self._data = robot.create_data()

    def measure(self, k: int, t: float, state: MpcMeasurement, /) -> MpcMeasurement:
        return state

    def record(
        self,
        k: int,
        t: float,
        state: MpcMeasurement,
        measurement: MpcMeasurement,
        command: MpcCommand,
        joint_input: np.ndarray | None,
        /,
    ) -> None:
        if k > 0:  # the row of cycle k - 1, at its t + dt (as that cycle computed it)
            self._row((k - 1) * self.plant.dt + self.plant.dt, state)

    def actuate(
        self, k: int, t: float, state: MpcMeasurement, command: MpcCommand, /
    ) -> np.ndarray:
        self.plant.set_contact(self.schedule.in_contact(t))
        return command.us[0] if self.plant.formulation == "torque_feedback" else command.torque

    def finish(self, steps: int) -> None:
        """The last row: the state after the last of ``steps`` cycles."""
        self._row((steps - 1) * self.plant.dt + self.plant.dt, self.plant.state())

    def _row(self, t: float, state: MpcMeasurement) -> None:
        import pinocchio as pin

        pin.framesForwardKinematics(self.robot.model, self._data, state.q)
        log = self.log
        log.t.append(t)
        log.force.append(self.plant.force.copy())
        log.force_reference.append(self.schedule.force(t))
        log.ee_position.append(self._data.oMf[self.robot.contact_frame_id].translation.copy())
        log.ee_reference.append(self.schedule.ee_position(t))


def run_model_closed_loop(
    robot: RobotModel,
    mpc_config: MpcConfig,
    schedule: ContactSchedule,
    duration: float,
    plant_dt: float = 1e-3,
    q0: np.ndarray | None = None,
    node_factory: Callable[[bool], OcpNode] | None = None,
) -> ClosedLoopLog:
    """Run an MPC against its own formulation's dynamics for ``duration`` s; return the log.

    The MPC re-plans every ``mpc_config.ocp.period`` (a whole number of plant steps) and its
    command is held (zero-order hold) in between. The loop is :func:`ffmpc_core.runner.
    run_scenario`.
    """
    from ffmpc_core.runner import LockstepClock, PeriodicController, run_scenario

    ratio = mpc_config.ocp.period / plant_dt
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ConfigError("the MPC period must be a whole number of plant steps")
    plant = ModelPlant(
        robot,
        mpc_config.ocp.formulation,
        mpc_config.contact,
        plant_dt,
        mpc_config.ocp.cutoff_frequency,
    )
    plant.reset(robot.q_nominal if q0 is None else q0)
    mpc = ModelPredictiveController(robot, mpc_config, schedule, node_factory=node_factory)
    log = ClosedLoopLog()
    scenario = _ModelLoop(plant, schedule, log, robot)
    clock = LockstepClock.for_duration(plant_dt, duration)
    controller = PeriodicController(_TimedMpc(mpc, log), int(round(ratio)))
    steps = run_scenario(scenario, plant, [controller], clock)
    if steps:
        scenario.finish(steps)
    return log


def _conforms(plant: ModelPlant) -> Plant[MpcMeasurement]:
    """Static check (mypy): a ModelPlant is a :class:`~ffmpc_core.plant.Plant`."""
    return plant
