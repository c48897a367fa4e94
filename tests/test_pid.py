"""The low-level torque PID (eq 33): exact δo delay, tracking on the affine actuation model,
integral over time, anti-windup, derivative, the "without PID" mode and input checks."""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.actuation import ActuationModel, ActuationParams
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.pid import TorquePid, TorquePidGains
from ffmpc_core.robots import load_robot
from ffmpc_core.sensing import delay_cycles

NV = 7


def gains(kp=0.5, ki=100.0, kd=0.0, limit=50.0):
    return TorquePidGains(
        kp=np.full(NV, kp),
        ki=np.full(NV, ki),
        kd=np.full(NV, kd),
        integral_limit=np.full(NV, limit),
    )


@pytest.mark.parametrize("dt", [1e-3, 5e-4])
@pytest.mark.parametrize("enabled", [False, True])
def test_desired_torque_is_delayed_by_exactly_delta_o(dt, enabled):
    k = delay_cycles(0.005, dt)  # δo = 5 ms
    pid = TorquePid(gains(), dt, delay_cycles=k, enabled=enabled)
    desired = [np.full(NV, 1.0 + n) for n in range(30)]
    for n in range(30):
        delayed = desired[max(n - k, 0)]
        # measured = the delayed desired: no error, so the PID passes the feed-forward through
        out = pid.step(delayed, desired[n], t=n * dt)
        assert np.array_equal(out, delayed)


def closed_loop(pid, actuation, desired, cycles, dt):
    """τ̂ from the actuation model fed by the PID, at zero joint velocity (no friction)."""
    measured = actuation.step(desired, np.zeros(NV))  # the motor was already producing τ^d
    for n in range(cycles):
        motor = pid.step(measured, desired, t=n * dt)
        measured = actuation.step(motor, np.zeros(NV))
    return measured


def affine_actuation(a, b, noise=0.0):
    params = ActuationParams(
        gain=np.full(NV, a),
        offset=np.full(NV, b),
        torque_noise_std=np.full(NV, noise),
        delay_cycles=1,  # δs = 1 cycle
        static_friction=0.0,
        viscous_friction=0.0,
    )
    return ActuationModel(params, np.random.default_rng(0))


@pytest.mark.parametrize("a", [0.8, 1.2])
def test_integral_removes_the_steady_state_error_of_the_affine_bias(a):
    dt, b = 1e-3, 2.0
    desired = np.linspace(-40.0, 60.0, NV)
    pid = TorquePid(gains(), dt, delay_cycles=5)
    measured = closed_loop(pid, affine_actuation(a, b), desired, cycles=400, dt=dt)
    assert np.allclose(measured, desired, atol=1e-6)


def test_without_integral_the_error_is_the_proportional_steady_state():
    dt, a, b, kp = 1e-3, 0.8, 2.0, 0.5
    desired = np.array([-40.0, -25.0, -5.0, 5.0, 20.0, 35.0, 60.0])  # (a − 1)τ^d + b ≠ 0
    pid = TorquePid(gains(kp=kp, ki=0.0), dt, delay_cycles=5)
    measured = closed_loop(pid, affine_actuation(a, b), desired, cycles=400, dt=dt)
    # τ̂ = a(τ^d − K_P(τ̂ − τ^d)) + b  ⇒  τ̂ − τ^d = ((a − 1)τ^d + b) / (1 + a·K_P)
    expected = ((a - 1.0) * desired + b) / (1.0 + a * kp)
    assert np.allclose(measured - desired, expected, atol=1e-9)
    assert np.abs(measured - desired).min() > 0.1
    # and without any feedback the error is the full bias (a − 1)τ^d + b
    open_loop = TorquePid(gains(), dt, delay_cycles=5, enabled=False)
    measured = closed_loop(open_loop, affine_actuation(a, b), desired, cycles=50, dt=dt)
    assert np.allclose(measured - desired, (a - 1.0) * desired + b, atol=1e-9)


def test_default_gains_track_with_noise_and_bias():
    """Default gains on the iiwa's limits: the mean tracking error over 0.5 s is the noise's."""
    limit = load_robot("iiwa").torque_limit
    dt, a, b = 1e-3, 1.2, -2.0
    pid = TorquePid(TorquePidGains.default(limit), dt, delay_cycles=5)
    actuation = ActuationModel(
        ActuationParams(
            gain=np.full(NV, a),
            offset=np.full(NV, b),
            torque_noise_std=0.01 * limit,
            static_friction=0.0,
            viscous_friction=0.0,
        ),
        np.random.default_rng(1),
    )
    desired = 0.3 * limit
    measured = actuation.step(desired, np.zeros(NV))
    errors = []
    for n in range(700):
        motor = pid.step(measured, desired, t=n * dt)
        measured = actuation.step(motor, np.zeros(NV))
        if n >= 200:
            errors.append(measured - desired)
    errors = np.array(errors)
    assert np.all(np.abs(errors.mean(axis=0)) < 0.1 * 0.01 * limit + 1e-3)  # unbiased
    assert np.all(errors.std(axis=0) < 3.0 * 0.01 * limit)  # bounded: the loop is stable


@pytest.mark.parametrize("dt", [1e-3, 5e-4])
def test_integral_integrates_over_time(dt):
    ki, error, seconds = 2.0, 1.5, 0.1
    pid = TorquePid(gains(kp=0.0, ki=ki, limit=1e6), dt, delay_cycles=0)
    desired = np.full(NV, 10.0)
    cycles = round(seconds / dt)
    for n in range(cycles):
        out = pid.step(desired + error, desired, t=n * dt)
    assert np.allclose(out, desired - ki * error * seconds, atol=1e-12)
    assert np.allclose(pid.integral, error * seconds)


def test_anti_windup_clamps_the_integral_term():
    limit = 3.0
    pid = TorquePid(gains(kp=0.0, ki=100.0, limit=limit), 1e-3, delay_cycles=0)
    desired = np.zeros(NV)
    for n in range(1000):
        out = pid.step(desired + 5.0, desired, t=n * 1e-3)
    assert np.allclose(out, -limit)
    # the integral unwinds as soon as the error changes sign: 10 cycles of −5 remove 0.05 N·m·s
    for n in range(1000, 1010):
        out = pid.step(desired - 5.0, desired, t=n * 1e-3)
    assert np.allclose(out, -(limit - 100.0 * 5.0 * 10 * 1e-3))


def test_derivative_acts_on_the_measured_torque_rate():
    dt, kd = 1e-3, 0.01
    pid = TorquePid(gains(kp=0.0, ki=0.0, kd=kd), dt, delay_cycles=0)
    desired = np.zeros(NV)
    outputs = [pid.step(np.full(NV, 2.0 * n), desired, t=n * dt) for n in range(5)]
    assert np.allclose(outputs[0], 0.0)  # no derivative at the first call
    for out in outputs[1:]:
        assert np.allclose(out, -kd * 2.0 / dt)  # slope 2 N·m per cycle = 2000 N·m/s


def test_reset_and_input_checks():
    pid = TorquePid(gains(), 1e-3, delay_cycles=2)
    pid.step(np.ones(NV), np.zeros(NV), t=0.0)
    with pytest.raises(InputError):
        pid.step(np.ones(NV), np.zeros(NV), t=0.0)  # time must increase
    with pytest.raises(InputError):
        pid.step(np.full(NV, np.nan), np.zeros(NV), t=1.0)
    with pytest.raises(InputError):
        pid.step(np.ones(NV - 1), np.zeros(NV), t=1.0)
    pid.reset()
    assert np.array_equal(pid.integral, np.zeros(NV))
    out = pid.step(np.full(NV, 3.0), np.full(NV, 3.0), t=0.0)  # t may restart after reset
    assert np.array_equal(out, np.full(NV, 3.0))
    with pytest.raises(ConfigError):
        TorquePidGains(kp=np.ones(NV), ki=-np.ones(NV), kd=np.zeros(NV), integral_limit=1.0)
    with pytest.raises(ConfigError):
        TorquePid(gains(), dt=0.0)
    with pytest.raises(ConfigError):
        TorquePid(gains(), dt=1e-3, delay_cycles=-1)
