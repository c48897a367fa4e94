"""The time grid of the node graph: every stamp is a plant cycle, t_k = k·``plant.time_step``.

The plant publishes the state of cycle k with stamp t_k, and everything computed from it carries
the same stamp. A node turns a stamp back into the cycle index k and computes t as
``k * time_step``, exactly as the ROS-free runner does, so both paths hand bit-identical times to
the controllers. A stamp off the grid (a driver's own clock: t_k + 0.37 ms) belongs to the newest
cycle at or before it, t_k ≤ stamp < t_{k+1}, a stamp less than :data:`GRID_TOLERANCE_NS` before
t_{k+1} counting as cycle k + 1 (:func:`cycle_at`); the controllers then take it as the
measurement of t_k. Its own stamp, not t_k, is judged against the node's clock
(:class:`ffmpc_ros.input_gate.InputGate`: stale, from the future).

No rclpy here but the ``builtin_interfaces/Time`` message: the grid is plain arithmetic.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

from builtin_interfaces.msg import Time as TimeMsg

#: A stamp less than this before a cycle belongs to that cycle (a driver's clock rounded to the
#: grid), ns; every other stamp belongs to the newest cycle at or before it.
GRID_TOLERANCE_NS = 1000


def stamp_ns(stamp: TimeMsg) -> int | None:
    """A ROS stamp in ns, or None when it is no time (negative, or nanosec ≥ 10⁹)."""
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if sec < 0 or not 0 <= nanosec < 1_000_000_000:
        return None
    return sec * 1_000_000_000 + nanosec


def stamp_at(k: int, step_ns: int) -> TimeMsg:
    """The stamp of cycle k on a grid of ``step_ns`` (t_k = k·step_ns ns): the inverse of
    :func:`cycle_at`."""
    sec, nanosec = divmod(k * step_ns, 1_000_000_000)
    return TimeMsg(sec=int(sec), nanosec=int(nanosec))


def cycle_at(ns: int, step_ns: int) -> int:
    """The cycle a time of ``ns`` ≥ 0 belongs to on a grid of ``step_ns``: the newest cycle at
    or before it, within :data:`GRID_TOLERANCE_NS` (module docstring)."""
    return (ns + GRID_TOLERANCE_NS) // step_ns


def drop_stale_cycles(stores: Iterable[dict[int, Any]], newest: int, keep: int) -> None:
    """The cycle synchroniser's clean-up: delete from each per-cycle store (cycle k → input)
    every entry of a cycle before ``newest − keep``, an input whose partners never came."""
    oldest = newest - keep
    for store in stores:
        for old in [c for c in store if c < oldest]:
            del store[old]


class TimeGrid:
    """The cycles of a plant of time step ``time_step`` (s): stamps ↔ cycle index ↔ time."""

    def __init__(self, time_step: float) -> None:
        self.time_step = float(time_step)  # s
        self.step_ns = int(round(self.time_step * 1e9))  # ns

    def cycle_of(self, stamp: TimeMsg) -> int | None:
        """The cycle k a stamp belongs to (module docstring): the newest cycle at or before it;
        None for a stamp no ROS time can be (negative, or nanosec ≥ 10⁹)."""
        ns = stamp_ns(stamp)
        return None if ns is None else cycle_at(ns, self.step_ns)

    def cycle_of_time(self, t: float) -> int | None:
        """The cycle k of a time t = k·time_step (s), or None when t is off the grid (or not a
        time a ROS stamp can hold: negative, non-finite, or 2³¹ s and beyond)."""
        if not math.isfinite(t) or t < 0 or t >= 2.0**31:
            return None
        k = int(round(t / self.time_step))
        return k if abs(t - k * self.time_step) <= 1e-6 * self.time_step else None

    def stamp_of(self, k: int) -> TimeMsg:
        """The stamp of cycle k (t_k = k·time_step)."""
        return stamp_at(k, self.step_ns)

    def t_of(self, k: int) -> float:
        """t_k = k·time_step, s (the runner's float, bit for bit)."""
        return k * self.time_step
