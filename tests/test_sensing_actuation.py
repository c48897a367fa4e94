"""Sensing (eq 30, 32) and actuation (eq 31) models: exact delays, noise statistics,
reproducibility, friction and bias formulas."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ffmpc_core.actuation import (
    ActuationConfig,
    ActuationModel,
    ActuationParams,
    actuation_torque,
    joint_friction,
)
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.robots import load_robot
from ffmpc_core.sensing import (
    DelayLine,
    ForceSensingModel,
    JointSensingModel,
    JointSensorConfig,
    delay_cycles,
)

NV = 7


@pytest.mark.parametrize("k", [0, 1, 2, 5])
def test_delay_line_delays_by_exactly_k_cycles(k):
    line = DelayLine(k, shape=2)
    outputs = [line.step(np.array([n, -n], dtype=float)) for n in range(12)]
    for n, out in enumerate(outputs):
        expected = max(n - k, 0)  # before k samples exist: the first sample
        assert np.array_equal(out, [expected, -expected])
    line.reset(initial=np.array([7.0, 7.0]))
    outputs = [line.step(np.array([n, n], dtype=float)) for n in range(k + 3)]
    assert all(np.array_equal(o, [7.0, 7.0]) for o in outputs[:k])
    assert [o[0] for o in outputs[k:]] == [0.0, 1.0, 2.0]


def test_delay_line_output_is_a_copy_and_inputs_checked():
    line = DelayLine(0, shape=3)
    x = np.ones(3)
    y = line.step(x)
    y[0] = 5.0
    assert np.array_equal(line.step(x), np.ones(3))
    with pytest.raises(InputError):
        line.step(np.ones(2))
    with pytest.raises(InputError):
        line.step(np.array([1.0, np.nan, 0.0]))
    with pytest.raises(ConfigError):
        DelayLine(-1)
    with pytest.raises(ConfigError):
        DelayLine(1.5)


def test_delay_cycles_of_seconds():
    assert delay_cycles(0.005, 0.001) == 5  # δo at 1 kHz
    assert delay_cycles(0.005, 0.0005) == 10  # δo at 2 kHz
    assert delay_cycles(0.0, 0.001) == 0
    with pytest.raises(ConfigError):
        delay_cycles(0.0025, 0.001)
    with pytest.raises(ConfigError):
        delay_cycles(-0.001, 0.001)


@pytest.mark.parametrize("k", [0, 1, 3])
def test_sensing_delays_q_v_and_force_by_exactly_k_cycles(k):
    config = JointSensorConfig(delay_cycles=k, position_noise_std=0.0, velocity_noise_std=0.0)
    model = JointSensingModel(config, NV, rng=np.random.default_rng(0))
    force = ForceSensingModel(k, 0.0, 3, np.random.default_rng(0))
    signal = [np.arange(NV) + 10.0 * n for n in range(10)]
    for n in range(10):
        q_hat, v_hat = model.step(signal[n], -signal[n])
        f_hat = force.step(signal[n][:3] + 1.0)
        source = signal[max(n - k, 0)]
        assert np.array_equal(q_hat, source)
        assert np.array_equal(v_hat, -source)
        assert np.array_equal(f_hat, source[:3] + 1.0)


def test_sensing_noise_has_the_given_standard_deviations():
    config = JointSensorConfig(delay_cycles=0, position_noise_std=1e-3, velocity_noise_std=2e-3)
    model = JointSensingModel(config, NV, rng=np.random.default_rng(1))
    force = ForceSensingModel(0, 0.5, 1, np.random.default_rng(2))
    n = 20000
    q0 = np.linspace(-1.0, 1.0, NV)
    samples = [model.step(q0, np.zeros(NV)) for _ in range(n)]
    q_err = np.array([s[0] for s in samples]) - q0
    v_err = np.array([s[1] for s in samples])
    f_err = np.array([force.step(np.array([50.0])) for _ in range(n)]) - 50.0
    # The sample std of n Gaussian draws has a relative std of 1/sqrt(2n) = 0.5 %: 3 % is
    # six sigma; the mean's std is σ/sqrt(n).
    for err, sigma in ((q_err, 1e-3), (v_err, 2e-3), (f_err, 0.5)):
        assert np.allclose(err.std(axis=0), sigma, rtol=0.03)
        assert np.all(np.abs(err.mean(axis=0)) < 5.0 * sigma / math.sqrt(n))
    # the joints' noises are independent
    corr = np.corrcoef(q_err.T)
    assert np.abs(corr - np.eye(NV)).max() < 0.05


def test_same_seed_same_measurements_different_seed_different():
    def run(seed):
        model = JointSensingModel(JointSensorConfig(), NV, rng=np.random.default_rng(seed))
        return np.concatenate(
            [np.concatenate(model.step(np.zeros(NV), np.ones(NV))) for _ in range(50)]
        )

    assert np.array_equal(run(4), run(4))
    assert not np.allclose(run(4), run(5))


def test_sensing_rejects_bad_input():
    model = JointSensingModel(JointSensorConfig(), NV, rng=np.random.default_rng(0))
    with pytest.raises(InputError):
        model.step(np.zeros(NV - 1), np.zeros(NV))
    with pytest.raises(ConfigError):
        JointSensorConfig(position_noise_std=-1.0)
    with pytest.raises(ConfigError):
        JointSensorConfig(delay_cycles=-1)
    with pytest.raises(ConfigError):
        JointSensingModel(JointSensorConfig(), NV, rng=np.random.RandomState(0))


def test_joint_friction_matches_its_formula():
    v = np.array([-2.0, -0.3, -1e-3, 0.0, 1e-3, 0.3, 2.0])
    mu_s, mu_v, v_s = 1.0, 0.5, 0.2
    expected = [mu_s * math.tanh(x / v_s) + mu_v * x for x in v]
    assert np.allclose(joint_friction(v, mu_s, mu_v, v_s), expected, rtol=1e-14, atol=0)
    # far from rest it is Coulomb + viscous, at rest it vanishes and opposes the motion
    assert joint_friction(np.array([5.0]), mu_s, mu_v, v_s)[0] == pytest.approx(1.0 + 2.5)
    assert joint_friction(np.array([0.0]), mu_s, mu_v, v_s)[0] == 0.0
    tau_hat = actuation_torque(
        np.full(7, 10.0), v, 1.1, -0.5, mu_s, mu_v, v_s, noise=np.full(7, 0.25)
    )
    assert np.allclose(tau_hat, 1.1 * 10.0 - 0.5 - np.array(expected) + 0.25)


def test_bias_draws_are_uniform_in_the_paper_ranges():
    limit = load_robot("iiwa").torque_limit
    config = ActuationConfig(noise_fraction=0.01)

    def draw(seed):
        gain, offset = config.draw_bias(np.random.default_rng(seed), limit.size)
        return ActuationParams.from_config(config, limit, gain, offset)

    draws = [draw(s) for s in range(400)]
    gains = np.array([d.gain for d in draws])
    offsets = np.array([d.offset for d in draws])
    assert gains.min() >= 0.8 and gains.max() <= 1.2
    assert offsets.min() >= -2.0 and offsets.max() <= 2.0
    # uniform: mean at the centre, std = width/sqrt(12) (2800 draws: a few % tolerance)
    assert gains.mean() == pytest.approx(1.0, abs=0.01)
    assert gains.std() == pytest.approx(0.4 / math.sqrt(12), rel=0.05)
    assert offsets.mean() == pytest.approx(0.0, abs=0.05)
    assert offsets.std() == pytest.approx(4.0 / math.sqrt(12), rel=0.05)
    assert np.allclose(draws[0].torque_noise_std, 0.01 * limit)
    again = draw(0)
    assert np.array_equal(again.gain, draws[0].gain)
    assert np.array_equal(again.offset, draws[0].offset)
    # without random_bias: a = 1, b = 0, and nothing is drawn
    rng = np.random.default_rng(0)
    gain, offset = ActuationConfig(random_bias=False).draw_bias(rng, limit.size)
    assert np.array_equal(gain, np.ones(7)) and np.array_equal(offset, np.zeros(7))
    assert rng.bit_generator.state == np.random.default_rng(0).bit_generator.state


@pytest.mark.parametrize("k", [0, 1, 4])
def test_actuation_delays_the_motor_torque_by_exactly_k_cycles(k):
    params = ActuationParams(
        gain=np.full(NV, 0.9),
        offset=np.linspace(-1.0, 1.0, NV),
        torque_noise_std=np.zeros(NV),
        delay_cycles=k,
        static_friction=1.0,
        viscous_friction=0.5,
        friction_velocity=1.0,
    )
    model = ActuationModel(params, np.random.default_rng(0))
    commands = [np.full(NV, 3.0 * n + 1.0) for n in range(10)]
    velocity = np.linspace(-0.4, 0.4, NV)
    friction = joint_friction(velocity, 1.0, 0.5, 1.0)
    for n in range(10):
        tau_hat = model.step(commands[n], velocity)
        expected = 0.9 * commands[max(n - k, 0)] + params.offset - friction
        assert np.allclose(tau_hat, expected, rtol=0, atol=1e-12)


def test_actuation_noise_std_and_reproducibility():
    sigma = np.array([1.76, 1.76, 1.1, 1.1, 1.1, 0.4, 0.4])
    params = ActuationParams(
        gain=np.ones(NV),
        offset=np.zeros(NV),
        torque_noise_std=sigma,
        delay_cycles=0,
        static_friction=0.0,
        viscous_friction=0.0,
    )

    def run(seed, n=20000):
        model = ActuationModel(params, np.random.default_rng(seed))
        return np.array([model.step(np.full(NV, 5.0), np.zeros(NV)) for _ in range(n)]) - 5.0

    noise = run(2)
    assert np.allclose(noise.std(axis=0), sigma, rtol=0.03)
    assert np.array_equal(noise[:100], run(2, 100))
    assert not np.allclose(noise[:100], run(3, 100))


def test_actuation_rejects_bad_parameters_and_inputs():
    with pytest.raises(ConfigError):
        ActuationParams(gain=np.ones(NV), offset=np.zeros(NV), torque_noise_std=-np.ones(NV))
    with pytest.raises(ConfigError):
        ActuationParams(
            gain=np.ones(NV), offset=np.zeros(NV), torque_noise_std=0.0, friction_velocity=0.0
        )
    with pytest.raises(ConfigError):
        ActuationParams(gain=np.ones(NV), offset=np.zeros(3), torque_noise_std=0.0)
    model = ActuationModel(ActuationParams.ideal(NV), np.random.default_rng(0))
    with pytest.raises(InputError):
        model.step(np.full(NV, np.inf), np.zeros(NV))
    with pytest.raises(InputError):
        model.step(np.zeros(NV), np.zeros(NV + 1))
