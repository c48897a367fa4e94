"""The contact learner's exploration routine in PyBullet (studies.exploration).

Two closed-loop runs (module fixture, ~10 s simulated): the dice (2 sine periods, impacts at
0.15 and 0.35 m/s) and the rubber (1 period, an impact at 0.25 m/s, the fastest its 9 mm stop
allows). ``ffmpc study explore`` runs the full routine on three materials.
"""

from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.deformation import predicted_force_increase
from ffmpc_core.impact.exploration import sticking_contact_force
from ffmpc_core.impact.learner import fit_stiffness_damping, stack_data
from ffmpc_core.impact.limits import motion_basis
from ffmpc_core.impact.metrics import surface_offset_bias
from ffmpc_core.impact.scenario import MATERIALS, ExplorationConfig, Material
from studies.exploration import (
    format_checkpoints,
    format_summary,
    run_exploration,
    run_exploration_study,
)

DT = 1e-3


@pytest.fixture(scope="module")
def runs():
    dice = ExplorationConfig(
        material=MATERIALS["dice"], sine_cycles=2, impact_velocities=(0.15, 0.35)
    )
    rubber = ExplorationConfig(
        material=MATERIALS["rubber"], sine_cycles=1, impact_velocities=(0.25,)
    )
    return {"dice": run_exploration(dice), "rubber": run_exploration(rubber)}


def test_learner_recovers_the_material_set_in_pybullet(runs):
    """Noise-free forces: what is left is the measurement of z. The surface is the last
    force-free sample of the 5 mm/s approach, so z is at most 5 µm too large; the bound of that
    on Ê (surface_offset_bias, ~0.03 % of α on the dice, 0.07 % on the stiffer and thinner
    rubber) plus 2 learner standard errors must contain the truth, and that interval must be
    tight (< 0.1 %) for the check to mean something. Bullet's soft contact fits eq 3 to
    sub-mN elsewhere, so nothing else may show."""
    for name, run in runs.items():
        m = run.material
        final = run.final
        assert final.covers(m), (name, final)
        half_a, half_b = final.interval()
        assert half_a < 1e-3 * m.stiffness and half_b < 1e-3 * m.damping, name
        err_a, err_b = final.relative_errors(m)
        assert abs(err_a) < 1e-3 and abs(err_b) < 1e-3, name
        assert final.estimate.noise_std < 5e-3  # N: eq 3 holds on every sample fed
        assert final.z_bias_bound[0] > 10 * 2 * final.estimate.stiffness_std  # z dominates


def test_estimate_after_the_sinusoid_and_after_each_impact(runs):
    run = runs["dice"]
    labels = [c.label for c in run.checkpoints]
    assert labels == ["sinusoid", "impact 1", "impact 2"]
    samples = [c.estimate.samples for c in run.checkpoints]
    assert samples == sorted(samples) and samples[0] > 1000  # 2 s of sinusoid at 1 kHz
    assert np.isnan(run.checkpoints[0].pre_impact_velocity)
    # the impacts happen at the planned velocities (tracked to 2 %)
    measured = [c.pre_impact_velocity for c in run.checkpoints[1:]]
    np.testing.assert_allclose(measured, [0.15, 0.35], rtol=0.02)
    for c in run.checkpoints:
        assert c.covers(run.material), c.label
    # the sinusoid alone (no impacts, ż ≤ 5.7 cm/s) already identifies the damping
    err_a, err_b = run.checkpoints[0].relative_errors(run.material)
    assert abs(err_a) < 1e-3 and abs(err_b) < 1e-3
    table = format_checkpoints(run)
    assert "| sinusoid |" in table and "| impact 2 | 0.34" in table
    summary = format_summary(list(runs.values()))
    assert "| dice | 3000 | 20 |" in summary and "| rubber | 8000 | 60 |" in summary


def test_contact_onset_samples_carry_a_partial_step(runs):
    """Bullet's lag at impact: in the step in which the tool crosses the surface the contact
    acts only from the crossing on, so the reported force is eq 3's force times the fraction
    of the step in contact, ≈ z / (ż Δt) (measured within +0.04). Fed to the learner those
    samples bias β̂ low, by at most what they would if their force were 0 (an independent
    bound from the logged samples and the truth)."""
    for name, run in runs.items():
        m, log = run.material, run.log
        onset = log["onset"] & (log["phase"] >= 1)  # the impacts
        z, zd, f = log["z"][onset], log["zd"][onset], log["force"][onset]
        model = m.stiffness * z + m.damping * zd
        fraction = z / (zd * DT)
        assert np.all(fraction < 1.0) and np.all(zd > 0.1)
        np.testing.assert_allclose(f / model, fraction, atol=0.06)
        plain = run.final.with_onset
        err_b_plain = plain.damping / m.damping - 1.0
        assert err_b_plain < -1e-3, name  # a real effect, ≥ 10× the clean estimate's error
        everything = log["force"] > 0.0
        S, _ = stack_data(log["z"][everything], log["zd"][everything], log["force"][everything])
        G_inv = np.linalg.inv(S @ S.T)
        bound = np.abs(G_inv @ np.vstack([z, zd])) @ model
        assert abs(plain.damping - m.damping) <= bound[1], name


def test_why_z_is_not_pybullets_contact_distance(runs):
    """PyBullet's contact distance is the collision detection's, from the start of the step,
    while the force is the end-of-step one: z_bullet = z − ż Δt, so eq 17 finds β + α Δt
    (+15 % on the dice). The box's nominal top face is 10 µm above Bullet's effective surface;
    that offset, put into surface_offset_bias, predicts the error of z from the nominal top."""
    for name, run in runs.items():
        m = run.material
        a_b, b_b = run.alternatives["bullet distance"]
        assert b_b == pytest.approx(m.damping + m.stiffness * DT, rel=0.01), name
        assert abs(run.surface_offset) < 20e-6  # m: the surface found is Bullet's
        a_n, _ = run.alternatives["nominal top"]
        fed = run.log["fed"]
        S, F = stack_data(run.log["z"][fed], run.log["zd"][fed], run.log["force"][fed])
        E = fit_stiffness_damping(S, F)
        shift = surface_offset_bias(E[0], S @ S.T, S.sum(axis=1), -run.surface_offset)
        assert a_n - E[0] == pytest.approx(shift[0], rel=0.05), name
        assert abs(a_n / m.stiffness - 1.0) > 3e-4  # that error is larger than the tolerance


def test_no_joint_limit_is_violated_and_the_material_stays_elastic(runs):
    """The guard uses 0.9 of the acceleration limits; the impact's normal force and the friction
    of the sticking contact are expected one step ahead, so the realised q̈ stays at 0.9."""
    for name, run in runs.items():
        assert run.violations.total == 0, (name, run.violations)
        assert run.violations.max_ratio["acceleration"] < 0.92, name
        assert run.guard_stats["fallbacks"] == 0
        assert run.peak_penetration < run.material.max_penetration, name
        assert run.onset_samples >= len(run.checkpoints) - 1  # one per impact at least
        # Bullet's sphere–box contact stayed a single point (the force is k·depth + d·rate)
        assert run.log["contact_points"].max() == 1


def test_sticking_contact_force_keeps_the_contact_point_still():
    rng = np.random.default_rng(7)
    L = rng.normal(size=(3, 3))
    A = L @ L.T + 0.1 * np.eye(3)  # an inverse operational-space inertia, m/(N·s²)
    d = np.array([0.0, 0.0, -1.0])
    F = sticking_contact_force(10.0, A, friction=10.0, direction=d)
    T = motion_basis(d)[:3, 1:3]
    assert F @ -d == pytest.approx(10.0)
    np.testing.assert_allclose(T.T @ (A @ F), 0.0, atol=1e-12)  # no tangential acceleration
    tight = sticking_contact_force(10.0, A, friction=0.01, direction=d)
    assert np.linalg.norm(T.T @ tight) == pytest.approx(0.1)  # clipped to μ f_n
    np.testing.assert_allclose(sticking_contact_force(0.0, A, 0.5), 0.0)
    with pytest.raises(InputError):
        sticking_contact_force(-1.0, A, 0.5)
    with pytest.raises(InputError):
        sticking_contact_force(1.0, np.eye(2), 0.5)


def test_predicted_force_increase_and_surface_offset_bias():
    # 10 mm deep at 0.2 m/s holding 30 N on (3000 N/m, 20 N·s/m): eq 3 one step on = 34.6 N
    assert predicted_force_increase(3000.0, 20.0, 0.01, 0.2, 30.0, DT) == pytest.approx(4.6)
    assert predicted_force_increase(3000.0, 20.0, -0.01, 0.2, 0.0, DT) == 0.0  # still above
    assert predicted_force_increase(3000.0, 20.0, 0.01, -0.2, 30.0, DT) == 0.0  # retreating
    # the bias formula vs eq 17 on data whose z carries a constant error
    rng = np.random.default_rng(3)
    z = rng.uniform(0.0, 0.02, 400)
    zd = rng.normal(0.0, 0.1, 400)
    f = 3000.0 * z + 20.0 * zd
    eps = 5e-6
    S, F = stack_data(z + eps, zd, f)
    biased = fit_stiffness_damping(S, F)
    predicted = np.array([3000.0, 20.0]) + surface_offset_bias(3000.0, S @ S.T, S.sum(axis=1), eps)
    np.testing.assert_allclose(biased, predicted, rtol=1e-9)
    with pytest.raises(InputError):
        surface_offset_bias(1.0, np.eye(3), np.zeros(2), eps)


def test_config_validation():
    with pytest.raises(ConfigError):
        Material("thick", 1000.0, 10.0, 0.05)  # deeper than the hand allows
    with pytest.raises(ConfigError):
        Material("bad", -1.0, 10.0, 0.01)
    with pytest.raises(ConfigError):
        Material("bad", 1000.0, 10.0, 0.01, impact_velocities=(0.2, -0.1))
    with pytest.raises(ConfigError):
        ExplorationConfig(limit_margin=1.5)
    with pytest.raises(ConfigError):
        ExplorationConfig(sine_cycles=0)
    with pytest.raises(ConfigError):
        ExplorationConfig(approach_speed=0.0)
    with pytest.raises(ConfigError, match="unknown materials"):
        run_exploration_study(("steel",), progress=False)
    assert ExplorationConfig().velocities.tolist() == [0.15, 0.2, 0.25, 0.3, 0.35]
    assert ExplorationConfig(material=MATERIALS["rubber"]).velocities.tolist() == [
        0.15,
        0.2,
        0.25,
    ]
    # no object under the tool within the approach time
    far = replace(ExplorationConfig(), start_clearance=0.05, max_approach_time=0.05)
    with pytest.raises(ConfigError, match="no contact"):
        run_exploration(far)


def test_cli_explore(capsys, tmp_path):
    from ffmpc_ros.cli import main

    code = main(
        [
            "study",
            "explore",
            "--out",
            str(tmp_path / "explore"),
            "--workers",
            "1",
            "--materials",
            "foam",
            "--sine-cycles",
            "1",
            "--impact-velocities",
            "0.2",
        ]
    )
    out = capsys.readouterr().out
    assert code == 0
    assert "foam after sinusoid" in out
    assert re.search(r"foam after impact 1 at 0\.(19|20)\d m/s", out)
    assert "| foam | 800 | 8 |" in out
    assert (tmp_path / "explore" / "tables.md").is_file()
