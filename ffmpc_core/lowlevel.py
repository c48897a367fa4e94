"""The low-level loop between MPC solutions: what the 1 kHz torque loop sends (ROS-free).

Real MPC stacks never send a raw solver output straight to the motors. One class,
:class:`LowLevelController`, holds the whole policy, used by BOTH the ROS-free runner
(``sim_bridge.runner``) and the PID node (``ffmpc_ros.pid_node``):

* **hold** — until the first MPC command, the desired torque is a safe hold: gravity
  compensation plus an inertia-scaled joint PD around the posture measured when the hold began,
  τ_hold = g(q̂) + M_ii ω²·(q_hold − q̂) − 2ζ M_ii ω·q̇̂ (M_ii: diagonal of the joint-space
  inertia at q_hold, ω = 2π·``hold_frequency``);
* **blend** — when MPC commands start (or come back after a fallback) and the loop has already
  sent hold torques, the desired torque moves from τ_hold to the MPC torque with a minimum-jerk
  weight over ``blend_duration``; when the first command is there before anything was sent (the
  runner, and the graph in lockstep), there is nothing to blend from and the MPC torque is used
  at once — so a loop whose MPC is on time gives exactly the plain scheme;
* **track** — the MPC torque: on the cycle a command arrives, its torque τ*; on the cycles in
  between, τ* (the paper's plain scheme) or, with ``riccati_feedback``, τ* + G·(x̂ − x̂_solve)
  (G = ``MpcCommand.feedback_gain``, relative to ``MpcCommand.state``);
* **fallback** — when the newest command is older than ``stale_timeout`` (simulated time), the
  safe hold again, around the posture measured at that moment.

The desired torque τ^d (saturated to the robot's limits) then goes through the torque PID of
eq 33 (with its δo delay line) and the motor torque τ^m is saturated too. Nothing reads a
clock: t is given to every call.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import pinocchio as pin

from ffmpc_core.config import FORMULATIONS
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.pid import TorquePid
from ffmpc_core.robots import RobotModel
from ffmpc_core.tasks import min_jerk

#: Tolerance on simulated times, s (times are multiples of the plant step).
TIME_EPS = 1e-9


class LowLevelMode(IntEnum):
    """What the low-level loop is doing (the values are published by the PID node)."""

    HOLD = 0  # no MPC command yet: safe hold
    BLEND = 1  # hold → MPC torque
    TRACK = 2  # MPC torque (plus optional Riccati feedback)
    FALLBACK = 3  # MPC output stale: safe hold


@dataclass(frozen=True)
class LowLevelConfig:
    """Parameters of the low-level loop.

    Attributes:
        formulation: the MPC's formulation; decides the state x̂ = (q, q̇), (q, q̇, τ̂) or
            (q, q̇, λ̂) the Riccati feedback is computed on.
        force_dimension: entries of λ̂ (force-feedback).
        riccati_feedback: apply τ* + G·(x̂ − x̂_solve) between solves (off: the paper's scheme).
        stale_timeout: age of the newest command (s, simulated) beyond which the loop falls back
            to the safe hold; must exceed the MPC period.
        mpc_period: the MPC's re-planning period, s (only checked against ``stale_timeout``).
        blend_duration: hold → MPC blend duration, s (minimum-jerk weight).
        hold_frequency: natural frequency of the hold PD, Hz.
        hold_damping_ratio: its damping ratio ζ.
    """

    formulation: str = "force_feedback"
    force_dimension: int = 1
    riccati_feedback: bool = False
    stale_timeout: float = 0.004
    mpc_period: float = 0.002
    blend_duration: float = 0.1
    hold_frequency: float = 4.0
    hold_damping_ratio: float = 1.0

    def __post_init__(self) -> None:
        if self.formulation not in FORMULATIONS:
            raise ConfigError(f"formulation must be one of {FORMULATIONS}")
        if self.force_dimension not in (1, 3):
            raise ConfigError("force_dimension must be 1 or 3")
        values = (self.stale_timeout, self.mpc_period, self.blend_duration, self.hold_frequency)
        if not all(math.isfinite(v) for v in values) or self.mpc_period <= 0:
            raise ConfigError("stale_timeout, mpc_period, blend_duration, hold_frequency: finite")
        if self.stale_timeout <= self.mpc_period:
            raise ConfigError(
                f"stale_timeout ({self.stale_timeout} s) must exceed the MPC period "
                f"({self.mpc_period} s): an on-time MPC would otherwise look stale"
            )
        if self.blend_duration < 0 or self.hold_frequency < 0 or self.hold_damping_ratio < 0:
            raise ConfigError("blend_duration, hold_frequency, hold_damping_ratio must be >= 0")


@dataclass
class LowLevelMeasurement:
    """What the low-level loop reads each cycle: q̂ rad, q̇̂ rad/s, τ̂ N·m (joint order of the
    robot model) and, for the Riccati feedback of force-feedback, λ̂ N (the MPC's frame)."""

    q: np.ndarray
    v: np.ndarray
    torque: np.ndarray
    force: np.ndarray | None = None


@dataclass
class LowLevelCommand:
    """The part of an MPC output the low level uses (``MpcCommand`` has these attributes).

    torque N·m (nv); state x̂_solve (nx); feedback_gain G (nv × nx)."""

    torque: np.ndarray
    state: np.ndarray
    feedback_gain: np.ndarray


@dataclass
class LowLevelOutput:
    """One cycle's result: motor torque τ^m and desired torque τ^d (N·m, saturated), the mode,
    the age of the command used (s; inf without one) and the blend weight in [0, 1]."""

    motor_torque: np.ndarray
    desired_torque: np.ndarray
    mode: LowLevelMode
    command_age: float
    blend: float


class LowLevelController:
    """Hold / blend / track / fallback around the torque PID (see the module docstring).

    Shape: ``reset()``, ``set_command(command, t_command)`` when an MPC output arrives (t_command:
    the time of the measurement it was solved from, s), ``step(measurement, t) -> output`` once
    per plant cycle.
    """

    def __init__(self, robot: RobotModel, config: LowLevelConfig, pid: TorquePid) -> None:
        if pid.gains.nv != robot.nv:
            raise ConfigError(f"PID has {pid.gains.nv} joints, robot {robot.nv}")
        self.robot = robot
        self.config = config
        self.pid = pid
        nv = robot.nv
        self.nx = {
            "classical": 2 * nv,
            "torque_feedback": 3 * nv,
            "force_feedback": 2 * nv + config.force_dimension,
        }[config.formulation]
        self._data = robot.create_data()
        omega = 2.0 * math.pi * config.hold_frequency
        self._omega2, self._two_zeta_omega = omega * omega, 2.0 * config.hold_damping_ratio * omega
        self.reset()

    # -- state ------------------------------------------------------------------------------
    def reset(self) -> None:
        """Back to HOLD, no command, nothing sent; the PID forgets its history."""
        self.pid.reset()
        self._mode = LowLevelMode.HOLD
        self._command: LowLevelCommand | None = None
        self._command_t = -math.inf
        self._first_use = False
        self._sent_any = False
        self._blend_start = 0.0
        self._hold_q: np.ndarray | None = None
        self._hold_stiffness = np.zeros(self.robot.nv)
        self._hold_damping = np.zeros(self.robot.nv)
        self._t_previous: float | None = None

    @property
    def mode(self) -> LowLevelMode:
        return self._mode

    @property
    def command_time(self) -> float:
        """Time of the newest command, s (−inf before the first)."""
        return self._command_t

    # -- inputs -----------------------------------------------------------------------------
    def _vector(self, value, n: int, name: str) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (n,) or not np.all(np.isfinite(arr)):
            raise InputError(f"{name} must be {n} finite numbers, got shape {arr.shape}")
        return arr

    def set_command(self, command, t_command: float) -> None:
        """Take a new MPC output (``torque``, ``state``, ``feedback_gain``) solved at t_command.

        InputError (and the previous command kept) if it is malformed or not newer than the
        current one.
        """
        nv = self.robot.nv
        torque = self._vector(command.torque, nv, "command torque")
        state = self._vector(command.state, self.nx, "command state")
        gain = np.asarray(command.feedback_gain, dtype=float)
        if gain.shape != (nv, self.nx) or not np.all(np.isfinite(gain)):
            raise InputError(f"feedback_gain must be finite {nv}×{self.nx}, got {gain.shape}")
        if not math.isfinite(t_command) or t_command <= self._command_t:
            raise InputError(f"command time {t_command} is not after {self._command_t}")
        self._command = LowLevelCommand(torque, state, gain)
        self._command_t = float(t_command)
        self._first_use = True

    def state_from(self, meas: LowLevelMeasurement) -> np.ndarray:
        """x̂ of the formulation from a measurement (as ``ModelPredictiveController``)."""
        nv = self.robot.nv
        parts = [self._vector(meas.q, nv, "q"), self._vector(meas.v, nv, "v")]
        if self.config.formulation == "torque_feedback":
            parts.append(self._vector(meas.torque, nv, "torque"))
        elif self.config.formulation == "force_feedback":
            if meas.force is None:
                raise InputError("the Riccati feedback of force-feedback needs λ̂")
            parts.append(self._vector(meas.force, self.config.force_dimension, "force"))
        return np.concatenate(parts)

    # -- the policy ---------------------------------------------------------------------------
    def _start_hold(self, q: np.ndarray) -> None:
        """Hold around q: PD gains M_ii·ω², 2ζ·M_ii·ω from the joint-space inertia at q."""
        self._hold_q = q.copy()
        mass = pin.crba(self.robot.model, self._data, q)
        diag = np.diag(mass).copy()
        self._hold_stiffness = diag * self._omega2
        self._hold_damping = diag * self._two_zeta_omega

    def hold_torque(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """τ_hold = g(q̂) + K·(q_hold − q̂) − D·q̇̂, N·m (not saturated)."""
        if self._hold_q is None:
            self._start_hold(q)
        gravity = pin.computeGeneralizedGravity(self.robot.model, self._data, q)
        return gravity + self._hold_stiffness * (self._hold_q - q) - self._hold_damping * v

    def _mpc_torque(self, meas: LowLevelMeasurement) -> np.ndarray:
        """τ*, or τ* + G·(x̂ − x̂_solve) with the Riccati feedback; τ* alone on a cycle whose λ̂
        is missing (force-feedback: a rejected or lost wrench never stops the loop)."""
        cmd = self._command
        missing_force = self.config.formulation == "force_feedback" and meas.force is None
        if self._first_use or not self.config.riccati_feedback or missing_force:
            self._first_use = False
            return cmd.torque
        dx = self.state_from(meas) - cmd.state
        return self.robot.clip_torque(cmd.torque + cmd.feedback_gain @ dx)

    def step(self, meas: LowLevelMeasurement, t: float) -> LowLevelOutput:
        """One cycle at time t (s): desired and motor torques (N·m, saturated) and the mode."""
        nv = self.robot.nv
        q = self._vector(meas.q, nv, "q")
        v = self._vector(meas.v, nv, "v")
        measured = self._vector(meas.torque, nv, "torque")
        if not math.isfinite(t) or (self._t_previous is not None and t <= self._t_previous):
            raise InputError(f"t must be finite and increasing, got {t} after {self._t_previous}")
        age = t - self._command_t
        fresh = self._command is not None and age <= self.config.stale_timeout + TIME_EPS
        blend = 1.0
        if fresh:
            if self._mode in (LowLevelMode.HOLD, LowLevelMode.FALLBACK):
                if self._sent_any and self.config.blend_duration > 0.0:
                    self._mode, self._blend_start = LowLevelMode.BLEND, t
                else:
                    self._mode = LowLevelMode.TRACK
            tau_mpc = self._mpc_torque(meas)
            if self._mode == LowLevelMode.BLEND:
                blend = min_jerk((t - self._blend_start) / self.config.blend_duration)
                if blend >= 1.0:
                    self._mode, desired = LowLevelMode.TRACK, tau_mpc
                else:
                    desired = (1.0 - blend) * self.hold_torque(q, v) + blend * tau_mpc
            else:
                desired = tau_mpc
        else:
            if self._mode not in (LowLevelMode.HOLD, LowLevelMode.FALLBACK):
                self._mode = LowLevelMode.FALLBACK
                self._start_hold(q)
            blend = 0.0
            desired = self.hold_torque(q, v)
        desired = self.robot.clip_torque(desired)
        motor = self.robot.clip_torque(self.pid.step(measured, desired, t))
        self._t_previous = float(t)
        self._sent_any = True
        return LowLevelOutput(motor, desired, self._mode, float(age), float(blend))
