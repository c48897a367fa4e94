"""The simulated scenes of the impact and exploration experiments: which PyBullet plant a
scenario of :mod:`ffmpc_core.impact.scenario` runs on.

Plant-side only: the scenario (what the dice is, where, the tool radius) is pure data in
``ffmpc_core``; this module turns it into a :class:`~sim_bridge.plant.PlantConfig` (no table, the
fixed soft dice, the spherical tool). PyBullet is imported on first use of a function (through
:mod:`sim_bridge.plant`), not to import this module, so a study's settings parse without it.

Units: m, s, N/m, N·s/m; positions in the world frame.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the plant imports PyBullet: loaded when a scene is built, not to parse
    from ffmpc_core.impact.scenario import DiceConfig, ImpactStudyConfig
    from sim_bridge.plant import PlantConfig, SoftBoxConfig

__all__ = [
    "EXPLORATION_TOOL_RADIUS",
    "dice_box",
    "exploration_plant_config",
    "impact_plant_config",
]

#: Radius of the exploration's spherical tool, m: larger than any z̄ (3 cm), so that the sphere's
#: centre stays above the surface (with the 1 cm sphere, Bullet's persistent contact manifold
#: held a second contact point for 7 steps once the centre was below it, doubling the force;
#: see :mod:`studies.exploration`).
EXPLORATION_TOOL_RADIUS = 0.04


def dice_box(dice: DiceConfig) -> SoftBoxConfig:
    """The PyBullet box of ``dice``: static (Bullet mass 0), its centre ``size/2`` below the
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
    """The PyBullet plant of the impact experiment: no table, the dice, the spherical tool of
    radius ``cfg.tool_radius`` (m), stepped every ``cfg.time_step`` (s)."""
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
