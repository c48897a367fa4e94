"""Side-by-side tables of studies run the same way on different plants (or code versions):
``ffmpc study compare A/results.json B/results.json --labels PyBullet MuJoCo``.

Two kinds of study document are compared, each with its own kind of the same:

* ``ffmpc study paper`` (``kind: paper``; or ``ffmpc study polishing``, its Tables II–III
  alone): per section, PID mode, command delay δo and MPC, for
  each document E_λ (N, mean over the runs a reflex did not abort), E_P (mm, the same runs),
  λmax (N, largest over every run), the aborted runs and the runs over a joint velocity or
  motor torque limit (any sample above 1× the robot's limit), then the order of the three MPCs
  in E_λ per row group;
* ``ffmpc study impact`` (its ``runs`` list): per run, the pre-impact velocity (m/s), contact
  time (s), peak penetration (mm, with the bound z̄ the planner keeps), peak force (N), the
  joint-limit violations and the reflex.

Nothing is recomputed from logs: the numbers are the ones the studies wrote. The documents
must be comparable — the same seeds, formulations and δo settings for the paper study, the
same runs for the impact study — or :class:`~ffmpc_core.errors.ConfigError` says which
differ; each study's plant, command line and overrides head the table.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ffmpc_core.errors import ConfigError, InputError
from studies.paper import SECTIONS
from studies.study import LABELS, delta_o_groups, delta_o_label

#: Short names of the formulations in the order strings ("FF < TF < C").
SHORT = {"classical": "C", "torque_feedback": "TF", "force_feedback": "FF"}
#: The paper's name of each section's table, by PID mode (the simulation study is Table II
#: without the PID and Table III with it).
TABLE_NAMES: dict[str, str | dict[bool, str]] = {
    "simulation": {False: "Table II", True: "Table III"},
    "experiment_1": "Exp. 1",
    "experiment_2": "Table V",
    "experiment_3_1": "Table VI",
    "experiment_3_2": "Table VII",
    "experiment_3_3": "Exp. 3.3 (push)",
}


def table_name(section: str, pid: bool) -> str:
    """The paper's name of a section's table ("Table III"), or the section key."""
    name = TABLE_NAMES.get(section, section)
    return name[pid] if isinstance(name, dict) else name


def load_results(path: str | Path) -> dict[str, Any]:
    """A study's ``results.json`` (a directory is read as its ``results.json``)."""
    path = Path(path)
    if path.is_dir():
        path = path / "results.json"
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise InputError(f"{path}: no such results file") from exc
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not JSON ({exc})") from exc
    if not isinstance(doc, dict) or ("sections" not in doc and "runs" not in doc):
        raise InputError(f"{path}: not the results.json of a paper or impact study")
    return doc


def study_kind(doc: dict[str, Any]) -> str:
    """``"paper"`` (a paper study, or a polishing study: compared as its one table) or
    ``"impact"``."""
    return "paper" if doc.get("kind") in ("paper", "polishing") else "impact"


def _sections(doc: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """``{section key: study document}`` of a paper study; a polishing study is its one
    ``simulation`` section (the same tables, Table II/III)."""
    if doc.get("kind") == "polishing":
        return {"simulation": doc}
    return {key: section["study"] for key, section in doc["sections"].items()}


def over_limit(run: dict[str, Any]) -> bool:
    """Whether a paper-study run went over a joint velocity or motor torque limit (1×)."""
    ratios = list(run.get("max_velocity_ratio") or []) + list(run.get("max_torque_ratio") or [])
    return any(r > 1.0 for r in ratios)


def cell_summary(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """One table cell: the runs, the aborted and over-limit counts, and E_λ (N), E_P (mm) means
    over the runs that were not aborted (NaN if none), λmax (N) over every run."""
    kept = [r for r in runs if not r.get("aborted", False)]

    def mean(key: str) -> float:
        values = [r["metrics_true"][key] for r in kept]
        return sum(values) / len(values) if values else math.nan

    return {
        "runs": len(runs),
        "aborted": sum(1 for r in runs if r.get("aborted", False)),
        "over_limit": sum(1 for r in runs if over_limit(r)),
        "force_mae": mean("force_mae"),
        "position_mae_mm": mean("position_mae_mm"),
        "max_force": max((r["metrics_true"]["max_force"] for r in runs), default=math.nan),
    }


def paper_cells(doc: dict[str, Any]) -> dict[tuple[str, bool, str | None, str], dict[str, Any]]:
    """``{(section, PID on, δo setting, formulation): cell_summary}`` of a paper study."""
    cells = {}
    sections = _sections(doc)
    for section in SECTIONS:
        if section.key not in sections:
            continue
        study = sections[section.key]
        for setting, group in delta_o_groups(study):
            for run_pid in sorted({bool(r["pid_enabled"]) for r in group["runs"]}, reverse=True):
                for form in doc.get("grid", doc)["formulations"]:
                    runs = [
                        r
                        for r in group["runs"]
                        if r["formulation"] == form and bool(r["pid_enabled"]) == run_pid
                    ]
                    cells[(section.key, run_pid, setting, form)] = cell_summary(runs)
    return cells


def _check_comparable(docs: Sequence[dict[str, Any]], keys: Sequence[str]) -> None:
    first = docs[0]
    for i, doc in enumerate(docs[1:], start=2):
        for key in keys:
            if doc.get(key) != first.get(key):
                raise ConfigError(
                    f"study {i} differs from study 1 in {key!r}: {doc.get(key)!r} vs "
                    f"{first.get(key)!r}; compare studies run the same way"
                )


def _delta_text(setting: str | None) -> str:
    """δo of a row: "5 ms", "measured", or "—" (the scenario's own)."""
    if setting is None:
        return "—"
    try:
        return f"{1e3 * float(setting):g} ms"
    except ValueError:
        return delta_o_label(setting)


def _number(value: float, digits: int = 2) -> str:
    return "—" if math.isnan(value) else f"{value:.{digits}f}"


def _order(cells: dict, key: tuple, forms: Sequence[str]) -> str:
    """The formulations in increasing E_λ ("FF < C < TF"); one with every run aborted is named
    after it ("FF < C (TF: every run aborted)")."""
    values = {f: cells[(*key, f)]["force_mae"] for f in forms}
    ranked = sorted((f for f in forms if not math.isnan(values[f])), key=lambda f: values[f])
    order = " < ".join(SHORT[f] for f in ranked)
    missing = [SHORT[f] for f in forms if math.isnan(values[f])]
    if missing:
        order += f" ({', '.join(missing)}: every run aborted)"
    return order


def paper_comparison(docs: Sequence[dict[str, Any]], labels: Sequence[str]) -> str:
    """The markdown side-by-side table of paper studies (see the module docstring)."""
    grids = [doc.get("grid", doc) for doc in docs]
    _check_comparable(grids, ("seeds", "formulations", "command_delays"))
    forms = grids[0]["formulations"]
    all_cells = [paper_cells(doc) for doc in docs]
    header = ["table", "PID", "δo", "MPC"]
    for label in labels:
        header += [f"{label}: E_λ (N)", "E_P (mm)", "λmax (N)", "aborted / over"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    groups = list(dict.fromkeys(key[:3] for key in all_cells[0]))
    orders = []
    for group in groups:
        section, pid, setting = group
        title = table_name(section, pid)
        delta = _delta_text(setting)
        for form in forms:
            row = [title, "on" if pid else "off", delta, SHORT[form]]
            for cells in all_cells:
                c = cells.get((*group, form))
                if c is None:
                    row += ["—"] * 4
                    continue
                row += [
                    _number(c["force_mae"]),
                    _number(c["position_mae_mm"]),
                    _number(c["max_force"], 1),
                    f"{c['aborted']} / {c['over_limit']}",
                ]
            lines.append("| " + " | ".join(row) + " |")
        order = " · ".join(
            f"{label} {_order(cells, group, forms)}"
            for label, cells in zip(labels, all_cells, strict=True)
        )
        where = f"PID {'on' if pid else 'off'}" + ("" if setting is None else f", δo {delta}")
        orders.append(f"- {title}, {where}: {order}")
    seeds = grids[0]["seeds"]
    names = ", ".join(f"{SHORT[f]} {LABELS[f].lower()}" for f in forms)
    intro = [
        f"Seeds {seeds[0]}–{seeds[-1]}: {len(seeds)} runs per row and study. MPC: {names}. "
        "E_λ and E_P are means over the runs a reflex did not abort, λmax the largest over "
        "every run; aborted: runs the robot's reflexes stopped; over: runs with a joint "
        "velocity or motor torque sample above 1× the robot's limit.",
        "",
    ]
    return "\n".join(
        _sources(docs, labels) + intro + lines + ["", "Order in E_λ:", "", *orders, ""]
    )


def _sources(docs: Sequence[dict[str, Any]], labels: Sequence[str]) -> list[str]:
    """One line per study: its label, plant, command line and the values it set."""
    lines = []
    for label, doc in zip(labels, docs, strict=True):
        engine = doc.get("plant_engine") or doc.get("config", {}).get("engine") or "?"
        overrides = doc.get("overrides") or {}
        if len(overrides) <= 3:
            changed = [f"{k}={v}" for k, v in overrides.items()]
        else:
            changed = [f"{len(overrides)} values set"]
        notes = changed
        extra = f" ({', '.join(notes)})" if notes else ""
        lines.append(f"- **{label}**: {engine}, `{doc.get('command_line', '?')}`{extra}")
    return [*lines, ""]


def _impact_key(run: dict[str, Any]) -> tuple[str, str]:
    return run["name"], run.get("strategy") or ""


def impact_comparison(docs: Sequence[dict[str, Any]], labels: Sequence[str]) -> str:
    """The markdown side-by-side table of impact studies (see the module docstring)."""
    keys = [[_impact_key(r) for r in doc["runs"]] for doc in docs]
    if any(k != keys[0] for k in keys[1:]):
        raise ConfigError("the impact studies ran different runs; compare studies run the same way")
    bounds = [doc.get("config", {}).get("dice", {}).get("max_penetration") for doc in docs]
    header = ["run", "strategy"]
    for label in labels:
        header += [
            f"{label}: pre-impact velocity (m/s)",
            "contact (s)",
            "peak penetration (mm)",
            "peak force (N)",
            "violations",
            "aborted",
        ]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    by_doc = [{_impact_key(r): r for r in doc["runs"]} for doc in docs]
    for key in keys[0]:
        row = [key[0], key[1] if key[0].startswith("maximal") else "—"]
        for runs in by_doc:
            r = runs[key]
            reflex = r.get("reflex") or {}
            row += [
                _number(r["pre_impact_velocity"], 3),
                _number(r["contact_time"], 3),
                _number(1e3 * r["peak_penetration"], 1),
                _number(r["peak_force"], 1),
                str(r["violations"]["total"]),
                "yes" if reflex.get("aborted") else "no",
            ]
        lines.append("| " + " | ".join(row) + " |")
    bound = " · ".join(
        f"{label} {_number(1e3 * b, 1) if b is not None else '?'} mm"
        for label, b in zip(labels, bounds, strict=True)
    )
    footer = ["", f"Penetration bound z̄ kept by the planner: {bound}.", ""]
    return "\n".join(_sources(docs, labels) + lines + footer)


def compare(paths: Sequence[str | Path], labels: Sequence[str] | None = None) -> str:
    """The side-by-side markdown table of two or more studies' ``results.json`` of one kind;
    ``labels`` default to each document's plant engine."""
    if len(paths) < 2:
        raise ConfigError("compare needs two results files or more")
    docs = [load_results(p) for p in paths]
    kinds = {study_kind(d) for d in docs}
    if len(kinds) != 1:
        raise ConfigError(f"cannot compare a paper study with an impact study ({paths})")
    if labels is None:
        labels = [
            str(d.get("plant_engine") or d.get("config", {}).get("engine") or i)
            for i, d in enumerate(docs, start=1)
        ]
    if len(labels) != len(docs):
        raise ConfigError(f"{len(labels)} labels for {len(docs)} results files")
    if kinds == {"paper"}:
        return paper_comparison(docs, labels)
    return impact_comparison(docs, labels)
