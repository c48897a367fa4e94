"""Two ``ffmpc study paper`` reports side by side, per section (with the torque PID, true force):
mean E_λ (N) and E_P (mm) over the seeds, C / TF / FF, and the runs over a joint speed limit
(largest |q̇|/limit in brackets), as a Markdown table.

    python benchmarks/compare_paper_studies.py BEFORE/results.json AFTER/results.json
"""

from __future__ import annotations

import json
import sys

import numpy as np

FORMULATIONS = ("classical", "torque_feedback", "force_feedback")
Run = tuple[float, float, float]  # E_λ (N), E_P (mm), largest |q̇|/limit


def runs_with_pid(path: str) -> dict[str, dict[str, list[Run]]]:
    """{section (the simulation per δo): {formulation: [run]}} of the runs with the PID."""
    doc = json.load(open(path))
    out: dict[str, dict[str, list[Run]]] = {}
    for key, section in doc["sections"].items():
        for r in section["study"]["runs"]:
            if not r["pid_enabled"]:
                continue
            tag = key + (f" δo={r.get('delta_o_setting')}" if key == "simulation" else "")
            metrics = r["metrics_true"]
            run = (metrics["force_mae"], metrics["position_mae_mm"], max(r["max_velocity_ratio"]))
            out.setdefault(tag, {}).setdefault(r["formulation"], []).append(run)
    return out


def means(section: dict[str, list[Run]], index: int) -> str:
    return " / ".join(f"{np.mean([run[index] for run in section[f]]):.2f}" for f in FORMULATIONS)


def over_limit(section: dict[str, list[Run]]) -> str:
    counts = " / ".join(str(sum(run[2] > 1.0 for run in section[f])) for f in FORMULATIONS)
    largest = max(run[2] for f in FORMULATIONS for run in section[f])
    return f"{counts} ({largest:.2f})"


def main() -> None:
    before, after = runs_with_pid(sys.argv[1]), runs_with_pid(sys.argv[2])
    print(
        "| section | E_λ before (N) | E_λ after (N) | E_P before (mm) | E_P after (mm) "
        "| runs over a speed limit before (max ratio) | after |"
    )
    print("|---|---|---|---|---|---|---|")
    for tag, old in before.items():
        new = after[tag]
        print(
            f"| {tag} | {means(old, 0)} | {means(new, 0)} | {means(old, 1)} | {means(new, 1)} "
            f"| {over_limit(old)} | {over_limit(new)} |"
        )


if __name__ == "__main__":
    main()
