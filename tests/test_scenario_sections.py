"""The scenario's sections are the core's configuration classes: the objects a run builds hold
the section as it is (no field-by-field copy), and what they derive from it (per-joint gains,
σ_τ in N·m, the drawn bias) comes from the named functions."""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.actuation import GAIN_RANGE, OFFSET_RANGE, ActuationConfig
from ffmpc_core.errors import ConfigError
from ffmpc_core.pid import PidConfig, TorquePid, TorquePidGains
from ffmpc_core.polishing import (
    actuation_model,
    draw_run,
    joint_sensing_model,
    lowlevel_controller,
)
from ffmpc_core.scenario import SCHEMA, Scenario, load_scenario
from ffmpc_core.sensing import JointSensorConfig


def test_the_sections_are_the_core_classes_and_the_objects_hold_them(robot):
    s = load_scenario("polishing", {"pid.kp": 0.2, "pid.stale_timeout": 0.006})
    assert type(s.pid) is PidConfig
    assert type(s.joint_sensor) is JointSensorConfig
    assert type(s.plant.actuation) is ActuationConfig
    low = lowlevel_controller(s, robot)
    assert low.config.pid is s.pid
    assert low.config.mpc_period == s.mpc.ocp.period
    assert low.config.force_dimension == s.mpc.contact.dimension
    sensing = joint_sensing_model(s, robot.nv, np.random.default_rng(0))
    assert sensing.config is s.joint_sensor


def test_the_pid_of_the_section_is_eq_33_with_gains_scaled_by_the_torque_limits(robot):
    s = load_scenario("polishing", {"pid.kp": 0.2, "pid.ki": 15.0, "pid.integral_fraction": 0.4})
    pid = lowlevel_controller(s, robot).pid
    assert np.array_equal(pid.gains.kp, np.full(7, 0.2))
    assert np.array_equal(pid.gains.ki, np.full(7, 15.0))
    assert np.array_equal(pid.gains.integral_limit, 0.4 * robot.torque_limit)
    assert pid.delay_cycles == s.pid.delay_cycles and pid.enabled == s.pid.enabled
    # the same as the gains given by hand: same torques from the same inputs
    by_hand = TorquePid(
        TorquePidGains.default(robot.torque_limit, 0.2, 15.0, 0.0, 0.4),
        s.plant.time_step,
        delay_cycles=s.pid.delay_cycles,
        torque_limit=robot.torque_limit,
    )
    rng = np.random.default_rng(1)
    for k in range(20):
        measured, desired = rng.standard_normal(7), rng.standard_normal(7)
        t = k * s.plant.time_step
        assert np.array_equal(pid.step(measured, desired, t), by_hand.step(measured, desired, t))


def test_live_limits_replace_the_pid_config_and_keep_the_timeout_above_the_period(robot):
    s = load_scenario("polishing")
    low = lowlevel_controller(s, robot)
    low.set_limits(torque_limit_fraction=0.5, stale_timeout=0.01)
    assert low.config.pid == PidConfig(torque_limit_fraction=0.5, stale_timeout=0.01)
    assert np.array_equal(low.torque_limit, 0.5 * robot.torque_limit)
    with pytest.raises(ConfigError, match="stale_timeout"):
        low.set_limits(stale_timeout=s.mpc.ocp.period)
    assert low.config.pid.stale_timeout == 0.01  # nothing changed
    # live gains: the PID's arrays and the config that states them change together
    low.set_gains(kp=0.3, ki=12.0)
    assert (low.config.pid.kp, low.config.pid.ki, low.config.pid.kd) == (0.3, 12.0, 0.0)
    assert np.array_equal(low.pid.gains.kp, np.full(7, 0.3))
    assert np.array_equal(low.pid.gains.ki, np.full(7, 12.0))
    with pytest.raises(ConfigError):
        low.set_gains(kd=-1.0)
    assert low.config.pid.kd == 0.0 and np.array_equal(low.pid.gains.kd, np.zeros(7))


def test_the_actuation_section_gives_the_run_bias_and_sigma_tau_in_newton_metres(robot):
    s = load_scenario("polishing", {"plant.actuation_noise_fraction": 0.01, "seed": 4})
    draws = draw_run(s, robot, np.random.default_rng(4))
    lo, hi = GAIN_RANGE
    assert all(lo <= a <= hi for a in draws.actuation_gain)
    lo, hi = OFFSET_RANGE
    assert all(lo <= b <= hi for b in draws.actuation_offset)
    params = actuation_model(s, robot, draws, np.random.default_rng(0)).params
    assert np.array_equal(params.torque_noise_std, 0.01 * robot.torque_limit)
    assert params.delay_cycles == s.plant.actuation.delay_cycles
    assert np.array_equal(params.gain, draws.actuation_gain)
    off = load_scenario("polishing", {"plant.actuation_random_bias": False})
    plain = draw_run(off, robot, np.random.default_rng(4))
    assert plain.actuation_gain == (1.0,) * 7 and plain.actuation_offset == (0.0,) * 7


def test_the_actuation_fields_keep_the_plant_section_names():
    names = {
        "plant.actuation_random_bias": ("random_bias", True),
        "plant.actuation_delay_cycles": ("delay_cycles", 3),
        "plant.actuation_noise_fraction": ("noise_fraction", 0.02),
        "plant.static_friction": ("static_friction", 0.7),
        "plant.viscous_friction": ("viscous_friction", 0.2),
        "plant.friction_velocity": ("friction_velocity", 2.0),
    }
    assert set(names) <= set(SCHEMA)
    assert not [n for n in SCHEMA if n.startswith("plant.actuation.")]
    s = Scenario(name="x").with_overrides({name: value for name, (_, value) in names.items()})
    for field_name, value in names.values():
        assert getattr(s.plant.actuation, field_name) == value
