"""Joint-position observer: the measured joint positions with their noise filtered by the
measured joint velocities (a complementary filter), for the MPC's initial state.

The paper's sensing model (Sec. VI-B2) adds white noise of σ_q = 10⁻³ rad to every measured
joint position and σ_q̇ = 10⁻³ rad/s to every measured velocity. The MPCs' end-effector costs
turn the position noise into torque: 1 mrad on a shoulder joint moves the tool's believed
position by ~0.6 mm, which c4 = 10³–10⁴ corrects within a 15 ms horizon. On the iiwa the
torques excite the arm's self-motion (joints 1 and 3 turning against each other, which barely
moves the tool and which only the posture and joint-velocity costs hold): measured at the
polishing defaults (classical MPC, seed 101), the joint-1 − joint-3 velocity oscillates at
~36 Hz with 0.27 rad/s RMS, 0.07 rad/s without the position noise, and the sum of the two
eats the velocity limits' margin on the fast circle.

Over one MPC step the integrated velocity noise is σ_q̇·Δt = 2·10⁻⁶ rad (Δt = 2 ms), 500 times
below σ_q, so integrating the measured velocity gives the position's fast changes almost
without noise; the measured position gives its slow changes (no drift). With α = exp(−Δt/T):

    q̂_k = q_k ⊕ α·((q̂_{k−1} ⊕ Δt·(q̇_k + q̇_{k−1})/2) ⊖ q_k)

(pinocchio's integrate and interpolate; plain sums for the arms' revolute joints). For white
position noise σ_q the estimate's noise is σ_q·√((1 − α)/(1 + α)) (×0.10 at T = 0.1 s,
Δt = 2 ms), plus the integrated velocity noise, about σ_q̇·√(T·Δt/2) for T ≫ Δt (10⁻⁵ rad there). The
trapezoid integrates a linearly changing velocity exactly, so at constant acceleration the
estimate has no lag at all; a jerk j leaves j·Δt³/12·α/(1 − α) at most (rad; 3·10⁻⁸·j there).
This is the steady-state Kalman filter of q_{k+1} = q_k + Δt·q̇_k with gain 1 − α.

``mpc.position_observer_time`` is T (0: the measured q as it is); the MPC runs the observer at
its own ticks (:meth:`ffmpc_core.mpc.ModelPredictiveController.step`), so the runner, the node
graph and the real-time loop share it.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.robots import RobotModel


def check_time_constant(time_constant: float) -> float:
    """T (s) as a float; ConfigError unless finite and >= 0."""
    if not (math.isfinite(time_constant) and time_constant >= 0.0):
        raise ConfigError(f"the observer time constant must be >= 0 s, got {time_constant!r}")
    return float(time_constant)


def position_observer_gain(time_constant: float, dt: float) -> float:
    """α = exp(−Δt/T) of the observer: the weight of the velocity-integrated position (0 for
    T = 0: the measured position alone). T, Δt in s; ConfigError for T < 0 or Δt ≤ 0."""
    check_time_constant(time_constant)
    if not (math.isfinite(dt) and dt > 0.0):
        raise ConfigError(f"the observer step must be > 0 s, got {dt!r}")
    return 0.0 if time_constant == 0.0 else math.exp(-dt / time_constant)


class JointPositionObserver:
    """The complementary filter of the module docstring for one robot.

    Attributes:
        time_constant: T, s: below 1/T the estimate follows the measured positions, above it
            the integrated measured velocities.
        max_gap: s; a step further than this from the previous one (or back in time) starts
            again from the measurement (an outage: the velocities in between are unknown).
    """

    def __init__(self, robot: RobotModel, time_constant: float, max_gap: float) -> None:
        if not (math.isfinite(max_gap) and max_gap > 0.0):
            raise ConfigError(f"max_gap must be > 0 s, got {max_gap!r}")
        self.robot = robot
        self.time_constant = check_time_constant(time_constant)
        self.max_gap = float(max_gap)
        self.reset()

    def reset(self) -> None:
        """Forget the estimate: the next update returns its measurement."""
        self._t: float | None = None
        self._q: np.ndarray | None = None  # q̂ of the last update, rad
        self._v: np.ndarray | None = None  # the last measured q̇, rad/s

    def update(self, q: np.ndarray, v: np.ndarray, t: float) -> np.ndarray:
        """q̂ at time t (s) from the measured q (rad, nq) and q̇ (rad/s, nv); a new array.
        InputError for a non-finite or mis-sized input (the estimate is left as it was)."""
        model = self.robot.model
        q = np.asarray(q, dtype=float)
        v = np.asarray(v, dtype=float)
        if q.shape != (model.nq,) or v.shape != (model.nv,):
            raise InputError(
                f"the observer needs q of size {model.nq} and v of size {model.nv}, "
                f"got {q.shape} and {v.shape}"
            )
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v)) and math.isfinite(t)):
            raise InputError(f"non-finite joint state at t = {t!r}: not observed")
        previous_t, previous_q, previous_v = self._t, self._q, self._v
        self._t, self._v = float(t), v.copy()
        if (
            self.time_constant == 0.0
            or previous_t is None
            or previous_q is None
            or previous_v is None
            or not 0.0 < t - previous_t <= self.max_gap
        ):
            self._q = q.copy()
            return q.copy()
        dt = t - previous_t
        alpha = position_observer_gain(self.time_constant, dt)
        predicted = pin.integrate(model, previous_q, 0.5 * dt * (v + previous_v))
        estimate = pin.interpolate(model, q, predicted, alpha)  # q ⊕ α·(predicted ⊖ q)
        self._q = estimate
        return estimate.copy()
