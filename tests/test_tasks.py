"""Task schedules: phases, continuity, and the paper's polishing numbers."""

import numpy as np
import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_core.tasks import ForceSquareTask, PolishingTask


def make_task(**kw):
    return PolishingTask(np.array([0.5, 0.0, 0.45]), np.array([0.55, 0.0, 0.30]), **kw)


def test_polishing_phases_and_circle():
    task = make_task()
    assert task.reference(0.0).in_contact is False
    np.testing.assert_allclose(task.ee_position(0.0), [0.5, 0.0, 0.45])
    np.testing.assert_allclose(task.ee_position(task.contact_time), [0.55, 0.0, 0.30])
    assert task.force(task.contact_time - 1e-6) == 0.0
    assert task.force(task.circle_start) == pytest.approx(50.0)
    # the circle: 14 cm diameter in the horizontal plane, 3 rad/s
    ts = np.linspace(task.circle_start, task.circle_start + 2 * np.pi / 3.0, 200)
    pts = np.array([task.ee_position(t) for t in ts])
    center = task.circle_center()
    np.testing.assert_allclose(np.linalg.norm(pts[:, :2] - center[:2], axis=1), 0.07, atol=1e-12)
    np.testing.assert_allclose(pts[:, 2], 0.30)
    speed = np.linalg.norm(np.diff(pts, axis=0), axis=1) / np.diff(ts)
    np.testing.assert_allclose(speed, 0.07 * 3.0, rtol=1e-3)
    ref = task.reference(task.circle_start + 0.1)
    assert ref.in_contact and ref.force[0] == pytest.approx(50.0)
    np.testing.assert_allclose(ref.ee_position_diag, [1, 1, 0])


def test_reach_is_continuous():
    task = make_task()
    ts = np.linspace(0, task.duration, 5000)
    pts = np.array([task.ee_position(t) for t in ts])
    assert np.max(np.linalg.norm(np.diff(pts, axis=0), axis=1)) < 1e-3


def test_fast_variant_and_3d_reference():
    task = make_task(angular_velocity=6.0)
    ref = task.reference(task.circle_start + 0.2, dimension=3)
    assert ref.force.shape == (3,) and ref.force[2] == pytest.approx(50.0)


def test_bad_config():
    with pytest.raises(ConfigError):
        make_task(reach=-1.0)


def test_force_square():
    task = ForceSquareTask(np.array([0.5, 0, 0.45]), np.array([0.55, 0, 0.3]))
    t0 = task.square_start
    assert task.force(t0 + 0.1) == 50.0
    assert task.force(t0 + task.period * 0.75) == 20.0
    assert task.force(t0 + task.period * 1.25) == 50.0
    assert task.reference(t0).in_contact
