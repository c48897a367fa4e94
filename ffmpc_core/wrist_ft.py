"""A wrist force/torque sensor as a real cell has one (issue 27): it sits between the flange and
the tool, so it measures the tool's weight (which turns with the wrist) and its own bias besides
the contact wrench; the force node removes both with the calibrated bias, mass and centre of mass
and the robot's current orientation (pinocchio forward kinematics of the measured q).

Frames. S, the sensor frame, is the robot's flange frame (:attr:`RobotModel.flange_frame`: the
sensor is mounted on the flange, the tool on the sensor); C is the contact frame
(``RobotModel.tool_placement`` in S); W is the world. A wrench is ``[f; m]`` (N, N·m).

The sensor's reading (what the tool exerts on the sensor, the usual sign of an F/T sensor: a
push on the tool's tip reads as that push), in S about S's origin:

    w_S = X_SC·w_C + w_tool + b + ν,    w_tool = Y·(g_S − a_S) − v_S ×* (Y·v_S)

* X_SC·w_C: the contact wrench the environment exerts on the tool (the plant's, about C's
  origin, world axes) moved to S (:func:`contact_wrench_in_sensor`);
* w_tool: the tool's weight [m·g_S; c × m·g_S] (:func:`tool_gravity_wrench`; mass m and centre
  of mass c in S, :class:`~ffmpc_core.robots.ToolLoad`; g_S = R_WSᵀ·g gravity in S), the model
  of ``ft_sensor.inertial_wrench: false`` (the default). With ``inertial_wrench: true`` it is the
  tool's gravito-inertial wrench Y·(g_S − a_S) − v_S ×* (Y·v_S) (Newton–Euler; Y its spatial
  inertia about S, v_S and a_S the spatial velocity and acceleration of S in S, a_S from the
  true q̇ of two successive cycles), which at rest is the weight;
* b: the sensor's bias (6 numbers, S);
* ν ~ N(0, diag(σ_f² I₃, σ_m² I₃)), drawn after the delay of δs cycles (as eq 32).

The compensation (:class:`WristCompensator`) subtracts the calibrated bias b̂ and the calibrated
tool's weight [m̂·ĝ_S; ĉ × m̂·ĝ_S] with ĝ_S = R̂_WSᵀ·g from the MEASURED q̂ (as ros2_controllers'
and the FZI controllers' gravity compensations) and, with ``inertial_wrench``, the tool's
inertial wrench from the measured q̂, q̇̂ (a point mass m̂ at ĉ); it moves the result to C's
origin in world axes (the frame of the MPC's force, ``contact_world_aligned``). The inertial
part is large in this simulation: the simulated wrist shakes at a few hundred Hz (joint
accelerations of 62–249 rad/s² RMS on joints 5–7 in the polishing run, seed 0), which a 1 kg
tool turns into tens of newtons of inertial force (README "The wrist F/T sensor").

Every random number comes from the generator handed in (the ``force_sensor`` device's during
the run), six draws per reading in the order fx, fy, fz, mx, my, mz.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from ffmpc_core.config import ContactConfig
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.robots import RobotModel, ToolLoad
from ffmpc_core.sensing import DelayLine, ForceSensingModel, measured_force

__all__ = [
    "ContactForceSensing",
    "ForcePipeline",
    "WristCompensator",
    "WristForceSensing",
    "WristSensorModel",
    "contact_wrench_in_sensor",
    "sensor_wrench_to_contact_world",
    "tool_gravity_wrench",
]


def tool_gravity_wrench(
    rotation_ws: np.ndarray, mass: float, center_of_mass: npt.ArrayLike, gravity: np.ndarray
) -> np.ndarray:
    """The tool's weight as the wrist sensor reads it: ``[m·g_S; c × m·g_S]`` (N, N·m, sensor
    frame about its origin), g_S = R_WSᵀ·g (``gravity`` in m/s², world frame; ``rotation_ws``
    the sensor frame's orientation in the world; c in m, sensor frame)."""
    force = mass * (rotation_ws.T @ gravity)
    return np.concatenate([force, np.cross(np.asarray(center_of_mass, float), force)])


def contact_wrench_in_sensor(
    wrench_world: np.ndarray, sensor: pin.SE3, contact: pin.SE3
) -> np.ndarray:
    """A wrench about the contact frame's origin in world axes (N, N·m; the plant's
    ``wrench_world``) as the sensor frame sees it: sensor axes, about the sensor's origin.
    ``sensor``, ``contact``: the two frames' world placements."""
    force, moment = wrench_world[:3], wrench_world[3:]
    lever = contact.translation - sensor.translation
    rotation = sensor.rotation
    return np.concatenate([rotation.T @ force, rotation.T @ (moment + np.cross(lever, force))])


def sensor_wrench_to_contact_world(
    wrench_sensor: np.ndarray, sensor: pin.SE3, contact: pin.SE3
) -> np.ndarray:
    """The inverse of :func:`contact_wrench_in_sensor`: a wrench in sensor axes about the
    sensor's origin → world axes about the contact frame's origin (N, N·m)."""
    rotation = sensor.rotation
    force = rotation @ wrench_sensor[:3]
    lever = contact.translation - sensor.translation
    return np.concatenate([force, rotation @ wrench_sensor[3:] - np.cross(lever, force)])


def _noise_std(force_noise_std: float, moment_noise_std: float) -> np.ndarray:
    std = np.array([force_noise_std] * 3 + [moment_noise_std] * 3, dtype=float)
    if not np.all(np.isfinite(std)) or np.any(std < 0.0):
        raise ConfigError(
            f"noise standard deviations must be finite and >= 0, got {force_noise_std!r} N, "
            f"{moment_noise_std!r} N·m"
        )
    return std


def _bias(bias: npt.ArrayLike) -> np.ndarray:
    arr = np.asarray(bias, dtype=float)
    if arr.shape != (6,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"an F/T bias is 6 finite numbers (N, N·m), got {bias!r}")
    return arr


class WristSensorModel:
    """The wrist sensor device (module docstring): ``step(q, v, wrench_world)`` once per cycle
    with the plant's TRUE joint state (rad, rad/s) and contact wrench returns the raw reading
    w_S (N, N·m, sensor frame); :meth:`static_readings` are readings at rest without contact
    (the calibration poses). With ``inertial=False`` the tool is weighed as if at rest
    (w_tool = [m·g_S; c × m·g_S], q̇ unused); with ``inertial=True`` its inertial wrench is read
    too.

    Args:
        robot: the robot (kinematics; the sensor frame is its flange frame).
        load: the tool really mounted (the plant's).
        bias: b, 6 numbers (N, N·m), sensor frame.
        delay: δs in cycles.
        force_noise_std, moment_noise_std: σ_f (N), σ_m (N·m).
        time_step: s, the cycle (for the acceleration a = (q̇_k − q̇_{k−1}) / Δt).
        rng: the sensor's generator.
        inertial: read the tool's inertial wrench too.
    """

    def __init__(
        self,
        robot: RobotModel,
        load: ToolLoad,
        bias: npt.ArrayLike,
        delay: int,
        force_noise_std: float,
        moment_noise_std: float,
        time_step: float,
        rng: np.random.Generator,
        inertial: bool = False,
    ) -> None:
        if not isinstance(rng, np.random.Generator):
            raise ConfigError("rng must be a numpy.random.Generator")
        if not (np.isfinite(time_step) and time_step > 0.0):
            raise ConfigError(f"time_step must be > 0 s, got {time_step!r}")
        self.robot = robot
        self.load = load
        self.bias = _bias(bias)
        self.noise_std = _noise_std(force_noise_std, moment_noise_std)
        self.time_step = float(time_step)
        self.rng = rng
        self.inertial = bool(inertial)
        self.gravity = np.array(robot.model.gravity.linear, dtype=float)
        self._inertia = load.inertia()
        self._data = robot.create_data()
        self._sensor_id = robot.model.getFrameId(robot.flange_frame)
        self._delay = DelayLine(delay, 6)
        self._v_previous: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the history (delay line and the previous q̇)."""
        self._delay.reset()
        self._v_previous = None

    def true_reading(
        self, q: np.ndarray, v: np.ndarray, a: np.ndarray, wrench_world: np.ndarray
    ) -> np.ndarray:
        """X_SC·w_C + w_tool at (q, q̇, q̈) (rad, rad/s, rad/s²): the reading of an ideal
        sensor without bias and noise (N, N·m, sensor frame)."""
        model, data = self.robot.model, self._data
        if not self.inertial:
            pin.framesForwardKinematics(model, data, q)
            sensor, contact = data.oMf[self._sensor_id], data.oMf[self.robot.contact_frame_id]
            weight = tool_gravity_wrench(
                sensor.rotation, self.load.mass, self.load.center_of_mass, self.gravity
            )
            return contact_wrench_in_sensor(wrench_world, sensor, contact) + weight
        pin.forwardKinematics(model, data, q, v, a)
        sensor = pin.updateFramePlacement(model, data, self._sensor_id)
        contact = pin.updateFramePlacement(model, data, self.robot.contact_frame_id)
        velocity = pin.getFrameVelocity(model, data, self._sensor_id, pin.LOCAL)
        acceleration = pin.getFrameAcceleration(model, data, self._sensor_id, pin.LOCAL)
        gravity = pin.Motion(sensor.rotation.T @ self.gravity, np.zeros(3))
        y = self._inertia
        tool = y * (gravity - acceleration) - velocity.cross(y * velocity)
        return contact_wrench_in_sensor(wrench_world, sensor, contact) + tool.vector

    def step(self, q: np.ndarray, v: np.ndarray, wrench_world: np.ndarray) -> np.ndarray:
        """The raw reading w_S of this cycle (N, N·m, sensor frame; module docstring)."""
        v_previous = v if self._v_previous is None else self._v_previous
        a = (v - v_previous) / self.time_step
        self._v_previous = np.array(v, dtype=float)
        delayed = self._delay.step(self.true_reading(q, v, a, wrench_world) + self.bias)
        return delayed + self.noise_std * self.rng.standard_normal(6)

    def static_readings(self, q: np.ndarray, samples: int, rng: np.random.Generator) -> np.ndarray:
        """``samples`` readings at rest in posture q without contact (samples×6; N, N·m, sensor
        frame): the tool's weight + bias + noise drawn from ``rng`` (the calibration's)."""
        zero = np.zeros(self.robot.nv)
        reading = self.true_reading(q, zero, zero, np.zeros(6)) + self.bias
        return reading + self.noise_std * rng.standard_normal((samples, 6))


class WristCompensator:
    """The force node's compensation (module docstring): ``compensate(raw, q̂, q̇̂)`` once per
    cycle → the contact wrench about the contact frame's origin, world axes (N, N·m), from the
    raw reading (sensor frame) and the measured joint state of the same cycle (rad, rad/s), with
    the calibrated bias b̂ (6), mass m̂ (kg) and centre of mass ĉ (m, sensor frame).

    It subtracts b̂ and the tool's weight [m̂·ĝ_S; ĉ × m̂·ĝ_S] at the measured orientation (a
    static compensation, as ros2_controllers' and FZI's); with ``inertial=True`` the tool's
    gravito-inertial wrench Ŷ·(ĝ_S − â_S) − v̂_S ×* (Ŷ·v̂_S) of a point mass m̂ at ĉ instead, the
    motion of S from (q̂, q̇̂, q̈̂ = (q̇̂_k − q̇̂_{k−1}) / Δt) (the tool's rotational inertia about
    its centre of mass is not calibrated: taken as 0). ``enabled=False`` subtracts nothing (the
    uncompensated pipeline: only the frame change).
    """

    def __init__(
        self,
        robot: RobotModel,
        bias: npt.ArrayLike,
        mass: float,
        center_of_mass: npt.ArrayLike,
        time_step: float,
        enabled: bool = True,
        inertial: bool = False,
    ) -> None:
        self.robot = robot
        self.bias = _bias(bias)
        self.mass = float(mass)
        self.center_of_mass = np.asarray(center_of_mass, dtype=float)
        if self.center_of_mass.shape != (3,) or not np.all(np.isfinite(self.center_of_mass)):
            raise ConfigError(f"centre of mass must be 3 finite numbers, got {center_of_mass!r}")
        if not (np.isfinite(time_step) and time_step > 0.0):
            raise ConfigError(f"time_step must be > 0 s, got {time_step!r}")
        self.time_step = float(time_step)
        self.enabled = bool(enabled)
        self.inertial = bool(inertial)
        self.gravity = np.array(robot.model.gravity.linear, dtype=float)
        self._inertia = pin.Inertia(self.mass, self.center_of_mass, np.zeros((3, 3)))
        self._data = robot.create_data()
        self._sensor_id = robot.model.getFrameId(robot.flange_frame)
        self._v_previous: np.ndarray | None = None

    def reset(self) -> None:
        """Forget the previous q̇̂."""
        self._v_previous = None

    def compensation(self, rotation_ws: np.ndarray) -> np.ndarray:
        """b̂ + the calibrated weight at orientation R̂_WS (N, N·m, sensor frame): the static
        compensation."""
        weight = tool_gravity_wrench(rotation_ws, self.mass, self.center_of_mass, self.gravity)
        return self.bias + weight

    def _dynamic(self, q_hat: np.ndarray, v_hat: np.ndarray, a_hat: np.ndarray) -> np.ndarray:
        """b̂ + Ŷ·(ĝ_S − â_S) − v̂_S ×* (Ŷ·v̂_S) (sensor frame); leaves the placements in data."""
        model, data = self.robot.model, self._data
        pin.forwardKinematics(model, data, q_hat, v_hat, a_hat)
        pin.updateFramePlacements(model, data)
        velocity = pin.getFrameVelocity(model, data, self._sensor_id, pin.LOCAL)
        acceleration = pin.getFrameAcceleration(model, data, self._sensor_id, pin.LOCAL)
        rotation = data.oMf[self._sensor_id].rotation
        gravity = pin.Motion(rotation.T @ self.gravity, np.zeros(3))
        y = self._inertia
        tool = y * (gravity - acceleration) - velocity.cross(y * velocity)
        return self.bias + tool.vector

    def compensate(self, raw: np.ndarray, q_hat: np.ndarray, v_hat: np.ndarray) -> np.ndarray:
        """The compensated contact wrench (N, N·m), world axes about the contact frame origin."""
        raw = np.asarray(raw, dtype=float)
        if raw.shape != (6,) or not np.all(np.isfinite(raw)):
            raise InputError(f"an F/T reading is 6 finite numbers, got {raw!r}")
        v_previous = v_hat if self._v_previous is None else self._v_previous
        self._v_previous = np.array(v_hat, dtype=float)
        model, data = self.robot.model, self._data
        if self.enabled and self.inertial:
            a_hat = (v_hat - v_previous) / self.time_step
            wrench = raw - self._dynamic(q_hat, v_hat, a_hat)
        else:
            pin.framesForwardKinematics(model, data, q_hat)
            rotation = data.oMf[self._sensor_id].rotation
            wrench = raw - self.compensation(rotation) if self.enabled else raw
        sensor, contact = data.oMf[self._sensor_id], data.oMf[self.robot.contact_frame_id]
        return sensor_wrench_to_contact_world(wrench, sensor, contact)


class ForcePipeline(Protocol):
    """What the polishing loop reads the force through, once per cycle: the plant's true
    (q rad, q̇ rad/s, contact wrench N and N·m about the contact frame, world axes) and the
    joint sensor's (q̂ rad, q̇̂ rad/s) of the same cycle → λ̂ (N, the MPC's contact components)."""

    def measure(
        self,
        q: np.ndarray,
        v: np.ndarray,
        wrench_world: np.ndarray,
        q_hat: np.ndarray,
        v_hat: np.ndarray,
    ) -> np.ndarray:
        """λ̂ of this cycle, N (the MPC's contact components)."""
        ...


class ContactForceSensing:
    """The paper's sensor (eq 32, ``ft_sensor.model: contact``): λ̂ = λ(t − δs) + ν_λ on the
    MPC's contact components; no tool weight, no bias (q, q̇ and q̂ are not used)."""

    def __init__(self, model: ForceSensingModel, contact: ContactConfig) -> None:
        self.model = model
        self.contact = contact

    def measure(
        self,
        q: np.ndarray,
        v: np.ndarray,
        wrench_world: np.ndarray,
        q_hat: np.ndarray,
        v_hat: np.ndarray,
    ) -> np.ndarray:
        """λ̂ = λ(t − δs) + ν_λ (eq 32), N, from the true contact wrench (world axes)."""
        return self.model.step(measured_force(wrench_world, self.contact))


class WristForceSensing:
    """The wrist sensor and the force node's compensation (``ft_sensor.model: wrist``):
    λ̂ = the MPC's components of ``compensator.compensate(sensor.step(q, q̇, w), q̂, q̇̂)``.
    :attr:`last_wrench` keeps the last compensated wrench (the node publishes all six)."""

    def __init__(
        self, sensor: WristSensorModel, compensator: WristCompensator, contact: ContactConfig
    ) -> None:
        self.sensor = sensor
        self.compensator = compensator
        self.contact = contact
        self.last_wrench = np.zeros(6)

    def wrench(
        self,
        q: np.ndarray,
        v: np.ndarray,
        wrench_world: np.ndarray,
        q_hat: np.ndarray,
        v_hat: np.ndarray,
    ) -> np.ndarray:
        """The compensated wrench of this cycle (N, N·m; contact frame origin, world axes)."""
        raw = self.sensor.step(q, v, wrench_world)
        self.last_wrench = self.compensator.compensate(raw, q_hat, v_hat)
        return self.last_wrench

    def measure(
        self,
        q: np.ndarray,
        v: np.ndarray,
        wrench_world: np.ndarray,
        q_hat: np.ndarray,
        v_hat: np.ndarray,
    ) -> np.ndarray:
        """λ̂, N: the MPC's components of the compensated wrench (:meth:`wrench`)."""
        return measured_force(self.wrench(q, v, wrench_world, q_hat, v_hat), self.contact)
