"""The joint-position observer (``mpc.position_observer_time``): its noise against the formulas
of ffmpc_core.joint_observer, no lag at constant acceleration, restarts and bad input, and in
closed loop the MPC's torque command no longer chattering with the paper's position noise."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.joint_observer import JointPositionObserver, position_observer_gain
from ffmpc_core.mpc import MpcConfig
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from studies.polishing import run_polishing

DT = 0.002  # s, the MPC's period
T = 0.1  # s, the polishing scenarios' observer time constant


@pytest.fixture(scope="module")
def iiwa():
    return load_robot("iiwa")


def _stationary_error(robot, position_noise: float, velocity_noise: float) -> float:
    """Std of q̂ − q (rad) for a robot at rest measured with white noise, after the start."""
    rng = np.random.default_rng(7)
    observer = JointPositionObserver(robot, T, max_gap=0.02)
    q = robot.q_nominal
    errors = []
    for k in range(8000):
        estimate = observer.update(
            q + position_noise * rng.standard_normal(robot.nq),
            velocity_noise * rng.standard_normal(robot.nv),
            k * DT,
        )
        if k >= 1000:
            errors.append(estimate - q)
    return float(np.std(errors))


def test_position_noise_is_divided_as_the_formula_says(iiwa):
    alpha = position_observer_gain(T, DT)
    expected = 1e-3 * math.sqrt((1.0 - alpha) / (1.0 + alpha))  # 1e-4 rad: ×0.1
    assert _stationary_error(iiwa, 1e-3, 0.0) == pytest.approx(expected, rel=0.1)


def test_integrated_velocity_noise_stays_near_its_estimate(iiwa):
    expected = 1e-3 * math.sqrt(T * DT / 2.0)  # 1e-5 rad
    assert _stationary_error(iiwa, 0.0, 1e-3) == pytest.approx(expected, rel=0.25)


def test_no_lag_at_constant_acceleration(iiwa):
    """The trapezoid integrates a linearly changing velocity exactly: q̂ = q with exact
    measurements, although the estimate leans on the integrated velocity (α ≈ 0.98)."""
    observer = JointPositionObserver(iiwa, T, max_gap=0.02)
    q0, v0 = iiwa.q_nominal, np.linspace(-1.0, 1.0, iiwa.nv)
    acceleration = np.linspace(20.0, -20.0, iiwa.nv)  # rad/s²
    worst = 0.0
    for k in range(400):
        t = k * DT
        q = q0 + v0 * t + 0.5 * acceleration * t**2
        worst = max(worst, float(np.max(np.abs(observer.update(q, v0 + acceleration * t, t) - q))))
    assert worst < 1e-12


def test_the_estimate_follows_a_position_step_within_its_time_constant(iiwa):
    """A position change the velocities do not show (an encoder offset) is taken in with T."""
    observer = JointPositionObserver(iiwa, T, max_gap=0.02)
    q, v = iiwa.q_nominal, np.zeros(iiwa.nv)
    observer.update(q, v, 0.0)
    shifted = q + 0.01
    steps = int(round(T / DT))
    for k in range(1, steps + 1):
        estimate = observer.update(shifted, v, k * DT)
    np.testing.assert_allclose(estimate - q, 0.01 * (1.0 - math.exp(-1.0)), rtol=1e-9)


def test_restarts_from_the_measurement(iiwa):
    observer = JointPositionObserver(iiwa, T, max_gap=0.02)
    q, v = iiwa.q_nominal, np.zeros(iiwa.nv)
    observer.update(q, v, 0.0)
    for t in (0.03, 0.01):  # a gap longer than max_gap, then time going back
        jump = q + t
        np.testing.assert_array_equal(observer.update(jump, v, t), jump)
    observer.reset()
    np.testing.assert_array_equal(observer.update(q, v, 0.012), q)
    # T = 0: the measurement as it is, always
    raw = JointPositionObserver(iiwa, 0.0, max_gap=0.02)
    for k in range(3):
        np.testing.assert_array_equal(raw.update(q + k, v + 1.0, k * DT), q + k)


def test_bad_input_is_refused_and_leaves_the_estimate(iiwa):
    observer = JointPositionObserver(iiwa, T, max_gap=0.02)
    q, v = iiwa.q_nominal, np.zeros(iiwa.nv)
    first = observer.update(q, v, 0.0)
    bad_q = q.copy()
    bad_q[2] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        observer.update(bad_q, v, DT)
    with pytest.raises(InputError, match="size"):
        observer.update(q[:3], v, DT)
    # the next good sample continues from the last good estimate, not from a restart
    shifted = q + 0.01
    alpha = position_observer_gain(T, 2 * DT)
    np.testing.assert_allclose(
        observer.update(shifted, v, 2 * DT), shifted + alpha * (first - shifted), rtol=1e-12
    )
    with pytest.raises(ConfigError):
        JointPositionObserver(iiwa, -0.1, max_gap=0.02)
    with pytest.raises(ConfigError):
        MpcConfig(position_observer_time=float("nan"))
    with pytest.raises(ConfigError, match="position_observer_time"):
        load_scenario("polishing", overrides={"mpc.position_observer_time": -1.0})


def _command_chatter(observer_time: float) -> np.ndarray:
    """Median |τ^d change| per MPC tick (N·m, per joint) over the stand-still and the reach of
    the classical MPC at the polishing defaults (the paper's σ_q = 1e-3 rad)."""
    scenario = load_scenario(
        "polishing",
        overrides={
            "mpc.formulation": "classical",
            "seed": 101,
            "mpc.position_observer_time": observer_time,
        },
    )
    log = run_polishing(scenario, duration=0.5).log
    every = int(round(scenario.mpc.ocp.period / scenario.plant.time_step))
    commands = log["tau_desired"][every::every]  # one row per MPC tick
    return np.median(np.abs(np.diff(commands, axis=0)), axis=0)


def test_the_observer_stops_the_torque_command_chattering():
    """Measured (ffmpc_core.joint_observer): without the observer joint 3's command changes by
    ~10 N·m from one 2 ms tick to the next in free space, with it by ~0.25 N·m."""
    raw, observed = _command_chatter(0.0), _command_chatter(T)
    assert raw[2] > 3.0
    assert observed[2] < raw[2] / 10.0
    assert np.all(observed <= raw + 1e-9)
