"""Learn before you strike hard: an exploratory touch, then the maximal strike from the learned
model (Dehio & Kheddar 2020, Sec. IV-C and V, made robust to a wrong prior).

The paper's controller (:class:`~ffmpc_core.impact.control.ImpactController`) plans eq 14 with
one material. With only a prior (e.g. 2400 N/m, 15 N·s/m from a data sheet) that is not the
truth, the first strike is planned for the wrong material: a softer object takes the end-effector
past z̄ (eq 12), a stiffer one produces forces beyond the eq 11 polytope, and a force target that
the real material cannot hold within z̄ is pressed for anyway. The paper itself learns the
material from exploratory penetrations *before* the impact experiments (Sec. VI, "Learning
Procedure": a sinusoidal penetration and five impacts at 0.15–0.35 m/s). This controller does the
same online, in one run:

1. **touch** — approach at the eq 14 bound that is safe for every material of the *plausible
   range* around the prior (:meth:`MaterialInterval.from_prior`, factors 0.4–4 by default):
   :class:`~ffmpc_core.impact.robust.RobustImpactPlanner` solves eq 14 for each corner of the
   range and keeps the smallest ż_imp. The margin enters eq 12 through each corner's eq 3 ``E``
   and eq 5–8 ``A_d, B_d, C, D``: the penetration bound z ≤ z̄ (binding for the soft corners) and
   the force–acceleration polytope ``P [z̈; E s] ≤ p`` of eq 11 (binding for the stiff corners).
2. **touch contact** — at the contact threshold, brake and regulate a small ``touch_force``
   (admittance, as after the paper's impacts) while the recursive learner (eq 19–21) collects
   ``(z, ż, f)``, z from the last force-free sample. The impact excites the damping, the pressing
   the stiffness. Leave once the learner is confident (``learner_min_samples``, relative
   standard errors ≤ ``learner_max_relative_std``) and ``touch_dwell`` has passed, or at
   ``max_touch_time`` with whatever it has.
3. **decide** — the knowledge becomes the learner's confidence interval
   (:meth:`MaterialInterval.from_estimate`: ±max(3σ, 10 %) on α, ±max(3σ, 25 %) on β). The force
   target is checked against its worst case, the softest α̲: ``f_des / α̲ > z̄`` →
   :class:`~ffmpc_core.errors.InfeasibleTargetError` is kept in :attr:`refusal`, the robot
   retracts and holds (phase ``refused``); it never strikes.
4. **retract** — a smooth move (cosine profile at ``retract_acceleration_fraction`` of the
   contact-space acceleration bound) to ``retract_height`` above the touched surface.
5. **strike** — the maximal approach of Sec. IV-C, eq 14 over the corners of the *learned*
   interval (narrow: the bound is close to the one of the true material), then regulation of the
   target force (admittance) and online learning as in the paper.

Before any motion (the constructor) two checks raise :class:`InfeasibleTargetError`: the
touch force must be holdable by the softest plausible material (``touch_force / α̲ ≤ z̄``), and
the target must be holdable by at least the stiffest one (``f_des / ᾱ ≤ z̄``): a target that no
plausible material can hold is refused before moving, one that only some can hold is decided
after the touch, when the knowledge is the learner's interval.

Frames, units and signs as in :mod:`ffmpc_core.impact.control` (d unit, world frame; z, ż along
d, m and m/s; f the pressing force, N).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError, InfeasibleTargetError, InputError, SolverError
from ffmpc_core.impact.control import (
    CartesianCommand,
    ImpactController,
    ImpactControllerConfig,
    ImpactMeasurement,
)
from ffmpc_core.impact.deformation import measured_deformation, one_step_impact_force
from ffmpc_core.impact.learner import ContactEstimate, RecursiveContactLearner
from ffmpc_core.impact.limits import JointLimits
from ffmpc_core.impact.robust import (
    MaterialInterval,
    RobustImpactPlanner,
    RobustPlan,
    check_force_target,
)
from ffmpc_core.robots import RobotModel

__all__ = [
    "CONTACT",
    "REFUSED",
    "RETRACT",
    "STRIKE",
    "TOUCH",
    "TOUCH_CONTACT",
    "LearningGate",
    "TouchCycleInputs",
    "TouchFirstConfig",
    "TouchFirstImpactController",
    "fed_surface",
]

TOUCH = "touch"
TOUCH_CONTACT = "touch_contact"
RETRACT = "retract"
STRIKE = "strike"
CONTACT = "contact"
REFUSED = "refused"
#: Phases in which the tool is moving towards the object and may hit it at the next step.
APPROACH_PHASES = (TOUCH, STRIKE)
#: Phases in which the learner is fed (eq 19–20), z from the surface latched at their start.
LEARNING_PHASES = (TOUCH_CONTACT, CONTACT)


@dataclass(frozen=True)
class LearningGate:
    """What decides whether the next cycle's sample is fed to the learner (eq 19–20), after a
    :meth:`TouchFirstImpactController.step`: the controller's ``phase`` and the surface point
    (m, world frame): in an approach phase the last force-free sample (None before the
    first sample of the approach), in a learning phase the surface of the current contact
    (None in the other phases). ``learn``: the controller learns online at all."""

    phase: str
    surface: np.ndarray | None
    learn: bool = True


def fed_surface(
    gate: LearningGate, position: np.ndarray, force: float, contact_threshold: float
) -> np.ndarray | None:
    """The surface point (m, world) the sample of a cycle is fed to the learner against (z =
    dᵀ(p − surface)), or None when that cycle feeds nothing — THE feeding rule of the
    touch-first scheme, used by :meth:`TouchFirstImpactController.step` and by the impact
    graph's contact learner node (from the planner's gate of the previous cycle).

    ``position``: the cycle's contact-frame position p (m, world); ``force``: its pressing
    force (N). An approach phase feeds the cycle the contact begins (force ≥
    ``contact_threshold``), against the last force-free sample (p itself without one); a
    learning phase feeds every cycle with force > 0; the others feed nothing."""
    if not gate.learn:
        return None
    if gate.phase in APPROACH_PHASES:
        if force < contact_threshold:
            return None
        return np.asarray(position, dtype=float).copy() if gate.surface is None else gate.surface
    if gate.phase in LEARNING_PHASES and force > 0.0:
        return gate.surface
    return None


@dataclass(frozen=True)
class TouchCycleInputs:
    """What the task controller (:class:`~ffmpc_core.impact.controllers.ImpactTaskController`)
    takes from the touch-first approach before the approach's step of a cycle.

    Attributes:
        strike: the approach is in its strike (a contact declared now is the task's contact;
            the exploratory touch's is not).
        impact_force: the joint-limit guard's impact force along d (N,
            :meth:`TouchFirstImpactController.impact_force_estimate`).
        handover_allowed: the regulation may be handed over to the force-feedback MPC (the
            strike-first strategy: only once the target is admitted from the learned
            interval; touch-first strikes only after that check)."""

    strike: bool
    impact_force: float
    handover_allowed: bool = True


@dataclass(frozen=True)
class TouchFirstConfig:
    """Parameters of the touch-first scheme (see the module docstring).

    Attributes:
        stiffness_factors, damping_factors: the plausible range before any contact, as factors
            of the prior's α and β (lower ≤ 1 ≤ upper).
        touch_force: force regulated during the touch, N.
        touch_dwell: minimal time in contact during the touch, s.
        max_touch_time: the touch ends after this long in contact even if the learner is not
            confident yet (its interval is then wide, the strike slower, or the target refused), s.
        learner_min_samples: samples before the estimate counts as confident.
        learner_max_relative_std: ... and relative standard errors of α̂ and β̂ at most this.
        sigmas: k of the learned interval α̂ ± k σ_α (same for β).
        stiffness_floor, damping_floor: relative half-widths the learned interval has at least
            (what σ does not see: the deformation origin is the last force-free sample, up to
            ż·Δt above the surface; the simulator's contact lags one step).
        retract_height: height above the touched surface the strike starts from, m.
        retract_acceleration_fraction: fraction of the contact-space acceleration bound (eq 10–11
            at the start of the retract, zero force) the retract's cosine profile peaks at.
        impact_force_factor: κ of the joint-limit guard's impact force ``κ (β + α Δt) ż`` (see
            :meth:`TouchFirstImpactController.impact_force_estimate`).
        penetration_margin: m off z̄ in eq 12 for the touch and the strike (the reaction delay
            after the contact threshold, see :class:`RobustImpactPlanner`); the force-target
            check uses the full z̄.
    """

    stiffness_factors: tuple[float, float] = param(
        (0.4, 4.0), "", (1e-3, 1e3), "plausible α range, factors of the prior"
    )
    damping_factors: tuple[float, float] = param(
        (0.4, 4.0), "", (1e-3, 1e3), "plausible β range, factors of the prior"
    )
    touch_force: float = param(15.0, "N", (0.01, 500.0), "force regulated during the touch")
    touch_dwell: float = param(0.15, "s", (0.0, 60.0), "minimal time in contact during the touch")
    max_touch_time: float = param(1.0, "s", (0.0, 60.0), "longest touch")
    learner_min_samples: int = param(50, "", (3, 10**6), "samples before confident")
    learner_max_relative_std: float = param(
        0.05, "", (1e-9, 10.0), "relative std errors at most this"
    )
    sigmas: float = param(3.0, "", (0.0, 100.0), "k of the learned interval α̂ ± k σ")
    stiffness_floor: float = param(
        0.1, "", (0.0, 10.0), "least relative half-width of the α interval"
    )
    damping_floor: float = param(
        0.25, "", (0.0, 10.0), "least relative half-width of the β interval"
    )
    retract_height: float = param(
        0.06, "m", (0.0, 1.0), "height above the surface the strike starts"
    )
    retract_acceleration_fraction: float = param(0.5, "", (0.0, 1.0), "peak of the retract profile")
    impact_force_factor: float = param(1.5, "", (0.0, 100.0), "κ of the guard's impact force")
    penetration_margin: float = param(0.004, "m", (0.0, 0.5), "off z̄ in eq 12 for touch and strike")

    def __post_init__(self) -> None:
        for name in (
            "touch_force",
            "touch_dwell",
            "max_touch_time",
            "learner_max_relative_std",
            "retract_height",
        ):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"TouchFirstConfig.{name} must be positive, got {value}")
        if self.max_touch_time < self.touch_dwell:
            raise ConfigError("max_touch_time must be ≥ touch_dwell")
        n = self.learner_min_samples
        if int(n) != n or n < 3:
            raise ConfigError("learner_min_samples must be an integer ≥ 3")
        for name in ("sigmas", "stiffness_floor", "damping_floor"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ConfigError(f"TouchFirstConfig.{name} must be ≥ 0, got {value}")
        if not (np.isfinite(self.penetration_margin) and self.penetration_margin >= 0.0):
            raise ConfigError("penetration_margin must be ≥ 0 (m)")
        if not (np.isfinite(self.impact_force_factor) and self.impact_force_factor >= 1.0):
            raise ConfigError("impact_force_factor must be ≥ 1")
        if not 0.0 < self.retract_acceleration_fraction <= 1.0:
            raise ConfigError("retract_acceleration_fraction must be in (0, 1]")


class TouchFirstImpactController(ImpactController):
    """Touch, learn, decide, retract, strike: ``reset()`` / ``step(measurement, t)``.

    Args:
        robot, limits: as :class:`ImpactController`.
        config: the controller's configuration; ``config.material`` is the PRIOR (its z̄ is the
            bound of the object), ``config.target_force`` the force after the strike.
        touch: see :class:`TouchFirstConfig`.
        learner: the eq 19–21 learner (default: its own
            :class:`~ffmpc_core.impact.learner.RecursiveContactLearner`). In the impact graph
            the planner node gives one that holds the contact learner node's estimates (the
            node feeds the samples :func:`fed_surface` selects from :meth:`learning_gate`); the
            controller calls ``update`` for each sample it selects and reads the estimate.

    Raises:
        InfeasibleTargetError: before any motion, see the module docstring.

    Attributes (after steps): ``phase``; ``knowledge`` (the current :class:`MaterialInterval`);
    ``touch_time``, ``touch_velocity`` (s, m/s: the exploratory contact); ``contact_time``,
    ``contact_velocity`` (the strike's contact); ``decision_time`` (s); ``learned``
    (the :class:`ContactEstimate` the strike was planned from, or None); ``refusal`` (the
    :class:`InfeasibleTargetError` kept when the target was refused after the touch, or None);
    ``last_robust_plan`` (:class:`RobustPlan` of the last approach cycle).
    """

    #: When the target is checked from the learned interval (in a refusal's message).
    decision_moment = "before the strike"

    def __init__(
        self,
        robot: RobotModel,
        limits: JointLimits,
        config: ImpactControllerConfig,
        touch: TouchFirstConfig | None = None,
        *,
        learner: RecursiveContactLearner | None = None,
    ) -> None:
        self.touch = touch if touch is not None else TouchFirstConfig()
        self.prior_knowledge = MaterialInterval.from_prior(
            config.material, self.touch.stiffness_factors, self.touch.damping_factors
        )
        self.config = config
        self._check_before_motion()
        self.robust = RobustImpactPlanner(config.planner, self.touch.penetration_margin)
        super().__init__(robot, limits, config, learner=learner)

    def _check_before_motion(self) -> None:
        """The checks before any motion (module docstring); InfeasibleTargetError."""
        config = self.config
        if self.touch.touch_force <= config.contact_threshold:
            raise ConfigError("touch_force must be above the contact threshold (N)")
        # The touch must be safe for the softest plausible material ...
        check_force_target(
            self.touch.touch_force, self.prior_knowledge, "the exploratory touch force"
        )
        # ... and the target holdable by at least the stiffest plausible one.
        check_force_target(
            config.target_force,
            self.prior_knowledge,
            "even the stiffest plausible material cannot hold it",
            worst_case=False,
        )

    def reset(self) -> None:
        """Back to the touch approach with the prior's plausible range as the knowledge."""
        super().reset()
        self.phase = TOUCH
        self.knowledge = self.prior_knowledge
        self.touch_time: float | None = None
        self.touch_velocity: float | None = None
        self.decision_time: float | None = None
        self.learned: ContactEstimate | None = None
        self.refusal: InfeasibleTargetError | None = None
        self.last_robust_plan: RobustPlan | None = None
        self._free_position: np.ndarray | None = None  # last force-free sample, world m
        self._touch_surface: float | None = None  # along d from the hold pose, m
        self._retract: tuple[float, float, float, float] | None = None  # t0, x0, x1, T

    # ------------------------------------------------------------------ helpers
    def learning_gate(self) -> LearningGate:
        """The gate of the next cycle's feeding rule (:func:`fed_surface`)."""
        if self.phase in APPROACH_PHASES:
            surface = self._free_position
        elif self.phase in LEARNING_PHASES:
            surface = self._contact_position
        else:
            surface = None
        return LearningGate(
            self.phase, None if surface is None else surface.copy(), self.config.learn_online
        )

    def cycle_inputs(
        self, speed: float, dt: float, force: float, position: np.ndarray | None = None
    ) -> TouchCycleInputs:
        """The task controller's inputs of this cycle, before :meth:`step`: speed along d
        (m/s), control period (s), pressing force (N) and contact-frame position (m, world)
        of the cycle's measurement."""
        return TouchCycleInputs(
            strike=self.phase == STRIKE,
            impact_force=self.impact_force_estimate(speed, dt, force, position),
            handover_allowed=self.handover_allowed(),
        )

    def handover_allowed(self) -> bool:
        """Whether the regulation may be handed over to the force-feedback MPC: always (the
        strike comes only after the target was admitted from the learned interval)."""
        return True

    def learner_confident(self) -> ContactEstimate | None:
        """The learner's estimate if it meets the confidence of :class:`TouchFirstConfig`."""
        tc = self.touch
        return self.learner.confident_estimate(tc.learner_min_samples, tc.learner_max_relative_std)

    def impact_force_estimate(
        self, speed: float, dt: float, force: float = 0.0, position: np.ndarray | None = None
    ) -> float:
        """Force (N) of an impact during the next step at ``speed`` (m/s along d), for the
        joint-limit guard: ``κ (β + α Δt) ż`` with the current knowledge's NOMINAL material (the
        prior during the touch, the learned one for the strike); 0 when not approaching.

        Once the measured pressing ``force`` (N) has reached the contact threshold while still
        approaching (the step the contact is detected, before :meth:`step` switches to the
        regulation), the impact is no longer hypothetical: its damping force arrives during
        this step, and it is bounded by the knowledge's WORST case ``(β̄ + ᾱ Δt) ż`` (the force
        already measured is compensated by the guard separately). Measured: starting 0.2 m
        above a 7200 N/m, 45 N·s/m dice, the touch's force rose from 3.9 N to 17.5 N in that
        step, the nominal prior reserved 8.6 N, and the regulation's braking took joint 2 to
        1.06× its acceleration limit; reserving the worst case for that one step keeps it.
        ``(β + α Δt) ż`` is eq 3 after one step in contact; in PyBullet the first contact force
        was measured 1.35–1.46× that (the contact starts anywhere inside the step before it is
        detected), hence κ = ``impact_force_factor`` (1.5).

        Not the stiffest corner: the guard keeps ``|q̈ + Δq̈_impact| ≤ q̈_max`` per joint, and
        with the corner's force (4× the prior) the predicted Δq̈ of the light wrist joints
        exceeds q̈_max, which turns the box into a forced acceleration towards the object (we
        measured the strike overrunning the eq 14 bound by 0.1 m/s). The corners already
        bound the impact in eq 14 (``f_1 = β ż_imp`` inside the eq 11 polytope for each).
        ``position`` (the contact frame, m, world) is not used here (see the strike-first
        strategy)."""
        if self.phase not in APPROACH_PHASES:
            return 0.0
        k = self.knowledge
        if force >= self.config.contact_threshold:
            return one_step_impact_force(k.stiffness_upper, k.damping_upper, speed, dt)
        kappa = self.touch.impact_force_factor
        return one_step_impact_force(k.stiffness, k.damping, speed, dt, factor=kappa)

    def learn(self, position: np.ndarray, speed: float, force: float) -> None:
        """Eq 19–20 for a sample taken while another controller acts (e.g. the force-feedback
        MPC after the hand-over): contact-frame position (m, world), speed along d (m/s) and
        pressing force (N); z from the last force-free sample before this contact. Ignored
        outside the strike's contact phase or without force."""
        if self.phase != CONTACT:
            return
        p = np.asarray(position, dtype=float)
        surface = fed_surface(self.learning_gate(), p, force, self.config.contact_threshold)
        if surface is not None:
            self.learner.update(
                measured_deformation(p, surface, self.config.direction), speed, force
            )

    # ------------------------------------------------------------------ the cycle
    def step(self, measurement: ImpactMeasurement, t: float) -> CartesianCommand:
        """One control cycle at time ``t`` (s)."""
        q, v, dt, p, R, pdot, along, speed, force = self._cycle_state(measurement, t)
        cfg = self.config
        d = cfg.direction
        surface = fed_surface(self.learning_gate(), p, force, cfg.contact_threshold)

        if self.phase in APPROACH_PHASES:
            if force <= 0.0 or self._free_position is None:
                self._free_position = p.copy()
            if force >= cfg.contact_threshold:
                if self.phase == TOUCH:
                    self.phase = TOUCH_CONTACT
                    self.touch_time, self.touch_velocity = t, speed
                    self._touch_surface = float(d @ (self._free_position - self._hold_position))
                else:
                    self.phase = CONTACT
                    self.contact_time, self.contact_velocity = t, speed
                self._contact_position = self._free_position.copy()
                # the regulation never references deeper than z̄ below this surface
                self._regulation_limit = float(
                    d @ (self._free_position - self._hold_position)
                ) + cfg.admittance.max_depth(cfg.material.max_penetration)
                self._x_ref = along
                self._v_ref = speed
        if self.phase == TOUCH_CONTACT:
            cmd = self._regulate(
                p, speed, force, dt, self.touch.touch_force, TOUCH_CONTACT, surface
            )
            if self._touch_done(t):
                self._decide(q, v, along, t)
            return cmd
        if self.phase == CONTACT:
            return self._regulate(p, speed, force, dt, cfg.target_force, CONTACT, surface)
        if self.phase in (RETRACT, REFUSED):
            return self._retract_step(force, t)
        return self._robust_approach_step(q, v, along, force, dt, t)

    def _robust_approach_step(
        self, q: np.ndarray, v: np.ndarray, along: float, force: float, dt: float, t: float
    ) -> CartesianCommand:
        """Sec. IV-C with eq 14 over the corners of the current knowledge."""
        cfg = self.config
        last = self._last_plan
        if last is not None and t - last[0] < cfg.replan_period - 1e-9:
            _, bound, acc_lo, acc_hi, plan = last
        else:
            plan = None
            try:
                bounds = self.mapper.update(q, v)
                robust = self.robust.max_pre_impact_velocity(bounds, self.knowledge)
                self.last_robust_plan = robust
                plan = robust.plan
                bound = max(robust.pre_impact_velocity, 0.0)
                acc_lo, acc_hi = bounds.acceleration_range(0.0)
            except SolverError:
                self.solver_failures += 1  # no certified bound: command rest
                bound, acc_lo, acc_hi = 0.0, 0.0, 0.0
            self._last_plan = (t, bound, acc_lo, acc_hi, plan)
        cmd = self._approach_command(along, force, dt, bound, acc_lo, acc_hi, plan)
        return replace(cmd, phase=self.phase)

    def _regulate(
        self,
        p: np.ndarray,
        speed: float,
        force: float,
        dt: float,
        target: float,
        phase: str,
        surface: np.ndarray | None,
    ) -> CartesianCommand:
        """Admittance towards ``target`` (N) and eq 19–20 learning of this cycle's sample
        against ``surface`` (m, world; :func:`fed_surface`, None: not fed)."""
        if surface is not None:
            self.learner.update(
                measured_deformation(p, surface, self.config.direction), speed, force
            )
        return self._admittance_command(force, target, dt, phase)

    def _touch_done(self, t: float) -> bool:
        assert self.touch_time is not None  # set when the touch began
        in_contact = t - self.touch_time
        if in_contact >= self.touch.max_touch_time:
            return True
        return in_contact >= self.touch.touch_dwell and self.learner_confident() is not None

    def _decide(self, q: np.ndarray, v: np.ndarray, along: float, t: float) -> None:
        """Step 3 of the module docstring, then start the retract."""
        tc = self.touch
        zbar = self.config.material.max_penetration
        self.decision_time = t
        try:
            est = self.learner.estimate()
            self.knowledge = MaterialInterval.from_estimate(
                est, zbar, tc.sigmas, tc.stiffness_floor, tc.damping_floor
            )
            self.learned = est
            self.material = replace(self.material, stiffness=est.stiffness, damping=est.damping)
        except (InputError, ConfigError):
            self.knowledge = self.prior_knowledge  # nothing usable learned: keep the range
        try:
            check_force_target(self.config.target_force, self.knowledge, self.decision_moment)
            self.phase = RETRACT
        except InfeasibleTargetError as exc:
            self.refusal = exc
            self.phase = REFUSED
        assert self._touch_surface is not None  # latched with the touch
        x1 = self._touch_surface - tc.retract_height
        try:
            acc_hi = self.mapper.update(q, v).acceleration_range(0.0)[1]
        except SolverError:
            acc_hi = 0.0
        acc = tc.retract_acceleration_fraction * max(acc_hi, 0.5)
        duration = float(np.pi * np.sqrt(abs(x1 - along) / (2.0 * acc)))
        self._retract = (t, along, x1, max(duration, 1e-3))

    def _retract_step(self, force: float, t: float) -> CartesianCommand:
        """The cosine move of step 4; at its end the strike (or, refused, a hold) starts."""
        assert self._retract is not None  # set by _decide before the RETRACT phase
        t0, x0, x1, T = self._retract
        tau = min(t - t0, T)
        w = np.pi / T
        x = x0 + (x1 - x0) * 0.5 * (1.0 - np.cos(w * tau))
        xd = (x1 - x0) * 0.5 * w * np.sin(w * tau)
        xdd = (x1 - x0) * 0.5 * w * w * np.cos(w * tau) if tau < T else 0.0
        phase = self.phase
        if t - t0 >= T and self.phase == RETRACT:
            self.phase = STRIKE
            self._v_ref = 0.0
            self._last_plan = None
            self._free_position = None
        d = self.config.direction
        hold_position, hold_rotation = self._hold_pose()
        return CartesianCommand(
            phase=phase,
            position=hold_position + x * d,
            velocity=xd * d,
            acceleration=xdd * d,
            rotation=hold_rotation.copy(),
            pre_impact_velocity=float("nan"),
            force=force,
            target_force=self.config.target_force,
        )
