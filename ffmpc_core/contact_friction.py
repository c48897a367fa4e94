"""Coulomb friction of a sliding contact, as joint torques (for the MPC's delay predictor).

The paper's contact models (eq 4–5 rigid, eq 16–18 visco-elastic) are pure sliding: no force
acts along the surface (its Sec. VIII-1 names a Coulomb friction model as the improvement). The
simulated table has Coulomb friction (lateral coefficient 0.5, paper VI-B), so at 50 N a 25 N
drag opposes the polishing motion. The OCPs keep the paper's model; the δo predictor
(:meth:`ffmpc_core.mpc.ModelPredictiveController.predict`), which integrates the robot over the
δo it cannot act on, adds this drag when ``ContactConfig.friction_coefficient`` > 0: without it
the predicted state runs ahead of the robot (measured: README, "The delay predictor and the
table's friction").
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ffmpc_core.config import ContactConfig
from ffmpc_core.robots import RobotModel


def contact_normal(robot: RobotModel, data: pin.Data, contact: ContactConfig) -> np.ndarray:
    """Unit contact normal, world frame: the axis ``contact.normal_axis`` of the contact's frame
    (the world axis for LOCAL_WORLD_ALIGNED, the frame's own axis for LOCAL). Needs the frame
    placements of ``data`` (forward kinematics done)."""
    if contact.frame_type == "LOCAL":
        return np.array(data.oMf[robot.contact_frame_id].rotation[:, contact.normal_axis])
    normal = np.zeros(3)
    normal[contact.normal_axis] = 1.0
    return normal


def coulomb_friction_torque(
    robot: RobotModel,
    data: pin.Data,
    q: np.ndarray,
    v: np.ndarray,
    normal_force: float,
    contact: ContactConfig,
) -> np.ndarray:
    """Joint torques J_linᵀ f of the surface's friction on the contact frame, N·m.

    f = −μ·λ_n·tanh(‖v_t‖ / v_s)·v_t / ‖v_t‖, N, world frame: μ =
    ``contact.friction_coefficient``, λ_n = max(normal_force, 0) N (the normal force pressing
    the tool on the surface), v_t the contact point's velocity (m/s, world) without its component
    along the normal (:func:`contact_normal`), v_s = ``contact.friction_velocity`` m/s (the
    tanh smooths the sign of Coulomb's law at rest). J_lin: the contact frame's linear Jacobian in
    LOCAL_WORLD_ALIGNED axes. Zero without a normal force or with μ = 0.
    """
    mu = contact.friction_coefficient
    pressing = max(float(normal_force), 0.0)
    if mu == 0.0 or pressing == 0.0:
        return np.zeros(robot.nv)
    frame = robot.contact_frame_id
    jacobian = pin.computeFrameJacobian(
        robot.model, data, q, frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    )[:3]  # computeFrameJacobian runs the forward kinematics of q into data
    pin.updateFramePlacement(robot.model, data, frame)
    normal = contact_normal(robot, data, contact)
    velocity = jacobian @ v
    tangential = velocity - (velocity @ normal) * normal
    speed = float(np.linalg.norm(tangential))
    if speed == 0.0:
        return np.zeros(robot.nv)
    force = -mu * pressing * np.tanh(speed / contact.friction_velocity) * tangential / speed
    return jacobian.T @ force
