"""How the studies report the robot's reflexes (:mod:`ffmpc_core.reflex`): the aborted runs of
a table, a cell per run, and the line under a table that says whether the reflex was on.

Every study table counts its aborted runs (a run a reflex stopped: the robot braked to rest on
its own and ignored the controllers from then on). A study run with the reflexes off
(``plant.reflex: false``) says so: nothing was stopped, and the count is of the runs that
WOULD have been aborted (the crossing each would have stopped on is in its summary).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["aborted_count", "reflex_cell", "reflex_note", "reflexes_enabled"]


def _event(report: dict[str, Any] | None) -> dict[str, Any] | None:
    return (report or {}).get("event")


def aborted_count(reports: Sequence[dict[str, Any] | None]) -> int:
    """Runs with a crossing the robot stops on: aborted (reflex on) or that would have been
    (reflex off). A report of ``RobotReflex.report`` per run (None or {}: no reflex ran)."""
    return sum(1 for r in reports if _event(r) is not None)


def reflexes_enabled(reports: Sequence[dict[str, Any] | None]) -> bool | None:
    """True if every run had its reflexes on, False if every one had them off, None if mixed
    or unknown (no report)."""
    states = {bool(r["enabled"]) for r in reports if r and "enabled" in r}
    return states.pop() if len(states) == 1 else None


def reflex_cell(report: dict[str, Any] | None) -> str:
    """One run's table cell: "aborted: velocity joint 4 at 2.345 s" (with the reflex off:
    "would abort: ..."), "—" without a crossing."""
    event = _event(report)
    if event is None:
        return "—"
    where = "" if event["joint"] is None else f" joint {event['joint'] + 1}"
    verb = "aborted" if event["stopped"] else "would abort"
    return f"{verb}: {event['kind']}{where} at {event['t']:.3f} s"


def reflex_note(reports: Sequence[dict[str, Any] | None]) -> str:
    """The line under a study table: how many of its runs a reflex aborted, and whether the
    reflexes were on (off: the count is of the runs that would have been aborted)."""
    total, aborted = len(reports), aborted_count(reports)
    enabled = reflexes_enabled(reports)
    if enabled is False:
        return (
            f"Reflexes OFF (`plant.reflex: false`): nothing was stopped, the metrics include the "
            f"raw excess; {aborted} of {total} runs would have been aborted by the robot's own "
            "reflexes (a data-sheet limit it stops on, or commands missing)."
        )
    mixed = " (reflexes on in some runs only)" if enabled is None and total else ""
    return (
        f"Aborted by the robot's own reflexes (a data-sheet limit it stops on, or commands "
        f"missing; `ffmpc_core.reflex`): {aborted} of {total} runs{mixed}."
    )
