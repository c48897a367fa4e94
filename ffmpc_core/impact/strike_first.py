"""The first contact is the task's impact: strike at the bound safe for every material still
plausible, regulate, learn from the impact and the regulation (Dehio & Kheddar 2020, Sec. IV-C,
V and VI, made robust to a wrong prior without a separate touch).

:class:`~ffmpc_core.impact.touch_first.TouchFirstImpactController` touches the object at the
eq 14 bound that is safe for the whole plausible range, learns for 0.15 s, retracts and strikes
again from the learned interval. Its touch is already an impact at a speed safe for every
plausible material; this controller makes that impact the task's:

1. **strike** — the maximal approach of Sec. IV-C with eq 14 over the corners of the current
   *knowledge* (:class:`~ffmpc_core.impact.robust.RobustImpactPlanner`): before any contact
   the prior's plausible range (:meth:`MaterialInterval.from_prior`), or the interval a previous
   run learned on this object (:attr:`StrikeFirstConfig.remembered_stiffness`,
   :attr:`~StrikeFirstConfig.remembered_damping`). Where the approach knows the object cannot be
   touched yet — the object's surface is known (``surface_known``) to within
   ``surface_tolerance`` along d, the
   premise of the paper's baseline, which has the contact location as its target — the tool may
   move faster than the eq 14 bound, as long as it can still brake to that bound at
   ``braking_fraction`` of the contact-space deceleration bound (eq 10–11, zero force) before
   the earliest possible contact (:func:`approach_speed_limit`; the braking ends
   ``settle_time`` at that bound before the band). Inside that band, or with an
   unknown surface (``surface_known`` false: the paper's premise, the impact may come at the
   next step), the speed is the eq 14 bound.
2. **contact** — at the contact threshold, the regulation of the target force (admittance;
   the task controller may hand over to the force-feedback MPC once the target is admitted)
   while the recursive learner (eq 19–21) is fed from the impact on (z from the last
   force-free sample). The admittance reference never goes deeper than z̄ below that surface
   (:func:`~ffmpc_core.impact.control.admittance_step`'s ``max_position``): a target the
   material cannot hold within z̄ is stopped short of, not pressed for.
3. **decide** (in contact, no retract) — once the learner is confident (the touch-first rule:
   ``touch.learner_min_samples``, ``touch.learner_max_relative_std``) or
   ``max_decision_time`` after the contact with what it has, the knowledge becomes the
   learner's interval (:meth:`MaterialInterval.from_estimate`) and the target is checked
   against its softest material. Admitted: the regulation goes on (and the hand-over may
   engage); the learner keeps sharpening the model from the regulation. Refused: the robot
   retracts ``touch.retract_height`` above the surface and holds (phase ``refused``,
   :attr:`refusal` with the numbers).

No second impact is planned: the task strikes once. A contact lost during the regulation is
re-made by the admittance reference (at most its ``max_velocity``, 0.1 m/s, far below any eq 14
bound of the study), not by a new strike.

Before any motion (the constructor) the target is checked: with a remembered interval against
its softest material (a target the object could not hold last time is refused before moving),
without one against the stiffest plausible material (refused only if no plausible material can
hold it; the rest is decided from the learned interval after the contact).

Frames, units and signs as in :mod:`ffmpc_core.impact.control` (d unit, world frame; z, ż along
d, m and m/s; f the pressing force, N).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError, SolverError
from ffmpc_core.impact.control import (
    CartesianCommand,
    ImpactControllerConfig,
    ImpactMeasurement,
)
from ffmpc_core.impact.learner import RecursiveContactLearner
from ffmpc_core.impact.limits import JointLimits
from ffmpc_core.impact.robust import MaterialInterval, check_force_target
from ffmpc_core.impact.touch_first import (
    CONTACT,
    REFUSED,
    STRIKE,
    TouchFirstConfig,
    TouchFirstImpactController,
    fed_surface,
)
from ffmpc_core.robots import RobotModel

__all__ = [
    "StrikeFirstConfig",
    "StrikeFirstImpactController",
    "approach_speed_limit",
    "remembered_interval",
]


@dataclass(frozen=True)
class StrikeFirstConfig:
    """Parameters of the strike-first strategy (see the module docstring); the plausible range,
    the learner's confidence, the learned interval's width, the guard's impact force, eq 12's
    penetration margin and the retract height of a refusal are the touch-first strategy's
    (:class:`~ffmpc_core.impact.touch_first.TouchFirstConfig`), shared.

    Attributes:
        surface_known: the approach is given the object's surface (False: its position is
            unknown, the paper's premise: the impact may come at the next step, the approach
            never exceeds the eq 14 bound).
        surface_tolerance: how far (m, along −d) above the expected surface the object may
            begin.
        surface_offset: where the approach expects the surface, m along −d from the object's
            true top face (0: where it is; > 0: expected above it). The true surface must lie
            within ``surface_tolerance`` above the expected one for the strike to be safe.
        braking_fraction: fraction of the contact-space deceleration bound (eq 10–11 at zero
            force; the smallest met so far on the approach: it changes with the configuration)
            the approach plans to brake with before the band.
        settle_time: s at the eq 14 bound before the band: the braking ends ``settle_time ·
            ż_imp`` above it, so that the tracking lag of the deceleration (measured 0.016 m/s
            at 1.2 m/s² on the study's path) has decayed when a contact becomes possible.
        max_decision_time: s after the contact: decide from the learner's estimate as it is
            (wide interval) if it is not confident by then.
        remembered_stiffness, remembered_damping: the interval (N/m; N·s/m) a previous run
            learned on this object, the knowledge before contact (None: none, both or neither).
    """

    surface_known: bool = param(True, "", None, "the approach is given the dice's surface")
    surface_tolerance: float = param(0.02, "m", (0.0, 10.0), "contact possible this far above it")
    surface_offset: float = param(
        0.0, "m", (-1.0, 1.0), "expected surface above the dice's top face"
    )
    braking_fraction: float = param(
        0.8, "", (1e-6, 1.0), "of the deceleration bound, before the band"
    )
    settle_time: float = param(0.05, "s", (0.0, 10.0), "at the eq 14 bound before the band")
    max_decision_time: float = param(0.5, "s", (1e-3, 60.0), "decide by then after the contact")
    remembered_stiffness: tuple[float, float] | None = param(
        None, "N/m", (0.0, 1e7), "[lo, hi] a previous run learned"
    )
    remembered_damping: tuple[float, float] | None = param(
        None, "N·s/m", (0.0, 1e5), "[lo, hi] a previous run learned"
    )

    def __post_init__(self) -> None:
        tol = self.surface_tolerance
        if not (np.isfinite(tol) and tol >= 0.0):
            raise ConfigError(f"StrikeFirstConfig.surface_tolerance must be ≥ 0 (m), got {tol}")
        if not np.isfinite(self.surface_offset):
            raise ConfigError("StrikeFirstConfig.surface_offset must be finite (m)")
        if not 0.0 < self.braking_fraction <= 1.0:
            raise ConfigError("StrikeFirstConfig.braking_fraction must be in (0, 1]")
        if not (np.isfinite(self.settle_time) and self.settle_time >= 0):
            raise ConfigError("StrikeFirstConfig.settle_time must be ≥ 0 (s)")
        if not (np.isfinite(self.max_decision_time) and self.max_decision_time > 0):
            raise ConfigError("StrikeFirstConfig.max_decision_time must be positive (s)")
        given = (self.remembered_stiffness is None, self.remembered_damping is None)
        if given[0] != given[1]:
            raise ConfigError("remembered_stiffness and remembered_damping: both or neither")
        for name in ("remembered_stiffness", "remembered_damping"):
            value = getattr(self, name)
            if value is None:
                continue
            lo, hi = (float(x) for x in value)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo <= hi):
                raise ConfigError(
                    f"StrikeFirstConfig.{name} must be [lower, upper], 0 ≤ lower ≤ upper"
                )
        if self.remembered_stiffness is not None and self.remembered_stiffness[0] <= 0.0:
            raise ConfigError("StrikeFirstConfig.remembered_stiffness must be positive (N/m)")


def remembered_interval(
    config: StrikeFirstConfig, max_penetration: float
) -> MaterialInterval | None:
    """The knowledge a previous run left (:class:`MaterialInterval`, source ``remembered``,
    nominal = the middle of each range; z̄ m), or None."""
    if config.remembered_stiffness is None or config.remembered_damping is None:
        return None
    (a0, a1), (b0, b1) = config.remembered_stiffness, config.remembered_damping
    return MaterialInterval(
        stiffness=0.5 * (a0 + a1),
        damping=0.5 * (b0 + b1),
        stiffness_lower=float(a0),
        stiffness_upper=float(a1),
        damping_lower=float(b0),
        damping_upper=float(b1),
        max_penetration=float(max_penetration),
        source="remembered",
    )


def approach_speed_limit(
    impact_velocity: float, distance: float, deceleration: float, velocity_upper: float
) -> float:
    """The fastest approach speed (m/s along d) from which the tool still reaches the earliest
    possible contact, ``distance`` m ahead (≤ 0: it may be touched at the next step), no faster
    than ``impact_velocity`` (the eq 14 bound, m/s) when braking at ``deceleration`` (m/s², ≥ 0):
    ``min(sqrt(v_imp² + 2 a δ), ż̄)`` with ż̄ = ``velocity_upper`` (eq 9, m/s), and never below
    ``min(v_imp, ż̄)``."""
    v_imp = max(float(impact_velocity), 0.0)
    top = max(float(velocity_upper), 0.0)
    if distance <= 0.0 or deceleration <= 0.0:
        return min(v_imp, top)
    return min(float(np.sqrt(v_imp * v_imp + 2.0 * deceleration * distance)), max(top, v_imp))


class StrikeFirstImpactController(TouchFirstImpactController):
    """Strike, regulate, learn, decide in contact: ``reset()`` / ``step(measurement, t)``.

    Args:
        robot, limits, config, learner: as :class:`TouchFirstImpactController`
            (``config.material`` is the PRIOR, its z̄ the object's bound).
        touch: the shared parameters (plausible range, learner confidence, interval width,
            guard impact force, penetration margin, retract height).
        strike: see :class:`StrikeFirstConfig`.
        surface: the expected surface point (m, world frame) the approach brakes before (None:
            unknown, as ``surface_known`` False).

    Raises:
        InfeasibleTargetError: before any motion, see the module docstring.

    Attributes (besides the touch-first ones; ``touch_time`` stays None): ``admitted`` (the
    target passed the check from the learned interval), ``band_time`` (s: when the approach
    entered the band of possible contact, None before), ``initial_knowledge`` (the interval
    before contact).
    """

    decision_moment = "in contact, after the impact"

    def __init__(
        self,
        robot: RobotModel,
        limits: JointLimits,
        config: ImpactControllerConfig,
        touch: TouchFirstConfig | None = None,
        strike: StrikeFirstConfig | None = None,
        *,
        surface: np.ndarray | None = None,
        learner: RecursiveContactLearner | None = None,
    ) -> None:
        self.strike = strike if strike is not None else StrikeFirstConfig()
        self.surface = None if surface is None else np.asarray(surface, dtype=float).copy()
        if self.surface is not None and self.surface.shape != (3,):
            raise ConfigError("surface must be a 3-vector (m, world frame)")
        super().__init__(robot, limits, config, touch, learner=learner)

    def _check_before_motion(self) -> None:
        """The admissible-target check before the first contact (module docstring)."""
        cfg = self.config
        remembered = remembered_interval(self.strike, cfg.material.max_penetration)
        self.initial_knowledge = remembered if remembered is not None else self.prior_knowledge
        if remembered is not None:
            check_force_target(
                cfg.target_force, remembered, "from the interval a previous run learned"
            )
        else:
            check_force_target(
                cfg.target_force,
                self.prior_knowledge,
                "even the stiffest plausible material cannot hold it",
                worst_case=False,
            )

    def reset(self) -> None:
        """Back to the strike approach with the knowledge before contact."""
        super().reset()
        self.phase = STRIKE
        self.knowledge = self.initial_knowledge
        self.admitted = False
        self.band_time: float | None = None
        self._decided = False
        self._last_limit = 0.0  # m/s
        self._deceleration = float("inf")  # m/s², the smallest bound met on the approach

    # ------------------------------------------------------------------ what the task sees
    def handover_allowed(self) -> bool:
        """Whether the regulation may be handed over to the force-feedback MPC: only once the
        target was admitted from the learned interval (the MPC does not know z̄)."""
        return self.phase == CONTACT and self.admitted

    def band_distance(self, position: np.ndarray) -> float:
        """How far along d (m) the contact-frame point ``position`` (m, world) is from the
        earliest possible contact (``surface_tolerance`` above the expected surface); −inf
        without a known surface (the contact may come at the next step)."""
        tol = self.strike.surface_tolerance
        if self.surface is None or not self.strike.surface_known:
            return -np.inf
        d = self.config.direction
        expected = self.surface - self.strike.surface_offset * d
        return float(d @ (expected - np.asarray(position, dtype=float))) - tol

    def impact_force_estimate(
        self, speed: float, dt: float, force: float = 0.0, position: np.ndarray | None = None
    ) -> float:
        """As :meth:`TouchFirstImpactController.impact_force_estimate`, and 0 while the tool at
        ``position`` (the contact frame, m, world; None: unknown) cannot reach the band of
        possible contact within the next step at ``speed`` (m/s, doubled for margin)."""
        if (
            self.phase == STRIKE
            and position is not None
            and self.band_distance(position) > 2.0 * max(speed, 0.0) * dt
        ):
            return 0.0
        return super().impact_force_estimate(speed, dt, force, position)

    # ------------------------------------------------------------------ the cycle
    def step(self, measurement: ImpactMeasurement, t: float) -> CartesianCommand:
        """One control cycle at time ``t`` (s)."""
        q, v, dt, p, R, pdot, along, speed, force = self._cycle_state(measurement, t)
        cfg = self.config
        surface = fed_surface(self.learning_gate(), p, force, cfg.contact_threshold)
        if self.phase == STRIKE:
            if force <= 0.0 or self._free_position is None:
                self._free_position = p.copy()
            if force >= cfg.contact_threshold:
                self.phase = CONTACT
                self.contact_time, self.contact_velocity = t, speed
                self._contact_position = self._free_position.copy()
                hold, _ = self._hold_pose()
                self._touch_surface = float(cfg.direction @ (self._free_position - hold))
                self._regulation_limit = self._touch_surface + cfg.admittance.max_depth(
                    cfg.material.max_penetration
                )
                self._x_ref = along
                self._v_ref = speed
        if self.phase == CONTACT:
            cmd = self._regulate(p, speed, force, dt, cfg.target_force, CONTACT, surface)
            if not self._decided and self._decision_due(t):
                self._decide_in_contact(q, v, along, t)
            return cmd
        if self.phase == REFUSED:
            return self._retract_step(force, t)
        return self._strike_step(q, v, p, along, force, dt, t)

    def _decision_due(self, t: float) -> bool:
        assert self.contact_time is not None  # set with the contact
        if t - self.contact_time >= self.strike.max_decision_time:
            return True
        return self.learner_confident() is not None

    def _decide_in_contact(self, q: np.ndarray, v: np.ndarray, along: float, t: float) -> None:
        """Step 3 of the module docstring: the learned interval, the target check; a refusal
        starts the retract (the touch-first decision's, from the contact's surface)."""
        self._decided = True
        self._decide(q, v, along, t)
        if self.phase == REFUSED:
            return
        self.admitted = True
        self.phase = CONTACT  # no retract: the regulation goes on
        self._retract = None

    def _strike_step(
        self,
        q: np.ndarray,
        v: np.ndarray,
        p: np.ndarray,
        along: float,
        force: float,
        dt: float,
        t: float,
    ) -> CartesianCommand:
        """Sec. IV-C with eq 14 over the corners of the knowledge, and the speed limit of the
        known surface outside the band of possible contact (module docstring, step 1)."""
        cfg = self.config
        last = self._last_plan
        if last is not None and t - last[0] < cfg.replan_period - 1e-9:
            _, bound, acc_lo, acc_hi, plan = last
            limit = self._last_limit
        else:
            plan = None
            try:
                bounds = self.mapper.update(q, v)
                robust = self.robust.max_pre_impact_velocity(bounds, self.knowledge)
                self.last_robust_plan = robust
                plan = robust.plan
                bound = max(robust.pre_impact_velocity, 0.0)
                acc_lo, acc_hi = bounds.acceleration_range(0.0)
                # the smallest deceleration bound met on this approach (it changes with the
                # configuration: 2.5–7 m/s² on the study's path, 3.5 at the dice)
                self._deceleration = min(self._deceleration, max(-acc_lo, 0.0))
                sc = self.strike
                limit = approach_speed_limit(
                    bound,
                    self.band_distance(p) - bound * sc.settle_time,
                    sc.braking_fraction * self._deceleration,
                    bounds.velocity_upper,
                )
            except SolverError:
                self.solver_failures += 1  # no certified bound: command rest
                bound, acc_lo, acc_hi, limit = 0.0, 0.0, 0.0, 0.0
            self._last_plan = (t, bound, acc_lo, acc_hi, plan)
            self._last_limit = limit
        if self.band_time is None and self.band_distance(p) <= 0.0:
            self.band_time = t
        cmd = self._approach_command(along, force, dt, limit, acc_lo, acc_hi, plan)
        return replace(cmd, phase=self.phase, pre_impact_velocity=bound)
