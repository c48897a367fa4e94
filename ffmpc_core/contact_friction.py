"""Coulomb friction of a sliding contact, as joint torques (for the MPC's delay predictor).

The paper's contact models (eq 4–5 rigid, eq 16–18 visco-elastic) are pure sliding: no force
acts along the surface (its Sec. VIII-1 names a Coulomb friction model as the improvement). The
simulated table has Coulomb friction (lateral coefficient 0.5, paper VI-B), so at 50 N a 25 N
drag opposes the polishing motion. The OCPs keep the paper's model; the δo predictor
(:meth:`ffmpc_core.mpc.ModelPredictiveController.predict`), which integrates the robot over the
δo it cannot act on, adds this drag when ``ContactConfig.friction_coefficient`` > 0: without it
the predicted state runs ahead of the robot (measured: README, "The delay predictor and the
table's friction").

The same drag enters the force the force-feedback MPC measures. Its 1-D force state is the
force along the contact normal it assumes (world z); on a table tilted by an unknown θ the tool
slides along the tilted surface, so the drag −μ·N·d (d: the unit sliding direction) has a part
−μ·N·(d·n̂) along that assumed normal n̂, which swings with the direction of the circle
(±μ·N·sin θ: ±2.2 N at 50 N, μ = 0.5, θ = 5°). :func:`normal_force_without_friction` removes
it, with the sliding direction from :class:`SlidingDirectionEstimator`
(``ContactConfig.friction_in_measured_force``).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ffmpc_core.config import ContactConfig
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.robots import RobotModel

#: Largest change of the measured normal force that :func:`normal_force_without_friction` makes,
#: as a fraction of it: the drag's share is μ·|d·n̂| ≤ μ·sin θ (0.05 for μ = 0.5 at the study's
#: largest tilt 6°); a larger one would come from a sliding direction that is not along the
#: surface (the tool moving off or into it), not from friction, and is cut here.
MAX_FRICTION_CORRECTION = 0.1


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


def normal_force_without_friction(
    measured_normal_force: float,
    sliding_direction: np.ndarray,
    normal: np.ndarray,
    friction_coefficient: float,
) -> float:
    """The normal force N pressing the tool on the surface from the force λ̂ measured along the
    normal n̂ the controller assumes, N.

    The surface pushes the tool with N·n − μ·N·d (n: its true normal, d: the unit direction the
    tool slides in, along the surface, so d·n = 0; Coulomb drag with μ =
    ``friction_coefficient``). Along n̂: λ̂ = N·(n·n̂) − μ·N·(d·n̂), so with n·n̂ = cos θ ≈ 1
    (the tilt θ is unknown; 1 − cos 6° = 0.5 %):

        N = λ̂ / (1 − μ·(d·n̂)),

    the factor kept within 1 ± :data:`MAX_FRICTION_CORRECTION`. ``sliding_direction`` d (a unit
    vector, :class:`SlidingDirectionEstimator`) and ``normal`` n̂: world frame. λ̂ ≤ 0 (no
    contact) is returned as it is.
    """
    lam = float(measured_normal_force)
    if lam <= 0.0:
        return lam
    share = friction_coefficient * float(np.dot(sliding_direction, normal))
    share = min(max(share, -MAX_FRICTION_CORRECTION), MAX_FRICTION_CORRECTION)
    return lam / (1.0 - share)


class SlidingDirectionEstimator:
    """The direction the contact point slides in, world frame, from the measured joint state.

    The contact frame's linear velocity (LOCAL_WORLD_ALIGNED, m/s) is low-pass filtered with
    time constant ``filter_time`` (s): the sliding direction turns with the task (0.5 Hz on the
    3 rad/s circle), while the tool's vibration along the normal (tens of Hz) would otherwise
    tip it. The direction is the filtered velocity over its norm, once the filtered speed
    across the assumed normal exceeds ``min_speed`` (m/s); below it (at rest or starting) the
    friction's direction is unknown and :meth:`direction` is None.
    """

    def __init__(
        self,
        robot: RobotModel,
        contact: ContactConfig,
        filter_time: float,
        min_speed: float,
    ) -> None:
        if not np.isfinite(filter_time) or filter_time < 0.0:
            raise ConfigError(f"filter_time must be >= 0 s, got {filter_time}")
        if not np.isfinite(min_speed) or min_speed <= 0.0:
            raise ConfigError(f"min_speed must be > 0 m/s, got {min_speed}")
        self.robot = robot
        self.contact = contact
        self.filter_time = float(filter_time)
        self.min_speed = float(min_speed)
        self._data = robot.create_data()
        self.normal = np.zeros(3)
        self.velocity = np.zeros(3)
        self._t: float | None = None

    def reset(self) -> None:
        """Forget the filtered velocity (the next update starts from the measured one)."""
        self._t = None
        self.velocity[:] = 0.0

    def update(self, q: np.ndarray, v: np.ndarray, t: float) -> None:
        """Filter in the contact point's velocity at (q rad, v rad/s) measured at time t (s).
        InputError for a time before the last update's."""
        robot, data = self.robot, self._data
        pin.forwardKinematics(robot.model, data, q, v)
        pin.updateFramePlacement(robot.model, data, robot.contact_frame_id)
        velocity = pin.getFrameVelocity(
            robot.model, data, robot.contact_frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        ).linear
        self.normal[:] = contact_normal(robot, data, self.contact)
        if self._t is None:
            self.velocity[:] = velocity
        else:
            dt = t - self._t
            if dt < 0.0:
                raise InputError(f"sliding velocity at t = {t} s, before the last {self._t} s")
            gain = 1.0 if self.filter_time == 0.0 else 1.0 - np.exp(-dt / self.filter_time)
            self.velocity += gain * (velocity - self.velocity)
        self._t = float(t)

    def direction(self) -> np.ndarray | None:
        """Unit sliding direction d (world), or None while the filtered speed across the
        normal is below ``min_speed``."""
        across = self.velocity - (self.velocity @ self.normal) * self.normal
        if float(np.linalg.norm(across)) < self.min_speed:
            return None
        return self.velocity / float(np.linalg.norm(self.velocity))
