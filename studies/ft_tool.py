"""The wrist F/T sensor with a heavy tool (issue 27): polishing runs without a tool and with a
1 kg tool whose centre of mass is off the tool axis, behind a wrist sensor with a bias.

Variants (:data:`VARIANTS`, each a set of scenario overrides on every seed):

* ``no tool`` — the scenario as it is (the paper's sensor, eq 32);
* ``tool, compensated`` — the tool on the flange (the plant carries it, the controllers' model
  too), the wrist sensor (``ft_sensor.model: wrist``) with the bias :data:`BIAS`, calibrated at
  the start of the run and compensated with the measured joint state;
* ``tool, not compensated`` — the same with ``ft_sensor.calibration: none``: the tool's weight
  and the bias reach the MPC;
* ``tool, ideal sensor`` — the tool, and the paper's sensor that does not see it: what a perfect
  compensation would give (the tool's own effect on the robot's dynamics);
* ``tool, inertial, compensated`` — the sensor also reads the tool's inertial wrench and the
  compensation removes it from the measured joint state (``ft_sensor.inertial_wrench``).

:func:`tool_study` runs them (the polishing study's runs, :mod:`studies.study`) and
:func:`tool_table` prints E_λ (true normal force, N) per seed, the mean, and the change of the
mean against ``no tool``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import load_scenario
from studies.study import RunSpec, run_specs

#: The tool: 1 kg, centre of mass 30 / −20 / 80 mm in the flange (= sensor) frame.
TOOL: dict[str, Any] = {"plant.tool_mass": 1.0, "plant.tool_center_of_mass": (0.03, -0.02, 0.08)}
#: The wrist sensor's bias: fx, fy, fz (N), mx, my, mz (N·m), sensor frame.
BIAS = (2.0, -1.5, 3.0, 0.1, -0.05, 0.02)
_WRIST: dict[str, Any] = {**TOOL, "ft_sensor.model": "wrist", "ft_sensor.bias": BIAS}
VARIANTS: dict[str, dict[str, Any]] = {
    "no tool": {},
    "tool, compensated": _WRIST,
    "tool, not compensated": {**_WRIST, "ft_sensor.calibration": "none"},
    "tool, ideal sensor": dict(TOOL),
    "tool, inertial, compensated": {**_WRIST, "ft_sensor.inertial_wrench": True},
}
#: The variants ``ffmpc ft tool-study`` runs by default.
DEFAULT_VARIANTS = ("no tool", "tool, compensated", "tool, not compensated", "tool, ideal sensor")


def tool_specs(
    scenario: str,
    seeds: Iterable[int],
    variants: Sequence[str] = DEFAULT_VARIANTS,
    overrides: dict[str, Any] | None = None,
    duration: float | None = None,
) -> list[tuple[str, RunSpec]]:
    """(variant, run) for every variant and seed (ConfigError for an unknown variant or a bad
    override, before anything runs)."""
    base = load_scenario(scenario, overrides or {})
    out = []
    for name in variants:
        if name not in VARIANTS:
            raise ConfigError(f"unknown variant {name!r}; variants: {list(VARIANTS)}")
        extra = {**(overrides or {}), **VARIANTS[name]}
        for seed in seeds:
            spec = RunSpec(
                scenario,
                base.mpc.ocp.formulation,
                base.pid.enabled,
                int(seed),
                duration,
                tuple(extra.items()),
            )
            spec.load()  # checks the overrides now
            out.append((name, spec))
    return out


def tool_study(
    scenario: str = "polishing",
    seeds: Iterable[int] = range(5),
    variants: Sequence[str] = DEFAULT_VARIANTS,
    overrides: dict[str, Any] | None = None,
    workers: int | None = 1,
    progress: bool = False,
    duration: float | None = None,
) -> dict[str, dict[str, Any]]:
    """Run the variants on the seeds; {variant: {"seeds", "force_mae" (N), "position_mae_mm",
    "max_force" (N), "contact_missed", "failed"}} with one entry per seed (a failed run: NaN
    and its error; a run whose guarded approach never detected the contact: its metrics NaN,
    ``contact_missed`` True, since it never polished)."""
    seeds = list(seeds)
    specs = tool_specs(scenario, seeds, variants, overrides, duration)
    outcomes = run_specs([s for _, s in specs], workers=workers, progress=progress)
    result: dict[str, dict[str, Any]] = {}
    for (name, spec), outcome in zip(specs, outcomes, strict=True):
        row = result.setdefault(
            name,
            {
                "seeds": [],
                "force_mae": [],
                "position_mae_mm": [],
                "max_force": [],
                "contact_missed": [],
                "failed": [],
            },
        )
        row["seeds"].append(spec.seed)
        summary = outcome.summary or {}
        missed = bool(summary.get("contact_missed", False))
        row["contact_missed"].append(missed)
        metrics = summary.get("metrics_true") if not missed else None
        for key in ("force_mae", "position_mae_mm", "max_force"):
            row[key].append(float(metrics[key]) if metrics else float("nan"))
        if outcome.error:
            row["failed"].append(f"seed {spec.seed}: {outcome.error}")
    return result


def mean_force_error(result: dict[str, dict[str, Any]], variant: str) -> float:
    """The mean E_λ (N) of a variant over its seeds (NaN if a run failed or missed the
    contact)."""
    return float(np.mean(result[variant]["force_mae"]))


def tool_table(result: dict[str, dict[str, Any]]) -> str:
    """E_λ per seed and its mean (N, true normal force), E_P and λmax means, and the change of
    the mean E_λ against ``no tool`` (markdown). A seed whose run never touched the table (the
    guarded approach missed the contact) reads "no contact", its means "—"."""
    seeds = next(iter(result.values()))["seeds"]
    head = ["variant", *(f"E_λ seed {s}" for s in seeds), "E_λ mean", "vs no tool"]
    head += ["E_P mean (mm)", "λmax max (N)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    reference = mean_force_error(result, "no tool") if "no tool" in result else None
    for name, row in result.items():
        mean = float(np.mean(row["force_mae"]))
        if not np.isfinite(mean):
            change = "—"
        else:
            change = "" if reference is None else f"{100.0 * (mean / reference - 1.0):+.1f} %"
        pairs = zip(row["force_mae"], row["contact_missed"], strict=True)
        values = ["no contact" if m else f"{x:.3f}" for x, m in pairs]
        cells = [name, *values, _number(mean, 3), change]
        cells += [
            _number(np.mean(row["position_mae_mm"]), 2),
            _number(np.max(row["max_force"]), 1),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    failed = [f for row in result.values() for f in row["failed"]]
    lines += [f"failed: {f}" for f in failed]
    return "\n".join(lines)


def _number(value: float, digits: int) -> str:
    """``value`` with ``digits`` decimals, "—" when it is not a number (a missed contact)."""
    return f"{value:.{digits}f}" if np.isfinite(value) else "—"
