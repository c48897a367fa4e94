"""The status topic and diagnostics of a low-level node (the torque PID, the
linear_feedback_controller law): one part both nodes compose.

Each cycle the node publishes its status (layout ``lowlevel_status``: t (s), mode, the age of the
newest command (s, simulated; 10⁹ for none yet), the blend factor and the node's rejections so
far). Its diagnostics add the loop's mode (hold, blend, track, fallback) and the command's age,
and report an ERROR while the loop is in its safe hold (FALLBACK) after the commands went stale or
were refused.
"""

from __future__ import annotations

from collections import Counter

import numpy as np
from rclpy.publisher import Publisher

from ffmpc_core.lowlevel import LowLevelMode, LowLevelOutput
from ffmpc_ros import layouts

#: The command age published before any command came, s.
NO_COMMAND_AGE = 1e9


class LowLevelReport:
    """A low-level node's status and diagnostics (module docstring).

    Args:
        status: the node's status publisher (layout ``lowlevel_status``).
        rejected: the node's rejections per kind (read, never changed).
        command: what the loop tracks, for the messages (``"MPC command"``, ``"Control"``).
        age_key: the diagnostics key of the command's age (s).
    """

    def __init__(
        self, status: Publisher, rejected: Counter[str], command: str, age_key: str
    ) -> None:
        self._status = status
        self._rejected = rejected
        self._command = command
        self._age_key = age_key
        self.last_output: LowLevelOutput | None = None  # the newest cycle's output

    def publish(self, t: float, out: LowLevelOutput) -> None:
        """The status of the cycle of time ``t`` (s) that gave ``out``."""
        self.last_output = out
        age = out.command_age if np.isfinite(out.command_age) else NO_COMMAND_AGE
        self._status.publish(
            layouts.LOWLEVEL_STATUS.pack(
                {
                    "t": t,
                    "mode": float(out.mode),
                    "command_age": age,
                    "blend": out.blend,
                    "rejected": float(sum(self._rejected.values())),
                }
            )
        )

    def values(self) -> dict[str, str]:
        """The loop's mode and the command's age (s, simulated), for the diagnostics."""
        out = self.last_output
        if out is None:
            return {"mode": "none (no cycle yet)"}
        return {"mode": out.mode.name.lower(), self._age_key: f"{out.command_age:.4f}"}

    def problems(self) -> list[str]:
        """The safe hold after the commands went stale or were refused (FALLBACK)."""
        out = self.last_output
        if out is not None and out.mode == LowLevelMode.FALLBACK:
            return [f"safe hold: no fresh {self._command} (age {out.command_age:.4f} s)"]
        return []
