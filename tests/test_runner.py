"""The ROS-free closed loop (studies.polishing): determinism and force tracking.

Each run here is short (0.3–1.0 s of simulated time, ~1–3 s wall) with the paper's sensing and
actuation imperfections on (noise, delays, random actuation bias, joint friction).
"""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.metrics import limit_ratios
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import PAPER_SCHEDULE, load_scenario
from studies.polishing import run_polishing

#: Contact from the first instant: the tool starts ON the believed table (start_height 0, and
#: with circle_radius 0 the table pivots about the point under the tool, so the tilt cannot lift
#: the surface away nor push it into the tool), the force ramps 0 → 50 N over 0.3 s.
EARLY_CONTACT = {
    **PAPER_SCHEDULE,  # no touch phase, the circle stepped
    "task.still": 0.0,
    "task.reach": 0.1,
    "task.force_ramp": 0.3,
    "task.start_height": 0.0,
}


def _comparable(summary: dict) -> dict:
    """A run summary without its timing fields (wall clock, solve times)."""
    return {k: v for k, v in summary.items() if k not in ("wall_time_s", "solve_time_median_s")}


def test_same_seed_gives_identical_metrics_and_another_seed_does_not() -> None:
    overrides = {**EARLY_CONTACT, "task.force_ramp": 0.1, "seed": 7}
    scenario = load_scenario("polishing", overrides)
    first = run_polishing(scenario, duration=0.3)
    second = run_polishing(load_scenario("polishing", overrides), duration=0.3)
    assert _comparable(first.summary()) == _comparable(second.summary())
    for name, values in first.log.items():
        np.testing.assert_array_equal(values, second.log[name], err_msg=name)
    # The contact really happened (otherwise equality would be trivial).
    assert first.log["force_true"].max() > 5.0

    other = run_polishing(load_scenario("polishing", {**overrides, "seed": 8}), duration=0.3)
    assert other.draws.tilt_angle != first.draws.tilt_angle
    assert other.draws.actuation_gain != first.draws.actuation_gain
    assert not np.array_equal(other.log["force_measured"], first.log["force_measured"])


def test_force_feedback_mpc_reaches_and_holds_the_force_target() -> None:
    """Force-feedback MPC + torque PID, paper noise/delays/bias on: after the 0.3 s ramp (ending
    at t = 0.4 s) the TRUE normal force over the last 0.3 s of a 1 s run stays at 50 N.

    Tolerances: the force sensor noise is σλ = 0.5 N and it is fed back, the actuation noise is
    1 % of the torque limits (≈ 1.8 N·m on the shoulder, a few N at the tool) and the actuation
    bias (a, b) is only compensated by the PID's integral: a held mean within 1.5 N (3 % of the
    target, 3σλ) and every sample within 5 N (10 %) — with no contact break. Seed 0 draws a
    5.3° tilt; measured on this code: mean 50.2 N, samples within ±2.5 N (without the PID the
    same run holds 42.2 N and fails this test: the bias is then uncompensated).
    """
    seed = 0
    scenario = load_scenario(
        "polishing",
        {**EARLY_CONTACT, "task.circle_radius": 0.0, "seed": seed, "pid.enabled": True},
    )
    assert scenario.mpc.ocp.formulation == "force_feedback"
    assert scenario.ft_sensor.force_noise_std == 0.01 and scenario.plant.actuation.random_bias
    result = run_polishing(scenario, duration=1.0)
    t, force = result.log["t"], result.log["force_true"]
    assert np.all(result.log["force_reference"][t >= 0.4] == pytest.approx(50.0))
    held = force[t >= t[-1] - 0.3]
    assert held.size >= 299
    assert abs(held.mean() - 50.0) < 1.5, held.mean()
    assert np.max(np.abs(held - 50.0)) < 5.0, (held.min(), held.max())
    assert held.min() > 1e-3  # no contact break
    # The metrics window (the circle phase, here a hold) agrees: small MAE, no break.
    assert result.metrics_true.force_mae < 2.0
    assert result.metrics_true.contact_break_percent == 0.0


def test_default_polishing_keeps_every_joint_below_its_velocity_limit() -> None:
    """The default polishing scenario (force-feedback MPC, seed 0, 5 s: the whole circle) with
    the joint-limit barrier of the scenario file (bounds at 0.9 of the limits): every joint's
    max |v|/limit stays below 1. Without the barrier (c_lim = 0, the code before it) joint 3
    reached 1.0049 at t = 2.97 s; with c_lim 0.01, measured 0.836. With the orientation terms
    (rotation 20, angular velocity 0.05) and c_lim 0.01, 1.36; the defaults (rotation 5,
    c_lim 1): 0.841 (docs/explanation/mpc.md). ~5 s wall."""
    scenario = load_scenario("polishing")
    assert scenario.seed == 0 and scenario.mpc.ocp.formulation == "force_feedback"
    assert scenario.mpc.cost_weights().state_limit > 0.0
    result = run_polishing(scenario, duration=5.0)
    assert result.log["t"][-1] >= 4.99
    ratios = limit_ratios(result.safety_log["v"], load_robot(scenario.robot).velocity_limit)[0]
    np.testing.assert_array_equal(ratios, result.max_velocity_ratio)
    assert ratios.max() < 1.0, ratios
    assert result.metrics_true.contact_break_percent == 0.0
