"""Fault injection: what can go wrong in a run, when, and for how long (ROS-free, reusable).

A :class:`Fault` names a kind, a start time and a duration (simulated s). The ROS-free runner
(``sim_bridge.runner.run_scenario(..., faults=[...])``) applies them; ``parse_fault`` reads the
command-line form ``KIND@T[+DURATION]`` (e.g. ``mpc-dropout@0.6+0.05``, ``nan-wrench@0.5``;
without a duration the fault lasts to the end of the run) so that ``ffmpc run --fault`` can
reuse it. Kinds:

* ``mpc-dropout`` — the MPC gives no command (not solved, nothing sent);
* ``sensor-dropout`` — no new joint, torque or force measurement reaches the controllers: the
  MPC is not solved and the low level sees the last measurement received;
* ``torque-spike`` — the MEASURED joint torques τ̂ read by the controllers become ``value``
  (default 1e9 N·m, every joint); the torque applied to the plant is unchanged;
* ``nan-wrench`` — the measured force λ̂ read by the controllers becomes NaN.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from ffmpc_core.errors import ConfigError

#: The kinds of fault a run can inject.
FAULT_KINDS = ("mpc-dropout", "sensor-dropout", "torque-spike", "nan-wrench")

_PATTERN = re.compile(r"^\s*([a-z-]+)\s*@\s*([^+\s]+)\s*(?:\+\s*(\S+))?\s*$")


@dataclass(frozen=True)
class Fault:
    """One fault: ``kind`` (one of :data:`FAULT_KINDS`), ``start`` s, ``duration`` s (None: to
    the end of the run), ``value`` (torque-spike: the τ̂ read, N·m)."""

    kind: str
    start: float
    duration: float | None = None
    value: float = 1e9

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise ConfigError(f"fault kind must be one of {FAULT_KINDS}, got {self.kind!r}")
        if not (math.isfinite(self.start) and self.start >= 0.0):
            raise ConfigError(f"fault start must be a finite time >= 0 s, got {self.start}")
        if self.duration is not None and not (math.isfinite(self.duration) and self.duration > 0.0):
            raise ConfigError(f"fault duration must be > 0 s (or None), got {self.duration}")

    @property
    def end(self) -> float:
        """End time, s (inf when the fault lasts to the end)."""
        return math.inf if self.duration is None else self.start + self.duration

    def active(self, t: float, eps: float = 1e-9) -> bool:
        """True at time t (s) within [start, end)."""
        return self.start - eps <= t < self.end - eps

    def __str__(self) -> str:
        tail = "" if self.duration is None else f"+{self.duration:g}"
        return f"{self.kind}@{self.start:g}{tail}"


def parse_fault(text: str) -> Fault:
    """``KIND@T[+DURATION]`` (seconds) → Fault; ConfigError with the expected form otherwise."""
    match = _PATTERN.match(text)
    if match is None:
        raise ConfigError(f"fault {text!r}: expected KIND@T[+DURATION], e.g. mpc-dropout@0.6+0.05")
    kind, start, duration = match.groups()
    try:
        return Fault(kind, float(start), None if duration is None else float(duration))
    except ValueError:
        raise ConfigError(f"fault {text!r}: T and DURATION must be numbers (s)") from None


def faults_from(items: Iterable[Fault | str] | None) -> tuple[Fault, ...]:
    """A tuple of Faults from Faults and/or ``KIND@T[+DURATION]`` strings (None: none)."""
    if items is None:
        return ()
    return tuple(item if isinstance(item, Fault) else parse_fault(item) for item in items)


def active_kinds(faults: Sequence[Fault], t: float) -> dict[str, Fault]:
    """The faults active at t (s), by kind (the first listed wins for a kind)."""
    out: dict[str, Fault] = {}
    for fault in faults:
        if fault.kind not in out and fault.active(t):
            out[fault.kind] = fault
    return out


__all__ = ["FAULT_KINDS", "Fault", "active_kinds", "faults_from", "parse_fault"]
