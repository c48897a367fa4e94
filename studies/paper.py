"""``ffmpc study paper``: every table of the force-feedback paper (Kleff et al.) that the project
reproduces, as one command on the one run engine, with one report.

Sections (:data:`SECTIONS`), each a grid of :class:`studies.study.RunSpec` (formulation × torque
PID mode × seed, the same seeds everywhere):

* the simulation study (VI-C, Tables II–IV): scenario ``polishing``, PID off and on, one grid per
  OCP delay δo (``mpc.command_delay``; default 0 and 5 ms), with the paired comparison
  (force-feedback minus each other controller per seed, Wilcoxon signed-rank p);
* Experiment 1 (VII-B, force square signal): ``force_square``;
* Experiment 2 (VII-C, Table V, perfect table): ``perfect_table`` (no tilt);
* Experiment 3.1 (VII-D1, Table VI, unknown tilt): ``tilt``;
* Experiment 3.2 (VII-D2, Table VII, 6 rad/s): ``polishing_fast``;
* Experiment 3.3 (VII-D3, pushes): ``push``, with the force and position errors during and after
  the push (:func:`ffmpc_core.polishing.polishing_push_metrics`).

The experiments run with the torque PID and the scenario's own δo. Every run of every section
goes to :func:`studies.execute.execute_jobs` in ONE batch (one Dask cluster, or in-process with
``workers=1``), each cached in ``OUT/cache`` (or ``cache_dir``) as it ends, so a killed study
resumes. Writes ``paper.md`` (each table beside the paper's numbers where the paper prints them,
the seeds, the scenario file and cost weights of each section, the wall time) and
``results.json`` (one study document per section, as ``ffmpc study polishing`` writes).
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from ffmpc_core.config import FORMULATIONS
from ffmpc_core.errors import ConfigError
from ffmpc_core.metrics import PUSH_RECOVERY_WINDOW
from ffmpc_core.scenario import resolve_scenario_path
from studies.execute import RunOutcome, prepare_output_dir, study_cache, write_json
from studies.reflexes import reflex_note
from studies.study import (
    LABELS,
    PAPER_FORCE_SQUARE_MAE,
    PAPER_TABLES,
    RunSpec,
    _counts,
    _load_measured_delays,
    _mean_std,
    _pm,
    _save_measured_delays,
    _seed_range,
    _table,
    delta_o_groups,
    delta_o_label,
    delta_per_seed,
    execute_specs,
    grid_specs,
    paired_table,
    resolve_command_delays,
    source_state,
    study_document,
    table_cells,
    validate_specs,
)

__all__ = [
    "DEFAULT_COMMAND_DELAYS",
    "PaperReport",
    "PaperSection",
    "SECTIONS",
    "paper_figures",
    "paper_report",
    "paper_specs",
    "push_rows",
    "run_paper",
]

#: δo of the simulation study's grids, s (the paper's Tables II/III columns at two delays).
DEFAULT_COMMAND_DELAYS: tuple[float, ...] = (0.0, 0.005)
#: Rows of Tables II/III, in :data:`PAPER_TABLES` order.
TABLE_ROWS = ("E_P (mm)", "E_λ (N)", "λmax (N)", "t_break (%)")


@dataclass(frozen=True)
class PaperSection:
    """One table of the paper: the scenario it runs, the PID modes, whether it has one grid per
    δo, and which of the paper's tables it sits beside."""

    key: str
    title: str
    scenario: str
    kind: str  # "polishing" | "force_square" (the study document's kind)
    pid_modes: tuple[bool, ...]
    per_delta: bool
    paper: str | None  # key of PAPER_TABLES ("V", ...), "force_square", or None
    note: str
    #: The paper's figure of this experiment, drawn from the plotted seed: its number ("6")
    #: and caption; None: the paper has no such figure (the simulation study).
    figure: tuple[str, str] | None = None

    @property
    def figure_file(self) -> str | None:
        """The figure's file name in the study's directory (``fig6_experiment_2.png``)."""
        return None if self.figure is None else f"fig{self.figure[0]}_{self.key}.png"


SECTIONS: tuple[PaperSection, ...] = (
    PaperSection(
        "simulation",
        "Simulation study (VI-C): Tables II–IV",
        "polishing",
        "polishing",
        (False, True),
        True,
        "II-IV",
        "Table tilt θ ~ U(±6°) and actuation bias drawn per seed; without (Table II) and with "
        "(Table III) the torque PID; Table IV = no-PID minus PID per seed.",
    ),
    PaperSection(
        "experiment_1",
        "Experiment 1 (VII-B): force square signal",
        "force_square",
        "force_square",
        (True,),
        False,
        "force_square",
        "Normal-force MAE over the square signal; the paper's values are from the robot.",
        figure=("4", "Experiment 1: normal force square signal tracking"),
    ),
    PaperSection(
        "experiment_2",
        "Experiment 2 (VII-C, Table V): slow polishing, perfect table",
        "perfect_table",
        "polishing",
        (True,),
        False,
        "V",
        "3 rad/s on a horizontal table (no tilt).",
        figure=("6", "Experiment 2: slow polishing task, perfect table model"),
    ),
    PaperSection(
        "experiment_3_1",
        "Experiment 3.1 (VII-D1, Table VI): slow circle, unknown tilt",
        "tilt",
        "polishing",
        (True,),
        False,
        "VI",
        "3 rad/s on a table tilted by a fixed 6°, unknown to the controllers.",
        figure=("7", "Experiment 3.1: slow polishing task, unknown table tilt"),
    ),
    PaperSection(
        "experiment_3_2",
        "Experiment 3.2 (VII-D2, Table VII): fast circle, unknown tilt",
        "polishing_fast",
        "polishing",
        (True,),
        False,
        "VII",
        "6 rad/s, table tilt θ ~ U(±6°) per seed.",
        figure=("8", "Experiment 3.2: fast polishing task, unknown table tilt"),
    ),
    PaperSection(
        "experiment_3_3",
        "Experiment 3.3 (VII-D3): fast circle with a push",
        "push",
        "polishing",
        (True,),
        False,
        None,
        "6 rad/s on the horizontal table with a lateral push on the tool mid-circle. The paper "
        "prints no numbers for it (Fig. 9, qualitative).",
        figure=("9", "Experiment 3.3: fast polishing task with an external push"),
    ),
)


def paper_specs(
    seeds: Sequence[int],
    formulations: Sequence[str] = FORMULATIONS,
    command_delays: Sequence[float | str] = DEFAULT_COMMAND_DELAYS,
    duration: float | None = None,
    overrides: dict[str, Any] | None = None,
    plot_seed: int | None = None,
) -> dict[str, list[RunSpec]]:
    """The runs of every section, ``{section key: specs}``; the ``plot_seed`` runs of the
    sections with a figure send back their plot logs."""
    out = {}
    for section in SECTIONS:
        out[section.key] = grid_specs(
            section.scenario,
            formulations,
            section.pid_modes,
            seeds,
            duration,
            overrides,
            plot_seed=plot_seed if section.figure is not None else None,
            command_delays=command_delays if section.per_delta else None,
        )
    return out


@dataclass
class PaperReport:
    """What ``ffmpc study paper`` produced: ``results.json``'s document, ``paper.md``."""

    out_dir: Path
    document: dict
    text: str
    files: list[Path]
    outcomes: dict[str, list[RunOutcome]] = field(repr=False)


def run_paper(
    out_dir: str | os.PathLike,
    seeds: Sequence[int],
    *,
    formulations: Sequence[str] = FORMULATIONS,
    command_delays: Sequence[float | str] = DEFAULT_COMMAND_DELAYS,
    duration: float | None = None,
    overrides: dict[str, Any] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    force: bool = False,
    cache: bool = True,
    cache_dir: str | os.PathLike | None = None,
    fresh: bool = False,
    command_line: str = "",
    progress: bool = True,
    plot_seed: int | None = None,
) -> PaperReport:
    """Run every section (:data:`SECTIONS`) in one batch and write ``paper.md``,
    ``results.json`` and the paper's figures (4, 6–9: :func:`paper_figures`, from the
    ``plot_seed`` runs, default the first seed) into ``out_dir`` (refused if it exists, unless
    ``force`` or an interrupted study to resume: :func:`studies.execute.check_output_dir`)."""
    if plot_seed is None:
        plot_seed = int(seeds[0])
    elif plot_seed not in seeds:
        raise ConfigError(f"plot seed {plot_seed}: expected one of the seeds {list(seeds)}")
    by_section = paper_specs(seeds, formulations, command_delays, duration, overrides, plot_seed)
    every = [spec for specs in by_section.values() for spec in specs]
    validate_specs(every)  # a bad scenario or override fails before any run
    out = prepare_output_dir(out_dir, force, resume=cache and not fresh)
    run_cache = study_cache(out, cache, cache_dir)
    start = time.perf_counter()
    known = _load_measured_delays(run_cache, every) if run_cache and not fresh else {}
    delays: dict[str, dict] = {}
    for key, specs in by_section.items():
        by_section[key], delays[key] = resolve_command_delays(specs, measured=known)
        for formulation, record in delays[key].items():
            if "measured_step_median_s" in record:
                known[formulation] = float(record["measured_step_median_s"])
    if run_cache is not None:
        _save_measured_delays(run_cache, every, {}, known)
    every = [spec for specs in by_section.values() for spec in specs]
    batch = execute_specs(
        every, workers, progress, scheduler=scheduler, cache=run_cache, fresh=fresh
    )
    wall = time.perf_counter() - start
    execution = batch.execution(run_cache)
    outcomes: dict[str, list[RunOutcome]] = {}
    sections: dict[str, Any] = {}
    index = 0
    for section in SECTIONS:
        specs = by_section[section.key]
        outcomes[section.key] = batch.outcomes[index : index + len(specs)]
        index += len(specs)
        doc = study_document(
            section.kind,
            specs,
            outcomes[section.key],
            command_line=command_line,
            workers=batch.workers,
            wall_time=wall,
            command_delays=delays[section.key],
            execution=execution,
        )
        scenario = specs[0].load()
        sections[section.key] = {
            "title": section.title,
            "note": section.note,
            "scenario": section.scenario,
            "scenario_file": str(resolve_scenario_path(section.scenario)),
            "pid_enabled": list(section.pid_modes),
            "weights": {f: scenario.mpc.weights.get(f, {}) for f in formulations},
            "paper": _paper_values(section, formulations),
            "study": doc,
        }
    from ffmpc_core.selfcheck import installed_versions

    document = {
        "kind": "paper",
        "command_line": command_line,
        "created_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "wall_time_s": wall,
        "workers": batch.workers,
        "execution": execution,
        "seeds": list(seeds),
        "formulations": list(formulations),
        "command_delays": list(command_delays),
        "duration_s": duration,
        "plant_engine": sections[SECTIONS[0].key]["study"]["plant_engine"],
        "overrides": dict(overrides or {}),
        "push_recovery_window_s": PUSH_RECOVERY_WINDOW,
        "plot_seed": plot_seed,
        "source": source_state(),
        "versions": {
            "python": platform.python_version(),
            "platform": platform.platform(),
            **installed_versions(),
        },
        "sections": sections,
    }
    figures = paper_figures(outcomes, by_section, out, plot_seed)
    document["figures"] = {key: path.name for key, path in figures.items()}
    text = paper_report(document)
    files = [out / "results.json", out / "paper.md", *figures.values()]
    write_json(files[0], document)
    files[1].write_text(text, encoding="utf-8")
    return PaperReport(out, document, text, files, outcomes)


def paper_figures(
    outcomes: dict[str, list[RunOutcome]],
    specs: dict[str, list[RunSpec]],
    out: Path,
    plot_seed: int,
) -> dict[str, Path]:
    """The paper's Fig. 4 (Experiment 1: true normal force vs the square reference) and Figs.
    6–9 (Experiments 2, 3.1, 3.2, 3.3: (a) true normal force vs reference, (b) tangential
    position error; Fig. 9 shades the push) of the ``plot_seed`` runs, every controller with the
    torque PID, as PNG files in ``out``: ``{section key: path}`` (a section whose plotted runs
    all failed has none)."""
    from studies.study import plot_force_square, plot_polishing

    written: dict[str, Path] = {}
    for section in SECTIONS:
        if section.figure is None or section.figure_file is None:
            continue
        number, caption = section.figure
        path = out / section.figure_file
        title = f"Fig. {number} — {caption} (simulation, seed {plot_seed}, torque PID)"
        if section.kind == "force_square":
            drawn = plot_force_square(outcomes[section.key], path, title)
        else:
            plant = specs[section.key][0].load().plant
            pushes = (
                [(plant.push_time, plant.push_time + plant.push_duration)]
                if plant.push_enabled
                else []
            )
            drawn = plot_polishing(outcomes[section.key], True, path, title, pushes, "push")
        if drawn:
            written[section.key] = path
    return written


def _paper_values(section: PaperSection, formulations: Sequence[str]) -> dict[str, Any] | None:
    """The paper's numbers beside a section (as printed), or None where it prints none."""
    if section.paper == "II-IV":
        return {n: {f: list(PAPER_TABLES[n][f]) for f in formulations} for n in ("II", "III", "IV")}
    if section.paper == "force_square":
        return {"force_mae_N": {f: PAPER_FORCE_SQUARE_MAE[f] for f in formulations}}
    if section.paper is not None:
        rows = ("Force (N)", "Position (mm)")
        return {
            section.paper: {
                row: {f: PAPER_TABLES[section.paper][f][i] for f in formulations}
                for i, row in enumerate(rows)
            }
        }
    return None


# --------------------------------------------------------------------------- the report
def _beside(
    forms: Sequence[str], rows: Sequence[Sequence[str]], paper: dict[str, dict[str, str]]
) -> list[str]:
    """A table with each controller's column followed by the paper's (``paper[row][form]``;
    "–" where the paper prints nothing for that row)."""
    header = [""]
    for f in forms:
        header += [LABELS[f], f"{LABELS[f]} (paper)"]
    out = []
    for row in rows:
        cells = [row[0]]
        for i, f in enumerate(forms):
            cells += [row[i + 1], paper.get(row[0], {}).get(f, "–")]
        out.append(cells)
    return _table(header, out)


def _paper_rows(number: str, forms: Sequence[str], names: Sequence[str]) -> dict:
    return {name: {f: PAPER_TABLES[number][f][i] for f in forms} for i, name in enumerate(names)}


def _simulation_section(doc: dict, forms: Sequence[str]) -> list[str]:
    lines: list[str] = []
    modes = doc["grid"]["pid_enabled"]
    for setting, sub in delta_o_groups(doc):
        label = delta_o_label(setting)
        lines += [f"### {label} (`mpc.command_delay: {setting}`)", ""]
        for number, pid in (("II", False), ("III", True)):
            if pid not in modes:
                continue
            what = "with" if pid else "without"
            lines += [f"#### Table {number} — {what} torque PID (true force, {label})", ""]
            rows = table_cells(sub, forms, pid, "true")
            lines += _beside(forms, rows, _paper_rows(number, forms, TABLE_ROWS))
            lines += ["", f"Runs: {_counts(sub, forms, pid)}.", ""]
            lines += paired_table(
                sub, pid, f"#### Paired comparison, Table {number} (true force, {label})"
            )
        if set(modes) >= {True, False}:
            lines += [f"#### Table IV — no-PID minus PID, per seed (true force, {label})", ""]
            deltas = {f: delta_per_seed(sub, f, "true") for f in forms}
            rows = [
                ["ΔE_λ (N)"] + [_pm(*_mean_std(d["force_mae"])) for d in deltas.values()],
                ["ΔE_τ (N m)"] + [_pm(*_mean_std(d["torque_mae"])) for d in deltas.values()],
            ]
            lines += _beside(forms, rows, _paper_rows("IV", forms, ("ΔE_λ (N)", "ΔE_τ (N m)")))
            pairs = ", ".join(f"{LABELS[f]} {len(d['seeds'])}" for f, d in deltas.items())
            lines += ["", f"Seed pairs: {pairs}.", ""]
    return lines


def _experiment_section(section: PaperSection, doc: dict, forms: Sequence[str]) -> list[str]:
    rows = table_cells(doc, forms, True, "true")
    paper: dict[str, dict[str, str]] = {}
    if section.paper == "force_square":
        paper = {"E_λ (N)": {f: f"{PAPER_FORCE_SQUARE_MAE[f]:.2f}" for f in forms}}
    elif section.paper is not None:
        # The paper's "Force (N)" and "Position (mm)" rows beside E_λ and E_P.
        paper = _paper_rows(section.paper, forms, ("E_λ (N)", "E_P (mm)"))
    lines = [f"### With torque PID (true force, {delta_o_label(None)})", ""]
    lines += _beside(forms, rows, paper)
    lines += ["", f"Runs: {_counts(doc, forms, True)}.", ""]
    if section.paper not in (None, "force_square"):
        lines += [
            f"The paper's Table {section.paper} (hardware): MAE of the normal force (Force) and "
            "of the end-effector position (Position) over one circle, mean ± std over 10 "
            "circles of one run; here E_λ and the tangential E_P over the circle phase, mean ± "
            "std over the seeds.",
            "",
        ]
    if section.key == "experiment_3_3":
        lines += ["### During and after the push (true force)", ""]
        lines += _table(["", *(LABELS[f] for f in forms)], push_rows(doc, forms))
        lines += [
            "",
            f"During: the cycles the push acts on; after: the {PUSH_RECOVERY_WINDOW:g} s that "
            "follow it (cut at the end of the circle). E_λ and E_P mean ± std over the seeds, "
            "max λ the largest normal force of any seed; n/a: no run had a sample in that "
            "phase (the run ended before it).",
            "",
        ]
    return lines


def push_rows(doc: dict, forms: Sequence[str]) -> list[list[str]]:
    """Rows of the push table: per push and phase, E_λ (N), E_P (mm) and max |λ| (N) of the
    runs with PID, from their summaries' ``push_true`` (mean ± std, max over the seeds)."""
    runs = [r for r in doc["runs"] if r["pid_enabled"]]
    pushes = max((len(r.get("push_true", [])) for r in runs), default=0)
    rows: list[list[str]] = []
    for i in range(pushes):
        which = f"push {i + 1}" if pushes > 1 else "push"
        for phase in ("during", "after"):
            force = [f"E_λ (N), {phase} {which}"]
            position = [f"E_P (mm), {phase} {which}"]
            peak = [f"max λ (N), {phase} {which}"]
            for form in forms:
                cells = [
                    r["push_true"][i][phase]
                    for r in runs
                    if r["formulation"] == form and len(r.get("push_true", [])) > i
                ]
                cells = [c for c in cells if c["samples"] > 0]
                force.append(_pm(*_mean_std([c["force_mae"] for c in cells])))
                position.append(_pm(*_mean_std([c["position_mae_mm"] for c in cells])))
                peak.append(f"{max(c['max_force'] for c in cells):.2f}" if cells else "n/a")
            rows += [force, position, peak]
    return rows


def _weights_line(weights: dict[str, dict[str, float]]) -> str:
    parts = []
    for form, w in weights.items():
        inner = ", ".join(f"{k} {v:g}" for k, v in w.items()) or "the code's defaults"
        parts.append(f"{LABELS[form]}: {inner}")
    return "; ".join(parts)


def _aborted_lines(runs: Sequence[tuple[str, dict]]) -> list[str]:
    """ "Aborted runs": how many runs of every section the robot's reflexes aborted (and whether
    they were on: ``studies.reflexes.reflex_note``), then each one with its section and event."""
    lines = ["## Aborted runs (the robot's own reflexes; left out of every aggregate)", ""]
    lines += [reflex_note([r.get("reflex") for _, r in runs]), ""]
    for title, r in runs:
        event = (r.get("reflex") or {}).get("event")
        if event is None:
            continue
        pid = "on" if r["pid_enabled"] else "off"
        delta = f", {delta_o_label(r['delta_o_setting'])}" if "delta_o_setting" in r else ""
        lines.append(
            f"- {title}: {LABELS[r['formulation']]}, PID {pid}{delta}, seed {r['seed']}: "
            f"{event['message']}"
        )
    return lines + [""]


def paper_report(document: dict) -> str:
    """``paper.md``: every section's tables beside the paper's values, seeds, scenario files,
    cost weights and the wall time."""
    forms = document["formulations"]
    seeds = document["seeds"]
    execution = document["execution"]
    runs = sum(
        len(s["study"]["runs"]) + len(s["study"]["failures"]) for s in document["sections"].values()
    )
    duration = document["duration_s"]
    lines = [
        "# The force-feedback paper's tables in simulation (`ffmpc study paper`)",
        "",
        f"Command: `{document['command_line']}`.",
        "",
        f"{len(seeds)} seeds ({_seed_range(seeds)}), the same in every section; each seed draws "
        "the table tilt (where the scenario has a random one) and the actuation bias, the same "
        f"for every controller. {runs} runs ({execution['cached']} from the cache, "
        f"{execution['executed']} run: {execution['cluster']}, {document['workers']} "
        f"worker(s)); wall time {document['wall_time_s']:.1f} s.",
        "",
        (
            "Simulated time per run: the whole task of each scenario."
            if duration is None
            else f"Simulated time per run: {duration:g} s (a SMOKE RUN: shorter than the task, "
            "the numbers are not the paper's experiment)."
        ),
        "",
        f"Plant simulator (`plant.engine`): {document.get('plant_engine', 'pybullet')}.",
        "",
        "Metrics from the plant's TRUE normal force along the tilted table normal, over the "
        "circle phase (the square signal for Experiment 1): E_P, E_λ mean ± std over the seeds, "
        "λmax and t_break the max over the seeds (eq 34–35); runs the robot's own reflexes "
        "aborted are counted under each table ('Runs: ... (n aborted)') and left out of the "
        "aggregates (listed under 'Aborted runs'). The measured-force metrics of every "
        "run are in results.json. Columns '(paper)': the paper's printed values (Tables II–IV "
        "simulation; Experiment 1 and Tables V–VII on the robot); '–': the paper prints none.",
        "",
    ]
    if document["overrides"]:
        sets = ", ".join(f"`{k}={v}`" for k, v in document["overrides"].items())
        lines += [f"Overrides applied to every section: {sets}.", ""]
    failures = []
    aborted: list[tuple[str, dict]] = []
    for key, section_doc in document["sections"].items():
        section = next(s for s in SECTIONS if s.key == key)
        doc = section_doc["study"]
        pid = ", ".join("on" if p else "off" for p in section_doc["pid_enabled"])
        delays = doc["grid"].get("command_delays")
        delta = (
            ", ".join(delta_o_label(d) for d in delays)
            if delays
            else ", ".join(
                f"{LABELS[f]} {1e3 * r['delta_o_s']:g} ms" for f, r in doc["command_delay"].items()
            )
            or "the scenario's"
        )
        lines += [
            f"## {section_doc['title']}",
            "",
            f"{section_doc['note']} Scenario `{section_doc['scenario']}` "
            f"(`{section_doc['scenario_file']}`), torque PID {pid}, δo: {delta}.",
            "",
            f"Cost weights (`mpc.weights` of that file"
            f"{', with the overrides' if document['overrides'] else ''}): "
            f"{_weights_line(section_doc['weights'])}.",
            "",
        ]
        if section.key == "simulation":
            lines += _simulation_section(doc, forms)
        else:
            lines += _experiment_section(section, doc, forms)
        figure = document.get("figures", {}).get(key)
        if figure is not None and section.figure is not None:
            lines += [
                f"Fig. {section.figure[0]} ({section.figure[1]}), seed {document['plot_seed']}: "
                f"![Fig. {section.figure[0]}]({figure})",
                "",
            ]
        failures += [(section_doc["title"], f) for f in doc["failures"]]
        aborted += [(section_doc["title"], r) for r in doc["runs"]]
    lines += _aborted_lines(aborted)
    lines += ["## Failed runs (left out of every aggregate)", ""]
    if not failures:
        lines += ["None.", ""]
    for title, f in failures:
        pid_state = "on" if f["pid_enabled"] else "off"
        delta = f", {delta_o_label(f['delta_o_setting'])}" if "delta_o_setting" in f else ""
        lines.append(
            f"- {title}: {LABELS[f['formulation']]}, PID {pid_state}{delta}, seed {f['seed']}: "
            f"{f['error']}"
        )
    if failures:
        lines.append("")
    return "\n".join(lines) + "\n"
