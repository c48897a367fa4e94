"""The one plant shape every closed loop drives (no simulator here: a protocol only).

Three plants have it: the PyBullet plant (:class:`sim_bridge.plant.Plant`, state
:class:`sim_bridge.plant.PlantState`), the MuJoCo plant
(:class:`sim_bridge.mujoco_plant.MujocoPlant`, the same state) and an OCP formulation's own dynamics
(:class:`ffmpc_core.model_plant.ModelPlant`, state :class:`ffmpc_core.mpc.MpcMeasurement`).
A closed loop written against :class:`Plant` runs on either.
"""

from __future__ import annotations

from typing import Protocol, TypeVar, runtime_checkable

import numpy as np

__all__ = ["Plant"]

StateT_co = TypeVar("StateT_co", covariant=True)


@runtime_checkable
class Plant(Protocol[StateT_co]):
    """A simulated robot advanced by one joint command per fixed step.

    Attributes:
        dt: the step, s.
    """

    dt: float

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        """Start at joint positions ``q`` (rad) and velocities ``v`` (rad/s, default rest),
        time 0."""
        ...

    def step(self, command: np.ndarray, /) -> None:
        """Apply the joint command (N·m; the low-pass input for a torque-feedback model plant)
        for one step of ``dt`` s."""
        ...

    def state(self) -> StateT_co:
        """The state after the last step (the truth, before any sensing model)."""
        ...
