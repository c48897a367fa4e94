"""Cartesian command → joint torques: a task-space inverse-dynamics law (robot-specific part).

For the contact frame (pinocchio ``LOCAL_WORLD_ALIGNED``; linear m, m/s, angular rad, rad/s):

1. desired task acceleration (6,)::

       ẍ* = [a_ff + K_d (v_ref − v) + K_p (p_ref − p);  −D_ω ω + K_ω log3(R_ref Rᵀ)]

2. joint accelerations: the primary task plus, as the paper's secondary task, the smallest joint
   acceleration (Moore–Penrose solution) with a small null-space joint damping against
   self-motion drift::

       q̈ = J⁺ (ẍ* − J̇ q̇) + (I − J⁺ J)(−k_null q̇)

3. inverse dynamics with the measured contact force (the force the environment exerts on the
   robot, world frame, N) compensated::

       τ = M q̈ + h − J_linᵀ F_ext,   saturated to the torque limits (N·m).

Gains: ``K_p`` 1/s², ``K_d`` 1/s, ``K_ω`` 1/s², ``D_ω`` 1/s, ``k_null`` 1/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.control import CartesianCommand
from ffmpc_core.robots import RobotModel

__all__ = ["TaskSpaceGains", "TaskSpaceInverseDynamics"]

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


@dataclass(frozen=True)
class TaskSpaceGains:
    """Gains of the law (see the module docstring for units)."""

    position: float = 400.0
    velocity: float = 40.0
    orientation: float = 400.0
    angular_velocity: float = 40.0
    null_damping: float = 10.0
    pinv_damping: float = 1e-6

    def __post_init__(self) -> None:
        for name, value in self.__dict__.items():
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"TaskSpaceGains.{name} must be finite and ≥ 0")


class TaskSpaceInverseDynamics:
    """The law of the module docstring, with preallocated pinocchio data."""

    def __init__(self, robot: RobotModel, gains: TaskSpaceGains | None = None) -> None:
        self.robot = robot
        self.gains = gains if gains is not None else TaskSpaceGains()
        self._data = robot.create_data()

    def torque(
        self,
        command: CartesianCommand,
        q: np.ndarray,
        v: np.ndarray,
        external_force: np.ndarray | None = None,
    ) -> np.ndarray:
        """Joint torques (N·m) realising ``command`` at (q rad, v rad/s)."""
        model, data, fid = self.robot.model, self._data, self.robot.contact_frame_id
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if q.shape != (model.nq,) or v.shape != (model.nv,):
            raise InputError("q and v have the wrong size")
        g = self.gains
        pin.forwardKinematics(model, data, q, v, np.zeros(model.nv))
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        oMf = data.oMf[fid]
        J = pin.getFrameJacobian(model, data, fid, _LWA)
        vel = pin.getFrameVelocity(model, data, fid, _LWA)
        drift = pin.getFrameClassicalAcceleration(model, data, fid, _LWA)
        lin = (
            command.acceleration
            + g.velocity * (command.velocity - vel.linear)
            + g.position * (command.position - oMf.translation)
        )
        ang = g.orientation * pin.log3(command.rotation @ oMf.rotation.T) - g.angular_velocity * (
            vel.angular
        )
        xdd = np.concatenate([lin, ang]) - np.concatenate([drift.linear, drift.angular])
        JJt = J @ J.T + g.pinv_damping * np.eye(6)
        Jpinv = J.T @ np.linalg.inv(JJt)
        qdd = Jpinv @ xdd + (np.eye(model.nv) - Jpinv @ J) @ (-g.null_damping * v)
        M = pin.crba(model, data, q)
        M = np.triu(M) + np.triu(M, 1).T
        tau = M @ qdd + pin.nonLinearEffects(model, data, q, v)
        if external_force is not None:
            tau -= J[:3].T @ np.asarray(external_force, dtype=float)
        return self.robot.clip_torque(tau)
