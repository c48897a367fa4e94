"""Input validation and rejection counting of one node: what a node's callbacks call first.

A message is rejected when the node is not active (kind ``<topic>:inactive``), it is malformed
(NaN/Inf, wrong length, unknown or missing joint names, wrong frame_id: ``<topic>:value``, from
the parser, :mod:`ffmpc_ros.message_parsing`), stamped with no time (negative, nanosec ≥ 10⁹:
``<topic>:stamp``), of a cycle not after the last accepted one from the same topic (out of order,
duplicate, or a second sample within one cycle: ``<topic>:order``), older than ``max_input_age``
on the node's simulated clock (``<topic>:stale``), or stamped more than
:data:`MAX_FUTURE_STAMP` ahead of the node's clock (``<topic>:future``: never adopted, so a
spoofed or corrupted stamp cannot make every genuine message look old). A rejected message
changes nothing; the gate logs one warning per kind of rejection and per :data:`LOG_THROTTLE`
seconds (wall time), and counts every rejection in :attr:`InputGate.rejected` (reported by the
node's diagnostics and its results file, :mod:`ffmpc_ros.node_results`).
"""

from __future__ import annotations

import math
import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from builtin_interfaces.msg import Time as TimeMsg

from ffmpc_core.errors import InputError
from ffmpc_ros.time_grid import TimeGrid, cycle_at, stamp_ns

#: Minimum wall time between two log lines of the same kind, s.
LOG_THROTTLE = 2.0
#: A stamp more than this ahead of the node's clock is rejected (from the future), s. Ten plant
#: cycles: far above the reordering of ``/clock`` and data topics between two processes (at most
#: a cycle or two in lockstep), far below any delay a spoofed stamp could hide behind.
MAX_FUTURE_STAMP = 0.01


class ThrottledLog:
    """Log lines of a node, at most one per kind per :data:`LOG_THROTTLE` s of wall time.

    Args:
        logger: returns the node's logger (rclpy's ``get_logger``); a logger that fails (the
            node shutting down) is ignored.
        clock: wall time, s (``time.monotonic``; tests pass their own).
    """

    def __init__(self, logger: Callable[[], Any], clock: Callable[[], float] = time.monotonic):
        self._logger = logger
        self._clock = clock
        self._last: dict[str, float] = {}
        self.lines: Counter[str] = Counter()  # lines logged per kind

    def line(self, kind: str, text: Callable[[], str], warning: bool) -> bool:
        """Log ``text()`` (a warning or an info line) unless a line of ``kind`` was logged less
        than LOG_THROTTLE s ago; True when it was logged (counted in :attr:`lines`)."""
        now = self._clock()
        last = self._last.get(kind)
        if last is not None and now - last < LOG_THROTTLE:
            return False
        self._last[kind] = now
        self.lines[kind] += 1
        try:
            logger = self._logger()
            (logger.warning if warning else logger.info)(text())
        except Exception:  # noqa: BLE001  (shutting down: the logger's context is gone)
            pass
        return True


class InputGate:
    """The checks every input of a node passes (module docstring), and their counts.

    Args:
        grid: the plant's time grid.
        log: the node's throttled log.
        name_of: the fully qualified name of a graph topic (the key of the counts).
        now_ns: the node's clock, ns (simulated time).
        has_time: whether the node got a /clock sample (a clock still at 0 without one cannot
            tell a stamp from the future).
        state: the node's lifecycle state (inputs count only while ``"active"``).
        max_input_age: the oldest input accepted, s of simulated time.
    """

    def __init__(
        self,
        grid: TimeGrid,
        log: ThrottledLog,
        *,
        name_of: Callable[[str], str],
        now_ns: Callable[[], int],
        has_time: Callable[[], bool],
        state: Callable[[], str],
        max_input_age: float = math.inf,
    ) -> None:
        self.grid = grid
        self.log = log
        self._name_of = name_of
        self._now_ns = now_ns
        self._has_time = has_time
        self._state = state
        self.max_input_age = float(max_input_age)
        self.rejected: Counter[str] = Counter()  # rejections per kind
        self.accepted: Counter[str] = Counter()  # accepted inputs per topic
        self._last_cycle: dict[str, int] = {}  # newest accepted cycle per topic

    def reject(self, kind: str, message: str) -> None:
        """Count a rejection and log it (at most one line per kind per LOG_THROTTLE s)."""
        self.rejected[kind] += 1
        self.log.line(
            kind,
            lambda: f"rejected {kind}: {message} ({self.rejected[kind]} so far; output kept safe)",
            warning=True,
        )

    def inform(self, kind: str, message: str) -> None:
        """Log an info line, at most one per kind per LOG_THROTTLE s."""
        self.log.line(kind, lambda: message, warning=False)

    def check_stamp(self, topic: str, stamp: TimeMsg) -> int | None:
        """The cycle of an input's stamp if :meth:`check_cycle` accepts it (judged by the stamp
        itself: from the future, stale); otherwise reject it and return None. Call
        :meth:`accept` once the whole message is accepted."""
        topic = self._name_of(topic)
        state = self._state()
        if state != "active":
            self.reject(f"{topic}:inactive", f"{topic} ignored: the node is {state}")
            return None
        ns = stamp_ns(stamp)
        if ns is None:
            self.reject(f"{topic}:stamp", f"stamp {stamp.sec}.{stamp.nanosec:09d} is no time")
            return None
        k = cycle_at(ns, self.grid.step_ns)
        return k if self.check_cycle(topic, k, ns) else None

    def check_cycle(
        self, topic: str, k: int, stamp: int | None = None, ordered: bool = True
    ) -> bool:
        """Whether an input of cycle k stamped ``stamp`` (ns; default t_k) may be used: of a
        cycle after the last accepted one from ``topic`` (unless not ``ordered``: the caller
        keeps its own order, the PID's commands), stamped at most :data:`MAX_FUTURE_STAMP` ahead
        of the node's clock and at most ``max_input_age`` behind it. Rejects it otherwise."""
        topic = self._name_of(topic)
        last = self._last_cycle.get(topic)
        if ordered and last is not None and k <= last:
            self.reject(f"{topic}:order", f"cycle {k} is not after the last accepted {last}")
            return False
        now_ns = self._now_ns()
        stamp = k * self.grid.step_ns if stamp is None else stamp
        ahead = (stamp - now_ns) * 1e-9
        # A node that has no time yet (no /clock sample on either reader, the clock at 0) cannot
        # tell a stamp from the future: it judges from its first /clock on. Seen: a lockstep
        # MPC whose clock stayed at 0 for 11 cycles rejected genuine inputs, and the run
        # diverged from the runner (3 of 20 launches under load).
        no_time_yet = now_ns == 0 and not self._has_time()
        if ahead > MAX_FUTURE_STAMP and not no_time_yet:
            self.reject(
                f"{topic}:future",
                f"stamp {stamp * 1e-9:.6f} s is {ahead:.4f} s ahead of this node's clock "
                f"({now_ns * 1e-9:.6f} s; tolerance {MAX_FUTURE_STAMP} s)",
            )
            return False
        if now_ns > 0 and -ahead > self.max_input_age:
            self.reject(f"{topic}:stale", f"stamp {stamp * 1e-9:.6f} s is {-ahead:.4f} s old")
            return False
        return True

    def accept(self, topic: str, k: int) -> None:
        """Record an accepted input of cycle k (the newest cycle accepted from ``topic``)."""
        topic = self._name_of(topic)
        self._last_cycle[topic] = max(k, self._last_cycle.get(topic, k))
        self.accepted[topic] += 1

    def last_cycle(self, topic: str) -> int:
        """The newest cycle accepted from ``topic`` (-1: none yet)."""
        return self._last_cycle.get(self._name_of(topic), -1)

    def receive(self, topic: str, msg: Any, parse: Callable[[Any], Any]) -> tuple[int, Any] | None:
        """Check the stamp of ``msg``, parse it, accept its cycle: ``(k, parse(msg))``, or None
        when the stamp or the values are rejected (``parse`` raises InputError for bad values)."""
        topic = self._name_of(topic)
        k = self.check_stamp(topic, msg.header.stamp)
        if k is None:
            return None
        try:
            value = parse(msg)
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            return None
        self.accept(topic, k)
        return k, value
