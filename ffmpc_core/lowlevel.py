"""The low-level loop between MPC solutions: what the 1 kHz torque loop sends (ROS-free).

Real MPC stacks never send a raw solver output straight to the motors. One class,
:class:`LowLevelController`, holds the whole policy, used by BOTH the ROS-free runner
(``studies.polishing``) and the PID node (``ffmpc_ros.pid_node``):

* **hold** — until the first MPC command, the safe hold of :meth:`LowLevelController.hold_torque`
  (below);
* **blend** — when MPC commands start (or come back after a fallback) and the loop has already
  sent hold torques, the desired torque moves from τ_hold to the MPC torque with a minimum-jerk
  weight w over ``blend_duration``: the PID's reference is w·τ*(t − δo) + (1 − w)·τ_hold(t), the
  MPC part through the δo delay line, the hold part without it; when the first command is there
  before anything was sent (the runner, and the graph in lockstep), there is nothing to blend
  from and the MPC torque is used at once — so a loop whose MPC is on time gives exactly the
  plain scheme;
* **track** — the MPC torque: on the cycle a command arrives, its torque τ*; on the cycles in
  between, τ* (the paper's plain scheme) or, with ``riccati_feedback``, τ* + G·(x̂ − x̂_solve)
  (G = ``MpcCommand.feedback_gain``, relative to ``MpcCommand.state``);
* **fallback** — the safe hold again, engaged on the first cycle whose newest command is older
  than ``stale_timeout`` (simulated time), or on the first cycle after an invalid command
  (non-finite or implausible torque, :meth:`LowLevelController.set_command`) or an explicit
  :meth:`LowLevelController.engage_hold` (the MPC failed), or — with ``velocity_guard`` on —
  on a cycle whose predicted speed exceeds ``velocity_guard`` × a joint's velocity limit (the
  axis velocity monitoring of an industrial cell): the command is dropped, the brake below
  takes the motion down, and the next MPC command blends in from the hold again. The speed is
  predicted :data:`GUARD_LOOKAHEAD` cycles ahead, |q̇̂ + n·(q̇̂ − q̇̂_prev)|, since the measurement
  is a cycle old and the brake acts a cycle later: on the iiwa's A5 at rest, 10 N·m adds about
  0.25× its velocity limit per cycle.

In track, the desired torque τ^d (saturated to the robot's limits) goes through the torque PID of
eq 33 (with its δo delay line) and the motor torque τ^m is saturated too. **The hold torque
bypasses the δo delay line**: it is computed from this cycle's measurement and is the PID's
reference as it is (``TorquePid.step(..., undelayed=τ_hold, weight=0)``), so no delay sits inside
the hold's feedback loop (through the 5 ms delay line, the old diagonal-inertia hold PD drove
joints to 3–5× their velocity limits at saturated torque). The same PID object runs on: its
integral keeps rejecting the actuation bias b and gain a of eq 31 (on the iiwa's light wrist
b ≈ 1.5 N·m would otherwise bend the hold by ~0.3 rad) and its delay line keeps filling, so the
MPC takes over without a jump (switching between two PIDs, or resetting one, at the end of a
blend kicked the wrist to 1.9–3.5× its velocity limit after a 50–100 ms dropout; measured).
Nothing reads a clock: t is given to every call.

The safe hold (stable by construction). Rigid-body model M(q)q̈ + C(q, q̇)q̇ + g(q) = τ, ω =
2π·``hold_frequency``, K_d = 2ζω, K_p = ω² (ζ = ``hold_damping_ratio``). Two phases:

* **brake** (damping first) while the robot moves (kinetic energy T̂ = ½q̇̂ᵀM(q̂)q̇̂ >
  ``hold_settle_energy``; an energy, not a joint speed, so the light wrist's torque-noise jitter
  does not count as motion):
  τ = g(q̂) − s·K_d·M(q̂)·q̇̂, with the largest s ∈ [0, 1] that keeps every |τ_i| within
  ``hold_torque_fraction`` × its limit. With T = ½ q̇ᵀMq̇ and the skew symmetry of Ṁ − 2C,
  Ṫ = q̇ᵀ(τ − g) = −s·K_d·q̇ᵀMq̇ = −2·s·K_d·T ≤ 0 for ANY s ≥ 0: the kinetic energy decays
  (time constant 1/(2K_d) at s = 1), whatever the saturation does — no joint is ever driven
  faster, and the scaling keeps the torques within the limits;
* **hold** once T̂ ≤ ``hold_settle_energy``: the posture q_h is latched and
  τ = g(q̂) + M_h·(−K_p·(q̂ − q_h) − K_d·q̇̂), M_h = M(q_h) the FULL joint-space mass matrix
  (not its diagonal), constant during the hold. K_p·M_h and K_d·M_h are constant symmetric
  positive definite, so this is a PD plus gravity compensation with V = T + ½K_p·eᵀM_h·e,
  V̇ = −K_d·q̇ᵀM_h·q̇ ≤ 0 (Takegaki–Arimoto; LaSalle: e → 0); near q_h, M(q) ≈ M_h and each
  joint is the decoupled critically damped q̈ = −K_p·e − K_d·q̇. If that torque would exceed
  ``hold_torque_fraction`` × a limit, or T̂ exceeds 4 × the settle energy (a push), the hold
  goes back to brake.

V is continuous when the posture is latched (e = 0 then, V = T) and drops when the hold goes
back to brake (V → T), so V never increases during the whole safe hold: it is stable by
construction, with saturation. Velocities: T never exceeds its value at engagement, so no joint
is driven faster than the motion the hold inherited. The torque fraction left (default 25 %)
absorbs what the model does not know: the actuation gain a ∈ [0.8, 1.2] and bias |b| ≤ 2 N·m of
eq 31, friction, noise; the PID's integral (above, bounded by its anti-windup limit) removes
the bias slowly (K_I = 20 s⁻¹), outside this argument. Why brake first rather than a PD around
the posture where the hold began: after a dropout at speed, that posture is already behind the
robot, and a PD around it reverses the motion and saturates (its V̇ is then indefinite); braking
along −M·q̇ dissipates at any saturation scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import IntEnum
from typing import Protocol

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from ffmpc_core.config import FORMULATIONS
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.pid import PidConfig, TorquePid
from ffmpc_core.plausibility import check_torque
from ffmpc_core.robots import RobotModel, mass_matrix
from ffmpc_core.tasks import min_jerk

#: Tolerance on simulated times, s (times are multiples of the plant step).
TIME_EPS = 1e-9
#: Cycles ahead the velocity guard predicts the measured joint speed (one of sensing delay, one
#: before the brake's torque acts).
GUARD_LOOKAHEAD = 2


class LowLevelMode(IntEnum):
    """What the low-level loop is doing (the values are published by the PID node)."""

    HOLD = 0  # no MPC command yet: safe hold
    BLEND = 1  # hold → MPC torque
    TRACK = 2  # MPC torque (plus optional Riccati feedback)
    FALLBACK = 3  # MPC output stale or invalid: safe hold


@dataclass(frozen=True)
class LowLevelConfig:
    """Parameters of the low-level loop: the ``pid`` section (:class:`~ffmpc_core.pid.PidConfig`,
    as it is) with what the loop takes from the MPC, and the safe hold's constants.

    Attributes:
        formulation: the MPC's formulation; decides the state x̂ = (q, q̇), (q, q̇, τ̂) or
            (q, q̇, λ̂) the Riccati feedback is computed on.
        force_dimension: entries of λ̂ (force-feedback; the MPC's ``contact.dimension``).
        riccati_feedback: apply τ* + G·(x̂ − x̂_solve) between solves (off: the paper's scheme).
        mpc_period: the MPC's re-planning period, s (only checked against ``stale_timeout``).
        pid: the torque PID and the loop's settings (:class:`~ffmpc_core.pid.PidConfig`), read
            here:

            * ``stale_timeout``: age of the newest command (s, simulated) beyond which the loop
              falls back to the safe hold; must exceed ``mpc_period``. The default, 4 ms = two
              MPC periods, tolerates ONE missed solve: a command is stamped with the time of
              the measurement it was solved from and, in the graph, arrives up to one period
              later, so a one-period timeout would trip on every on-time command with any
              jitter. The hold then engages on the first loop cycle past the timeout: at most
              5 ms after the last good command's measurement. An invalid command engages it on
              the next cycle.
            * ``blend_duration``: hold → MPC blend duration, s (minimum-jerk weight).
            * ``hold_frequency``: natural frequency ω/2π of the hold PD, Hz (K_p = ω²,
              K_d = 2ζω); ``hold_damping_ratio``: its damping ratio ζ (1: critically damped).
            * ``torque_limit_fraction``: fraction of each joint's data-sheet torque limit that
              τ^d and τ^m are saturated to, in (0, 1] (a cell's own, lower limit; live on the
              pid node: :meth:`LowLevelController.set_limits`).
            * ``velocity_guard``: fraction of each joint's velocity limit above which a
              measured joint speed engages the safe hold (module docstring), in [0, 1]; 0 turns
              the guard off (the paper's scheme, and the studies' default: a run over a limit
              is reported, not hidden). Why (README "Faults, the safe hold and plausibility
              limits"): on the real-time graph the force-feedback MPC's wrist chatter reached
              1.05× joint A5's velocity limit on a CI machine.
        hold_settle_energy: kinetic energy ½q̇ᵀMq̇ (J) under which the hold latches its posture
            (brake above it; back to brake above 4× it). 2e-3 J: 0.04 rad/s on the iiwa's
            shoulder (M₁₁ ≈ 2.2 kg·m²), far above the wrist's noise jitter (~1e-4 J).
        hold_torque_fraction: fraction of each joint's torque limit the hold may use, in (0, 1].
        force_hold_time: simulated s a plausible λ̂ is held for the Riccati feedback of
            force-feedback (sample and hold): on a cycle whose λ̂ is missing (None: lost or
            rejected) or not finite, the newest λ̂ at most this old is used; beyond, the cycle
            sends the MPC torque τ* without feedback. One bad or late wrench never stops the
            loop, and a dead sensor never feeds an old force for long. 50 ms: the graph's
            ``max_input_age``.
    """

    formulation: str = "force_feedback"
    force_dimension: int = 1
    riccati_feedback: bool = False
    mpc_period: float = 0.002
    pid: PidConfig = field(default_factory=PidConfig)
    hold_settle_energy: float = 2e-3
    hold_torque_fraction: float = 0.75
    force_hold_time: float = 0.05

    def __post_init__(self) -> None:
        if self.formulation not in FORMULATIONS:
            raise ConfigError(f"formulation must be one of {FORMULATIONS}")
        if self.force_dimension not in (1, 3):
            raise ConfigError("force_dimension must be 1 or 3")
        if not math.isfinite(self.mpc_period) or self.mpc_period <= 0:
            raise ConfigError(f"mpc_period must be a finite number of s > 0, got {self.mpc_period}")
        if self.pid.stale_timeout <= self.mpc_period:
            raise ConfigError(
                f"stale_timeout ({self.pid.stale_timeout} s) must exceed the MPC period "
                f"({self.mpc_period} s): an on-time MPC would otherwise look stale"
            )
        if not (math.isfinite(self.hold_settle_energy) and self.hold_settle_energy > 0):
            raise ConfigError("hold_settle_energy must be > 0 J")
        if not 0.0 < self.hold_torque_fraction <= 1.0:
            raise ConfigError("hold_torque_fraction must lie in (0, 1]")
        if not (math.isfinite(self.force_hold_time) and self.force_hold_time >= 0):
            raise ConfigError("force_hold_time must be a finite number of s >= 0")


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


class CommandLike(Protocol):
    """What :meth:`LowLevelController.set_command` reads (``MpcCommand``, ``LowLevelCommand``)."""

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
    per plant cycle; ``engage_hold()`` when the MPC failed. ``pid`` is the torque PID of eq 33
    that ``config.pid`` states (:meth:`from_config` builds it so; a test may hand in another).
    """

    @classmethod
    def from_config(
        cls, robot: RobotModel, config: LowLevelConfig, dt: float
    ) -> LowLevelController:
        """The loop around the torque PID that ``config.pid`` states
        (:meth:`~ffmpc_core.pid.TorquePid.from_config`: scaled by the robot's torque limits);
        ``dt``: the control cycle, s."""
        return cls(robot, config, TorquePid.from_config(config.pid, dt, robot.torque_limit))

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
        omega = 2.0 * math.pi * config.pid.hold_frequency
        self._kp, self._kd = omega * omega, 2.0 * config.pid.hold_damping_ratio * omega
        self._hold_budget = config.hold_torque_fraction * robot.torque_limit
        self._torque_limit = config.pid.torque_limit_fraction * robot.torque_limit
        # rad/s, the speeds that engage the safe hold (None: guard off)
        self._guard_speed = (
            config.pid.velocity_guard * np.abs(robot.velocity_limit)
            if config.pid.velocity_guard > 0.0
            else None
        )
        self.reset()

    def set_limits(
        self, torque_limit_fraction: float | None = None, stale_timeout: float | None = None
    ) -> None:
        """Change the saturation (fraction of the data-sheet torque limits) and/or the command
        timeout of the safe hold (s) from the next :meth:`step` on; None keeps one. ConfigError
        (nothing changed) for a value :class:`LowLevelConfig` refuses."""
        c = self.config.pid
        pid = replace(  # validates (__post_init__)
            c,
            torque_limit_fraction=c.torque_limit_fraction
            if torque_limit_fraction is None
            else float(torque_limit_fraction),
            stale_timeout=c.stale_timeout if stale_timeout is None else float(stale_timeout),
        )
        config = replace(self.config, pid=pid)  # checks stale_timeout against the MPC period
        self.config = config
        self._torque_limit = config.pid.torque_limit_fraction * self.robot.torque_limit

    def set_gains(
        self, kp: float | None = None, ki: float | None = None, kd: float | None = None
    ) -> None:
        """Change the PID's K_P, K_I and/or K_D (the same for every joint; None keeps one) from
        the next :meth:`step` on (:meth:`~ffmpc_core.pid.TorquePid.set_gains`), and
        ``config.pid`` with them. ConfigError (nothing changed) for a value that is not finite
        and >= 0."""
        c = self.config.pid
        pid = replace(  # validates (__post_init__)
            c,
            kp=c.kp if kp is None else float(kp),
            ki=c.ki if ki is None else float(ki),
            kd=c.kd if kd is None else float(kd),
        )
        self.pid.set_gains(kp=kp, ki=ki, kd=kd)
        self.config = replace(self.config, pid=pid)

    @property
    def torque_limit(self) -> np.ndarray:
        """The torque limits τ^d and τ^m are saturated to, N·m (per joint)."""
        return self._torque_limit.copy()

    def _clip(self, tau: np.ndarray) -> np.ndarray:
        """Saturate to :attr:`torque_limit` (N·m); InputError for a non-finite or implausible
        torque (``RobotModel.clip_torque``'s rule: a fault, never a command to saturate)."""
        return np.clip(self.robot.clip_torque(tau), -self._torque_limit, self._torque_limit)

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
        self._hold_mass = np.zeros((self.robot.nv, self.robot.nv))
        self._t_previous: float | None = None
        self._held_force: np.ndarray | None = None  # newest finite λ̂, N
        self._held_force_t = -math.inf  # its time, s
        self.invalid_commands = 0
        self.velocity_guard_trips = 0  # commands the velocity guard dropped
        self._v_previous: np.ndarray | None = None  # q̇̂ of the previous cycle, rad/s

    @property
    def mode(self) -> LowLevelMode:
        """What the low level does this cycle: hold, blend, track or fallback."""
        return self._mode

    @property
    def command_time(self) -> float:
        """Time of the newest command, s (−inf before the first)."""
        return self._command_t

    @property
    def hold_posture(self) -> np.ndarray | None:
        """The latched hold posture q_h, rad (None while braking or outside the hold)."""
        return None if self._hold_q is None else self._hold_q.copy()

    # -- inputs -----------------------------------------------------------------------------
    def _vector(self, value: npt.ArrayLike, n: int, name: str) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (n,) or not np.all(np.isfinite(arr)):
            raise InputError(f"{name} must be {n} finite numbers, got shape {arr.shape}")
        return arr

    def engage_hold(self) -> None:
        """Drop the current command: the next :meth:`step` is the safe hold (FALLBACK, or HOLD
        before any command was used) until a new valid command arrives."""
        self._command = None

    def check_command(self, command: CommandLike) -> LowLevelCommand:
        """``command`` as the low level would take it, changing nothing: its torque of nv
        finite values within ``plausibility.COMMAND_TORQUE_FACTOR`` × the limits, its state of
        nx finite values and a finite nv × nx gain; InputError otherwise. A receiver of
        commands from topics (``ffmpc_ros.pid_node``) checks with it before a message may
        claim its cycle: a rejected message from outside the graph then leaves the genuine
        command of that cycle usable and the loop out of the safe hold."""
        nv = self.robot.nv
        raw = np.asarray(command.torque, dtype=float)
        if raw.shape != (nv,):
            raise InputError(f"command torque must be {nv} finite numbers, got shape {raw.shape}")
        torque = check_torque(raw, self.robot.torque_limit, "command torque")
        state = self._vector(command.state, self.nx, "command state")
        gain = np.asarray(command.feedback_gain, dtype=float)
        if gain.shape != (nv, self.nx) or not np.all(np.isfinite(gain)):
            raise InputError(f"feedback_gain must be finite {nv}×{self.nx}, got {gain.shape}")
        return LowLevelCommand(torque, state, gain)

    def set_command(self, command: CommandLike, t_command: float) -> None:
        """Take a new MPC output (``torque``, ``state``, ``feedback_gain``) solved at t_command.

        InputError if it is malformed or not newer than the current one (the previous command
        is then kept), or if its torque is non-finite or implausible (beyond
        ``plausibility.COMMAND_TORQUE_FACTOR`` × the limits): that is a failed MPC, and the current
        command is dropped too, so the next cycle is the safe hold.
        """
        nv = self.robot.nv
        raw = np.asarray(command.torque, dtype=float)
        if raw.shape != (nv,):
            raise InputError(f"command torque must be {nv} finite numbers, got shape {raw.shape}")
        try:
            torque = check_torque(raw, self.robot.torque_limit, "command torque")
        except InputError:
            self.invalid_commands += 1
            self.engage_hold()
            raise
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

    def _force_for_feedback(self, force: npt.ArrayLike | None, t: float) -> np.ndarray | None:
        """λ̂ for this cycle's Riccati feedback: the measured one when finite (and then held),
        else the held one if at most ``force_hold_time`` old, else None (τ* alone)."""
        if force is not None:
            arr = np.asarray(force, dtype=float)
            if arr.shape != (self.config.force_dimension,) or np.all(np.isfinite(arr)):
                if arr.shape == (self.config.force_dimension,):
                    self._held_force, self._held_force_t = arr.copy(), t
                return arr  # (a wrong shape is refused by state_from: a caller's error)
        if self._held_force is not None and t - self._held_force_t <= (
            self.config.force_hold_time + TIME_EPS
        ):
            return self._held_force
        return None

    # -- the safe hold ------------------------------------------------------------------------
    def _start_hold(self) -> None:
        """A new hold: brake first (the posture is latched once the robot is at rest)."""
        self._hold_q = None

    def _mass(self, q: np.ndarray) -> np.ndarray:
        return mass_matrix(self.robot.model, self._data, q)

    def _scaled(self, gravity: np.ndarray, tau_pd: np.ndarray) -> tuple[np.ndarray, float]:
        """(g + s·τ_pd, s) with the largest s ∈ [0, 1] keeping |τ_i| ≤ the hold's budget."""
        room = np.maximum(self._hold_budget - np.abs(gravity), 0.0)
        need = np.abs(tau_pd)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratios = np.where(need > room, room / np.where(need > 0.0, need, 1.0), 1.0)
        scale = float(min(1.0, ratios.min()))
        return gravity + scale * tau_pd, scale

    def hold_torque(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """The safe hold's torque, N·m, from q̂ (rad) and q̇̂ (rad/s) — brake or latched PD
        (module docstring); within ``hold_torque_fraction`` of the limits unless gravity alone
        needs more (the caller saturates)."""
        settle = self.config.hold_settle_energy
        gravity = pin.computeGeneralizedGravity(self.robot.model, self._data, q)
        mass = self._mass(q)
        energy = 0.5 * float(v @ mass @ v)
        if self._hold_q is not None and energy > 4.0 * settle:
            self._hold_q = None  # pushed: brake again
        if self._hold_q is None and energy <= settle:
            self._hold_q = q.copy()
            self._hold_mass = mass
        if self._hold_q is not None:
            tau_pd = self._hold_mass @ (-self._kp * (q - self._hold_q) - self._kd * v)
            tau, scale = self._scaled(gravity, tau_pd)
            if scale >= 1.0:
                return tau
            self._hold_q = None  # the PD would saturate: brake (dissipative at any scale)
        tau, _ = self._scaled(gravity, mass @ (-self._kd * v))
        return tau

    # -- the policy ---------------------------------------------------------------------------
    def _mpc_torque(self, meas: LowLevelMeasurement) -> np.ndarray:
        """τ*, or τ* + G·(x̂ − x̂_solve) with the Riccati feedback; τ* alone on a cycle whose λ̂
        is missing (force-feedback: a rejected or lost wrench never stops the loop)."""
        cmd = self._command
        assert cmd is not None  # called only when the command is fresh, hence set
        missing_force = self.config.formulation == "force_feedback" and meas.force is None
        if self._first_use or not self.config.riccati_feedback or missing_force:
            self._first_use = False
            return cmd.torque
        dx = self.state_from(meas) - cmd.state
        return self._clip(cmd.torque + cmd.feedback_gain @ dx)

    def step(self, meas: LowLevelMeasurement, t: float) -> LowLevelOutput:
        """One cycle at time t (s): desired and motor torques (N·m, saturated) and the mode."""
        nv = self.robot.nv
        q = self._vector(meas.q, nv, "q")
        v = self._vector(meas.v, nv, "v")
        measured = self._vector(meas.torque, nv, "torque")
        if not math.isfinite(t) or (self._t_previous is not None and t <= self._t_previous):
            raise InputError(f"t must be finite and increasing, got {t} after {self._t_previous}")
        if self.config.formulation == "force_feedback" and self.config.riccati_feedback:
            force = self._force_for_feedback(meas.force, t)
            if force is not meas.force:
                meas = LowLevelMeasurement(meas.q, meas.v, meas.torque, force)
        if self._guard_speed is not None:
            ahead = v if self._v_previous is None else v + GUARD_LOOKAHEAD * (v - self._v_previous)
            self._v_previous = v
            if self._command is not None and np.any(np.abs(ahead) > self._guard_speed):
                self.velocity_guard_trips += 1
                self.engage_hold()  # too fast: the brake, then a blend from the next command
        age = t - self._command_t
        fresh = self._command is not None and age <= self.config.pid.stale_timeout + TIME_EPS
        blend = 1.0
        if fresh:
            try:
                tau_raw = self._mpc_torque(meas)
                tau_mpc = self._clip(tau_raw)
            except InputError:  # the Riccati feedback gave an implausible torque
                self.invalid_commands += 1
                self.engage_hold()
                fresh = False
        if fresh:
            if self._mode in (LowLevelMode.HOLD, LowLevelMode.FALLBACK):
                if self._sent_any and self.config.pid.blend_duration > 0.0:
                    self._mode, self._blend_start = LowLevelMode.BLEND, t
                else:
                    self._mode = LowLevelMode.TRACK
            if self._mode == LowLevelMode.BLEND:
                blend = min_jerk((t - self._blend_start) / self.config.pid.blend_duration)
                if blend >= 1.0:
                    self._mode = LowLevelMode.TRACK
            if self._mode == LowLevelMode.BLEND:
                # The MPC torque enters the delay line; the hold part reaches the motors without.
                hold = self._clip(self.hold_torque(q, v))
                desired = self._clip((1.0 - blend) * hold + blend * tau_raw)
                motor = self.pid.step(measured, tau_mpc, t, undelayed=hold, weight=blend)
            else:
                desired = tau_mpc
                motor = self.pid.step(measured, tau_mpc, t)
            motor = self._clip(motor)
        else:
            if self._mode not in (LowLevelMode.HOLD, LowLevelMode.FALLBACK):
                self._mode = LowLevelMode.FALLBACK
                self._start_hold()
            blend = 0.0
            desired = self._clip(self.hold_torque(q, v))
            # To the motors without the δo delay line; the PID's integral keeps rejecting the
            # actuation bias, and its delay line fills with the hold torque.
            motor = self._clip(self.pid.step(measured, desired, t, desired, 0.0))
        self._t_previous = float(t)
        self._sent_any = True
        return LowLevelOutput(motor, desired, self._mode, float(age), float(blend))
