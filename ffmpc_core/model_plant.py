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
    whole ``ModelPredictiveController.step``: state, references, warm start, solve, command) and
    ``converged``."""

    t: list[float] = field(default_factory=list)
    force: list[np.ndarray] = field(default_factory=list)
    force_reference: list[float] = field(default_factory=list)
    ee_position: list[np.ndarray] = field(default_factory=list)
    ee_reference: list[np.ndarray] = field(default_factory=list)
    iterations: list[int] = field(default_factory=list)
    solve_time: list[float] = field(default_factory=list)
    step_time: list[float] = field(default_factory=list)
    converged: list[bool] = field(default_factory=list)

    def arrays(self) -> dict[str, np.ndarray]:
        return {k: np.asarray(v) for k, v in self.__dict__.items()}


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

    The MPC re-plans every ``mpc_config.period`` (a whole number of plant steps) and its
    command is held (zero-order hold) in between.
    """
    ratio = mpc_config.period / plant_dt
    if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
        raise ConfigError("the MPC period must be a whole number of plant steps")
    every = int(round(ratio))
    plant = ModelPlant(
        robot, mpc_config.formulation, mpc_config.contact, plant_dt, mpc_config.cutoff_frequency
    )
    plant.reset(robot.q_nominal if q0 is None else q0)
    mpc = ModelPredictiveController(robot, mpc_config, schedule, node_factory=node_factory)
    data = robot.create_data()
    log = ClosedLoopLog()
    command: MpcCommand | None = None
    import pinocchio as pin

    for k in range(int(round(duration / plant_dt))):
        t = k * plant_dt
        if k % every == 0:
            measurement = plant.measurement()
            start = time.perf_counter()
            command = mpc.step(measurement, t)
            log.step_time.append(time.perf_counter() - start)
            log.iterations.append(command.iterations)
            log.solve_time.append(command.solve_time)
            log.converged.append(command.converged)
        assert command is not None  # k = 0 solved
        control = command.us[0] if mpc_config.formulation == "torque_feedback" else command.torque
        plant.step(control, schedule.in_contact(t))
        q = plant.x[: robot.nq]
        pin.framesForwardKinematics(robot.model, data, q)
        log.t.append(t + plant_dt)
        log.force.append(plant.force.copy())
        log.force_reference.append(schedule.force(t + plant_dt))
        log.ee_position.append(data.oMf[robot.contact_frame_id].translation.copy())
        log.ee_reference.append(schedule.ee_position(t + plant_dt))
    return log


def _conforms(plant: ModelPlant) -> Plant[MpcMeasurement]:
    """Static check (mypy): a ModelPlant is a :class:`~ffmpc_core.plant.Plant`."""
    return plant
