"""Fault injection: what can go wrong in a run, when, and for how long (ROS-free, reusable).

A :class:`Fault` names a kind, a start time and a duration (simulated s). The ROS-free runner
(``studies.polishing.run_polishing(..., faults=[...])``) applies them; ``parse_fault`` reads the
command-line form ``KIND@T[+DURATION]`` (e.g. ``mpc-dropout@0.6+0.05``, ``nan-wrench@0.5``;
without a duration the fault lasts to the end of the run) so that ``ffmpc run --fault`` can
reuse it. Kinds:

* ``mpc-dropout`` — the MPC gives no command (not solved, nothing sent);
* ``sensor-dropout`` — no new joint, torque or force measurement reaches the controllers: the
  MPC is not solved and the low level sees the last measurement received;
* ``torque-spike`` — the MEASURED joint torques τ̂ read by the controllers become ``value``
  (default 1e9 N·m, every joint); the torque applied to the plant is unchanged;
* ``nan-wrench`` — the measured force λ̂ read by the controllers becomes NaN;
* ``future-stamp`` — a message stamped far ahead (:data:`FUTURE_STAMP_AHEAD`) arrives on a
  sensor topic: it must be rejected, never adopted (node graph only);
* ``node-kill`` — a node's process is killed (SIGKILL) at ``start``; ``node-kill:NODE@T`` names
  the node (default :data:`DEFAULT_KILLED_NODE`); the torque loop must hold the robot safely
  (node graph only, multi-process).
* ``loop-stall`` — the real-time loop process (plant, sensors, torque loop) is frozen for
  ``duration`` wall s from the cycle at simulated ``start``, as a preempted process would be;
  the physical plant does not wait: it steps on under the motor torque last sent (real time
  only, ``ffmpc_ros.realtime``);
* ``mpc-stall`` — the real-time MPC process is stopped (SIGSTOP) for ``duration`` wall s from
  simulated ``start`` (real time only).

Where each kind is applied in the node graph (``ffmpc run --fault``): see
``ffmpc_ros.fault_injector``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from ffmpc_core.errors import ConfigError

#: The kinds of fault a run can inject.
FAULT_KINDS = (
    "mpc-dropout",
    "sensor-dropout",
    "torque-spike",
    "nan-wrench",
    "future-stamp",
    "node-kill",
    "loop-stall",
    "mpc-stall",
)
#: The kinds a real-time run injects (``ffmpc_ros.realtime``): process stalls, given a duration.
REALTIME_KINDS = ("loop-stall", "mpc-stall")
#: The kinds the ROS-free run (``studies.polishing.run_polishing``) applies.
RUNNER_KINDS = ("mpc-dropout", "sensor-dropout", "torque-spike", "nan-wrench")
#: How far ahead of the clock a ``future-stamp`` message is stamped, s.
FUTURE_STAMP_AHEAD = 1.0
#: The node ``node-kill`` kills unless one is named.
DEFAULT_KILLED_NODE = "mpc"

_PATTERN = re.compile(r"^\s*([a-z-]+)(?::([a-z_]+))?\s*@\s*([^+\s]+)\s*(?:\+\s*(\S+))?\s*$")


@dataclass(frozen=True)
class Fault:
    """One fault: ``kind`` (one of :data:`FAULT_KINDS`), ``start`` s, ``duration`` s (None: to
    the end of the run), ``value`` (torque-spike: the τ̂ read, N·m), ``node`` (node-kill: the
    node killed; None for the other kinds)."""

    kind: str
    start: float
    duration: float | None = None
    value: float = 1e9
    node: str | None = None

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ConfigError(f"fault kind must be one of {FAULT_KINDS}, got {self.kind!r}")
        if not (math.isfinite(self.start) and self.start >= 0.0):
            raise ConfigError(f"fault start must be a finite time >= 0 s, got {self.start}")
        if self.duration is not None and not (math.isfinite(self.duration) and self.duration > 0.0):
            raise ConfigError(f"fault duration must be > 0 s (or None), got {self.duration}")
        if self.kind == "node-kill":
            if self.node is None:
                object.__setattr__(self, "node", DEFAULT_KILLED_NODE)
            if self.duration is not None:
                raise ConfigError("node-kill takes no duration: a killed node stays dead")
        elif self.kind in REALTIME_KINDS and self.duration is None:
            raise ConfigError(f"{self.kind} needs a duration ({self.kind}@T+DURATION, wall s)")
        elif self.node is not None:
            raise ConfigError(f"only node-kill names a node (node-kill:NODE@T), got {self}")

    @property
    def end(self) -> float:
        """End time, s (inf when the fault lasts to the end)."""
        return math.inf if self.duration is None else self.start + self.duration

    def active(self, t: float, eps: float = 1e-9) -> bool:
        """True at time t (s) within [start, end)."""
        return self.start - eps <= t < self.end - eps

    def __str__(self) -> str:
        tail = "" if self.duration is None else f"+{self.duration:g}"
        node = "" if self.node is None else f":{self.node}"
        return f"{self.kind}{node}@{self.start:g}{tail}"


def parse_fault(text: str) -> Fault:
    """``KIND[:NODE]@T[+DURATION]`` (seconds) → Fault; ConfigError with the expected form
    otherwise (``:NODE`` only for node-kill)."""
    match = _PATTERN.match(text)
    if match is None:
        raise ConfigError(
            f"fault {text!r}: expected KIND@T[+DURATION] or node-kill:NODE@T, e.g. "
            "mpc-dropout@0.6+0.05"
        )
    kind, node, start, duration = match.groups()
    try:
        t0, length = float(start), None if duration is None else float(duration)
    except ValueError:
        raise ConfigError(f"fault {text!r}: T and DURATION must be numbers (s)") from None
    return Fault(kind, t0, length, node=node)


def faults_from(items: Iterable[Fault | str] | None) -> tuple[Fault, ...]:
    """A tuple of Faults from Faults and/or ``KIND@T[+DURATION]`` strings (None: none)."""
    if items is None:
        return ()
    return tuple(item if isinstance(item, Fault) else parse_fault(item) for item in items)


def require_kinds(faults: Sequence[Fault], supported: Sequence[str], where: str) -> None:
    """ConfigError (one line) naming the first fault whose kind ``where`` cannot inject."""
    for fault in faults:
        if fault.kind not in supported:
            raise ConfigError(
                f"fault {fault}: {fault.kind} is not supported in {where} "
                f"(supported there: {', '.join(supported) or 'none'})"
            )


def active_kinds(faults: Sequence[Fault], t: float) -> dict[str, Fault]:
    """The faults active at t (s), by kind (the first listed wins for a kind)."""
    out: dict[str, Fault] = {}
    for fault in faults:
        if fault.kind not in out and fault.active(t):
            out[fault.kind] = fault
    return out


__all__ = [
    "DEFAULT_KILLED_NODE",
    "FAULT_KINDS",
    "FUTURE_STAMP_AHEAD",
    "REALTIME_KINDS",
    "RUNNER_KINDS",
    "Fault",
    "active_kinds",
    "faults_from",
    "parse_fault",
    "require_kinds",
]
