"""PyBullet side of ffmpc: the simulated plant (ROS-free) and the studies run on it.

The plant's names are imported on first use (``from sim_bridge import Plant``), so that
importing a light module of the package (``sim_bridge.study``'s output-directory rule, for the
command line's early checks) does not load PyBullet.
"""

from __future__ import annotations

import importlib
from typing import Any

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


def __getattr__(name: str) -> Any:
    if name in __all__:
        return getattr(importlib.import_module("sim_bridge.plant"), name)
    raise AttributeError(f"module 'sim_bridge' has no attribute {name!r}")
