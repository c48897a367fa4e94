"""The impact and exploration experiments' scenarios: configuration, schema, start pose.

Pure data and kinematics (no simulator, no ROS): what :mod:`studies.impact_study`,
:mod:`studies.exploration`, the impact graph's nodes (:mod:`ffmpc_ros.impact_common`) and the
simulated scenes (:mod:`sim_bridge.scenes`) build a run from. The experiments themselves (the
closed loops, tables, figures) are in :mod:`studies`; the run metrics in
:mod:`ffmpc_core.impact.metrics`.

Impact (Dehio & Kheddar 2020, Sec. VI, Fig. 4; ``ffmpc study impact``, ``impact.yaml``):
:class:`DiceConfig` (the true soft dice), :class:`ImpactStudyConfig` (every setting of one run),
:data:`IMPACT_SCHEMA` (the dotted parameter names, units and ranges of ``--set``),
:func:`task_config` (the controller configuration of one approach × regulation run),
:func:`start_pose`, :func:`dice_measurement`, :func:`check_before_motion`.

Exploration (Sec. V–VI; ``ffmpc study explore``, ``explore.yaml``): :class:`Material`,
:data:`MATERIALS`, :class:`ExplorationConfig`, :data:`EXPLORATION_SCHEMA`.

Units: SI (m, s, N, N/m, N·s/m, rad); positions in the world frame. Signs: the motion direction
is ``d = DOWN = (0, 0, −1)``; the pressing force ``f`` is the world-z component of the force the
object exerts on the tool (N, > 0 when pressing).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pinocchio as pin

from ffmpc_core.config import CostWeights
from ffmpc_core.declaration import param
from ffmpc_core.errors import ConfigError
from ffmpc_core.impact.control import AdmittanceForceController, ImpactControllerConfig
from ffmpc_core.impact.controllers import (
    BaselineApproachConfig,
    ContactMeasurement,
    HandoverConfig,
    ImpactTaskConfig,
    contact_measurement,
    handover_mpc_weights,
)
from ffmpc_core.impact.deformation import SoftMaterial
from ffmpc_core.impact.learner import ExplorationReference, exploration_reference
from ffmpc_core.impact.limits import JointLimits
from ffmpc_core.impact.planner import PlannerConfig
from ffmpc_core.impact.robust import MaterialInterval, check_force_target
from ffmpc_core.impact.strike_first import StrikeFirstConfig, remembered_interval
from ffmpc_core.impact.task_space import JointLimitGuardConfig, TaskSpaceGains
from ffmpc_core.impact.touch_first import TouchFirstConfig
from ffmpc_core.robots import RobotModel
from ffmpc_core.scenario import PLANT_ENGINES, ConfigSchema, cost_weight_specs

# -- the impact experiment ----------------------------------------------------------------------
#: How the maximal approach treats the unknown material: ``strike_first`` (the first contact
#: is the task's impact, at the bound safe for every material still plausible; learn from the
#: impact and the regulation, decide the target in contact), ``touch_first`` (touch at the
#: bound safe for the plausible range, learn, re-plan from the learned interval, then strike)
#: or ``prior`` (the paper's scheme with the prior as if it were the truth; the fault of
#: issue 12).
STRATEGIES = ("strike_first", "touch_first", "prior")
#: The strategies whose approach controller feeds the learner by its own rule
#: (:func:`~ffmpc_core.impact.touch_first.fed_surface`) and gates the contact.
LEARNING_STRATEGIES = ("strike_first", "touch_first")
DOWN = np.array([0.0, 0.0, -1.0])


@dataclass(frozen=True)
class DiceConfig:
    """The soft dice: what the simulator sets (the truth) and where it is.

    The simulated box is built from it by :func:`sim_bridge.scenes.dice_box`.

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

    stiffness: float = param(
        3000.0, "N/m", (1.0, 1e7), "true stiffness of the dice set in the plant"
    )
    damping: float = param(20.0, "N·s/m", (0.0, 1e5), "true damping of the dice set in the plant")
    size: float = param(0.16, "m", (0.01, 1.0), "edge length of the dice")
    mass: float = param(0.1, "kg", (0.0, 100.0), "recorded only: the dice is fixed")
    position_xy: tuple[float, float] = param(
        (0.6, 0.0), "m", (-2.0, 2.0), "centre of the dice, horizontal, world frame"
    )
    top_height: float = param(0.08, "m", (-1.0, 2.0), "height of the top face, world frame")
    max_penetration: float = param(0.03, "m", (1e-4, 0.5), "z̄, the elastic-domain bound kept")
    lateral_friction: float = param(0.5, "", (0.0, 10.0), "Coulomb friction of the dice")
    collision_margin: float = param(0.05, "m", (1e-4, 0.5), "Bullet's collision margin of the dice")

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
        mpc_constraints: the hand-over MPC's hard constraints on or off (off by default:
            :class:`~ffmpc_core.impact.controllers.HandoverConfig` says why).
        learner_min_samples: samples before the learner's estimate may replace the prior.
        learner_max_relative_std: ... and the largest relative standard error of α̂ and β̂.
        steady_band: |f − target| ≤ steady_band · target counts as steady (5 %).
        steady_hold: ... for at least this long, s (0.2).
        strategy: the maximal approach's treatment of the unknown material (:data:`STRATEGIES`).
        touch: parameters of the ``touch_first`` strategy
            (:class:`~ffmpc_core.impact.touch_first.TouchFirstConfig`); the plausible range,
            the learner's confidence, the learned interval's width, the guard's impact force,
            eq 12's penetration margin and the retract height serve ``strike_first`` too.
        strike: parameters of the ``strike_first`` strategy
            (:class:`~ffmpc_core.impact.strike_first.StrikeFirstConfig`).
        handover_blend: the force-feedback MPC's torque is blended in linearly over this long,
            s, from the admittance controller's (both through the joint-limit guard, so every
            blend is admissible: q̈ is affine in τ and the admissible set is convex); 0 = switch.
        tool_radius: radius of the simulated spherical tool, m (1 cm); with the dice's
            collision margin it must exceed z̄ (see :attr:`DiceConfig.collision_margin`).
        engine: the simulator of the plant (:data:`ffmpc_core.scenario.PLANT_ENGINES`:
            ``pybullet`` or ``mujoco``; the same robot, dice and contact parameters).
        reflex: the robot's own reflexes (:mod:`ffmpc_core.reflex`): stop on a data-sheet
            limit, run aborted (False: crossings reported only).
    """

    dice: DiceConfig = field(default_factory=DiceConfig)
    prior_stiffness: float = param(
        HandoverConfig.prior_stiffness, "N/m", (1.0, 1e7), "prior α of the planner and the MPC"
    )
    prior_damping: float = param(
        HandoverConfig.prior_damping, "N·s/m", (0.0, 1e5), "prior β of the planner and the MPC"
    )
    approach_height: float = param(
        0.46, "m", (0.01, 1.0), "tool height above the top face at the start"
    )
    target_force: float = param(
        HandoverConfig.target_force, "N", (0.1, 500.0), "force held after contact"
    )
    contact_threshold: float = param(2.0, "N", (0.01, 100.0), "force that declares the contact")
    duration: float = param(4.0, "s", (0.01, 600.0), "simulated time per run")
    time_step: float = param(1e-3, "s", (1e-5, 0.01), "plant step = control period")
    replan_period: float = param(0.0, "s", (0.0, 10.0), "between eq 9-14 solves (0: every cycle)")
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    limit_margin: float = param(
        0.9, "", (0.01, 1.0), "fraction of the data-sheet q̈ and q̇ limits used"
    )
    lateral_weight: float = param(
        100.0, "", (1e-6, 1e6), "weight of the 5 other task directions in the guard"
    )
    baseline_frequency: float = param(5.0, "rad/s", (0.01, 1000.0), "ω of the baseline's reference")
    baseline_target_depth: float = param(
        0.005, "m", (0.0, 0.5), "baseline's static target below the top"
    )
    admittance: AdmittanceForceController = field(default_factory=AdmittanceForceController)
    # the hand-over MPC's settings: HandoverConfig's defaults, declared there once
    handover_speed: float = param(
        HandoverConfig.handover_speed,
        "m/s",
        (1e-6, 10.0),
        "in-contact speed below which the MPC takes over",
    )
    mpc_period: float = param(
        HandoverConfig.mpc_period, "s", (1e-5, 1.0), "force-feedback MPC period (whole plant steps)"
    )
    mpc_horizon: int = param(HandoverConfig.mpc_horizon, "nodes", (1, 1000), "OCP nodes N")
    mpc_dt: float = param(HandoverConfig.mpc_dt, "s", (1e-5, 1.0), "OCP node duration")
    mpc_force_weight: float = param(
        HandoverConfig.mpc_force_weight, "1/N²", (0.0, math.inf), "c6 of the pressing nodes"
    )
    mpc_weights: CostWeights = field(default_factory=handover_mpc_weights)
    mpc_constraints: bool = param(
        HandoverConfig.mpc_constraints,
        "",
        None,
        "the hand-over MPC's hard constraints (off: see docs)",
    )
    learner_min_samples: int = param(
        HandoverConfig.learner_min_samples,
        "",
        (3, 10**6),
        "samples before the estimate replaces the prior",
    )
    learner_max_relative_std: float = param(
        HandoverConfig.learner_max_relative_std,
        "",
        (1e-9, 10.0),
        "largest relative std error of α̂, β̂",
    )
    steady_band: float = param(
        0.05, "", (1e-6, 1.0), "|f − target| ≤ this · target counts as steady"
    )
    steady_hold: float = param(0.2, "s", (1e-6, 60.0), "... for at least this long")
    strategy: str = param(
        "strike_first", "", list(STRATEGIES), "maximal approach: strike_first, touch_first or prior"
    )
    touch: TouchFirstConfig = field(default_factory=TouchFirstConfig)
    strike: StrikeFirstConfig = field(default_factory=StrikeFirstConfig)
    handover_blend: float = param(
        HandoverConfig.blend, "s", (0.0, 10.0), "admittance → MPC torque blend (0: switch)"
    )
    tool_radius: float = param(0.01, "m", (1e-3, 0.2), "radius of the spherical tool")
    engine: str = param(
        "pybullet", "", list(PLANT_ENGINES), "simulator of the plant: pybullet | mujoco"
    )
    reflex: bool = param(True, "", None, "the robot's own reflexes: stop on a limit, run aborted")

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
        if self.engine not in PLANT_ENGINES:
            raise ConfigError(f"engine must be one of {PLANT_ENGINES}, got {self.engine!r}")
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
    "engine": "plant.engine",
    "reflex": "plant.reflex",
    "prior_": "planner.prior_",
    "mpc_": "mpc.",
    "learner_": "learner.",
}
#: The impact study's schema: ``ffmpc study impact --scenario/--set`` and impact.yaml.
IMPACT_SCHEMA: ConfigSchema[ImpactStudyConfig] = ConfigSchema.of(
    ImpactStudyConfig,
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


def task_config(approach: str, regulation: str, cfg: ImpactStudyConfig) -> ImpactTaskConfig:
    """The controller configuration of one run
    (:class:`~ffmpc_core.impact.controllers.ImpactTaskController`) from the study's
    configuration."""
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
        touch=cfg.touch if cfg.strategy in LEARNING_STRATEGIES else None,
        strike=cfg.strike if cfg.strategy == "strike_first" else None,
        surface=expected_surface(cfg),
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
            symmetric_speed=cfg.strategy in LEARNING_STRATEGIES and approach == "maximal",
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
            mpc_constraints=cfg.mpc_constraints,
        ),
    )


def expected_surface(cfg: ImpactStudyConfig) -> np.ndarray:
    """The object's surface point the strike-first approach is given (m, world): the centre of
    the dice's top face, where the baseline's target is taken from too (the controller expects
    the surface ``strike.surface_offset`` above it)."""
    x, y = cfg.dice.position_xy
    return np.array([x, y, cfg.dice.top_height])


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


def check_before_motion(config: ImpactStudyConfig) -> None:
    """The learning strategies' checks before any motion (the constructors'), here before a
    study writes anything: raises :class:`~ffmpc_core.errors.InfeasibleTargetError` if the
    touch force is unsafe for the softest plausible material (touch-first), no plausible
    material can hold the target within z̄ (both), or the softest material of a remembered
    interval cannot (strike-first, then instead of the plausible range)."""
    if config.strategy == "strike_first":
        remembered = remembered_interval(config.strike, config.dice.max_penetration)
        if remembered is not None:
            check_force_target(
                config.target_force, remembered, "from the interval a previous run learned"
            )
            return
    elif config.strategy != "touch_first":
        return
    prior = MaterialInterval.from_prior(
        config.prior, config.touch.stiffness_factors, config.touch.damping_factors
    )
    if config.strategy == "touch_first":
        check_force_target(config.touch.touch_force, prior, "the exploratory touch force")
    check_force_target(
        config.target_force,
        prior,
        "even the stiffest plausible material cannot hold it",
        worst_case=False,
    )


# -- the exploration ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Material:
    """A soft object to explore: the truth set in PyBullet.

    Attributes:
        name: label. stiffness: α, N/m. damping: β, N·s/m.
        max_penetration: z̄, m: the elastic-domain bound (eq 12) the exploration stays within.
        impact_velocities: the pre-impact velocities of its exploration, m/s (paper: five in
            0.15–0.35). The impacts stop at 0.6 z̄ by tracking a constant deceleration
            ``v² / (1.2 z̄)``; at the object's place the Panda tracks ≈ 3.5 m/s² downwards
            within 0.9 of its joint limits, so a thin (small z̄) material gets the lower ones.
        note: why these numbers.
    """

    name: str
    stiffness: float
    damping: float
    max_penetration: float
    impact_velocities: tuple[float, ...] = (0.15, 0.2, 0.25, 0.3, 0.35)
    note: str = ""

    def __post_init__(self) -> None:
        if not (np.isfinite(self.stiffness) and self.stiffness > 0):
            raise ConfigError(f"Material.stiffness must be positive, got {self.stiffness}")
        if not (np.isfinite(self.damping) and self.damping >= 0):
            raise ConfigError(f"Material.damping must be >= 0, got {self.damping}")
        v = np.asarray(self.impact_velocities, dtype=float)
        if v.ndim != 1 or not np.all(np.isfinite(v)) or np.any(v <= 0):
            raise ConfigError("Material.impact_velocities must be positive numbers (m/s)")
        if not (np.isfinite(self.max_penetration) and 0 < self.max_penetration <= 0.03):
            raise ConfigError(
                "Material.max_penetration must be in (0, 0.03] m: the Panda hand's underside is "
                f"3.4 cm above the tool tip, got {self.max_penetration}"
            )

    def dice(self) -> DiceConfig:
        """The simulated object (the impact study's fixed cube) with this material."""
        return DiceConfig(
            stiffness=self.stiffness,
            damping=self.damping,
            max_penetration=self.max_penetration,
        )


#: The three materials of the study. Effective mass of the Panda along d at the object ≈ 3 kg
#: (the damping ratios ζ = β / (2 √(α m)) below use it).
MATERIALS: dict[str, Material] = {
    "foam": Material(
        "foam",
        stiffness=800.0,
        damping=8.0,
        max_penetration=0.03,
        note="a soft polyurethane cushion: 14 N at the sinusoid's 18 mm (a 0.16 m block at 11 % "
        "strain), ζ ≈ 0.08",
    ),
    "dice": Material(
        "dice",
        stiffness=3000.0,
        damping=20.0,
        max_penetration=0.03,
        note="the impact study's dice (the paper's 0.16 m soft dice): 54 N at 18 mm, ζ ≈ 0.1",
    ),
    "rubber": Material(
        "rubber",
        stiffness=8000.0,
        damping=60.0,
        max_penetration=0.015,
        impact_velocities=(0.15, 0.2, 0.25),
        note="a stiffer rubber pad, 2.7× the dice: 72 N at the sinusoid's 9 mm, ζ ≈ 0.2; "
        "z̄ = 1.5 cm keeps the force within the Panda's torques, and the impacts to 0.25 m/s "
        "(3.5 m/s² to stop in 9 mm)",
    ),
}


@dataclass(frozen=True)
class ExplorationConfig:
    """One exploration run.

    Attributes:
        material: the object (truth in PyBullet).
        start_clearance: tool height above the top face at the start, m.
        approach_speed: guarded-approach speed, m/s (bounds the surface error: speed · Δt).
        contact_threshold: force that ends the guarded approach, N (paper: 2).
        max_approach_time: s; ConfigError if no contact by then.
        sine_frequency, sine_cycles: the sinusoidal penetration (Hz, periods; amplitude 0.6 z̄).
        impact_velocities: pre-impact velocities, m/s; None = the material's.
        impact_height: the impacts start from rest this far above the surface, m.
        dwell: s at the stop depth after each impact.
        time_step: plant step = control period, s (paper: 1 kHz).
        limit_margin: fraction of the data-sheet acceleration and velocity limits the guard uses.
        lateral_weight: weight of the 5 directions other than d in the guard's QP.
        gains: task-space PD gains (1/s², 1/s).
        prior_stiffness, prior_damping: what the guard assumes for an impact before the
            learner is confident (N/m, N·s/m): the stiffest material expected.
        learner_min_samples, learner_max_relative_std: when the learner is confident enough to
            predict the next force for the guard (samples; relative standard error).
        reflex: the robot's own reflexes (:mod:`ffmpc_core.reflex`): stop on a data-sheet
            limit, run aborted (False: crossings reported only).
    """

    material: Material = field(default_factory=lambda: MATERIALS["dice"])
    start_clearance: float = param(
        0.003, "m", (1e-5, 1.0), "tool height above the top face at the start"
    )
    approach_speed: float = param(0.005, "m/s", (1e-5, 1.0), "guarded-approach speed")
    contact_threshold: float = param(
        2.0, "N", (0.01, 100.0), "force that ends the guarded approach"
    )
    max_approach_time: float = param(3.0, "s", (1e-3, 600.0), "no contact by then: ConfigError")
    sine_frequency: float = param(
        1.0, "Hz", (1e-3, 100.0), "frequency of the sinusoidal penetration"
    )
    sine_cycles: int = param(4, "", (1, 1000), "periods of the sinusoidal penetration")
    impact_velocities: tuple[float, ...] | None = param(
        None, "m/s", (1e-6, 10.0), "pre-impact velocities (null: the material's)"
    )
    impact_height: float = param(
        0.05, "m", (1e-5, 1.0), "the impacts start from rest this far above"
    )
    dwell: float = param(0.3, "s", (0.0, 60.0), "at the stop depth after each impact")
    time_step: float = param(1e-3, "s", (1e-5, 0.01), "plant step = control period")
    limit_margin: float = param(
        0.9, "", (0.01, 1.0), "fraction of the data-sheet q̈ and q̇ limits used"
    )
    lateral_weight: float = param(100.0, "", (1e-6, 1e6), "weight of the 5 directions other than d")
    gains: TaskSpaceGains = field(default_factory=TaskSpaceGains)
    prior_stiffness: float = param(2e4, "N/m", (1.0, 1e7), "α the guard assumes before confidence")
    prior_damping: float = param(
        100.0, "N·s/m", (0.0, 1e5), "β the guard assumes before confidence"
    )
    learner_min_samples: int = param(
        50, "", (3, 10**6), "samples before the learner predicts the force"
    )
    learner_max_relative_std: float = param(
        0.05, "", (1e-9, 10.0), "... and relative standard errors at most"
    )
    reflex: bool = param(True, "", None, "the robot's own reflexes: stop on a limit, run aborted")

    def __post_init__(self) -> None:
        positive = (
            "start_clearance",
            "approach_speed",
            "contact_threshold",
            "max_approach_time",
            "sine_frequency",
            "impact_height",
            "time_step",
            "limit_margin",
            "lateral_weight",
            "prior_stiffness",
            "learner_max_relative_std",
        )
        for name in positive:
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ConfigError(f"ExplorationConfig.{name} must be positive, got {value}")
        if self.limit_margin > 1.0:
            raise ConfigError("limit_margin must be <= 1")
        if not (np.isfinite(self.prior_damping) and self.prior_damping >= 0):
            raise ConfigError("prior_damping must be >= 0")
        if not (np.isfinite(self.dwell) and self.dwell >= 0):
            raise ConfigError("dwell must be >= 0")
        if int(self.sine_cycles) != self.sine_cycles or self.sine_cycles < 1:
            raise ConfigError("sine_cycles must be an integer >= 1")
        if int(self.learner_min_samples) != self.learner_min_samples or (
            self.learner_min_samples < 3
        ):
            raise ConfigError("learner_min_samples must be an integer >= 3")
        if self.impact_velocities is not None:
            v = np.asarray(self.impact_velocities, dtype=float)
            if v.ndim != 1 or not np.all(np.isfinite(v)) or np.any(v <= 0):
                raise ConfigError("impact_velocities must be positive numbers (m/s)")

    @property
    def velocities(self) -> np.ndarray:
        """The pre-impact velocities of this run, m/s."""
        v = self.impact_velocities
        return np.asarray(self.material.impact_velocities if v is None else v, dtype=float)

    def reference(self) -> ExplorationReference:
        """The exploration motion relative to the surface (``exploration_reference``)."""
        return exploration_reference(
            self.material.max_penetration,
            dt=self.time_step,
            sine_frequency=self.sine_frequency,
            sine_cycles=self.sine_cycles,
            impact_velocities=self.velocities,
            approach_height=self.impact_height,
            dwell=self.dwell,
        )


#: Dotted parameter names of ExplorationConfig's fields (see ffmpc_core.scenario.public_name).
#: ``material`` is not a parameter: ``ffmpc study explore --materials`` picks from MATERIALS.
EXPLORATION_NAMES: dict[str, str] = {
    "time_step": "plant.time_step",
    "reflex": "plant.reflex",
    "prior_": "guard.prior_",
    "limit_margin": "guard.limit_margin",
    "lateral_weight": "guard.lateral_weight",
    "learner_": "learner.",
}
#: The exploration study's schema: ``ffmpc study explore --scenario/--set`` and explore.yaml.
EXPLORATION_SCHEMA: ConfigSchema[ExplorationConfig] = ConfigSchema.of(
    ExplorationConfig, EXPLORATION_NAMES, exclude=("material",)
)


def load_exploration_config(
    name_or_path: str = "explore", overrides: dict[str, Any] | None = None
) -> ExplorationConfig:
    """An exploration scenario file (shipped name or path) with ``--set`` overrides (the
    material stays the default; ``run_exploration_study`` sets each one of ``--materials``)."""
    return EXPLORATION_SCHEMA.load(name_or_path, overrides)
