"""PyBullet side of ffmpc: the simulated plant (ROS-free) and, later, the node around it."""

from sim_bridge.plant import (
    Plant,
    PlantConfig,
    PlantState,
    SoftBoxConfig,
    TableConfig,
    ToolConfig,
    model_with_tool,
    tool_spatial_inertia,
)

__all__ = [
    "Plant",
    "PlantConfig",
    "PlantState",
    "SoftBoxConfig",
    "TableConfig",
    "ToolConfig",
    "model_with_tool",
    "tool_spatial_inertia",
]
