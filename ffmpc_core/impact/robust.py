"""Planning under model error: an interval of materials instead of one (Dehio & Kheddar 2020,
eq 3–8 and 12–14 with an uncertain ``E = [α, β]``, eq 15–21 for the interval).

The paper plans eq 14 with one material ``E = [α, β]`` (eq 3), which must come from the learner
(Sec. V) "unless precise knowledge is a priori available". Before the robot has touched an
object there is no such knowledge: a prior (e.g. a data sheet) can be off by a factor of two or
more, and the eq 14 bound computed from it is then not safe — a softer material than the prior
lets the end-effector past z̄ (eq 12), a stiffer one produces forces outside the eq 11 polytope
the plan respected.

What is known is therefore carried as an **interval** ``[α̲, ᾱ] × [β̲, β̄]``
(:class:`MaterialInterval`):

* before any contact, the *plausible range* around the prior (factors of the prior's α and β,
  :meth:`MaterialInterval.from_prior`);
* after contact data, the learner's **confidence interval**
  (:meth:`MaterialInterval.from_estimate`):
  ``α̂ ± max(k σ_α, ρ_α |α̂|)`` and likewise for β, with σ the standard errors of the RLS
  estimate (eq 21 and the confidence measure of :mod:`.learner`) and ρ a relative floor for what
  the noise model does not see (a biased deformation origin, the simulator's one-step lag).

How the margin enters the equations. Every material in the interval defines its own eq 3 ``E``,
eq 5 ``A_c``, eq 7 ``A_d, B_d`` and eq 8 ``C, D``, hence its own eq 12 constraint set (the
penetration bound z ≤ z̄ through eq 6 and the force–acceleration polytope ``P [z̈; E s] ≤ p``
through eq 8 and eq 3). :class:`RobustImpactPlanner` solves eq 14 once per **corner** of the
interval and keeps the smallest ``ż_imp``: the impact velocity is then one for which a safe
penetration (z ≤ z̄, forces and accelerations inside eq 11, at rest at the end) exists for
every corner material. It is a scenario robustification, not a single open-loop input sequence
that fits all materials: after contact the controller brakes against the force it measures (the
paper's admittance step), i.e. against the real material. That the corners are the worst cases
is the monotonicity of eq 14's bound in α and β over the boxes we use (softer → more
penetration, stiffer → more force); ``tests/faults`` checks it on a grid inside the plausible
range rather than assuming it.

The force target needs a steady penetration ``z_ss = f_des / α`` (eq 3 at rest). With the
interval's worst case ``α̲`` it must not exceed z̄: :func:`check_force_target` raises
:class:`~ffmpc_core.errors.InfeasibleTargetError` with the numbers otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ffmpc_core.errors import ConfigError, InfeasibleTargetError, InputError
from ffmpc_core.impact.deformation import SoftMaterial, deformation_dynamics
from ffmpc_core.impact.learner import ContactEstimate
from ffmpc_core.impact.limits import ContactSpaceBounds
from ffmpc_core.impact.planner import ImpactPlanner, PenetrationPlan, PlannerConfig

__all__ = [
    "MaterialInterval",
    "admits_target",
    "RobustPlan",
    "RobustImpactPlanner",
    "check_force_target",
    "steady_penetration",
]


def _factors(value: tuple[float, float], name: str) -> tuple[float, float]:
    lo, hi = (float(x) for x in value)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 < lo <= 1.0 <= hi):
        raise ConfigError(f"{name} must be (lower ≤ 1 ≤ upper), both positive, got {value}")
    return lo, hi


@dataclass(frozen=True)
class MaterialInterval:
    """What is known of the material: ``α ∈ [α̲, ᾱ]`` (N/m), ``β ∈ [β̲, β̄]`` (N·s/m), and the
    nominal values (N/m, N·s/m) inside the box, plus the penetration bound z̄ (m, eq 12).

    Attributes:
        stiffness, damping: the nominal material (the prior, or the learner's estimate).
        stiffness_lower, stiffness_upper: α̲ > 0, ᾱ.
        damping_lower, damping_upper: β̲ ≥ 0, β̄.
        max_penetration: z̄, m.
        source: ``"prior"`` or ``"learned"`` (for reports).
    """

    stiffness: float
    damping: float
    stiffness_lower: float
    stiffness_upper: float
    damping_lower: float
    damping_upper: float
    max_penetration: float
    source: str = "prior"

    def __post_init__(self) -> None:
        values = (
            self.stiffness,
            self.damping,
            self.stiffness_lower,
            self.stiffness_upper,
            self.damping_lower,
            self.damping_upper,
            self.max_penetration,
        )
        if not all(np.isfinite(v) for v in values):
            raise ConfigError(f"material interval must be finite, got {values}")
        if not 0.0 < self.stiffness_lower <= self.stiffness <= self.stiffness_upper:
            raise ConfigError(
                f"stiffness interval needs 0 < {self.stiffness_lower} ≤ {self.stiffness} ≤ "
                f"{self.stiffness_upper} (N/m)"
            )
        if not 0.0 <= self.damping_lower <= self.damping <= self.damping_upper:
            raise ConfigError(
                f"damping interval needs 0 ≤ {self.damping_lower} ≤ {self.damping} ≤ "
                f"{self.damping_upper} (N·s/m)"
            )
        if self.max_penetration <= 0.0:
            raise ConfigError("max_penetration must be positive (m)")

    @classmethod
    def from_prior(
        cls,
        prior: SoftMaterial,
        stiffness_factors: tuple[float, float] = (0.4, 4.0),
        damping_factors: tuple[float, float] = (0.4, 4.0),
    ) -> MaterialInterval:
        """The plausible range before any contact: ``[lo·α₀, hi·α₀] × [lo·β₀, hi·β₀]``."""
        ka, kb = _factors(stiffness_factors, "stiffness_factors")
        da, db = _factors(damping_factors, "damping_factors")
        return cls(
            stiffness=prior.stiffness,
            damping=prior.damping,
            stiffness_lower=ka * prior.stiffness,
            stiffness_upper=kb * prior.stiffness,
            damping_lower=da * prior.damping,
            damping_upper=db * prior.damping,
            max_penetration=prior.max_penetration,
            source="prior",
        )

    @classmethod
    def from_estimate(
        cls,
        estimate: ContactEstimate,
        max_penetration: float,
        sigmas: float = 3.0,
        stiffness_floor: float = 0.1,
        damping_floor: float = 0.25,
    ) -> MaterialInterval:
        """The learner's confidence interval: ``α̂ ± max(sigmas·σ_α, stiffness_floor·α̂)``,
        ``β̂ ± max(sigmas·σ_β, damping_floor·β̂)`` (the lower ends clipped to 5 % of the estimate
        and 0). Raises :class:`InputError` if the estimate is not usable (α̂ ≤ 0, NaN σ)."""
        a, b = float(estimate.stiffness), float(estimate.damping)
        sa, sb = float(estimate.stiffness_std), float(estimate.damping_std)
        if not (np.isfinite(a) and np.isfinite(b) and np.isfinite(sa) and np.isfinite(sb)):
            raise InputError(f"learner estimate not usable: α̂={a}, β̂={b}, σ=({sa}, {sb})")
        if a <= 0.0:
            raise InputError(f"learner estimate not usable: stiffness {a} N/m ≤ 0")
        if not (sigmas >= 0 and stiffness_floor >= 0 and damping_floor >= 0):
            raise ConfigError("sigmas and floors must be ≥ 0")
        b = max(b, 0.0)
        wa = max(sigmas * sa, stiffness_floor * a)
        wb = max(sigmas * sb, damping_floor * b)
        return cls(
            stiffness=a,
            damping=b,
            stiffness_lower=max(a - wa, 0.05 * a),
            stiffness_upper=a + wa,
            damping_lower=max(b - wb, 0.0),
            damping_upper=b + wb,
            max_penetration=float(max_penetration),
            source="learned",
        )

    def corners(self) -> tuple[SoftMaterial, ...]:
        """The four corner materials (α̲β̲, α̲β̄, ᾱβ̲, ᾱβ̄); duplicates removed."""
        out: list[SoftMaterial] = []
        for a in (self.stiffness_lower, self.stiffness_upper):
            for b in (self.damping_lower, self.damping_upper):
                m = SoftMaterial(a, b, self.max_penetration)
                if m not in out:
                    out.append(m)
        return tuple(out)

    def contains(self, stiffness: float, damping: float) -> bool:
        """Whether (α N/m, β N·s/m) lies in the box."""
        return bool(
            self.stiffness_lower <= stiffness <= self.stiffness_upper
            and self.damping_lower <= damping <= self.damping_upper
        )

    def describe(self) -> str:
        """One line: the box with its units."""
        return (
            f"{self.source} stiffness [{self.stiffness_lower:.0f}, "
            f"{self.stiffness_upper:.0f}] N/m, "
            f"damping [{self.damping_lower:.1f}, {self.damping_upper:.1f}] N·s/m"
        )


def steady_penetration(target_force: float, stiffness: float) -> float:
    """Eq 3 at rest (ż = 0): the deformation ``z = f / α`` (m) that holds ``f`` (N)."""
    return float(target_force) / float(stiffness)


def check_force_target(
    target_force: float, knowledge: MaterialInterval, when: str = "", worst_case: bool = True
) -> float:
    """Refuse a force target the material may not hold within z̄.

    The worst case of the current knowledge is the softest material, ``α̲``: the steady
    penetration ``f_des / α̲`` (m) must not exceed z̄. With ``worst_case=False`` the stiffest
    ``ᾱ`` is used instead: the target is refused only if *no* material of the interval can hold
    it. Returns the penetration; raises :class:`InfeasibleTargetError` (with the target, the
    stiffness used, the penetration and z̄) otherwise. ``when`` is added to the message.
    """
    f = float(target_force)
    if not (np.isfinite(f) and f > 0):
        raise ConfigError(f"target force must be positive and finite, got {f} N")
    stiffness = knowledge.stiffness_lower if worst_case else knowledge.stiffness_upper
    which = "softest" if worst_case else "stiffest"
    z = steady_penetration(f, stiffness)
    if z > knowledge.max_penetration:
        suffix = f" ({when})" if when else ""
        raise InfeasibleTargetError(
            f"force {f:g} N needs a steady penetration of {1e3 * z:.1f} mm = {f:g} N / "
            f"{stiffness:.0f} N/m with the {which} material still possible "
            f"({knowledge.describe()}), above the bound z̄ = "
            f"{1e3 * knowledge.max_penetration:.1f} mm{suffix}; refused before the motion "
            "that needs it: "
            f"ask for ≤ {stiffness * knowledge.max_penetration:.1f} N or allow a deeper "
            "penetration"
        )
    return z


def admits_target(
    estimate: ContactEstimate,
    target_force: float,
    max_penetration: float,
    sigmas: float = 3.0,
    stiffness_floor: float = 0.1,
    damping_floor: float = 0.25,
) -> bool:
    """Whether the learner's confidence interval (:meth:`MaterialInterval.from_estimate` with
    these widths) admits ``target_force`` (N): its softest material holds it within z̄
    (``max_penetration``, m). False for an unusable estimate."""
    try:
        interval = MaterialInterval.from_estimate(
            estimate, max_penetration, sigmas, stiffness_floor, damping_floor
        )
        check_force_target(target_force, interval)
    except (InputError, InfeasibleTargetError):
        return False
    return True


@dataclass(frozen=True)
class RobustPlan:
    """Eq 14 over the corners of a material interval.

    Attributes:
        pre_impact_velocity: the smallest corner bound, m/s (≥ 0 is not enforced here).
        plan: the binding corner's eq 14 plan.
        material: the binding corner.
        corner_velocities: each corner's bound, m/s, in :meth:`MaterialInterval.corners` order.
    """

    pre_impact_velocity: float
    plan: PenetrationPlan
    material: SoftMaterial
    corner_velocities: tuple[float, ...]


class RobustImpactPlanner:
    """Eq 14 for every corner of a :class:`MaterialInterval`; the bound is the minimum.

    One :class:`ImpactPlanner` per corner, so that each keeps its own warm start (the corners'
    problems differ; sharing one solver would restart it every call). A corner whose solve
    fails raises :class:`~ffmpc_core.errors.SolverError` (the caller commands rest).

    Args:
        config: eq 12–14 parameters.
        penetration_margin: m, taken off z̄ in eq 12's ``z_i ≤ z̄`` (0 ≤ margin < z̄). Eq 12
            lets the robot brake from the very first step in contact; a real controller
            declares the contact at a force threshold and its braking starts a few steps later
            (the admittance reference filter, the tracking law), and z is counted from the last
            force-free sample. With the learned model (no hidden margin from a stiffer-than-
            planned object) we measured the tool 1.9 mm past z̄ after a 0.475 m/s strike.
    """

    def __init__(
        self, config: PlannerConfig | None = None, penetration_margin: float = 0.0
    ) -> None:
        self.config = config if config is not None else PlannerConfig()
        margin = float(penetration_margin)
        if not (np.isfinite(margin) and margin >= 0.0):
            raise ConfigError(f"penetration_margin must be ≥ 0 (m), got {margin}")
        self.penetration_margin = margin
        self._planners: list[ImpactPlanner] = [ImpactPlanner(self.config) for _ in range(4)]

    def max_pre_impact_velocity(
        self, bounds: ContactSpaceBounds, knowledge: MaterialInterval
    ) -> RobustPlan:
        """The largest ż_imp (m/s) that is eq 14-feasible for all corners of ``knowledge``
        (with z̄ − ``penetration_margin``)."""
        zbar = knowledge.max_penetration - self.penetration_margin
        if zbar <= 0.0:
            raise ConfigError(
                f"penetration_margin {self.penetration_margin} m leaves no penetration "
                f"(z̄ = {knowledge.max_penetration} m)"
            )
        best: tuple[float, PenetrationPlan, SoftMaterial] | None = None
        velocities = []
        for planner, corner in zip(self._planners, knowledge.corners(), strict=False):
            material = replace(corner, max_penetration=zbar)
            dyn = deformation_dynamics(
                material.stiffness, material.damping, bounds.effective_mass, self.config.dt
            )
            plan = planner.max_pre_impact_velocity(dyn, bounds, material)
            velocities.append(plan.pre_impact_velocity)
            if best is None or plan.pre_impact_velocity < best[0]:
                best = (plan.pre_impact_velocity, plan, material)
        assert best is not None
        return RobustPlan(
            pre_impact_velocity=float(best[0]),
            plan=best[1],
            material=best[2],
            corner_velocities=tuple(float(v) for v in velocities),
        )
