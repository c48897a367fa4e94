"""Calibration of a wrist force/torque sensor and its tool: bias, mass and centre of mass from a
few static wrist poses without contact, by least squares (issue 27).

The model (:mod:`ffmpc_core.wrist_ft`): at rest and without contact the sensor reads, in its own
frame S,

    f = m·g_S + b_f,    τ = c × m·g_S + b_τ = −[g_S]× (m·c) + b_τ,    g_S = R_WSᵀ·g,

linear in x = (m, m·c, b_f, b_τ) (10 unknowns): each pose gives six rows of the regressor
(:func:`calibration_regressor`), the poses' averaged readings are stacked and solved in the
least-squares sense (:func:`identify_tool`). This is the standard identification of F/T
gravity compensation (force_torque_tools' ``ft_calib``, the agimus ``panda_ft_sensor_calibration``
fit; the poses must turn gravity in the sensor frame, :data:`CALIBRATION_WRIST_OFFSETS`).

Each pose's reading is the mean of ``samples`` readings, and its orientation R_WS comes from the
mean of as many measured q̂ (rad), as a cell averages the stationary window of each pose. In
simulation the procedure is :func:`startup_calibration`: the robot is at rest in each pose, so
the sensor reads the tool's weight, its bias and noise (:meth:`WristSensorModel.static_readings`);
the plant is not driven through the poses.

A calibration is refused (:class:`~ffmpc_core.errors.CalibrationError`, with the reason) by
:func:`check_calibration` when it is

* stale: older than ``max_age`` (s; ``ft_sensor.calibration_max_age``), or dated in the future;
* for another cell: another robot, sensor frame, or pose set (its poses' fingerprint differs
  from this cell's pose set);
* for another tool: its mass or centre of mass disagree with the tool the cell is configured
  with (the controllers' load data, ``plant.tool_mass``/``plant.tool_center_of_mass``) beyond
  :data:`MASS_MATCH_ABS` + :data:`MASS_MATCH_REL`·m and :data:`COM_MATCH`;
* implausible: a mass below −:data:`NEGATIVE_MASS_SIGMAS` standard errors or above
  ``plausibility.TOOL_MASS_MAX``, a centre of mass farther than ``TOOL_COM_RADIUS_MAX`` from the
  sensor, a bias beyond ``TARE_OFFSET_MAX`` (N) or ``BIAS_MOMENT_MAX`` (N·m), residuals beyond
  :data:`RESIDUAL_FACTOR` × the readings' expected noise (:func:`reading_noise`: a contact or a
  moving robot during a pose, a loose tool), or a pose set that does not turn gravity enough
  (regressor condition number above :data:`CONDITION_MAX`).

Files (:func:`save_calibration`, :func:`load_calibration`): YAML, format
:data:`FILE_FORMAT`, every field of :class:`FtCalibration`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
import os
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pinocchio as pin
import yaml

from ffmpc_core.errors import CalibrationError, ConfigError
from ffmpc_core.plausibility import (
    BIAS_MOMENT_MAX,
    TARE_OFFSET_MAX,
    TOOL_COM_RADIUS_MAX,
    TOOL_MASS_MAX,
)
from ffmpc_core.robots import RobotModel, ToolLoad
from ffmpc_core.wrist_ft import WristSensorModel

#: The wrist poses of the calibration, per robot: offsets (rad) of the last two joints from
#: ``q_nominal`` (the task's start, tool down above the table), every combination of the two
#: tuples: 16 poses that tilt the tool by up to ~100° and spin it about its axis, keeping the
#: tool's tip at or above its start height (tests/test_ft_calibration.py).
CALIBRATION_WRIST_OFFSETS: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "iiwa": ((0.0, 0.9, -0.9, -1.8), (-2.4, -0.8, 0.8, 2.4)),
    "panda": ((0.0, 0.9, -1.0, -1.45), (-3.2, -1.6, 0.0, 1.6)),
}
#: The calibration files' format (the ``format`` field).
FILE_FORMAT = "ffmpc_ft_calibration/1"
#: Residual RMS above this multiple of the expected noise (:func:`reading_noise`) is refused.
RESIDUAL_FACTOR = 4.0
#: Numerical floors of the expected noise (a noise-free sensor still has round-off), N, N·m.
NOISE_FLOOR_FORCE, NOISE_FLOOR_MOMENT = 1e-6, 1e-7
#: A mass below −this many standard errors is negative (refused); above +this many the mass is
#: resolved and its centre of mass is estimated (otherwise ĉ = 0: a weightless tool has none).
NEGATIVE_MASS_SIGMAS = 5.0
#: Largest condition number of the column-scaled regressor (the shipped pose sets: ~2–2.5;
#: poses that only spin the tool about a vertical axis: ~1e16).
CONDITION_MAX = 100.0
#: A calibrated mass matches the configured tool within MASS_MATCH_ABS + MASS_MATCH_REL·m (kg),
#: its centre of mass within COM_MATCH (m, when both masses are resolved).
MASS_MATCH_ABS, MASS_MATCH_REL, COM_MATCH = 0.02, 0.02, 0.005


@dataclass(frozen=True)
class FtCalibration:
    """A calibration of the wrist sensor and its tool (see the module docstring).

    Attributes:
        bias: b̂ = (b_f N, b_τ N·m), sensor frame.
        mass: m̂, kg.  mass_std: its standard error, kg.
        center_of_mass: ĉ, m, sensor frame ((0, 0, 0) when the mass is not resolved).
        residual_force, residual_moment: RMS of the fit's residuals, N and N·m.
        noise_force, noise_moment: the expected noise of an averaged reading at this
            calibration's mass (:func:`reading_noise`), N and N·m.
        condition: condition number of the column-scaled regressor.
        robot, sensor_frame: where it was taken.  poses_sha256: the pose set's fingerprint.
        samples: readings averaged per pose.  created: UNIX time (s) of the calibration.
    """

    bias: tuple[float, ...]
    mass: float
    mass_std: float
    center_of_mass: tuple[float, float, float]
    residual_force: float
    residual_moment: float
    noise_force: float
    noise_moment: float
    condition: float
    robot: str
    sensor_frame: str
    poses_sha256: str
    samples: int
    created: float

    def describe(self) -> str:
        """One line: b̂, m̂, ĉ and the residuals."""
        b = ", ".join(f"{x:.4f}" for x in self.bias)
        c = ", ".join(f"{1e3 * x:.2f}" for x in self.center_of_mass)
        return (
            f"bias [{b}] N, N·m; mass {self.mass:.4f} ± {self.mass_std:.4f} kg; centre of mass "
            f"[{c}] mm; residual RMS {self.residual_force:.2e} N, {self.residual_moment:.2e} N·m"
        )


def calibration_poses(robot: RobotModel) -> np.ndarray:
    """The calibration's joint configurations (rad), one per row
    (:data:`CALIBRATION_WRIST_OFFSETS`)."""
    try:
        tilts, spins = CALIBRATION_WRIST_OFFSETS[robot.name]
    except KeyError:
        raise ConfigError(f"no calibration poses for robot {robot.name!r}") from None
    poses = []
    for tilt in tilts:
        for spin in spins:
            q = robot.q_nominal.copy()
            q[-2] += tilt
            q[-1] += spin
            poses.append(q)
    return np.array(poses)


def poses_fingerprint(poses: np.ndarray) -> str:
    """A short SHA-256 of a pose set (rad, rounded to 1e-6)."""
    rounded = np.round(np.asarray(poses, dtype=float), 6) + 0.0  # (+0.0: no −0.0)
    return hashlib.sha256(rounded.tobytes()).hexdigest()[:16]


def calibration_regressor(gravity_sensor: np.ndarray) -> np.ndarray:
    """The six rows of one pose: [f; τ] = A·(m, m·c, b_f, b_τ) with g_S (m/s², sensor frame)."""
    a = np.zeros((6, 10))
    a[:3, 0] = gravity_sensor
    a[3:, 1:4] = -pin.skew(gravity_sensor)
    a[:3, 4:7] = np.eye(3)
    a[3:, 7:10] = np.eye(3)
    return a


def reading_noise(
    force_noise_std: float,
    moment_noise_std: float,
    position_noise_std: float,
    samples: int,
    nv: int,
    mass: float,
    com_distance: float,
    gravity: float = 9.81,
) -> tuple[float, float]:
    """The expected noise (standard deviation) of one pose's averaged reading, per force and per
    moment channel (N, N·m): the sensor's σ_f/√S, σ_m/√S and the weight's error from the
    orientation error of S measured through nv joints of noise σ_q averaged S times (at most
    σ_θ = σ_q·√nv/√S rad): m·g·σ_θ on forces, m·g·|c|·σ_θ on moments."""
    root = math.sqrt(samples)
    tilt = position_noise_std * math.sqrt(nv) / root
    force = math.hypot(force_noise_std / root, abs(mass) * gravity * tilt)
    moment = math.hypot(moment_noise_std / root, abs(mass) * gravity * com_distance * tilt)
    return max(force, NOISE_FLOOR_FORCE), max(moment, NOISE_FLOOR_MOMENT)


@dataclass(frozen=True)
class CalibrationNoise:
    """The noise figures the calibration is judged by: σ_f (N), σ_m (N·m) of the sensor, σ_q
    (rad) of the joint sensor, and the readings averaged per pose."""

    force_noise_std: float
    moment_noise_std: float
    position_noise_std: float
    samples: int


def identify_tool(
    robot: RobotModel,
    poses_measured: np.ndarray,
    readings: np.ndarray,
    noise: CalibrationNoise,
    poses_sha256: str,
    created: float,
) -> FtCalibration:
    """Least-squares bias, mass and centre of mass from the averaged readings (N×6, N and N·m,
    sensor frame) at the averaged measured poses (N×nv, rad); the fields of
    :class:`FtCalibration` (not checked: :func:`check_calibration`)."""
    poses_measured = np.asarray(poses_measured, dtype=float)
    readings = np.asarray(readings, dtype=float)
    if readings.ndim != 2 or readings.shape[1] != 6 or len(readings) != len(poses_measured):
        raise ConfigError("calibration readings must be N×6, one per measured pose")
    data = robot.create_data()
    sensor_id = robot.model.getFrameId(robot.flange_frame)
    gravity = np.array(robot.model.gravity.linear, dtype=float)
    rows = []
    for q in poses_measured:
        pin.framesForwardKinematics(robot.model, data, q)
        rows.append(calibration_regressor(data.oMf[sensor_id].rotation.T @ gravity))
    a = np.vstack(rows)
    b = readings.reshape(-1)
    # rows weighted by the sensor's own noise (force and moment channels differ in unit)
    s_f, s_m = reading_noise(
        noise.force_noise_std, noise.moment_noise_std, 0.0, noise.samples, robot.nv, 0.0, 0.0
    )
    weights = np.tile(np.array([1 / s_f] * 3 + [1 / s_m] * 3), len(readings))
    x, *_ = np.linalg.lstsq(a * weights[:, None], b * weights, rcond=None)
    residual = (b - a @ x).reshape(-1, 6)
    scaled = a / np.linalg.norm(a, axis=0)
    singular = np.linalg.svd(scaled, compute_uv=False)
    condition = float(singular[0] / singular[-1]) if singular[-1] > 0 else math.inf
    dof = max(a.shape[0] - a.shape[1], 1)
    chi2 = float(np.sum((residual.reshape(-1) * weights) ** 2)) / dof
    aw = a * weights[:, None]
    covariance = np.linalg.pinv(aw.T @ aw) * max(chi2, 1.0)
    mass, mass_std = float(x[0]), float(math.sqrt(max(covariance[0, 0], 0.0)))
    resolved = mass > NEGATIVE_MASS_SIGMAS * mass_std and mass > 0.0
    com = x[1:4] / mass if resolved else np.zeros(3)
    noise_force, noise_moment = reading_noise(
        noise.force_noise_std,
        noise.moment_noise_std,
        noise.position_noise_std,
        noise.samples,
        robot.nv,
        mass,
        float(np.linalg.norm(com)),
        float(np.linalg.norm(gravity)),
    )
    return FtCalibration(
        bias=tuple(float(v) for v in x[4:10]),
        mass=mass,
        mass_std=mass_std,
        center_of_mass=(float(com[0]), float(com[1]), float(com[2])),
        residual_force=float(np.sqrt(np.mean(residual[:, :3] ** 2))),
        residual_moment=float(np.sqrt(np.mean(residual[:, 3:] ** 2))),
        noise_force=noise_force,
        noise_moment=noise_moment,
        condition=condition,
        robot=robot.name,
        sensor_frame=robot.flange_frame,
        poses_sha256=poses_sha256,
        samples=int(noise.samples),
        created=float(created),
    )


def measure_poses(
    sensor: WristSensorModel,
    poses: np.ndarray,
    noise: CalibrationNoise,
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray]:
    """The simulated calibration run: at each pose (rad) at rest, ``noise.samples`` joint
    readings q + ν_q and as many sensor readings, averaged; returns (mean q̂ N×nv rad, mean
    readings N×6). Draws from ``rng``, per pose: the joint noise (samples×nv), then the
    sensor's (samples×6)."""
    samples = noise.samples
    q_means, readings = [], []
    for q in np.asarray(poses, dtype=float):
        joint = noise.position_noise_std * rng.standard_normal((samples, q.size))
        q_means.append(q + joint.mean(axis=0))
        readings.append(sensor.static_readings(q, samples, rng).mean(axis=0))
    return np.array(q_means), np.array(readings)


def startup_calibration(
    sensor: WristSensorModel,
    poses: np.ndarray,
    noise: CalibrationNoise,
    rng: np.random.Generator,
    created: float,
) -> FtCalibration:
    """Calibrate at the start of a run (simulated, :func:`measure_poses`), then
    :func:`identify_tool`."""
    q_means, readings = measure_poses(sensor, poses, noise, rng)
    robot = sensor.robot
    return identify_tool(robot, q_means, readings, noise, poses_fingerprint(poses), created)


def check_calibration(
    calibration: FtCalibration,
    robot: RobotModel,
    poses: np.ndarray,
    tool: ToolLoad,
    max_age: float,
    now: float,
) -> None:
    """Refuse a calibration that is stale, for another cell or tool, or implausible
    (CalibrationError with the reason; module docstring). ``tool``: the load the cell is
    configured with; ``now``: UNIX time, s."""
    c = calibration
    where = f"F/T calibration ({c.describe()})"
    if c.robot != robot.name or c.sensor_frame != robot.flange_frame:
        raise CalibrationError(
            f"{where} refused: taken on robot {c.robot!r} frame {c.sensor_frame!r}, this cell "
            f"is {robot.name!r} frame {robot.flange_frame!r}"
        )
    if c.poses_sha256 != poses_fingerprint(poses):
        raise CalibrationError(
            f"{where} refused: taken with another pose set ({c.poses_sha256}, this cell's is "
            f"{poses_fingerprint(poses)})"
        )
    age = now - c.created
    if age > max_age or age < -60.0:
        raise CalibrationError(
            f"{where} refused: stale, taken {age:.0f} s ({age / 3600:.2f} h) ago, older than "
            f"calibration_max_age {max_age:g} s"
            if age > max_age
            else f"{where} refused: dated {-age:.0f} s in the future"
        )
    _check_plausible(c, where)
    _check_tool(c, tool, where)


def _check_plausible(c: FtCalibration, where: str) -> None:
    reasons = []
    if not math.isfinite(c.condition) or c.condition > CONDITION_MAX:
        reasons.append(
            f"the poses do not turn gravity enough (condition {c.condition:.3g} > "
            f"{CONDITION_MAX:g})"
        )
    if c.mass < -NEGATIVE_MASS_SIGMAS * c.mass_std:
        reasons.append(f"negative mass {c.mass:.4f} kg")
    if c.mass > TOOL_MASS_MAX:
        reasons.append(f"mass {c.mass:.3f} kg above {TOOL_MASS_MAX:g} kg")
    if float(np.linalg.norm(c.center_of_mass)) > TOOL_COM_RADIUS_MAX:
        reasons.append(
            f"centre of mass {np.linalg.norm(c.center_of_mass):.3f} m from the sensor, beyond "
            f"{TOOL_COM_RADIUS_MAX:g} m"
        )
    bias = np.asarray(c.bias)
    if np.any(np.abs(bias[:3]) > TARE_OFFSET_MAX) or np.any(np.abs(bias[3:]) > BIAS_MOMENT_MAX):
        reasons.append(f"bias beyond {TARE_OFFSET_MAX:g} N or {BIAS_MOMENT_MAX:g} N·m")
    if c.residual_force > RESIDUAL_FACTOR * c.noise_force:
        reasons.append(
            f"force residual {c.residual_force:.3g} N > {RESIDUAL_FACTOR:g} × the noise "
            f"{c.noise_force:.3g} N (a contact or motion during a pose?)"
        )
    if c.residual_moment > RESIDUAL_FACTOR * c.noise_moment:
        reasons.append(
            f"moment residual {c.residual_moment:.3g} N·m > {RESIDUAL_FACTOR:g} × the noise "
            f"{c.noise_moment:.3g} N·m (a contact or motion during a pose?)"
        )
    if reasons:
        raise CalibrationError(f"{where} refused: implausible: " + "; ".join(reasons))


def _check_tool(c: FtCalibration, tool: ToolLoad, where: str) -> None:
    tolerance = MASS_MATCH_ABS + MASS_MATCH_REL * tool.mass
    if abs(c.mass - tool.mass) > tolerance:
        raise CalibrationError(
            f"{where} refused: another tool? calibrated {c.mass:.4f} kg, the cell's tool is "
            f"{tool.mass:.4f} kg (tolerance {tolerance:.3f} kg)"
        )
    resolved = tool.mass > 0.0 and any(x != 0.0 for x in c.center_of_mass)
    offset = float(np.linalg.norm(np.subtract(c.center_of_mass, tool.center_of_mass)))
    if resolved and offset > COM_MATCH:
        raise CalibrationError(
            f"{where} refused: another tool? calibrated centre of mass {1e3 * offset:.1f} mm "
            f"from the cell's tool's (tolerance {1e3 * COM_MATCH:.0f} mm)"
        )


def save_calibration(calibration: FtCalibration, path: str | os.PathLike) -> None:
    """Write ``calibration`` as YAML (format :data:`FILE_FORMAT`); never overwrites a file."""
    body: dict[str, Any] = {"format": FILE_FORMAT, **asdict(calibration)}
    body["bias"] = list(calibration.bias)
    body["center_of_mass"] = list(calibration.center_of_mass)
    with open(path, "x", encoding="utf-8") as stream:
        yaml.safe_dump(body, stream, sort_keys=False)


def load_calibration(path: str | os.PathLike) -> FtCalibration:
    """A calibration file (:func:`save_calibration`); CalibrationError if it cannot be read or
    is not one (it is not checked here: :func:`check_calibration`)."""
    try:
        with open(path, encoding="utf-8") as stream:
            body = yaml.safe_load(stream)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise CalibrationError(f"F/T calibration file {path}: cannot read it ({exc})") from None
    if not isinstance(body, dict) or body.get("format") != FILE_FORMAT:
        raise CalibrationError(f"F/T calibration file {path}: not a {FILE_FORMAT} file")
    body = dict(body)
    body.pop("format")
    try:
        calibration = FtCalibration(**body)
        bias = tuple(float(x) for x in calibration.bias)
        com = tuple(float(x) for x in calibration.center_of_mass)
        numbers = (*bias, *com, calibration.mass, calibration.mass_std, calibration.created)
        if len(bias) != 6 or len(com) != 3 or not all(math.isfinite(x) for x in numbers):
            raise ValueError("bias must be 6 and centre of mass 3 finite numbers")
    except (TypeError, ValueError) as exc:
        raise CalibrationError(f"F/T calibration file {path}: {exc}") from None
    return dataclasses.replace(calibration, bias=bias, center_of_mass=(com[0], com[1], com[2]))
