"""The safe-maximal-impact experiment of Dehio & Kheddar 2020 (Sec. VI, Fig. 4) in PyBullet.

Setup (``ffmpc study impact``):

* The Panda (torque-controlled, 1 kHz, the plant of :mod:`sim_bridge.plant`) holds its spherical
  tool pointing down, ``approach_height`` (0.46 m, as in the paper) above the top face of a soft
  dice: a 0.16 m cube whose TRUE contact stiffness and damping are set in PyBullet. The dice is
  FIXED (a static body: Bullet's mass 0; the paper's dice weighs 0.1 kg and rests on a table).
  Fixing it makes the tool–dice contact the only compliance: the spherical tool makes one
  contact point (the dice's 5 cm collision margin keeps it the only one in the study's depth
  range, see :class:`DiceConfig`), so the force is the box's nominal ``k·depth + d·rate``
  (Bullet applies stiffness per contact point; a dice resting on a table would add its 4-point
  support, 4× stiffer, in series, and its own 0.1 kg mode). The values the learner must find
  are then exactly the ones set in PyBullet.
* Material (our choice; the paper's Fig. 3 values are not in our copy of the text): stiffness
  3000 N/m and damping 20 N·s/m — a foam dice that takes 60 N at 2 cm (12.5 % strain) with a
  lightly damped response (damping ratio ≈ 0.08 with the Panda's ≈ 5 kg effective mass). The
  maximal penetration z̄ = 3 cm (the elastic-domain constraint of eq 12) is also set by the
  robot: the Panda hand's underside is 3.4 cm above the tool tip, deeper than that the hand
  would hit the dice.
* The planner (eq 12–14) starts from a PRIOR material, softer than the truth (2400 N/m,
  15 N·s/m, as from a data sheet): the robot has not touched the dice yet. The RLS learner
  (eq 19–21) is fed from the first contact on and its estimate goes to the force-feedback MPC.
* Strategy of the maximal approach (``strategy``). ``touch_first`` (the default):
  :class:`~ffmpc_core.impact.touch_first.TouchFirstImpactController` first touches the dice at
  the eq 14 bound that is safe for every material of the plausible range around the prior
  (0.4–4× its stiffness and damping: eq 14 solved for each corner, the smallest bound kept),
  regulates a 15 N touch while the learner collects data, plans the strike from the learner's
  confidence interval (or refuses a target the softest material of that interval cannot hold
  within z̄), retracts 6 cm above the touched surface and strikes at the eq 14 bound of the
  learned interval. ``prior``: the paper's scheme with the prior taken as the truth (a dice
  softer than the prior then goes past z̄, a stiffer one beyond the planned force).

Runs (approach × regulation). Every controller is an object of
:mod:`ffmpc_core.impact.controllers`; :class:`~ffmpc_core.impact.controllers.
ImpactTaskController` composes them (built by :func:`task_config` from the study's
configuration); this module only runs the plant, logs and summarises:

* approach ``maximal``: :class:`~ffmpc_core.impact.control.ImpactController` (Sec. IV-C): every
  cycle (or every ``replan_period``) map the joint limits to the contact space (eq 9–11), solve
  eq 14 for the maximal safe pre-impact velocity and track it; contact is declared at 2 N.
* approach ``baseline`` (the paper's comparison): the contact location as a static target. A
  critically damped second-order reference (:class:`~ffmpc_core.impact.controllers.
  BaselineApproach`, natural frequency ω, 5 rad/s) towards a point
  ``baseline_target_depth`` (5 mm) below the dice's top face, its acceleration saturated at the
  contact-space acceleration bound of eq 10–11, tracked by the same task-space law. Both
  approaches start at that acceleration bound; the baseline, knowing where the dice is, then
  runs faster in free space than the maximal one, whose speed is capped everywhere by the
  pre-impact bound (the impact may come at any step), and brakes. It arrives with a near-zero
  velocity (the target is a bit inside the dice so that the force does reach the 2 N
  threshold; a target exactly on the surface is approached asymptotically, never detected).
* regulation ``admittance`` (the paper): after contact the admittance force controller of
  :class:`~ffmpc_core.impact.control.AdmittanceForceController` drives the position reference to
  60 N (inside ImpactController for the maximal approach; the same update law,
  :class:`~ffmpc_core.impact.controllers.AdmittanceRegulator`, for the baseline).
* regulation ``ff_mpc`` (beyond the paper,
  :class:`~ffmpc_core.impact.controllers.ForceFeedbackHandover`): the force-feedback MPC
  (:class:`~ffmpc_core.mpc.ModelPredictiveController`, visco-elastic contact in the state) with
  the task "press 60 N where you are" (:class:`~ffmpc_core.tasks.PressTask`). It takes over
  once the impact is absorbed: in contact, when the tool moves into the dice no faster than the
  admittance controller's own speed limit (0.1 m/s; for the baseline that is at the contact).
  Until then the controller of the admittance run brakes as eq 14 planned: the planner's
  certificate (z ≤ z̄) assumes that braking, and an MPC with a force cost handed the full impact
  speed keeps pressing while the force is still below 60 N (we measured 46 mm of penetration
  and the hand hitting the dice with a 15 ms horizon, 34 mm with 200 ms). Its contact stiffness
  and damping are the learner's live estimate (``set_contact_parameters`` every MPC period)
  once the estimate is trustworthy (≥ 20 samples, standard errors ≤ 5 %), the prior before.
  MPC: 10 nodes of 20 ms (a 0.2 s horizon, the time scale of the dice–arm oscillation, ≈ 4 Hz;
  the polishing paper's 5 × 3 ms cannot see an impact through) re-solved every 4 ms; posture
  weight 1 and joint-velocity weight 0.1 (the defaults 0.01 let the redundant arm roll about the
  point contact: the impact scenario leaves ee_rotation at 0). The torque goes through the
  joint-limit guard with only the normal force compensated (the one the MPC models) and the contact
  point's tangential acceleration held at zero: the tool sticks on the foam, and compensating
  the measured friction force would push it sideways until it slips.

Joint limits (eq 1b–1e). Every torque sent goes through
:class:`~ffmpc_core.impact.task_space.JointLimitGuard`: a QP that keeps the joint accelerations
within the limits (also against an impact in the next step before contact), the velocities
within the limits over one step and the torques within theirs. The planner and the guard use the
same "control limits" (``limit_margin`` × the data-sheet acceleration and velocity limits), the
margin absorbing what a torque sent at the start of a step cannot know (the change of the
contact force during the step). Before contact the guard also bounds q̈ + Δq̈_impact, with
Δq̈ = M⁻¹ J_linᵀ F_imp the joint acceleration the impact force F_imp ≈ (β + α Δt) ż (prior
material, current speed) would add during the step in which the tool touches. The task-space
law weighs the five directions other than the motion 100× the motion direction (eq 2: ẋ_B = 0):
when a limit is active, the motion direction gives way (a tangential acceleration would change
the sticking friction force unannounced). Violations are counted against the full data-sheet
limits: q̈ is the finite difference of consecutive simulated joint velocities,
``(q̇[k+1] − q̇[k]) / Δt``, the acceleration actually realised over step k.

Signs: ``d = (0, 0, −1)``; the force ``f`` is the world-z component of the force the dice exerts
on the tool (N, > 0 when pressing), which is also the force-feedback MPC's λ.
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pinocchio as pin

from ffmpc_core.config import CostWeights
from ffmpc_core.errors import ConfigError, FfmpcError, InputError
from ffmpc_core.impact.control import AdmittanceForceController, ImpactControllerConfig
from ffmpc_core.impact.controllers import (
    APPROACHES,
    REGULATIONS,
    BaselineApproachConfig,
    ContactMeasurement,
    HandoverConfig,
    ImpactTaskCommand,
    ImpactTaskConfig,
    ImpactTaskController,
    contact_measurement,
)
from ffmpc_core.impact.deformation import SoftMaterial
from ffmpc_core.impact.limits import JointLimits, joint_limits
from ffmpc_core.impact.planner import PlannerConfig
from ffmpc_core.impact.robust import MaterialInterval, check_force_target
from ffmpc_core.impact.task_space import (
    JointLimitGuardConfig,
)
from ffmpc_core.impact.touch_first import (
    TouchFirstConfig,
)
from ffmpc_core.robots import RobotModel, load_robot
from ffmpc_core.runner import LockstepClock, run_scenario
from ffmpc_core.scenario import ConfigSchema, FieldDecl, cost_weight_specs
from studies.execute import RunCache, RunOutcome, canonical_json, execute_jobs, prepare_output_dir
from studies.study import DIVERGENCE_ERRORS

if TYPE_CHECKING:  # the plant imports PyBullet: loaded when a run starts, not to parse
    from sim_bridge.plant import PlantConfig, PlantState, SoftBoxConfig

__all__ = [
    "APPROACHES",
    "REGULATIONS",
    "DEFAULT_RUNS",
    "DiceConfig",
    "IMPACT_SCHEMA",
    "load_impact_config",
    "ImpactJob",
    "ImpactRun",
    "ImpactStudyResult",
    "ImpactStudyConfig",
    "LimitViolations",
    "count_limit_violations",
    "default_out_dir",
    "dice_measurement",
    "execute_impact_job",
    "format_table",
    "plot_runs",
    "run_impact",
    "run_impact_study",
    "plant_config",
    "run_metrics",
    "start_configuration",
    "start_pose",
    "task_config",
    "time_to_steady_force",
]

#: How the maximal approach treats the unknown material: ``touch_first`` (touch at the bound
#: safe for the plausible range, learn, re-plan from the learned interval, then strike) or
#: ``prior`` (the paper's scheme with the prior as if it were the truth; the fault of issue 12).
STRATEGIES = ("touch_first", "prior")
DOWN = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class DiceConfig:
    """The soft dice: what PyBullet simulates (the truth) and where it is.

    Attributes:
        stiffness: contact stiffness set in PyBullet, N/m (one contact point with the tool).
        damping: contact damping set in PyBullet, N·s/m.
        size: edge length, m (paper: 0.16).
        mass: kg (paper: 0.1); recorded only: the dice is static (fixed) in the simulation.
        position_xy: centre of the dice in the horizontal plane, m, world frame.
        top_height: height of the top face, m, world frame.
        max_penetration: z̄, m, the elastic-domain bound the planner keeps.
        lateral_friction: Coulomb friction of the dice (the tool's is 1; Bullet multiplies).
        collision_margin: Bullet's collision margin of the dice, m (edges rounded with it; the
            faces stay put). With PyBullet's 1 mm, a second contact point at the same depth
            appeared once the 1 cm tool sphere's centre passed the inner face (11.0 mm): the
            force doubled in one step (52.8 → 105.6 N on the 4800 N/m dice; joint 2 at 1.7× its
            acceleration limit; starting 0.2 m above the 7200 N/m dice it happened during the
            touch, 87 → 175 N, 3.9×, and the learner fed the doubled stiffness was never
            confident: the 60 N target was refused). With 5 cm the single contact holds to
            60 mm, past any penetration of the study (the prior strategy's reached 47.5 mm).
            A 5 cm tool sphere instead also avoided it but changed the tilting contact (the
            force-feedback MPC then broke the wrist's acceleration limit on the 7200/7.5 dice).
    """

    stiffness: float = 3000.0
    damping: float = 20.0
    size: float = 0.16
    mass: float = 0.1
    position_xy: tuple[float, float] = (0.6, 0.0)
    top_height: float = 0.08
    max_penetration: float = 0.03
    lateral_friction: float = 0.5
    collision_margin: float = 0.05

    def __post_init__(self) -> None:
        for name in ("stiffness", "size", "max_penetration"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise ConfigError(
                    f"dice {name} must be positive and finite, got {getattr(self, name)}"
                )
        if not (np.isfinite(self.damping) and self.damping >= 0):
            raise ConfigError(f"dice damping must be finite and >= 0, got {self.damping}")
        if self.max_penetration >= self.size:
            raise ConfigError("max_penetration must be smaller than the dice")
        if not (np.isfinite(self.collision_margin) and 0 < self.collision_margin < 0.5 * self.size):
            raise ConfigError("dice collision_margin must be in (0, size/2) (m)")

    def box(self) -> SoftBoxConfig:
        """The PyBullet box (static: mass 0)."""
        from sim_bridge.plant import SoftBoxConfig

        x, y = self.position_xy
        return SoftBoxConfig(
            position=(float(x), float(y), self.top_height - 0.5 * self.size),
            stiffness=self.stiffness,
            damping=self.damping,
            size=(self.size, self.size, self.size),
            mass=0.0,
            lateral_friction=self.lateral_friction,
            collision_margin=self.collision_margin,
        )


@dataclass(frozen=True)
class ImpactStudyConfig:
    """Everything one run is built from (defaults: the experiment of the module docstring).

    Attributes:
        dice: the true soft object.
        prior_stiffness, prior_damping: the material the planner and the MPC start from, N/m
            and N·s/m (the learner replaces them for the MPC once it is confident).
        approach_height: tool height above the dice's top face at the start, m (paper: 0.46).
        target_force: N (paper: 60). contact_threshold: N (paper: 2).
        duration: simulated time of each run, s.
        time_step: plant step = control period, s (paper: 1 kHz).
        replan_period: how often eq 9–14 are re-solved during the maximal approach, s
            (0 = every cycle as in the paper).
        planner: eq 12–14 parameters (paper: h = 20, Δt = 25 ms).
        limit_margin: fraction of the data-sheet acceleration and velocity limits the planner and
            the guard may use.
        lateral_weight: weight of the five task directions other than the motion (x, y and
            the orientation) relative to the motion direction in the guard's QP: the paper keeps
            ẋ_B = 0 (eq 2), so when a limit is active the motion direction gives way first.
        baseline_frequency: ω of the baseline's critically damped reference, rad/s.
        baseline_target_depth: the baseline's static target below the top face, m.
        admittance: the post-contact admittance controller.
        handover_speed: the force-feedback MPC takes over once the tool, in contact, moves into
            the dice no faster than this (with the touch-first strategy: moves either way no
            faster than this; a tool bouncing back at 0.17 m/s was handed over, and the MPC
            then spun the wrist past its acceleration limit), m/s (default: the admittance
            controller's speed limit, 0.1 m/s): the impact itself is absorbed by the braking
            eq 14 certified.
        mpc_period, mpc_horizon, mpc_dt: force-feedback MPC rate (s), nodes, node length (s).
        mpc_force_weight: c6 of the pressing nodes; mpc_weights: the other cost weights.
        learner_min_samples: samples before the learner's estimate may replace the prior.
        learner_max_relative_std: ... and the largest relative standard error of α̂ and β̂.
        steady_band: |f − target| ≤ steady_band · target counts as steady (5 %).
        steady_hold: ... for at least this long, s (0.2).
        strategy: the maximal approach's treatment of the unknown material (:data:`STRATEGIES`).
        touch: parameters of the ``touch_first`` strategy
            (:class:`~ffmpc_core.impact.touch_first.TouchFirstConfig`).
        handover_blend: the force-feedback MPC's torque is blended in linearly over this long,
            s, from the admittance controller's (both through the joint-limit guard, so every
            blend is admissible: q̈ is affine in τ and the admissible set is convex); 0 = switch.
        tool_radius: radius of the simulated spherical tool, m (1 cm); with the dice's
            collision margin it must exceed z̄ (see :attr:`DiceConfig.collision_margin`).
    """

    dice: DiceConfig = field(default_factory=DiceConfig)
    prior_stiffness: float = 2400.0
    prior_damping: float = 15.0
    approach_height: float = 0.46
    target_force: float = 60.0
    contact_threshold: float = 2.0
    duration: float = 4.0
    time_step: float = 1e-3
    replan_period: float = 0.0
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    limit_margin: float = 0.9
    lateral_weight: float = 100.0
    baseline_frequency: float = 5.0
    baseline_target_depth: float = 0.005
    admittance: AdmittanceForceController = field(default_factory=AdmittanceForceController)
    handover_speed: float = 0.1
    mpc_period: float = 0.004
    mpc_horizon: int = 10
    mpc_dt: float = 0.02
    mpc_force_weight: float = 3.0
    mpc_weights: CostWeights = field(
        default_factory=lambda: CostWeights(posture=1.0, joint_velocity=0.1)
    )
    learner_min_samples: int = 20
    learner_max_relative_std: float = 0.05
    steady_band: float = 0.05
    steady_hold: float = 0.2
    strategy: str = "touch_first"
    touch: TouchFirstConfig = field(default_factory=TouchFirstConfig)
    handover_blend: float = 0.05
    tool_radius: float = 0.01

    def __post_init__(self) -> None:
        positive = (
            "prior_stiffness",
            "approach_height",
            "target_force",
            "contact_threshold",
            "duration",
            "time_step",
            "limit_margin",
            "lateral_weight",
            "baseline_frequency",
            "mpc_period",
            "mpc_dt",
            "handover_speed",
            "steady_band",
            "steady_hold",
        )
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"ImpactStudyConfig.{name} must be positive, got {value}")
        if not (np.isfinite(self.prior_damping) and self.prior_damping >= 0):
            raise ConfigError("prior_damping must be >= 0")
        if self.limit_margin > 1.0:
            raise ConfigError("limit_margin must be <= 1")
        if self.contact_threshold >= self.target_force:
            raise ConfigError("contact_threshold must be below target_force")
        if not 0 <= self.baseline_target_depth < self.dice.max_penetration:
            raise ConfigError("baseline_target_depth must be in [0, max_penetration)")
        every = self.mpc_period / self.time_step
        if abs(every - round(every)) > 1e-9 or round(every) < 1:
            raise ConfigError("mpc_period must be a whole number of plant steps")
        if not (np.isfinite(self.replan_period) and self.replan_period >= 0):
            raise ConfigError("replan_period must be >= 0")
        if self.strategy not in STRATEGIES:
            raise ConfigError(f"strategy must be one of {STRATEGIES}, got {self.strategy!r}")
        if not (np.isfinite(self.handover_blend) and self.handover_blend >= 0):
            raise ConfigError("handover_blend must be >= 0 (s)")
        reach = self.tool_radius + self.dice.collision_margin
        if not (np.isfinite(reach) and self.tool_radius > 0 and reach > self.dice.max_penetration):
            raise ConfigError(
                f"tool_radius + dice collision_margin ({reach} m) must exceed the dice's "
                f"max_penetration ({self.dice.max_penetration} m): a sphere whose centre passes "
                "the box's inner face gets a second contact point in Bullet (double force)"
            )

    @property
    def prior(self) -> SoftMaterial:
        """The planner's material: prior stiffness/damping and the dice's z̄."""
        return SoftMaterial(self.prior_stiffness, self.prior_damping, self.dice.max_penetration)

    def control_limits(self, limits: JointLimits) -> JointLimits:
        """The limits the planner and the guard use: ``limit_margin`` × q̈_max and q̇_max."""
        return JointLimits(
            position_lower=limits.position_lower,
            position_upper=limits.position_upper,
            velocity=self.limit_margin * limits.velocity,
            acceleration=self.limit_margin * limits.acceleration,
            torque=limits.torque,
        )


#: Dotted parameter names of ImpactStudyConfig's fields (field-path prefix → name prefix, see
#: ffmpc_core.scenario.public_name): ``dice.stiffness`` → ``plant.dice_stiffness``,
#: ``prior_stiffness`` → ``planner.prior_stiffness``, ``mpc_horizon`` → ``mpc.horizon``.
IMPACT_NAMES: dict[str, str] = {
    "dice.": "plant.dice_",
    "time_step": "plant.time_step",
    "tool_radius": "plant.tool_radius",
    "prior_": "planner.prior_",
    "mpc_": "mpc.",
    "learner_": "learner.",
}
_INF = float("inf")
#: Unit, range or choices and meaning of every impact-study parameter (kinds: the annotations).
IMPACT_TABLE: dict[str, FieldDecl] = {
    "plant.dice_stiffness": ("N/m", (1.0, 1e7), "true stiffness of the dice set in PyBullet"),
    "plant.dice_damping": ("N·s/m", (0.0, 1e5), "true damping of the dice set in PyBullet"),
    "plant.dice_size": ("m", (0.01, 1.0), "edge length of the dice"),
    "plant.dice_mass": ("kg", (0.0, 100.0), "recorded only: the dice is fixed"),
    "plant.dice_position_xy": ("m", (-2.0, 2.0), "centre of the dice, horizontal, world frame"),
    "plant.dice_top_height": ("m", (-1.0, 2.0), "height of the top face, world frame"),
    "plant.dice_max_penetration": ("m", (1e-4, 0.5), "z̄, the elastic-domain bound kept"),
    "plant.dice_lateral_friction": ("", (0.0, 10.0), "Coulomb friction of the dice"),
    "plant.dice_collision_margin": ("m", (1e-4, 0.5), "Bullet's collision margin of the dice"),
    "plant.time_step": ("s", (1e-5, 0.01), "plant step = control period"),
    "plant.tool_radius": ("m", (1e-3, 0.2), "radius of the spherical tool"),
    "planner.prior_stiffness": ("N/m", (1.0, 1e7), "prior α of the planner and the MPC"),
    "planner.prior_damping": ("N·s/m", (0.0, 1e5), "prior β of the planner and the MPC"),
    "planner.horizon": ("steps", (2, 1000), "h of eq 12-14"),
    "planner.dt": ("s", (1e-4, 1.0), "Δt of eq 12-14"),
    "planner.cost": ("", ["qp", "lp"], "eq 14 (qp) or its LP variant"),
    "planner.control_effort_weight": ("s⁴/m²", (1e-12, _INF), "weight of Σ u_i² (eq 12)"),
    "planner.force_tracking_weight": ("1/N²", (0.0, _INF), "ω_f of eq 12"),
    "planner.target_force": ("N", (0.0, 500.0), "f_des of eq 12 (with ω_f > 0)"),
    "planner.velocity_weight": ("s/m", (1e-12, _INF), "−r of eq 14"),
    "planner.velocity_regularization": ("s/m", (1e-12, _INF), "R of eq 14"),
    "planner.max_halfplanes": ("", (3, 1000), "eq 11 rows per step"),
    "planner.solver": ("", ["daqp", "osqp"], "QP solver of eq 9-14"),
    "planner.eps": ("", (1e-12, 1.0), "OSQP tolerance"),
    "planner.primal_tol": ("", (1e-15, 1.0), "DAQP primal feasibility tolerance"),
    "planner.input_scale": ("m/s²", (1e-6, 1e6), "internal scaling of u"),
    "approach_height": ("m", (0.01, 1.0), "tool height above the top face at the start"),
    "target_force": ("N", (0.1, 500.0), "force held after contact"),
    "contact_threshold": ("N", (0.01, 100.0), "force that declares the contact"),
    "duration": ("s", (0.01, 600.0), "simulated time per run"),
    "replan_period": ("s", (0.0, 10.0), "between eq 9-14 solves (0: every cycle)"),
    "limit_margin": ("", (0.01, 1.0), "fraction of the data-sheet q̈ and q̇ limits used"),
    "lateral_weight": ("", (1e-6, 1e6), "weight of the 5 other task directions in the guard"),
    "baseline_frequency": ("rad/s", (0.01, 1000.0), "ω of the baseline's reference"),
    "baseline_target_depth": ("m", (0.0, 0.5), "baseline's static target below the top"),
    "admittance.admittance": ("m/(N·s)", (1e-9, 1.0), "admittance G"),
    "admittance.max_velocity": ("m/s", (1e-6, 10.0), "v_max"),
    "admittance.velocity_filter": ("", (0.0, 1.0), "γ per nominal_dt, in [0, 1)"),
    "admittance.nominal_dt": ("s", (1e-6, 1.0), "step of γ"),
    "handover_speed": ("m/s", (1e-6, 10.0), "in-contact speed below which the MPC takes over"),
    "mpc.period": ("s", (1e-5, 1.0), "force-feedback MPC period (whole plant steps)"),
    "mpc.horizon": ("nodes", (1, 1000), "OCP nodes N"),
    "mpc.dt": ("s", (1e-5, 1.0), "OCP node duration"),
    "mpc.force_weight": ("1/N²", (0.0, _INF), "c6 of the pressing nodes"),
    "learner.min_samples": ("", (3, 10**6), "samples before the estimate replaces the prior"),
    "learner.max_relative_std": ("", (1e-9, 10.0), "largest relative std error of α̂, β̂"),
    "steady_band": ("", (1e-6, 1.0), "|f − target| ≤ this · target counts as steady"),
    "steady_hold": ("s", (1e-6, 60.0), "... for at least this long"),
    "strategy": ("", list(STRATEGIES), "maximal approach: touch_first or prior"),
    "touch.stiffness_factors": ("", (1e-3, 1e3), "plausible α range, factors of the prior"),
    "touch.damping_factors": ("", (1e-3, 1e3), "plausible β range, factors of the prior"),
    "touch.touch_force": ("N", (0.01, 500.0), "force regulated during the touch"),
    "touch.touch_dwell": ("s", (0.0, 60.0), "minimal time in contact during the touch"),
    "touch.max_touch_time": ("s", (0.0, 60.0), "longest touch"),
    "touch.learner_min_samples": ("", (3, 10**6), "samples before confident"),
    "touch.learner_max_relative_std": ("", (1e-9, 10.0), "relative std errors at most this"),
    "touch.sigmas": ("", (0.0, 100.0), "k of the learned interval α̂ ± k σ"),
    "touch.stiffness_floor": ("", (0.0, 10.0), "least relative half-width of the α interval"),
    "touch.damping_floor": ("", (0.0, 10.0), "least relative half-width of the β interval"),
    "touch.retract_height": ("m", (0.0, 1.0), "height above the surface the strike starts"),
    "touch.retract_acceleration_fraction": ("", (0.0, 1.0), "peak of the retract profile"),
    "touch.impact_force_factor": ("", (0.0, 100.0), "κ of the guard's impact force"),
    "touch.penetration_margin": ("m", (0.0, 0.5), "off z̄ in eq 12 for touch and strike"),
    "handover_blend": ("s", (0.0, 10.0), "admittance → MPC torque blend (0: switch)"),
}
#: The impact study's schema: ``ffmpc study impact --scenario/--set`` and impact.yaml.
IMPACT_SCHEMA: ConfigSchema[ImpactStudyConfig] = ConfigSchema.of(
    ImpactStudyConfig,
    IMPACT_TABLE,
    IMPACT_NAMES,
    given=cost_weight_specs("mpc.weights.", 1),  # the MPC's contact is 1-D (normal)
)


def load_impact_config(
    name_or_path: str = "impact", overrides: dict[str, Any] | None = None
) -> ImpactStudyConfig:
    """An impact-study scenario file (shipped name or path) with ``--set`` overrides."""
    return IMPACT_SCHEMA.load(name_or_path, overrides)


def start_configuration(
    robot: RobotModel, position: np.ndarray, iterations: int = 300
) -> np.ndarray:
    """Joint positions (rad) that put the contact frame at ``position`` (m, world) with the
    orientation it has at ``robot.q_nominal`` (tool pointing down): damped least-squares inverse
    kinematics on SE(3), started from ``q_nominal``, with a small pull towards it in the null
    space. Raises ConfigError if it does not converge to 0.1 mm / 1 mrad."""
    model, data, fid = robot.model, robot.create_data(), robot.contact_frame_id
    target = pin.SE3(robot.contact_placement(robot.q_nominal).rotation, np.asarray(position))
    q = robot.q_nominal.copy()
    for _ in range(iterations):
        pin.framesForwardKinematics(model, data, q)
        err = pin.log6(data.oMf[fid].inverse() * target).vector
        if np.linalg.norm(err[:3]) < 1e-7 and np.linalg.norm(err[3:]) < 1e-6:
            break
        J = pin.computeFrameJacobian(model, data, q, fid, pin.ReferenceFrame.LOCAL)
        step = J.T @ np.linalg.solve(J @ J.T + 1e-8 * np.eye(6), err)
        null = np.eye(robot.nv) - np.linalg.pinv(J) @ J
        q = pin.integrate(model, q, step + 0.01 * null @ (robot.q_nominal - q))
    pin.framesForwardKinematics(model, data, q)
    err = pin.log6(data.oMf[fid].inverse() * target).vector
    if np.linalg.norm(err[:3]) > 1e-4 or np.linalg.norm(err[3:]) > 1e-3:
        raise ConfigError(f"no joint configuration puts the tool at {position}")
    if np.any(q < robot.position_lower) or np.any(q > robot.position_upper):
        raise ConfigError(f"the start configuration for {position} is outside the joint limits")
    return q


@dataclass(frozen=True)
class LimitViolations:
    """Samples (control steps) at which a joint exceeded a data-sheet limit (eq 1b–1e).

    Attributes:
        position: q outside [q̲, q̄]. velocity: |q̇| > q̇_max.
        acceleration: |q̈| > q̈_max with q̈ = (q̇[k+1] − q̇[k]) / Δt from the simulated q̇.
        torque: |τ| ≥ τ_max for the torque the controller sent (the plant would saturate it).
        max_ratio: largest |value| / limit of each kind (position: |q − mid-range| / half range,
            1 at a limit).
    """

    position: int
    velocity: int
    acceleration: int
    torque: int
    max_ratio: dict[str, float]

    @property
    def total(self) -> int:
        return self.position + self.velocity + self.acceleration + self.torque


def count_limit_violations(
    q: np.ndarray, v: np.ndarray, tau: np.ndarray, dt: float, limits: JointLimits
) -> LimitViolations:
    """Count the samples of a run (rows: steps) that break the limits; see LimitViolations."""
    mid = 0.5 * (limits.position_upper + limits.position_lower)
    half = 0.5 * (limits.position_upper - limits.position_lower)
    p_ratio = np.abs(q - mid) / half
    qdd = np.diff(v, axis=0) / dt
    v_ratio = np.abs(v) / limits.velocity
    a_ratio = np.abs(qdd) / limits.acceleration
    t_ratio = np.abs(tau) / limits.torque
    return LimitViolations(
        position=int(np.count_nonzero(np.any(p_ratio > 1.0, axis=1))),
        velocity=int(np.count_nonzero(np.any(v_ratio > 1.0, axis=1))),
        acceleration=int(np.count_nonzero(np.any(a_ratio > 1.0, axis=1))),
        torque=int(np.count_nonzero(np.any(t_ratio >= 1.0 - 1e-9, axis=1))),
        max_ratio={
            "position": float(p_ratio.max()) if p_ratio.size else 0.0,
            "velocity": float(v_ratio.max()) if v_ratio.size else 0.0,
            "acceleration": float(a_ratio.max()) if a_ratio.size else 0.0,
            "torque": float(t_ratio.max()) if t_ratio.size else 0.0,
        },
    )


def time_to_steady_force(
    t: np.ndarray, force: np.ndarray, target: float, band: float, hold: float, start: float
) -> float:
    """First time ≥ ``start`` (s) from which ``|f − target| ≤ band·target`` holds for ``hold`` s;
    NaN if never (within the data). ``t`` s, ``force`` N."""
    inside = np.abs(force - target) <= band * target
    dt = float(t[1] - t[0]) if t.size > 1 else 1.0
    need = int(round(hold / dt))
    k0 = int(np.searchsorted(t, start))
    run = 0
    for k in range(k0, t.size):
        run = run + 1 if inside[k] else 0
        if run > need:
            return float(t[k - need])
    return float("nan")


@dataclass
class ImpactRun:
    """One run's results.

    Attributes:
        approach, regulation: which run.
        pre_impact_velocity: speed along d at the last force-free sample before contact, m/s.
        contact_time: time the force reached the contact threshold, s (NaN: never).
        steady_time: :func:`time_to_steady_force` from the contact on, s (NaN: never).
        peak_force: N. peak_penetration: below the true top face, m.
        final_force: mean force over the last 0.2 s, N. final_force_error: max |f − target|
            over the last 0.2 s, N.
        violations: see LimitViolations (against the data-sheet limits).
        learned_stiffness, learned_damping: the RLS estimate at the end, N/m, N·s/m (NaN if
            the learner never got enough data); learned_std: their standard errors.
        learner_samples: samples fed to the learner.
        handover_time: when the force-feedback MPC took over, s (NaN: admittance runs).
        wall_time: s. guard_stats: the JointLimitGuard's counters. planner_failures: eq 14
            solves that failed (ImpactController.solver_failures).
        mpc_solve_time_median: s (force-feedback MPC only).
        log: time series (t, speed, force, penetration, bound, phase..., and the joint
            positions ``q`` (rad) and velocities ``v`` (rad/s) at each step).
        strategy: the maximal approach's strategy (:data:`STRATEGIES`; ``prior`` for the
            baseline, which plans nothing).
        touch_time, touch_velocity: the exploratory touch's contact (s) and speed at the last
            force-free sample before it (m/s); NaN without a touch.
        touch_peak_force, touch_peak_penetration: N and m, from the touch to the decision.
        decision_time: when the strike was decided (or refused) from the learned model, s.
        refusal: why the target was refused ("" if it was not); contact_time is then NaN.
        strike_knowledge: the material interval the strike was planned with.
    """

    approach: str
    regulation: str
    pre_impact_velocity: float
    contact_time: float
    steady_time: float
    peak_force: float
    peak_penetration: float
    final_force: float
    final_force_error: float
    violations: LimitViolations
    learned_stiffness: float
    learned_damping: float
    learned_std: tuple[float, float]
    learner_samples: int
    handover_time: float
    wall_time: float
    guard_stats: dict[str, int]
    planner_failures: int
    mpc_solve_time_median: float
    log: dict[str, np.ndarray] = field(repr=False)
    strategy: str = "prior"
    touch_time: float = float("nan")
    touch_velocity: float = float("nan")
    touch_peak_force: float = float("nan")
    touch_peak_penetration: float = float("nan")
    decision_time: float = float("nan")
    refusal: str = ""
    strike_knowledge: str = ""

    @property
    def name(self) -> str:
        return f"{self.approach}+{self.regulation}"

    def summary(self) -> dict:
        """JSON-friendly, without the time series."""
        out = {k: v for k, v in asdict(self).items() if k != "log"}
        out["violations"] = asdict(self.violations)
        out["violations"]["total"] = self.violations.total
        out["name"] = self.name
        return out

    @classmethod
    def from_summary(cls, summary: dict[str, Any], log: dict[str, np.ndarray]) -> ImpactRun:
        """The run back from its :meth:`summary` (e.g. read from a study's cache) and a log."""
        fields_ = {k: v for k, v in summary.items() if k != "name"}
        violations = {k: v for k, v in fields_.pop("violations").items() if k != "total"}
        fields_["learned_std"] = tuple(fields_["learned_std"])
        return cls(**fields_, violations=LimitViolations(**violations), log=log)


def run_metrics(
    cfg: ImpactStudyConfig,
    log: dict[str, np.ndarray],
    qs: np.ndarray,
    vs: np.ndarray,
    taus: np.ndarray,
    limits: JointLimits,
    contact_time: float | None,
    touch_speed: float,
) -> dict[str, Any]:
    """A run's metrics from its log (``t`` s, ``force`` N, ``penetration`` m per step), the
    joint positions and velocities of steps 0..K (rad, rad/s), the torques sent at steps
    0..K−1 (N·m), the data-sheet limits, the contact time (s, None: never) and the speed along
    d at the last force-free sample before it (m/s): ``pre_impact_velocity``,
    ``contact_time``, ``steady_time``, ``peak_force``, ``peak_penetration``, ``final_force``,
    ``final_force_error``, ``violations`` (see :class:`ImpactRun`). The ROS-free run and the
    impact graph both summarise with it."""
    t_log, force = log["t"], log["force"]
    nan = float("nan")
    contact = nan if contact_time is None else float(contact_time)
    steady = (
        nan
        if contact_time is None
        else time_to_steady_force(
            t_log, force, cfg.target_force, cfg.steady_band, cfg.steady_hold, contact
        )
    )
    tail = t_log >= t_log[-1] - 0.2
    return dict(
        pre_impact_velocity=float(touch_speed) if contact_time is not None else nan,
        contact_time=contact,
        steady_time=steady,
        peak_force=float(force.max()),
        peak_penetration=float(log["penetration"].max()),
        final_force=float(force[tail].mean()),
        final_force_error=float(np.abs(force[tail] - cfg.target_force).max()),
        violations=count_limit_violations(qs, vs, taus, cfg.time_step, limits),
    )


def touch_metrics(
    log: dict[str, np.ndarray],
    touch_time: float | None,
    touch_velocity: float | None,
    decision_time: float | None,
) -> dict[str, float]:
    """The touch-first run's touch metrics (:class:`ImpactRun`) from the log (``t`` s,
    ``force`` N, ``penetration`` m) and the touch-first controller's touch time (s), touch
    velocity (m/s) and decision time (s) (None: never). The ROS-free run and the impact graph
    both summarise with it."""
    nan = float("nan")
    t_log = log["t"]
    t_touch = nan if touch_time is None else float(touch_time)
    t_decide = nan if decision_time is None else float(decision_time)
    window = (t_log >= t_touch) & (t_log <= t_decide) if np.isfinite(t_decide) else None
    return dict(
        touch_time=t_touch,
        touch_velocity=nan if touch_velocity is None else float(touch_velocity),
        touch_peak_force=nan if window is None else float(log["force"][window].max()),
        touch_peak_penetration=(nan if window is None else float(log["penetration"][window].max())),
        decision_time=t_decide,
    )


def task_config(approach: str, regulation: str, cfg: ImpactStudyConfig) -> ImpactTaskConfig:
    """The controller configuration of one run (:class:`ImpactTaskController`) from the
    study's configuration."""
    dt = cfg.time_step
    return ImpactTaskConfig(
        approach=approach,
        regulation=regulation,
        controller=ImpactControllerConfig(
            direction=DOWN,
            material=cfg.prior,
            target_force=cfg.target_force,
            contact_threshold=cfg.contact_threshold,
            planner=cfg.planner,
            admittance=cfg.admittance,
            replan_period=cfg.replan_period,
        ),
        guard=JointLimitGuardConfig(
            dt=dt,
            margin=1.0,
            task_weights=(cfg.lateral_weight, cfg.lateral_weight, 1.0) + (cfg.lateral_weight,) * 3,
        ),
        time_step=dt,
        touch=cfg.touch if cfg.strategy == "touch_first" else None,
        baseline=BaselineApproachConfig(
            direction=DOWN,
            distance=cfg.approach_height + cfg.baseline_target_depth,
            frequency=cfg.baseline_frequency,
            refresh=max(cfg.replan_period, dt),
            time_step=dt,
        ),
        handover=HandoverConfig(
            direction=DOWN,
            target_force=cfg.target_force,
            time_step=dt,
            handover_speed=cfg.handover_speed,
            symmetric_speed=cfg.strategy == "touch_first" and approach == "maximal",
            blend=cfg.handover_blend,
            mpc_period=cfg.mpc_period,
            mpc_horizon=cfg.mpc_horizon,
            mpc_dt=cfg.mpc_dt,
            mpc_force_weight=cfg.mpc_force_weight,
            mpc_weights=cfg.mpc_weights,
            prior_stiffness=cfg.prior_stiffness,
            prior_damping=cfg.prior_damping,
            learner_min_samples=cfg.learner_min_samples,
            learner_max_relative_std=cfg.learner_max_relative_std,
        ),
    )


def dice_measurement(
    robot: RobotModel, data: pin.Data, q: np.ndarray, v: np.ndarray, wrench: np.ndarray
) -> ContactMeasurement:
    """One cycle's measurement of the experiment from q (rad), q̇ (rad/s) and the wrench on the
    tool ([f; m], N and N·m, world axes): the pressing force is the world-z force (d = DOWN).
    The ROS-free run and the impact graph's controller node both measure with it."""
    return contact_measurement(robot, data, q, v, wrench, DOWN, force=float(wrench[2]))


def start_pose(cfg: ImpactStudyConfig, robot: RobotModel) -> np.ndarray:
    """The start joint positions (rad): the tool ``approach_height`` above the dice's centre."""
    x0, y0 = cfg.dice.position_xy
    top = cfg.dice.top_height
    return start_configuration(robot, np.array([x0, y0, top + cfg.approach_height]))


def plant_config(cfg: ImpactStudyConfig) -> PlantConfig:
    """The PyBullet plant of the experiment: no table, the dice, the spherical tool."""
    from sim_bridge.plant import PlantConfig, ToolConfig

    return PlantConfig(
        time_step=cfg.time_step,
        table=None,
        soft_boxes=(cfg.dice.box(),),
        tool=ToolConfig(radius=cfg.tool_radius),
    )


class _ImpactLoop:
    """The impact run's scenario (:class:`~ffmpc_core.runner.LoopScenario`): the controller reads
    :func:`dice_measurement` of the true state, the plant gets the command's torque; the log
    (``t`` s, ``speed`` along d m/s, ``force`` world z on the tool N, ``penetration`` below the
    true top face m, the eq 14 ``bound`` m/s, the phase, the MPC's contact model and blend weight)
    and the joint positions ``qs`` (rad), velocities ``vs`` (rad/s, rows 0..K: the caller writes the
    final state) and torques ``taus`` (N·m) sent."""

    def __init__(self, robot: RobotModel, top: float, steps: int, dt: float) -> None:
        self.robot = robot
        self.data = robot.create_data()
        self.top = top
        self.log: dict[str, np.ndarray] = {
            "t": np.arange(steps) * dt,
            "speed": np.zeros(steps),
            "force": np.zeros(steps),
            "penetration": np.zeros(steps),
            "bound": np.full(steps, np.nan),
            "in_contact_phase": np.zeros(steps, dtype=bool),
            "mpc_stiffness": np.full(steps, np.nan),
            "mpc_damping": np.full(steps, np.nan),
            "phase": np.full(steps, "", dtype="<U13"),  # the maximal approach's phase
            "mpc_weight": np.zeros(steps),  # share of the MPC's torque in the blend
        }
        self.qs = np.zeros((steps + 1, robot.nq))
        self.vs = np.zeros((steps + 1, robot.nv))
        self.taus = np.zeros((steps, robot.nv))

    def measure(self, k: int, t: float, state: PlantState, /) -> ContactMeasurement:
        self.qs[k], self.vs[k] = state.q, state.v
        return dice_measurement(self.robot, self.data, state.q, state.v, state.wrench_world)

    def actuate(
        self, k: int, t: float, state: PlantState, command: ImpactTaskCommand, /
    ) -> np.ndarray:
        return command.torque

    def record(
        self,
        k: int,
        t: float,
        state: PlantState,
        m: ContactMeasurement,
        command: ImpactTaskCommand,
        joint_input: np.ndarray | None,
        /,
    ) -> None:
        log = self.log
        log["speed"][k] = m.speed
        log["force"][k] = m.force
        log["penetration"][k] = self.top - m.position[2]
        log["in_contact_phase"][k] = command.in_contact
        log["bound"][k] = command.pre_impact_velocity
        log["phase"][k] = command.phase
        log["mpc_stiffness"][k] = command.mpc_stiffness
        log["mpc_damping"][k] = command.mpc_damping
        log["mpc_weight"][k] = command.mpc_weight
        self.taus[k] = command.torque


def run_impact(
    approach: str,
    regulation: str,
    config: ImpactStudyConfig | None = None,
    robot: RobotModel | None = None,
) -> ImpactRun:
    """One run of the experiment (see the module docstring), in lockstep simulated time: the
    plant, :class:`~ffmpc_core.impact.controllers.ImpactTaskController` and the log."""
    if approach not in APPROACHES:
        raise ConfigError(f"approach must be one of {APPROACHES}, got {approach!r}")
    if regulation not in REGULATIONS:
        raise ConfigError(f"regulation must be one of {REGULATIONS}, got {regulation!r}")
    cfg = config if config is not None else ImpactStudyConfig()
    wall = time.perf_counter()
    robot = robot if robot is not None else load_robot("panda")
    dice = cfg.dice
    top = dice.top_height
    q0 = start_pose(cfg, robot)
    limits = joint_limits(robot)
    dt = cfg.time_step
    steps = int(round(cfg.duration / dt))
    # Raises InfeasibleTargetError here, before any motion, if no plausible material can hold
    # the target (or the touch force is unsafe for the softest one).
    controller = ImpactTaskController(
        robot, cfg.control_limits(limits), task_config(approach, regulation, cfg)
    )
    touch_first = controller.touch_first

    from sim_bridge.plant import Plant

    scenario = _ImpactLoop(robot, top, steps, dt)
    with Plant(robot, plant_config(cfg)) as plant:
        plant.reset(q0)
        run_scenario(scenario, plant, [controller], LockstepClock(dt, steps))
        s = plant.state()
        scenario.qs[steps], scenario.vs[steps] = s.q, s.v
    log, qs, vs, taus = scenario.log, scenario.qs, scenario.vs, scenario.taus

    learner = controller.learner
    handover = controller.handover
    guard = controller.guard
    approach_ctrl = controller.approach_controller
    solve_times = [] if handover is None else handover.solve_times
    learned_in_mpc = handover is not None and handover.learned
    metrics = run_metrics(
        cfg, log, qs, vs, taus, limits, controller.contact_time, controller.touch_speed
    )
    try:
        est = learner.estimate()
        learned = (est.stiffness, est.damping, (est.stiffness_std, est.damping_std))
    except InputError:  # never enough contact data
        learned = (float("nan"), float("nan"), (float("nan"), float("nan")))
    touch: dict[str, Any] = {}
    if touch_first is not None:
        touch = dict(
            touch_metrics(
                log, touch_first.touch_time, touch_first.touch_velocity, touch_first.decision_time
            )
        )
        touch.update(
            refusal="" if touch_first.refusal is None else str(touch_first.refusal),
            strike_knowledge=touch_first.knowledge.describe(),
        )
    return ImpactRun(
        approach=approach,
        regulation=regulation,
        strategy=cfg.strategy if approach == "maximal" else "prior",
        **touch,
        **metrics,
        learned_stiffness=float(learned[0]),
        learned_damping=float(learned[1]),
        learned_std=(float(learned[2][0]), float(learned[2][1])),
        learner_samples=learner.samples,
        handover_time=(
            float("nan") if controller.handover_time is None else controller.handover_time
        ),
        wall_time=time.perf_counter() - wall,
        guard_stats=dict(guard.stats),
        planner_failures=0 if approach_ctrl is None else approach_ctrl.solver_failures,
        mpc_solve_time_median=float(np.median(solve_times)) if solve_times else float("nan"),
        log=log | {"learned_in_mpc": np.array(learned_in_mpc), "q": qs[:steps], "v": vs[:steps]},
    )


#: The log series an impact job sends back from its worker (for the figure; float arrays).
PLOT_SERIES = ("t", "speed", "force", "penetration", "bound")


@dataclass(frozen=True)
class ImpactJob:
    """One run of the impact study (a :class:`studies.execute.Job`): the configuration and the
    (approach, regulation) pair; the run is a pure function of them."""

    config: ImpactStudyConfig
    approach: str
    regulation: str

    def key_document(self) -> dict[str, Any]:
        return {
            "study": "impact",
            "run": self.label,
            "config": IMPACT_SCHEMA.flatten(self.config),
            "plot_series": list(PLOT_SERIES),
        }

    def description(self) -> dict[str, Any]:
        return {"study": "impact", "approach": self.approach, "regulation": self.regulation}

    @property
    def label(self) -> str:
        return f"{self.approach}+{self.regulation}"

    @property
    def cost_rank(self) -> int:
        """The force-feedback MPC runs first (the slowest)."""
        return 0 if self.regulation == "ff_mpc" else 1


def execute_impact_job(job: ImpactJob) -> RunOutcome:
    """Run one impact job (in a Dask worker or in-process): its summary (JSON types) and the
    :data:`PLOT_SERIES` of its log, or the error of a run that diverged (as the polishing
    study's :func:`~studies.study.execute_run`)."""
    import pybullet

    try:
        run = run_impact(job.approach, job.regulation, job.config)
    except ConfigError:
        raise
    except (*DIVERGENCE_ERRORS, pybullet.error) as exc:
        return RunOutcome(job, error=f"{type(exc).__name__}: {exc}")
    summary = json.loads(canonical_json(run.summary()))
    return RunOutcome(job, summary=summary, plot_log={k: run.log[k] for k in PLOT_SERIES})


#: The runs of the study, in table order.
DEFAULT_RUNS = (
    ("maximal", "admittance"),
    ("maximal", "ff_mpc"),
    ("baseline", "admittance"),
    ("baseline", "ff_mpc"),
)
#: The paper's numbers (Sec. VI, Fig. 4), for comparison only.
PAPER = {
    "maximal_contact_time": 0.75,
    "maximal_pre_impact_velocity": 0.898,
    "baseline_contact_time": 1.38,
}


def _fmt(value: float, spec: str) -> str:
    return "—" if not np.isfinite(value) else format(value, spec)


def format_table(runs: list[ImpactRun], config: ImpactStudyConfig) -> str:
    """The study's table (Markdown), one row per run, then the learner's estimates."""
    dice = config.dice
    head = (
        "| run | pre-impact velocity (m/s) | contact (s) | steady force (s) | "
        "peak force (N) | peak penetration (mm) | final force (N) | "
        "violations q / q̇ / q̈ / τ | max q̈/q̈_max | wall (s) |"
    )
    lines = [head, "|" + "---|" * 10]
    for r in runs:
        v = r.violations
        settle = r.steady_time - r.contact_time
        lines.append(
            f"| {r.name} | {_fmt(r.pre_impact_velocity, '.3f')} | {_fmt(r.contact_time, '.3f')} "
            f"| {_fmt(r.steady_time, '.3f')} (+{_fmt(settle, '.3f')}) "
            f"| {_fmt(r.peak_force, '.1f')} | {_fmt(1e3 * r.peak_penetration, '.1f')} "
            f"| {_fmt(r.final_force, '.2f')} "
            f"| {v.position} / {v.velocity} / {v.acceleration} / {v.torque} "
            f"| {v.max_ratio['acceleration']:.3f} | {r.wall_time:.1f} |"
        )
    lines += [
        "",
        f"Learner (eq 19–21) at the end of each run vs the dice set in PyBullet "
        f"(stiffness {dice.stiffness:g} N/m, damping {dice.damping:g} N·s/m; planner prior "
        f"{config.prior_stiffness:g} N/m, {config.prior_damping:g} N·s/m):",
        "",
        "| run | samples | stiffness α̂ (N/m) | error | damping β̂ (N·s/m) | error | "
        "MPC handover (s) |",
        "|" + "---|" * 7,
    ]
    for r in runs:
        ek = (r.learned_stiffness / dice.stiffness - 1.0) * 100.0
        ed = (r.learned_damping / dice.damping - 1.0) * 100.0 if dice.damping > 0 else np.nan
        lines.append(
            f"| {r.name} | {r.learner_samples} | {_fmt(r.learned_stiffness, '.1f')} "
            f"| {_fmt(ek, '+.1f')} % | {_fmt(r.learned_damping, '.2f')} | {_fmt(ed, '+.1f')} % "
            f"| {_fmt(r.handover_time, '.3f')} |"
        )
    touched = [r for r in runs if r.strategy == "touch_first"]
    if touched:
        lines += [
            "",
            "Touch first (the maximal approach's exploratory touch at the eq 14 bound safe for "
            "the plausible range, then the strike planned from the learned interval):",
            "",
            "| run | touch (s) | touch velocity (m/s) | touch peak force (N) | "
            "touch peak penetration (mm) | decision (s) | strike planned with | refusal |",
            "|" + "---|" * 8,
        ]
        for r in touched:
            lines.append(
                f"| {r.name} | {_fmt(r.touch_time, '.3f')} | {_fmt(r.touch_velocity, '.3f')} "
                f"| {_fmt(r.touch_peak_force, '.1f')} "
                f"| {_fmt(1e3 * r.touch_peak_penetration, '.1f')} "
                f"| {_fmt(r.decision_time, '.3f')} | {r.strike_knowledge} "
                f"| {r.refusal or '—'} |"
            )
    lines += [
        "",
        f"Steady force: |f − {config.target_force:g}| ≤ {100 * config.steady_band:g} % for "
        f"{config.steady_hold:g} s (time it starts, and + its delay after the contact). "
        "Violations: control steps beyond the data-sheet limits; q̈ = (q̇[k+1] − q̇[k])/Δt of "
        "the simulated q̇; τ counts commanded torques at or over the limit. Paper (real Panda, "
        f"its dice): contact at {PAPER['maximal_contact_time']} s with "
        f"{PAPER['maximal_pre_impact_velocity']} m/s (maximal) vs "
        f"{PAPER['baseline_contact_time']} s (baseline).",
    ]
    return "\n".join(lines)


#: Line styles of the runs in the figure.
_STYLE = {
    ("maximal", "admittance"): dict(color="black", ls="-"),
    ("maximal", "ff_mpc"): dict(color="tab:red", ls="-"),
    ("baseline", "admittance"): dict(color="tab:cyan", ls="--"),
    ("baseline", "ff_mpc"): dict(color="tab:purple", ls="--"),
}


def plot_runs(runs: list[ImpactRun], config: ImpactStudyConfig, path: Path) -> Path:
    """A figure like the paper's Fig. 4: velocity along the motion (with the eq 14 bound of the
    maximal approach) and contact force over time, every run; PNG at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax_v, ax_f, ax_z) = plt.subplots(3, 1, figsize=(7.0, 6.6), sharex=True, dpi=90)
    bound_drawn = False
    for r in runs:
        t, log = r.log["t"], r.log
        style = _STYLE.get((r.approach, r.regulation), {})
        label = r.name.replace("ff_mpc", "FF-MPC")
        ax_v.plot(t, log["speed"], lw=1.2, label=label, **style)
        if r.approach == "maximal" and not bound_drawn:
            ax_v.plot(
                t,
                log["bound"],
                color="tab:blue",
                lw=5.0,
                alpha=0.3,
                zorder=1,
                label="max. safe pre-impact velocity (eq 14)",
            )
            bound_drawn = True
        ax_f.plot(t, log["force"], lw=1.2, label=label, **style)
        ax_z.plot(t, 1e3 * log["penetration"], lw=1.2, **style)
        if np.isfinite(r.contact_time):
            for ax in (ax_v, ax_f):
                ax.axvline(r.contact_time, color=style.get("color", "gray"), lw=0.6, ls=":")
    ax_f.axhline(config.target_force, color="tab:green", lw=1.5, label="desired force")
    ax_z.axhline(
        1e3 * config.dice.max_penetration, color="gray", lw=1.0, ls="-.", label="max. penetration z̄"
    )
    ax_z.set_ylim(bottom=-5.0)
    ax_v.set_ylabel("velocity along d (m/s)")
    ax_f.set_ylabel("contact force (N)")
    ax_z.set_ylabel("penetration (mm)")
    ax_z.set_xlabel("time (s)")
    ax_v.legend(fontsize=7, loc="upper right")
    ax_f.legend(fontsize=7, loc="upper left")
    ax_z.legend(fontsize=7, loc="upper left")
    for ax in (ax_v, ax_f, ax_z):
        ax.grid(alpha=0.3)
    dice = config.dice
    fig.suptitle(
        f"Panda on a soft dice (k = {dice.stiffness:g} N/m, d = {dice.damping:g} N·s/m): "
        "maximal impact vs baseline",
        fontsize=9,
    )
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path)
    plt.close(fig)
    return path


def default_out_dir() -> Path:
    """``benchmarks/results/impact_study/<UTC time>`` under the current directory."""
    stamp = datetime.now(timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return Path("benchmarks") / "results" / "impact_study" / stamp


@dataclass
class ImpactStudyResult:
    """Runs, the table (Markdown) and the files written."""

    runs: list[ImpactRun]
    table: str
    files: list[Path]
    wall_time: float


def check_before_motion(config: ImpactStudyConfig) -> None:
    """The touch-first strategy's checks before any motion (see
    :class:`~ffmpc_core.impact.touch_first.TouchFirstImpactController`): raises
    :class:`~ffmpc_core.errors.InfeasibleTargetError` if the touch force is unsafe for the
    softest plausible material or no plausible material can hold the target within z̄."""
    if config.strategy != "touch_first":
        return
    prior = MaterialInterval.from_prior(
        config.prior, config.touch.stiffness_factors, config.touch.damping_factors
    )
    check_force_target(config.touch.touch_force, prior, "the exploratory touch force")
    check_force_target(
        config.target_force,
        prior,
        "even the stiffest plausible material cannot hold it",
        worst_case=False,
    )


def run_impact_study(
    config: ImpactStudyConfig | None = None,
    runs: tuple[tuple[str, str], ...] = DEFAULT_RUNS,
    out_dir: Path | None = None,
    force: bool = False,
    progress: bool = True,
    command_line: str = "",
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    cache: bool = True,
    fresh: bool = False,
) -> ImpactStudyResult:
    """Run ``runs`` (:class:`ImpactJob`, through :func:`studies.execute.execute_jobs`: a Dask
    ``LocalCluster`` of ``workers`` processes by default, ``1`` in this process, or the workers
    of a running ``scheduler``), write ``results.json``, ``table.md`` and ``impact_fig4.png``
    into ``out_dir`` (refused if it exists, unless ``force`` or it holds an interrupted study:
    ``cache/`` and no ``results.json``, then the finished runs are read from its cache)."""
    cfg = config if config is not None else ImpactStudyConfig()
    if any(approach == "maximal" for approach, _ in runs):
        check_before_motion(cfg)  # refuse before any motion (and before writing anything)
    for approach, regulation in runs:
        if approach not in APPROACHES or regulation not in REGULATIONS:
            raise ConfigError(f"unknown run {approach}+{regulation}")
    out = prepare_output_dir(
        out_dir if out_dir is not None else default_out_dir(), force, resume=cache and not fresh
    )
    start = time.perf_counter()
    jobs = [ImpactJob(cfg, approach, regulation) for approach, regulation in runs]
    batch = execute_jobs(
        jobs,
        execute_impact_job,
        workers,
        progress,
        scheduler=scheduler,
        cache=RunCache(out / "cache") if cache else None,
        fresh=fresh,
    )
    failures = [o for o in batch.outcomes if o.summary is None]
    if failures:
        raise FfmpcError("; ".join(f"{o.spec.label} diverged: {o.error}" for o in failures))
    results = [ImpactRun.from_summary(o.summary or {}, o.plot_log or {}) for o in batch.outcomes]
    if progress:
        for r in results:
            print(
                f"  {r.name}: contact {_fmt(r.contact_time, '.3f')} s, {r.violations.total} "
                f"limit violations, {r.wall_time:.1f} s wall",
                flush=True,
            )
    table = format_table(results, cfg)
    wall = time.perf_counter() - start
    figure = plot_runs(results, cfg, out / "impact_fig4.png")
    document = {
        "command_line": command_line,
        "created": datetime.now(timezone.utc).isoformat(),
        "python": platform.python_version(),
        "config": json.loads(json.dumps(asdict(cfg), default=str)),
        "paper": PAPER,
        "runs": [r.summary() for r in results],
        "wall_time_s": wall,
        "execution": {
            "cached": batch.cached,
            "executed": batch.executed,
            "cluster": batch.cluster,
            "workers": batch.workers,
            "cache_dir": str(out / "cache") if cache else None,
        },
    }
    (out / "results.json").write_text(json.dumps(document, indent=2, default=float) + "\n")
    (out / "table.md").write_text(table + "\n")
    return ImpactStudyResult(
        runs=results,
        table=table,
        files=[out / "table.md", out / "results.json", figure],
        wall_time=wall,
    )
