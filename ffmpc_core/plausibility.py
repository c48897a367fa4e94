"""Plausibility limits on every physical input and learned value (one place, named, with units).

A value can be finite and still absurd: a torque sensor that reads 1e9 N·m, a force/torque
sensor offset of −1e9 N, a learned stiffness of 1e-9 or 1e12 N/m. Such a value must never be
adopted: it is rejected with a clear :class:`~ffmpc_core.errors.InputError` and the consumer keeps
its last safe state (the PID its integral, the F/T sensor its offset, the MPC and the impact
planner their prior contact model) or, for a torque command, the robot is put in the safe hold
(``ffmpc_core.lowlevel``). Clipping an absurd value to a bound, or replacing it by 0, is not a
safe answer: a 0 torque drops the arm, a torque clipped to the limit from ±inf drives it at full
torque.

Ranges and why:

* **Commanded torques** (before saturation): |τ_i| ≤ ``COMMAND_TORQUE_FACTOR`` = 100 × the
  joint's torque limit (N·m). The OCP has no hard torque bound and the low level saturates its
  output, so a raw MPC torque above the limit is normal: at first contact it reached 9.9× the
  limit (force-feedback with Riccati feedback, polishing seed 2, measured); 100× is no solver
  transient but a divergence.
* **Measured torques**: |τ̂_i| ≤ ``MEASURED_TORQUE_FACTOR`` = 5 × the limit. The joint torque is
  the motor torque (saturated) times the actuation gain (≤ 1.2, eq 31) plus bias, friction and
  noise: beyond 5× it is a broken sensor or a spike.
* **Forces** (F/T sensor): |λ_j| ≤ ``FORCE_MAX`` = 2000 N per axis, 10× the iiwa's 200 N class of
  contact and 40× the paper's 50 N reference (a 6-axis sensor of this class saturates at
  ~500–2500 N).
* **Tare offset**: |offset_j| ≤ ``TARE_OFFSET_MAX`` = 50 N per axis — a tare removes a sensor
  bias and the weight of a tool, not a contact force; a larger mean means the sensor is loaded
  or broken. The tare is refused while in contact.
* **Wrist F/T calibration** (``ffmpc_core.ft_calibration``): a tool mass in
  [0, ``TOOL_MASS_MAX``] = [0, 20] kg (the iiwa 7 carries 7 kg, the Panda 3 kg: 20 kg is no
  tool of theirs), its centre of mass within ``TOOL_COM_RADIUS_MAX`` = 0.3 m of the sensor (a
  wrist tool, not a beam), a force bias within ``TARE_OFFSET_MAX`` per axis and a moment bias
  within ``BIAS_MOMENT_MAX`` = 5 N·m per axis (a 6-axis sensor of the 500 N class has a
  ~10–50 N·m range; a larger offset is an overloaded sensor).
* **Measured joint states** (the MPC's x̂): each q_i within its data-sheet range widened by
  ``JOINT_POSITION_SLACK`` = 0.5 rad (an encoder that reads half a radian beyond a mechanical
  stop is broken; a joint without a finite range: |q_i| ≤ ``JOINT_POSITION_MAX`` = 1e3 rad),
  |q̇_i| ≤ ``MEASURED_VELOCITY_FACTOR`` = 20 × the joint's velocity limit (the robot's reflex
  stops it at 1×; with the reflex off the simulated wrist reached 5.95× — 1 kg tool, Riccati
  feedback, polishing seed 2 — which is a real motion to measure, not a broken sensor). A
  joint position of −1e300 rad is finite, and an OCP started from it overflows inside the
  solver (mim_solvers' line search aborts the process on a NaN cost).
* **Learned contact stiffness** α̂ ∈ [``STIFFNESS_MIN``, ``STIFFNESS_MAX``] = [10, 1e6] N/m: from a
  soft foam to a stiff surface seen through the tool (the project's materials: 1e3–1e4 N/m).
  Below, the material pushes back less than 1 N per 10 cm (no contact to model); above, the
  contact's natural frequency with a ~2 kg effective mass exceeds 110 Hz, which a 2 ms OCP
  step and a 1 kHz loop cannot resolve.
* **Learned contact damping** β̂ ∈ [``DAMPING_MIN``, ``DAMPING_MAX``] = [0, 1e5] N·s/m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from ffmpc_core.errors import InputError

#: Largest plausible |τ| of a command (before saturation), multiple of the joint torque limit.
COMMAND_TORQUE_FACTOR = 100.0
#: Largest plausible |τ̂| measured, multiple of the joint torque limit.
MEASURED_TORQUE_FACTOR = 5.0
#: Largest plausible |λ| per axis of the F/T sensor, N.
FORCE_MAX = 2000.0
#: Largest plausible |tare offset| per axis, N.
TARE_OFFSET_MAX = 50.0
#: Largest plausible calibrated tool mass, kg; centre of mass distance from the sensor, m.
TOOL_MASS_MAX, TOOL_COM_RADIUS_MAX = 20.0, 0.3
#: Largest plausible |moment bias| per axis of the wrist F/T sensor, N·m.
BIAS_MOMENT_MAX = 5.0
#: Largest plausible excess of a measured joint position beyond its range, rad; |q| of a joint
#: without a finite range, rad.
JOINT_POSITION_SLACK, JOINT_POSITION_MAX = 0.5, 1e3
#: Largest plausible |q̇| measured, multiple of the joint velocity limit.
MEASURED_VELOCITY_FACTOR = 20.0
#: Range of a learned contact stiffness α̂, N/m.
STIFFNESS_MIN, STIFFNESS_MAX = 10.0, 1e6
#: Range of a learned contact damping β̂, N·s/m.
DAMPING_MIN, DAMPING_MAX = 0.0, 1e5


def torque_plausible(
    tau: np.ndarray, torque_limit: np.ndarray, factor: float = MEASURED_TORQUE_FACTOR
) -> bool:
    """True when every τ_i is finite and |τ_i| ≤ factor·limit_i (N·m; default: a measurement)."""
    tau = np.asarray(tau, dtype=float)
    return bool(np.all(np.isfinite(tau)) and np.all(np.abs(tau) <= factor * torque_limit))


def check_torque(
    tau: npt.ArrayLike,
    torque_limit: np.ndarray,
    name: str = "torque",
    factor: float = COMMAND_TORQUE_FACTOR,
) -> np.ndarray:
    """τ (N·m) as a float array; InputError if any entry is non-finite or beyond factor × its
    limit (default: a command)."""
    arr = np.asarray(tau, dtype=float)
    if arr.shape != np.shape(torque_limit):
        raise InputError(f"{name} must have {np.size(torque_limit)} entries, got {arr.shape}")
    if not torque_plausible(arr, torque_limit, factor):
        raise InputError(
            f"{name} {np.array2string(arr, precision=3)} N·m is not finite or exceeds "
            f"{factor:g}× the torque limits: refused"
        )
    return arr


def check_force(force: npt.ArrayLike, name: str = "force") -> np.ndarray:
    """λ (N) as a float array; InputError if non-finite or |λ_j| > FORCE_MAX."""
    arr = np.asarray(force, dtype=float)
    if not np.all(np.isfinite(arr)) or np.any(np.abs(arr) > FORCE_MAX):
        raise InputError(
            f"{name} {np.array2string(arr, precision=3)} N is not finite or exceeds "
            f"{FORCE_MAX:g} N: refused"
        )
    return arr


@dataclass(frozen=True)
class JointStateRange:
    """The plausible measured joint state of one robot, computed once: q (rad) within
    [low, high] — each data-sheet range widened by JOINT_POSITION_SLACK, ±JOINT_POSITION_MAX
    where the range is not finite — and |q̇| (rad/s) ≤ max_velocity = MEASURED_VELOCITY_FACTOR ×
    the velocity limits."""

    low: np.ndarray
    high: np.ndarray
    max_velocity: np.ndarray

    @classmethod
    def of(
        cls, position_lower: np.ndarray, position_upper: np.ndarray, velocity_limit: np.ndarray
    ) -> JointStateRange:
        """The range of a robot's data-sheet limits (rad, rad/s)."""
        finite = np.isfinite(position_lower) & np.isfinite(position_upper)
        low = np.where(finite, position_lower - JOINT_POSITION_SLACK, -JOINT_POSITION_MAX)
        high = np.where(finite, position_upper + JOINT_POSITION_SLACK, JOINT_POSITION_MAX)
        return cls(low, high, MEASURED_VELOCITY_FACTOR * np.asarray(velocity_limit, float))

    def check(self, q: np.ndarray, v: np.ndarray) -> None:
        """InputError unless q and v (finite already) lie in the range."""
        if np.any(q < self.low) or np.any(q > self.high):
            raise InputError(
                f"joint positions {np.array2string(q, precision=3)} rad: beyond the joint "
                f"ranges by more than {JOINT_POSITION_SLACK:g} rad (a broken encoder): refused"
            )
        if np.any(np.abs(v) > self.max_velocity):
            raise InputError(
                f"joint velocities {np.array2string(v, precision=3)} rad/s exceed "
                f"{MEASURED_VELOCITY_FACTOR:g}× the velocity limits: refused"
            )


def check_tare_offset(offset: npt.ArrayLike) -> np.ndarray:
    """A tare offset (N) as a float array; InputError if |offset_j| > TARE_OFFSET_MAX."""
    arr = np.asarray(offset, dtype=float)
    if not np.all(np.isfinite(arr)) or np.any(np.abs(arr) > TARE_OFFSET_MAX):
        raise InputError(
            f"tare offset {np.array2string(arr, precision=3)} N exceeds {TARE_OFFSET_MAX:g} N "
            "per axis (a loaded or broken sensor): refused, the previous offset is kept"
        )
    return arr


def check_contact_parameters(stiffness: float, damping: float) -> tuple[float, float]:
    """(α̂ N/m, β̂ N·s/m); InputError outside [STIFFNESS_MIN, STIFFNESS_MAX] × [DAMPING_MIN,
    DAMPING_MAX] or non-finite."""
    k, b = float(stiffness), float(damping)
    if not (math.isfinite(k) and STIFFNESS_MIN <= k <= STIFFNESS_MAX):
        raise InputError(
            f"stiffness {k:g} N/m outside [{STIFFNESS_MIN:g}, {STIFFNESS_MAX:g}] N/m: refused"
        )
    if not (math.isfinite(b) and DAMPING_MIN <= b <= DAMPING_MAX):
        raise InputError(
            f"damping {b:g} N·s/m outside [{DAMPING_MIN:g}, {DAMPING_MAX:g}] N·s/m: refused"
        )
    return k, b


__all__ = [
    "BIAS_MOMENT_MAX",
    "DAMPING_MAX",
    "JOINT_POSITION_MAX",
    "JOINT_POSITION_SLACK",
    "MEASURED_VELOCITY_FACTOR",
    "JointStateRange",
    "DAMPING_MIN",
    "FORCE_MAX",
    "STIFFNESS_MAX",
    "STIFFNESS_MIN",
    "TARE_OFFSET_MAX",
    "TOOL_COM_RADIUS_MAX",
    "TOOL_MASS_MAX",
    "COMMAND_TORQUE_FACTOR",
    "MEASURED_TORQUE_FACTOR",
    "check_contact_parameters",
    "check_force",
    "check_tare_offset",
    "check_torque",
    "torque_plausible",
]
