"""The same polishing study on two plants side by side (``--plant pybullet`` vs ``--plant
mujoco``): per controller, with the torque PID, from the true force: E_λ (N) and E_P (mm) mean ±
std over the seeds, λmax (N) the max, the largest q̇/limit of any run and any joint, the runs
over a speed limit, and the mean wall time per run (s), as a Markdown table.

    python benchmarks/compare_plants.py PYBULLET/results.json MUJOCO/results.json

Each file is the ``results.json`` of ``ffmpc study polishing`` (its runs) or of ``ffmpc study
paper`` (the runs of its ``simulation`` section, one table per δo setting); the column heads are
the documents' ``plant_engine``.
"""

from __future__ import annotations

import json
import sys
from collections import defaultdict

import numpy as np

FORMULATIONS = ("classical", "torque_feedback", "force_feedback")
LABELS = {"classical": "C", "torque_feedback": "TF", "force_feedback": "FF"}


def pid_runs(path: str) -> tuple[str, dict[str, dict[str, list[dict]]]]:
    """(engine, {δo setting or "": {formulation: [run with the PID]}}) of one document."""
    with open(path, encoding="utf-8") as stream:
        doc = json.load(stream)
    runs = doc["sections"]["simulation"]["study"]["runs"] if "sections" in doc else doc["runs"]
    grouped: dict[str, dict[str, list[dict]]] = defaultdict(lambda: defaultdict(list))
    for run in runs:
        if run["pid_enabled"]:
            grouped[str(run.get("delta_o_setting") or "")][run["formulation"]].append(run)
    return str(doc.get("plant_engine", "pybullet")), grouped


def cells(runs: list[dict]) -> list[str]:
    """E_λ, E_P, λmax, largest q̇/limit (runs over 1), wall per run of one controller's runs."""
    if not runs:
        return ["n/a"] * 5
    force = [r["metrics_true"]["force_mae"] for r in runs]
    position = [r["metrics_true"]["position_mae_mm"] for r in runs]
    speed = [max(r["max_velocity_ratio"]) for r in runs]
    return [
        f"{np.mean(force):.2f} ± {np.std(force):.2f}",
        f"{np.mean(position):.2f} ± {np.std(position):.2f}",
        f"{max(r['metrics_true']['max_force'] for r in runs):.2f}",
        f"{max(speed):.3f} ({sum(s > 1.0 for s in speed)}/{len(speed)})",
        f"{np.mean([r['wall_time_s'] for r in runs]):.1f}",
    ]


def main(paths: list[str]) -> int:
    documents = [pid_runs(path) for path in paths]
    engines = [engine for engine, _ in documents]
    rows = ("E_λ (N)", "E_P (mm)", "λmax (N)", "max q̇/limit (runs > 1)", "wall per run (s)")
    for setting in documents[0][1]:
        if setting:
            print(f"\nδo setting {setting}:\n")
        head = [f"{LABELS[f]} {e}" for f in FORMULATIONS for e in engines]
        print("| | " + " | ".join(head) + " |")
        print("|---" * (len(head) + 1) + "|")
        columns = [cells(doc[setting][f]) for f in FORMULATIONS for _, doc in documents]
        for i, row in enumerate(rows):
            print(f"| {row} | " + " | ".join(column[i] for column in columns) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
