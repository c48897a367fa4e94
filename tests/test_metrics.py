"""Polishing metrics (VI-C, eq 34–35) on synthetic signals with known answers."""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.errors import InputError
from ffmpc_core.metrics import (
    PolishingMetrics,
    contact_break_percent,
    limit_ratios,
    max_normal_force,
    normal_force_mae,
    polishing_metrics,
    summarize,
    tangential_position_mae,
    torque_tracking_mae,
    window_mask,
)

DT = 1e-3
T = np.arange(0.0, 2.0, DT)  # 2000 samples


def circle(normal, radius=0.07, omega=3.0, center=(0.55, 0.0, 0.2)):
    """A circle in the plane of ``normal`` and an orthonormal basis (u, w) of that plane."""
    u = np.cross(normal, [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(normal, u)
    p = (
        np.asarray(center)
        + radius * np.cos(omega * T)[:, None] * u
        + radius * np.sin(omega * T)[:, None] * w
    )
    return p, u, w


@pytest.mark.parametrize("tilt_deg", [0.0, 6.0])
def test_position_error_counts_only_the_table_plane(tilt_deg):
    normal = pin.exp3(np.array([1.0, 0.0, 0.0]) * np.deg2rad(tilt_deg))[:, 2]
    reference, u, w = circle(normal)
    # 3 mm along u and 4 mm along w (5 mm in the plane), 9 mm along the normal (ignored)
    position = reference + 0.003 * u + 0.004 * w + 0.009 * normal
    assert tangential_position_mae(T, position, reference, normal) == pytest.approx(0.005)
    # an error that grows linearly with time: mean over the window = value at its middle
    growing = reference + (0.01 * T)[:, None] * u
    mae = tangential_position_mae(T, growing, reference, normal, start=0.5, end=1.5)
    assert mae == pytest.approx(0.01, rel=1e-9)


def test_force_mae_max_and_breaks():
    force = 50.0 + 3.0 * np.sin(2.0 * np.pi * T)  # whole periods over [0, 2) s
    # mean |3 sin| = 3·2/π
    assert normal_force_mae(T, force, 50.0) == pytest.approx(6.0 / math.pi, rel=1e-4)
    assert normal_force_mae(T, force, np.full(T.size, 47.0)) == pytest.approx(3.0, rel=1e-9)
    assert max_normal_force(T, force) == pytest.approx(53.0, rel=1e-6)
    assert max_normal_force(T, -2.0 * force) == pytest.approx(106.0, rel=1e-6)  # |λ|
    broken = force.copy()
    broken[T < 0.5] = 0.0  # 25 % of the samples
    broken[(T >= 1.0) & (T < 1.1)] = 1e-3  # at γ counts as a break: 5 % more
    broken[(T >= 1.2) & (T < 1.3)] = 2e-3  # above γ does not
    assert contact_break_percent(T, broken) == pytest.approx(30.0)
    assert contact_break_percent(T, broken, start=0.5) == pytest.approx(100 * 100 / 1500)
    assert contact_break_percent(T, force) == 0.0


def test_torque_mae_is_over_cycles_and_joints():
    desired = np.tile(np.arange(7.0), (T.size, 1))
    offsets = np.array([0.0, 1.0, -2.0, 3.0, 0.0, 0.5, -0.5])
    measured = desired + offsets
    assert torque_tracking_mae(T, desired, measured) == pytest.approx(np.abs(offsets).mean())
    with pytest.raises(InputError):
        torque_tracking_mae(T, desired, measured[:, :6])


def test_window_selects_the_samples():
    mask = window_mask(T, 0.5, 1.0)
    assert mask.sum() == 501 and T[mask][0] == pytest.approx(0.5)
    assert window_mask(T).all()
    with pytest.raises(InputError):
        window_mask(T, 5.0, 6.0)
    force = np.where(T < 1.0, 50.0, 60.0)
    assert normal_force_mae(T, force, 50.0, start=0.0, end=0.999) == 0.0
    assert normal_force_mae(T, force, 50.0, start=1.0) == pytest.approx(10.0)


def test_polishing_metrics_and_summary():
    normal = np.array([0.0, 0.0, 1.0])
    reference, u, _ = circle(normal)
    position = reference + 0.002 * u
    force = np.full(T.size, 52.0)
    force[:100] = 0.0
    desired = np.zeros((T.size, 7))
    metrics = polishing_metrics(
        T, position, reference, normal, force, 50.0, desired, desired + 1.0, start=0.0
    )
    assert metrics.position_mae_mm == pytest.approx(2.0)
    assert metrics.force_mae == pytest.approx((100 * 50.0 + 1900 * 2.0) / 2000)
    assert metrics.max_force == 52.0
    assert metrics.contact_break_percent == pytest.approx(5.0)
    assert metrics.torque_mae == pytest.approx(1.0)
    assert set(metrics.to_dict()) == {
        "position_mae_mm",
        "force_mae",
        "max_force",
        "contact_break_percent",
        "torque_mae",
    }
    other = PolishingMetrics(4.0, 1.0, 80.0, 0.0, 3.0)
    summary = summarize([metrics, other])
    assert summary["position_mae_mm_mean"] == pytest.approx(3.0)
    assert summary["position_mae_mm_std"] == pytest.approx(1.0)
    assert summary["max_force"] == 80.0
    assert summary["contact_break_percent"] == pytest.approx(5.0)
    assert summary["torque_mae_mean"] == pytest.approx(2.0)
    no_torque = polishing_metrics(T, position, reference, normal, force, 50.0)
    assert no_torque.torque_mae is None


def test_bad_signals_are_rejected():
    normal = np.array([0.0, 0.0, 1.0])
    reference, _, _ = circle(normal)
    with pytest.raises(InputError):
        tangential_position_mae(T, reference[:-1], reference, normal)
    with pytest.raises(InputError):
        tangential_position_mae(T, reference, reference, np.array([0.0, 0.0, 2.0]))
    bad = np.full(T.size, 50.0)
    bad[3] = np.nan
    with pytest.raises(InputError):
        normal_force_mae(T, bad, 50.0)
    with pytest.raises(InputError):
        normal_force_mae(T, np.full(T.size, 50.0), np.zeros(3))
    with pytest.raises(InputError):
        polishing_metrics(T, reference, reference, normal, bad * 0, 50.0, np.zeros((T.size, 7)))
    with pytest.raises(InputError):
        summarize([])


def test_limit_ratios_per_joint_with_the_worst_cycle_and_nan_as_broken():
    limit = np.array([2.0, 4.0])
    values = np.array([[1.0, -1.0], [-3.0, 2.0], [0.5, 3.9]])
    ratios, worst = limit_ratios(values, limit)
    np.testing.assert_allclose(ratios, [1.5, 0.975])
    assert worst == 1  # |−3|/2 is the largest ratio of the run
    ratios, worst = limit_ratios(np.array([[0.1, np.nan], [0.2, 0.1]]), limit)
    assert ratios[1] == math.inf and worst == 0
    ratios, worst = limit_ratios(np.zeros((0, 2)), limit)
    assert worst is None and ratios.tolist() == [0.0, 0.0]
