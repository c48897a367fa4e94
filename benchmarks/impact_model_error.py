"""Tabulate ``ffmpc study impact`` runs over dice that are not the prior (issue 12, item 9).

Reads ``<strategy>_<K>_<B>/results.json`` (one ``ffmpc study impact --dice-stiffness K
--dice-damping B [--strategy prior]`` output directory each) under ``ROOT`` and prints a
Markdown table: per run the refusal, touch and pre-impact velocities, time to contact, peak
penetration against z̄, peak and final force and the joint-limit violations.

    python benchmarks/impact_model_error.py ROOT > model_error.md
"""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

_REFUSAL = re.compile(r"steady penetration of (?P<z>[\d.]+) mm = (?P<f>[\d.]+) N / (?P<k>\d+) N/m")


def _f(value: float | None, spec: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "—"
    return format(value, spec)


def rows(root: Path) -> list[str]:
    """One Markdown row per run of every results.json under ``root``."""
    found = []
    for path in sorted(root.glob("*/results.json")):
        doc = json.loads(path.read_text())
        dice = doc["config"]["dice"]
        zbar = 1e3 * dice["max_penetration"]
        for run in doc["runs"]:
            found.append((doc["config"]["strategy"], dice["stiffness"], dice["damping"], run, zbar))
    order = {"touch_first": 0, "prior": 1}
    found.sort(key=lambda x: (order.get(x[0], 2), x[1], x[2], x[3]["name"]))
    out = []
    for strategy, k, b, r, zbar in found:
        v = r["violations"]
        pen = 1e3 * r["peak_penetration"]
        flag = " **over**" if pen > zbar + 1e3 * 1e-3 * (r["pre_impact_velocity"] or 0) else ""
        refusal = r.get("refusal") or ""
        m = _REFUSAL.search(refusal)
        if m:
            refusal = f"refused before the strike: {m['f']} N / {m['k']} N/m = {m['z']} mm > z̄"
        out.append(
            f"| {strategy} | {k:g} | {b:g} | {r['regulation']} "
            f"| {_f(r.get('touch_velocity'), '.3f')} | {_f(r['pre_impact_velocity'], '.3f')} "
            f"| {_f(r['contact_time'], '.3f')} | {pen:.1f} / {zbar:.0f}{flag} "
            f"| {r['peak_force']:.1f} | {r['final_force']:.1f} "
            f"| {v['position']} / {v['velocity']} / {v['acceleration']} / {v['torque']} "
            f"| {v['max_ratio']['acceleration']:.2f} | {refusal or '—'} |"
        )
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    head = (
        "| strategy | dice K (N/m) | dice B (N·s/m) | regulation | touch velocity (m/s) | "
        "pre-impact velocity (m/s) | time to contact (s) | peak penetration / z̄ (mm) | "
        "peak force (N) | final force (N) | violations q / q̇ / q̈ / τ | max q̈/q̈_max | refusal |"
    )
    print(head)
    print("|" + "---|" * 13)
    for row in rows(Path(argv[0])):
        print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
