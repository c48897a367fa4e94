"""Tabulate ``ffmpc study impact`` runs over dice that are not the prior (issues 12 and 24).

Reads every ``*/results.json`` under ``ROOT`` (one ``ffmpc study impact --dice-stiffness K
--dice-damping B [--strategies ...]`` output directory per dice) and prints a Markdown table:
one row per maximal run (strategy, regulation) and per baseline run, with the touch and
pre-impact velocities, the time to contact and to a steady force and both against the baseline
run of the same regulation on the same dice, the peak penetration against z̄, the peak and
final force, the joint-limit violations and the refusal or the regulation's stop short of the
target.

    python benchmarks/impact_model_error.py ROOT > model_error.md
"""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path
from typing import Any

_REFUSAL = re.compile(r"steady penetration of (?P<z>[\d.]+) mm = (?P<f>[\d.]+) N / (?P<k>\d+) N/m")
_STOPPED = re.compile(r"stopped (?P<d>[\d.]+) mm deep .* with (?P<f>[\d.]+) N at t = (?P<t>[\d.]+)")
#: Table order of the strategies (the baseline last).
ORDER = {"strike_first": 0, "touch_first": 1, "prior": 2, "baseline": 3}


def _f(value: float | None, spec: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return format(value, spec)


def _against(value: float | None, reference: float | None) -> str:
    """``value`` (s) and its change against ``reference`` (s), in %."""
    if value is None or not math.isfinite(value):
        return "—"
    if reference is None or not math.isfinite(reference) or reference <= 0:
        return f"{value:.3f}"
    return f"{value:.3f} ({100.0 * (value / reference - 1.0):+.0f} %)"


def _note(run: dict[str, Any]) -> str:
    """The refusal or the stop short, shortened to its numbers."""
    refusal = run.get("refusal") or ""
    m = _REFUSAL.search(refusal)
    if m:
        when = "in contact" if "in contact" in refusal else "before the strike"
        return f"refused {when}: {m['f']} N / {m['k']} N/m = {m['z']} mm > z̄"
    if refusal:
        return "refused: " + refusal
    m = _STOPPED.search(run.get("stopped_short") or "")
    if m:
        return f"stopped short: {m['f']} N at {m['d']} mm (t = {m['t']} s)"
    return "—"


def collect(root: Path) -> list[tuple[str, float, float, dict[str, Any], float]]:
    """(strategy or "baseline", dice K, dice B, run summary, z̄ mm) of every run under root."""
    found = []
    for path in sorted(root.glob("*/results.json")):
        doc = json.loads(path.read_text())
        dice = doc["config"]["dice"]
        zbar = 1e3 * dice["max_penetration"]
        for run in doc["runs"]:
            strategy = run["strategy"] if run["approach"] == "maximal" else "baseline"
            found.append((strategy, dice["stiffness"], dice["damping"], run, zbar))
    found.sort(key=lambda x: (ORDER.get(x[0], 9), x[1], x[2], x[3]["regulation"]))
    return found


def rows(root: Path) -> list[str]:
    """One Markdown row per run of every results.json under ``root``."""
    found = collect(root)
    baseline = {(k, b, r["regulation"]): r for s, k, b, r, _ in found if s == "baseline"}
    out = []
    for strategy, k, b, r, zbar in found:
        v = r["violations"]
        pen = 1e3 * r["peak_penetration"]
        flag = " **over**" if pen > zbar else ""
        ref = {} if strategy == "baseline" else baseline.get((k, b, r["regulation"]), {})
        out.append(
            f"| {strategy} | {k:g} | {b:g} | {r['regulation']} "
            f"| {_f(r.get('touch_velocity'), '.3f')} | {_f(r['pre_impact_velocity'], '.3f')} "
            f"| {_against(r['contact_time'], ref.get('contact_time'))} "
            f"| {_against(r['steady_time'], ref.get('steady_time'))} "
            f"| {pen:.1f} / {zbar:.0f}{flag} "
            f"| {r['peak_force']:.1f} | {r['final_force']:.1f} "
            f"| {v['position']} / {v['velocity']} / {v['acceleration']} / {v['torque']} "
            f"| {v['max_ratio']['acceleration']:.2f} | {_note(r)} |"
        )
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    head = (
        "| strategy | dice K (N/m) | dice B (N·s/m) | regulation | touch velocity (m/s) | "
        "pre-impact velocity (m/s) | contact (s) (vs baseline) | steady force (s) "
        "(vs baseline) | peak penetration / z̄ (mm) | peak force (N) | final force (N) | "
        "violations q / q̇ / q̈ / τ | max q̈/q̈_max | refusal or stop short |"
    )
    print(head)
    print("|" + "---|" * 14)
    for row in rows(Path(argv[0])):
        print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
