"""The linear_feedback_controller's law (agimus/loco-3d, a ros2_control controller), ROS-free.

An MPC is executed on hardware by a fast loop that applies the solver's first feed-forward
torque and Riccati gain between solves. The agimus ``linear_feedback_controller`` (version
4.0.3, ``src/lf_controller.cpp``: ``LFController::compute_control``) does it with

    τ = τ_ff + K·(x₀ ⊖ x),    x₀ ⊖ x = [pin.difference(q, q₀); v₀ − v]

at the robot's rate, from its ``linear_feedback_controller_msgs/Control`` (τ_ff: feedforward,
K: feedback_gain, x₀ = (q₀, v₀): initial_state) and the measured x = (q, v). K has one row per
actuated joint and 2·nv columns in pinocchio's tangent order (dq, then dv); on a serial arm
without continuous joints pin.difference(q, q₀) is q₀ − q. Crocoddyl's Riccati gain K₀ (u =
u₀ − K₀·(x ⊖ x₀)) is that K as it is; ffmpc's MPC command carries G = −K₀
(``torque + G·(x − x0)``), so K = −G (``ffmpc_ros.lfc_msgs``).

:func:`linear_feedback_torque` is that law alone. :class:`LinearFeedbackLoop` is the loop around
it, with ffmpc's safety rules where upstream has none:

* **hold** until the first control: ffmpc's safe hold (``LowLevelController.hold_torque``:
  brake, then a PD with gravity compensation; upstream runs its own joint PD there);
* **blend** from the hold to the law, linear over ``transition_duration`` s (upstream's
  ``pd_to_lf_transition_duration``), only when hold torques were already sent (the lockstep
  graph's first control arrives before anything was sent: the law at once);
* **track**: the law, saturated to the loop's torque limits; an implausible torque (non-finite
  or beyond ``plausibility.COMMAND_TORQUE_FACTOR`` × the limits) drops the control;
* **fallback**: a control older than ``stale_timeout`` (simulated s) or dropped: the safe hold
  again (upstream applies its last control for ever).

``remove_gravity``: subtract g(q) from the output, as upstream's
``remove_gravity_compensation_effort`` does for drives that add gravity compensation to the
commanded effort themselves (Panda's; KUKA FRI's torque mode). The output is the effort to
send, N·m, in the robot model's joint order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.lowlevel import TIME_EPS, LowLevelController, LowLevelMode, LowLevelOutput
from ffmpc_core.plausibility import check_torque
from ffmpc_core.robots import RobotModel


@dataclass(frozen=True)
class LinearFeedbackCommand:
    """One ``Control`` as arrays: feedforward τ_ff (N·m, nu), feedback_gain K (nu × 2·nv:
    N·m/rad for the dq columns, N·m·s/rad for the dv ones), q₀ (rad, nq), v₀ (rad/s, nv)."""

    feedforward: np.ndarray
    feedback_gain: np.ndarray
    q0: np.ndarray
    v0: np.ndarray


def state_difference(
    model: pin.Model, q: np.ndarray, v: np.ndarray, q0: np.ndarray, v0: np.ndarray
) -> np.ndarray:
    """x₀ ⊖ x = [pin.difference(model, q, q₀); v₀ − v] (2·nv): the tangent vector from the
    measured state (q rad, v rad/s) to the control's initial state, upstream's ``diff_state``."""
    return np.concatenate((pin.difference(model, q, q0), v0 - v))


def linear_feedback_torque(
    model: pin.Model, command: LinearFeedbackCommand, q: np.ndarray, v: np.ndarray
) -> np.ndarray:
    """τ = τ_ff + K·(x₀ ⊖ x), N·m: the linear_feedback_controller's law at the measured q (rad),
    v (rad/s), not saturated."""
    dx = state_difference(model, q, v, command.q0, command.v0)
    return command.feedforward + command.feedback_gain @ dx


class LinearFeedbackLoop:
    """Hold / blend / track / fallback around :func:`linear_feedback_torque` (module docstring).

    Shape: ``reset()``; ``set_command(command, t_command)`` when a Control arrives (t_command:
    its stamp, the time of the state it was solved from, s); ``step(q, v, t) -> output`` once
    per plant cycle (output: ``LowLevelOutput``, motor and desired torque both the effort sent).

    Args:
        robot: the robot model (joint order, limits).
        hold: the low level whose safe hold (``hold_torque``) and torque limits
            (``torque_limit``) are used; only those, never its PID.
        stale_timeout: control age (simulated s) beyond which the loop falls back to the hold.
        transition_duration: hold → law transition, s (0: switch at once).
        remove_gravity: subtract g(q) from every output (drives that add it themselves).
    """

    def __init__(
        self,
        robot: RobotModel,
        hold: LowLevelController,
        stale_timeout: float,
        transition_duration: float = 0.1,
        remove_gravity: bool = False,
    ) -> None:
        if not (math.isfinite(stale_timeout) and stale_timeout > 0):
            raise ConfigError(f"stale_timeout must be a positive number of s, got {stale_timeout}")
        if not (math.isfinite(transition_duration) and transition_duration >= 0):
            raise ConfigError(f"transition_duration must be >= 0 s, got {transition_duration}")
        self.robot = robot
        self.hold = hold
        self.stale_timeout = float(stale_timeout)
        self.transition_duration = float(transition_duration)
        self.remove_gravity = bool(remove_gravity)
        self._data = robot.create_data()
        self.reset()

    def reset(self) -> None:
        """Back to HOLD, no control, nothing sent."""
        self.hold.reset()
        self._mode = LowLevelMode.HOLD
        self._command: LinearFeedbackCommand | None = None
        self._command_t = -math.inf
        self._sent_any = False
        self._blend_start = 0.0
        self._t_previous: float | None = None
        self.invalid_commands = 0

    @property
    def mode(self) -> LowLevelMode:
        """The loop's mode: the safe hold, the transition to the law, or the law."""
        return self._mode

    @property
    def command_time(self) -> float:
        """Time of the newest control, s (−inf before the first)."""
        return self._command_t

    def _vector(self, value: npt.ArrayLike, n: int, name: str) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (n,) or not np.all(np.isfinite(arr)):
            raise InputError(f"{name} must be {n} finite numbers, got shape {arr.shape}")
        return arr

    def engage_hold(self) -> None:
        """Drop the current control: the next :meth:`step` is the safe hold."""
        self._command = None

    def set_command(self, command: LinearFeedbackCommand, t_command: float) -> None:
        """Take a new control solved at t_command (s). InputError if it is malformed or not newer
        than the current one (the current one is kept), or if its feed-forward is implausible
        (the control is then dropped too: the next cycle is the safe hold)."""
        nv, nq = self.robot.nv, self.robot.model.nq
        try:
            check_torque(command.feedforward, self.robot.torque_limit, "feedforward")
        except InputError:
            self.invalid_commands += 1
            self.engage_hold()
            raise
        self._vector(command.q0, nq, "q0")
        self._vector(command.v0, nv, "v0")
        gain = np.asarray(command.feedback_gain, dtype=float)
        if gain.shape != (nv, 2 * nv) or not np.all(np.isfinite(gain)):
            raise InputError(f"feedback_gain must be finite {nv}×{2 * nv}, got {gain.shape}")
        if not math.isfinite(t_command) or t_command <= self._command_t:
            raise InputError(f"control time {t_command} is not after {self._command_t}")
        self._command = command
        self._command_t = float(t_command)

    def _clip(self, tau: np.ndarray) -> np.ndarray:
        limit = self.hold.torque_limit
        return np.clip(self.robot.clip_torque(tau), -limit, limit)

    def _law(self, q: np.ndarray, v: np.ndarray) -> np.ndarray | None:
        """The saturated law, or None (control dropped) when it is implausible."""
        assert self._command is not None
        try:
            return self._clip(linear_feedback_torque(self.robot.model, self._command, q, v))
        except InputError:
            self.invalid_commands += 1
            self.engage_hold()
            return None

    def step(self, q: npt.ArrayLike, v: npt.ArrayLike, t: float) -> LowLevelOutput:
        """One cycle at time t (s) from the measured q (rad), v (rad/s): the effort to send
        (N·m, saturated; g(q) removed with ``remove_gravity``) and the mode."""
        nv = self.robot.nv
        q = self._vector(q, self.robot.model.nq, "q")
        v = self._vector(v, nv, "v")
        if not math.isfinite(t) or (self._t_previous is not None and t <= self._t_previous):
            raise InputError(f"t must be finite and increasing, got {t} after {self._t_previous}")
        age = t - self._command_t
        fresh = self._command is not None and age <= self.stale_timeout + TIME_EPS
        tau = self._law(q, v) if fresh else None
        blend = 0.0
        if tau is not None:
            if self._mode in (LowLevelMode.HOLD, LowLevelMode.FALLBACK):
                if self._sent_any and self.transition_duration > 0.0:
                    self._mode, self._blend_start = LowLevelMode.BLEND, t
                else:
                    self._mode = LowLevelMode.TRACK
            blend = 1.0
            if self._mode == LowLevelMode.BLEND:
                elapsed = t - self._blend_start  # (times are multiples of the plant step)
                blend = (
                    1.0
                    if elapsed >= self.transition_duration - TIME_EPS
                    else elapsed / self.transition_duration
                )
                if blend >= 1.0:
                    self._mode = LowLevelMode.TRACK
                else:  # upstream's linear PD → LF weight, the hold in the PD's place
                    tau = self._clip((1.0 - blend) * self.hold.hold_torque(q, v) + blend * tau)
        else:
            if self._mode not in (LowLevelMode.HOLD, LowLevelMode.FALLBACK):
                self._mode = LowLevelMode.FALLBACK
                self.hold.reset()  # a new hold: brake first
            tau = self._clip(self.hold.hold_torque(q, v))
        if self.remove_gravity:
            tau = tau - self.robot.gravity(q, self._data)
        self._t_previous = float(t)
        self._sent_any = True
        return LowLevelOutput(tau, tau.copy(), self._mode, float(age), float(blend))
