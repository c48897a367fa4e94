"""δo (``mpc.command_delay``): fixed values, the PID setting, and "measured" — the MPC's own
step time on this machine rounded up to the plant step — down to the study's results.json."""

from __future__ import annotations

import json

import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_core.polishing import mpc_config, resolve_command_delay
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from studies.study import grid_specs, run_study

DT = 1e-3  # plant.time_step of the shipped scenarios


def _is_plant_step_multiple(value: float) -> bool:
    return abs(value / DT - round(value / DT)) < 1e-9


@pytest.mark.parametrize(("setting", "cycles"), [(0.0, 0), (0.005, 5), ("0.003", 3)])
def test_a_fixed_value_is_unchanged_and_sets_the_pid_delay_line(setting, cycles):
    scenario = load_scenario("polishing", {"mpc.command_delay": setting})
    assert scenario.pid.delay_cycles == cycles
    resolved, record = resolve_command_delay(scenario)
    assert resolved == scenario
    assert record["delta_o_s"] == pytest.approx(float(setting), abs=1e-15)
    assert mpc_config(resolved).command_delay == pytest.approx(float(setting), abs=1e-15)


def test_pid_setting_keeps_pid_delay_cycles_and_an_explicit_cycle_override_wins():
    scenario = load_scenario("polishing")
    assert scenario.mpc.command_delay == "pid"
    resolved, record = resolve_command_delay(scenario)
    assert resolved == scenario and record["delta_o_s"] == pytest.approx(5 * DT)
    fixed = scenario.with_overrides({"mpc.command_delay": 0.002})
    # the paper-timing override (docs/tutorials/polishing.md)
    again = fixed.with_overrides({"pid.delay_cycles": 0})
    assert again.pid.delay_cycles == 0 and again.mpc.command_delay == "pid"
    with pytest.raises(ConfigError, match="whole number of plant steps"):
        scenario.with_overrides({"mpc.command_delay": 0.0025})
    for bad in ("soon", -0.001, float("nan"), True):
        with pytest.raises(ConfigError):
            scenario.with_overrides({"mpc.command_delay": bad})


@pytest.mark.parametrize(("median", "cycles"), [(0.0037, 4), (0.004, 4), (0.00401, 5), (0.0, 0)])
def test_a_measured_median_is_rounded_up_to_the_plant_step(median, cycles):
    scenario = load_scenario("polishing", {"mpc.command_delay": "measured"})
    with pytest.raises(ConfigError, match="resolve"):
        mpc_config(scenario)
    resolved, record = resolve_command_delay(scenario, measured=median)
    assert resolved.pid.delay_cycles == cycles == record["delay_cycles"]
    assert record["delta_o_s"] == pytest.approx(cycles * DT, abs=1e-15)
    assert record["delta_o_s"] >= median and record["measured_step_median_s"] == median
    assert mpc_config(resolved).command_delay == pytest.approx(cycles * DT, abs=1e-15)


def test_a_measured_delay_must_stay_inside_the_horizon():
    scenario = load_scenario("polishing", {"mpc.command_delay": "measured"})  # N·Δt = 15 ms
    with pytest.raises(ConfigError, match="horizon"):
        resolve_command_delay(scenario, measured=0.0151)


def test_measured_resolves_from_a_calibration_run_of_the_same_mpc():
    # N·Δt = 200 ms: room for a slow step on a loaded machine.
    overrides = {"mpc.horizon": 20, "mpc.dt": 0.01, "mpc.formulation": "classical"}
    scenario = load_scenario("polishing", {"mpc.command_delay": "measured", **overrides})
    resolved, record = resolve_command_delay(scenario, load_robot("iiwa"), steps=6)
    median = record["measured_step_median_s"]
    assert median > 0.0 and record["calibration_steps"] == 6
    assert _is_plant_step_multiple(record["delta_o_s"])
    assert median <= record["delta_o_s"] < median + DT + 1e-12
    assert resolved.pid.delay_cycles * DT == pytest.approx(record["delta_o_s"])


def test_the_study_writes_the_delta_o_it_used(tmp_path):
    short = {"task.still": 0.0, "task.reach": 0.02, "mpc.command_delay": "measured"}
    short |= {"mpc.horizon": 20, "mpc.dt": 0.01}  # room for a slow step on a loaded machine
    specs = grid_specs("polishing", ["classical"], [True], [0], duration=0.05, overrides=short)
    report = run_study("polishing", specs, tmp_path / "out", workers=1, progress=False)
    doc = json.loads((tmp_path / "out" / "results.json").read_text())
    record = doc["command_delay"]["classical"]
    assert record["setting"] == "measured"
    assert _is_plant_step_multiple(record["delta_o_s"])
    assert record["delta_o_s"] >= record["measured_step_median_s"] > 0.0
    assert [r["command_delay_s"] for r in doc["runs"]] == [record["delta_o_s"]]
    assert report.document["overrides"]["mpc.command_delay"] == "measured"
