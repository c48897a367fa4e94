"""The simulated scenes of the experiments: which plant a scenario runs on.

Plant-side only: the scenario is pure data in ``ffmpc_core``; this module turns it into a
:class:`~sim_bridge.plant.PlantConfig` and a plant of the scenario's engine (``plant.engine``:
:func:`make_plant`, the PyBullet plant :class:`sim_bridge.plant.Plant` or the MuJoCo plant
:class:`sim_bridge.mujoco_plant.MujocoPlant`, the same configuration and state). The polishing
scenes (:class:`~ffmpc_core.scenario.Scenario`: the tilted table, the actuation model of eq 31, the
external push; :func:`polishing_plant_config`, :func:`simulated_robot`, used by the ROS-free run,
the plant node and the real-time loop alike) and the impact and exploration scenes
(:mod:`ffmpc_core.impact.scenario`: no table, the fixed soft dice, the spherical tool).
PyBullet (and MuJoCo) are imported on first use of a function, not to import this module, so a
study's settings parse without them.

Units: m, s, N/m, N·s/m; positions in the world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

import numpy as np

from ffmpc_core.actuation import ActuationModel
from ffmpc_core.errors import ConfigError
from ffmpc_core.polishing import (
    PolishingSchedule,
    RunDraws,
    actuation_model,
    build_task,
    draw_run,
    tool_load,
)
from ffmpc_core.reflex import ReflexPlant, reflex_plant
from ffmpc_core.robots import RobotModel
from ffmpc_core.scenario import PLANT_ENGINES, Scenario

if TYPE_CHECKING:  # the plant imports PyBullet: loaded when a scene is built, not to parse
    from ffmpc_core.impact.scenario import DiceConfig, ImpactStudyConfig
    from sim_bridge.plant import PlantConfig, PlantState, SoftBoxConfig

__all__ = [
    "EXPLORATION_TOOL_RADIUS",
    "ScenePlant",
    "SimulatedRobot",
    "make_plant",
    "polishing_plant_config",
    "simulated_robot",
    "dice_box",
    "exploration_plant_config",
    "impact_plant_config",
]

#: Radius of the exploration's spherical tool, m: larger than any z̄ (3 cm), so that the sphere's
#: centre stays above the surface (with the 1 cm sphere, Bullet's persistent contact manifold
#: held a second contact point for 7 steps once the centre was below it, doubling the force;
#: see :mod:`studies.exploration`).
EXPLORATION_TOOL_RADIUS = 0.04


class ScenePlant(Protocol):
    """What the experiments use of a simulated plant, whatever its engine: the
    :class:`ffmpc_core.plant.Plant` shape with :class:`~sim_bridge.plant.PlantState`, the
    external push, the table normal and the plant's lifetime (both :class:`sim_bridge.plant.Plant`
    and :class:`sim_bridge.mujoco_plant.MujocoPlant` have it)."""

    dt: float
    robot: RobotModel
    config: PlantConfig

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None: ...

    def step(self, tau: np.ndarray, /) -> None: ...

    def state(self) -> PlantState: ...

    def apply_external_push(
        self, force_world: np.ndarray, steps: int, link: str | None = None
    ) -> None: ...

    @property
    def t(self) -> float: ...

    @property
    def table_normal(self) -> np.ndarray: ...

    def close(self) -> None: ...

    def __enter__(self) -> ScenePlant: ...

    def __exit__(self, *exc: object) -> None: ...


def make_plant(robot: RobotModel, config: PlantConfig, engine: str = "pybullet") -> ScenePlant:
    """The plant of ``config`` in the simulator ``engine`` (:data:`PLANT_ENGINES`; ConfigError
    for another name); the engine's module is imported here."""
    if engine == "pybullet":
        from sim_bridge.plant import Plant

        return Plant(robot, config)
    if engine == "mujoco":
        from sim_bridge.mujoco_plant import MujocoPlant

        return MujocoPlant(robot, config)
    raise ConfigError(f"plant engine must be one of {PLANT_ENGINES}, got {engine!r}")


def dice_box(dice: DiceConfig) -> SoftBoxConfig:
    """The plant's box of ``dice``: static (Bullet mass 0), its centre ``size/2`` below the
    top face, the dice's true stiffness (N/m), damping (N·s/m), friction and collision margin."""
    from sim_bridge.plant import SoftBoxConfig

    x, y = dice.position_xy
    return SoftBoxConfig(
        position=(float(x), float(y), dice.top_height - 0.5 * dice.size),
        stiffness=dice.stiffness,
        damping=dice.damping,
        size=(dice.size, dice.size, dice.size),
        mass=0.0,
        lateral_friction=dice.lateral_friction,
        collision_margin=dice.collision_margin,
    )


def impact_plant_config(cfg: ImpactStudyConfig) -> PlantConfig:
    """The plant configuration of the impact experiment (its engine: ``cfg.engine``): no table,
    the dice, the spherical tool of radius ``cfg.tool_radius`` (m), stepped every
    ``cfg.time_step`` (s)."""
    from sim_bridge.plant import PlantConfig, ToolConfig

    return PlantConfig(
        time_step=cfg.time_step,
        table=None,
        soft_boxes=(dice_box(cfg.dice),),
        tool=ToolConfig(radius=cfg.tool_radius),
    )


def exploration_plant_config(dice: DiceConfig, time_step: float) -> PlantConfig:
    """The PyBullet plant of the exploration: no table, the object ``dice`` (a material's
    :meth:`~ffmpc_core.impact.scenario.Material.dice`), the :data:`EXPLORATION_TOOL_RADIUS`
    sphere, stepped every ``time_step`` (s)."""
    from sim_bridge.plant import PlantConfig, ToolConfig

    return PlantConfig(
        time_step=time_step,
        table=None,
        soft_boxes=(dice_box(dice),),
        tool=ToolConfig(radius=EXPLORATION_TOOL_RADIUS),
    )


def polishing_plant_config(scenario: Scenario, task: PolishingSchedule, tilt: float) -> PlantConfig:
    """Table tilted by θ about an axis through the circle centre (or the contact point); the
    scenario's tool on the flange (``plant.tool_mass`` at ``plant.tool_center_of_mass``)."""
    from sim_bridge.plant import PlantConfig, TableConfig, ToolConfig

    p = scenario.plant
    load = tool_load(scenario)  # the tool on the flange: the same numbers as the controllers'
    tool = ToolConfig(radius=load.radius)
    if load.mass > 0.0:
        tool = ToolConfig(radius=load.radius, mass=load.mass, center_of_mass=load.center_of_mass)
    pivot = task.circle_center() if hasattr(task, "circle_center") else task.contact_position
    table = TableConfig(
        surface_point=tuple(pivot),
        tilt_angle=tilt,
        tilt_axis=p.table_tilt_axis,
        stiffness=p.table_stiffness,
        damping=p.table_damping,
        lateral_friction=p.table_friction,
    )
    return PlantConfig(time_step=p.time_step, table=table, tool=tool)


@dataclass
class SimulatedRobot:
    """The simulated side of one run, built from its scenario (:func:`simulated_robot`): the
    run's random draws, the task, the actuation model of eq 31, the plant of the scenario's
    engine (``plant.engine``) reset to the nominal posture, the same plant with the robot's
    reflexes (``reflex_plant``: step the robot through it, :mod:`ffmpc_core.reflex`; on unless
    ``plant.reflex`` is false), and the external push (cycle ``push_at``, −1 for none;
    ``push_steps`` cycles of ``push_force`` N, world frame). The ROS-free runner, the plant node
    and the real-time loop all build it here, so they simulate the same robot."""

    draws: RunDraws
    task: PolishingSchedule
    actuation: ActuationModel
    plant: ScenePlant
    reflex_plant: ReflexPlant[PlantState]
    push_at: int
    push_steps: int
    push_force: np.ndarray
    push_rise_steps: int = 0

    def push_if_due(self, k: int) -> None:
        """Apply the external push of cycle k: the whole push at its first cycle when it is a
        step (``push_rise_steps`` 0), else this cycle's share of its envelope
        (:func:`push_envelope`)."""
        if self.push_rise_steps == 0:
            if k == self.push_at:
                self.plant.apply_external_push(self.push_force, self.push_steps)
        elif 0 <= self.push_at <= k < self.push_at + self.push_steps:
            scale = push_envelope(k - self.push_at, self.push_steps, self.push_rise_steps)
            self.plant.apply_external_push(scale * self.push_force, 1)


def push_envelope(step: int, steps: int, rise_steps: int) -> float:
    """The push force's fraction (0–1) at physics step ``step`` of a push of ``steps`` steps
    whose force rises and falls along a raised cosine over ``rise_steps`` steps each
    (``plant.push_rise_time``), sampled at the middle of the step; 1 throughout when
    ``rise_steps`` is 0."""
    if rise_steps <= 0:
        return 1.0
    edge = min(step + 0.5, steps - step - 0.5) / rise_steps
    return 0.5 - 0.5 * math.cos(math.pi * min(1.0, max(0.0, edge)))


def simulated_robot(
    scenario: Scenario,
    robot: RobotModel,
    draw_rng: np.random.Generator,
    actuation_rng: np.random.Generator,
) -> SimulatedRobot:
    """Draw the run (tilt, actuation bias) and build the task, actuation and plant of a scenario;
    the generators are the run's ``draws`` and ``actuation`` devices (``spawn_generators``)."""
    draws = draw_run(scenario, robot, draw_rng)
    task = build_task(scenario, robot)
    actuation = actuation_model(scenario, robot, draws, actuation_rng)
    config = polishing_plant_config(scenario, task, draws.tilt_angle)
    plant = make_plant(robot, config, scenario.plant.engine)
    plant.reset(robot.q_nominal)
    p, dt = scenario.plant, scenario.plant.time_step
    return SimulatedRobot(
        draws=draws,
        task=task,
        actuation=actuation,
        plant=plant,
        reflex_plant=reflex_plant(plant, robot, enabled=p.reflex),
        push_at=int(round(p.push_time / dt)) if p.push_enabled else -1,
        push_steps=int(round(p.push_duration / dt)),
        push_force=np.array(p.push_force, dtype=float),
        push_rise_steps=int(round(p.push_rise_time / dt)),
    )
