"""PyBullet side of ffmpc: the simulated plant (ROS-free), the closed-loop runner and the
impact and exploration scenes (:mod:`sim_bridge.scenes`).

The experiments run on them live in :mod:`studies`, the top layer. The plant's names are
imported on first use (``from sim_bridge import Plant``), so that importing the package does
not load PyBullet.
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
