"""Learning stiffness and damping (Dehio & Kheddar 2020, eq 15–21) and the exploration motion."""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.learner import (
    RecursiveContactLearner,
    exploration_reference,
    fit_stiffness_damping,
    model_error,
    predict_force,
    stack_data,
)

ALPHA, BETA = 2000.0, 50.0  # N/m, N·s/m
SIGMA = 0.5  # N: force-sensor noise (a Panda-class F/T estimate is ~0.5–1 N)


def _synthetic(rng: np.random.Generator, sigma: float = SIGMA):
    """Contact samples of the exploration reference with noisy forces (eq 3 + noise)."""
    ref = exploration_reference(max_penetration=0.05, dt=2e-3)
    inside = ref.deformation > 0
    z, zd = ref.deformation[inside], ref.deformation_rate[inside]
    f = ALPHA * z + BETA * zd + rng.normal(scale=sigma, size=z.size)
    return z, zd, f


@pytest.mark.parametrize("lam", [0.0, 1e-6, 1e-2])
def test_recursive_equals_batch_least_squares(lam):
    rng = np.random.default_rng(21)
    z = rng.uniform(0.0, 0.03, 500)
    zd = rng.normal(0.0, 0.2, 500)
    f = 1500.0 * z + 30.0 * zd + rng.normal(0.0, 1.0, 500)
    learner = RecursiveContactLearner(regularization=lam)
    for k in range(z.size):
        learner.update(z[k], zd[k], f[k])
        if k in (5, 50, 499):  # identical at every step, not only at the end
            S, F = stack_data(z[: k + 1], zd[: k + 1], f[: k + 1])
            np.testing.assert_allclose(
                learner.coefficients(), fit_stiffness_damping(S, F, lam), rtol=1e-9
            )
    other = RecursiveContactLearner(regularization=lam)
    other.update_batch(z, zd, f)
    np.testing.assert_allclose(other.coefficients(), learner.coefficients(), rtol=1e-10)


def test_learner_recovers_stiffness_and_damping_within_noise():
    """With K samples and noise σ the estimate's standard error is σ·sqrt(diag((S Sᵀ)⁻¹)); we
    require the error below 4 standard errors (false-alarm rate ~1e-4) and the learner's own
    standard errors within 10 % of that theory (σ̂ from K ~ 4000 samples is ±2 %)."""
    rng = np.random.default_rng(1234)
    z, zd, f = _synthetic(rng)
    learner = RecursiveContactLearner()
    learner.update_batch(z, zd, f)
    est = learner.estimate()
    S, _ = stack_data(z, zd, f)
    se = SIGMA * np.sqrt(np.diag(np.linalg.inv(S @ S.T)))
    assert abs(est.stiffness - ALPHA) < 4 * se[0]
    assert abs(est.damping - BETA) < 4 * se[1]
    assert est.stiffness_std == pytest.approx(se[0], rel=0.1)
    assert est.damping_std == pytest.approx(se[1], rel=0.1)
    assert est.noise_std == pytest.approx(SIGMA, rel=0.1)
    assert abs(est.stiffness - ALPHA) / ALPHA < 0.01 and abs(est.damping - BETA) / BETA < 0.05
    # eq 16/18: the model error is the noise variance
    E = np.array([est.stiffness, est.damping])
    assert model_error(E, S, f[None, :]) == pytest.approx(SIGMA**2, rel=0.1)
    np.testing.assert_allclose(predict_force(E, S)[0], E[0] * z + E[1] * zd)


def test_confidence_measure_is_calibrated():
    """Over many seeded noise draws, |α̂ − α| < 2 se holds about 95 % of the time."""
    rng = np.random.default_rng(99)
    z0, zd0, _ = _synthetic(rng)
    hits = np.zeros(2)
    n = 300
    for _ in range(n):
        f = ALPHA * z0 + BETA * zd0 + rng.normal(scale=SIGMA, size=z0.size)
        learner = RecursiveContactLearner()
        learner.update_batch(z0, zd0, f)
        est = learner.estimate()
        hits += [
            abs(est.stiffness - ALPHA) < 2 * est.stiffness_std,
            abs(est.damping - BETA) < 2 * est.damping_std,
        ]
    coverage = hits / n
    assert np.all((coverage > 0.90) & (coverage < 0.99)), coverage


def test_exploration_reference_reaches_the_impact_velocities():
    ref = exploration_reference(max_penetration=0.04, dt=1e-3)
    assert ref.deformation.max() <= 0.04 + 1e-12
    np.testing.assert_allclose(ref.impact_velocities, np.linspace(0.15, 0.35, 5))
    # velocity when crossing the surface downwards (z from < 0 to ≥ 0) in each impact phase
    crossing = np.flatnonzero((ref.deformation[:-1] < 0) & (ref.deformation[1:] >= 0)) + 1
    assert crossing.size == 5
    np.testing.assert_allclose(ref.deformation_rate[crossing], ref.impact_velocities, rtol=0.02)
    # continuity: positions do not jump more than the velocity allows
    dz = np.abs(np.diff(ref.deformation))
    assert np.all(dz <= np.abs(ref.deformation_rate).max() * 1e-3 * 1.05 + 1e-9)
    # velocity is the derivative of position
    np.testing.assert_allclose(
        np.gradient(ref.deformation, 1e-3)[5:-5], ref.deformation_rate[5:-5], atol=0.02
    )
    assert ref.phase[0] == 0 and ref.phase.max() == 5


def test_learner_input_validation():
    with pytest.raises(ConfigError):
        RecursiveContactLearner(regularization=-1.0)
    learner = RecursiveContactLearner(regularization=0.0)
    with pytest.raises(InputError):
        learner.update(np.nan, 0.0, 1.0)
    with pytest.raises(InputError):
        learner.coefficients()  # no data: (S Sᵀ) singular
    with pytest.raises(InputError):
        stack_data([0.1, 0.2], [0.0], [1.0, 2.0])
    with pytest.raises(ConfigError):
        exploration_reference(max_penetration=0.02, sine_amplitude=0.03)
