"""The guarded approach (ffmpc_core.tasks.GuardedTask): a descent in free space until the
measured force detects the contact (hysteresis), then the contact phases shifted to that time."""

import math

import numpy as np
import pytest

from ffmpc_core.config import NodeReference
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.tasks import (
    ForceSquareTask,
    GuardedApproach,
    GuardedTask,
    LiveTask,
    PhaseWeights,
    PolishingTask,
)

START = np.array([0.5, 0.0, 0.45])
TABLE = np.array([0.55, 0.0, 0.30])
APPROACH = GuardedApproach(speed=0.03, depth=0.01, contact_force=2.0)


def make_task(**kw):
    inner = PolishingTask(
        START, TABLE, clearance=0.01, touch=0.3, touch_force=1.0, circle_ramp=0.2, **kw
    )
    return GuardedTask(inner, APPROACH)


def test_approach_parameters_are_checked():
    for bad in (
        dict(speed=0.0),
        dict(speed=math.nan),
        dict(depth=-1e-3),
        dict(contact_force=0.0),
        dict(contact_force=math.inf),
    ):
        kw = dict(speed=0.03, depth=0.01, contact_force=2.0) | bad
        with pytest.raises(ConfigError):
            GuardedApproach(**kw)


def test_descent_is_free_space_at_the_approach_speed_down_to_the_bound():
    task = make_task()
    t0 = task.contact_time  # the reach's end: 1 cm above the believed table
    np.testing.assert_allclose(task.ee_position(t0), TABLE + [0, 0, 0.01])
    for dt in (0.0, 0.1, 0.3, 0.5):
        ref = task.reference(t0 + dt)
        assert ref.in_contact is False and ref.force_weight == 0.0 and ref.force[0] == 0.0
        np.testing.assert_allclose(ref.ee_position_diag, [1, 1, 1])
        assert ref.ee_position_weight == task.weights.free_ee_position
        z = max(TABLE[2] + 0.01 - 0.03 * dt, TABLE[2] - 0.01)
        np.testing.assert_allclose(ref.ee_position, [TABLE[0], TABLE[1], z], atol=1e-12)
        assert task.force(t0 + dt) == 0.0 and not task.in_contact(t0 + dt)
    # the bound: 1 cm below the belief after (clearance + depth) / speed, then held
    bound_time = t0 + 0.02 / 0.03
    assert task.max_descent_time == pytest.approx(0.02 / 0.03)
    assert not task.contact_missed(bound_time - 0.01)
    assert task.contact_missed(bound_time + 1e-6)
    np.testing.assert_allclose(task.ee_position(bound_time + 5.0)[2], TABLE[2] - 0.01)
    # no contact: no evaluation window, and the run lasts the longest descent longer
    assert not task.in_circle(np.linspace(0, 10, 1000)).any()
    assert task.duration == pytest.approx(task.task.duration + 0.02 / 0.03)


def test_detection_is_the_first_measured_force_above_the_threshold_and_is_final():
    task = make_task()
    t0 = task.contact_time
    assert task.observe_force(50.0, t0 - 0.01) is False  # before the reach's end: ignored
    assert task.detected_at is None
    assert task.observe_force(1.9, t0 + 0.10) is False  # below the threshold
    assert task.observe_force(2.0, t0 + 0.11) is False  # at it: not above
    assert task.observe_force(math.nan, t0 + 0.12) is False  # a faulty reading: not fed
    assert task.observe_force(math.inf, t0 + 0.13) is False
    assert task.detected_at is None and not task.in_contact(t0 + 0.13)
    assert task.observe_force(2.1, t0 + 0.20) is True
    assert task.detected_at == pytest.approx(t0 + 0.20)
    # final: a force falling back (the touch's first milliseconds dip) keeps the contact phases
    assert task.observe_force(0.0, t0 + 0.22) is True
    assert task.observe_force(30.0, t0 + 0.5) is True
    assert task.detected_at == pytest.approx(t0 + 0.20)
    assert task.in_contact(t0 + 0.22)
    task.reset()
    assert task.detected_at is None and not task.in_contact(t0 + 0.22)
    assert task.descent_height(t0) == pytest.approx(TABLE[2] + 0.01)


def test_replay_detects_from_the_ticks_of_a_log():
    task = make_task()
    t = np.arange(0.0, 2.0, 1e-3)
    force = np.where(t >= 0.8505, 3.0, 0.0)  # above the threshold from cycle 851 on
    assert task.replay(t, force, every=2) == pytest.approx(0.852)  # the next tick, k = 852
    assert task.replay(t, np.zeros_like(t), every=2) is None
    with pytest.raises(InputError):
        task.replay(t, force[:-1], every=2)


def test_contact_phases_shift_with_the_detection_time():
    task = make_task()
    inner = task.task
    t_d = inner.contact_time + 0.37
    task.observe_force(5.0, t_d)
    assert task.shift == pytest.approx(0.37)
    a, b = NodeReference.empty(1), NodeReference.empty(1)
    for tau in np.linspace(inner.contact_time, inner.duration, 97):
        task.reference_into(tau + 0.37, a)
        inner.reference_into(tau, b)
        assert a.in_contact == b.in_contact
        np.testing.assert_allclose(a.ee_position, b.ee_position, rtol=0, atol=1e-12)
        np.testing.assert_allclose(a.force, b.force, rtol=1e-9, atol=1e-9)
        assert a.force_weight == b.force_weight
        assert task.force(tau + 0.37) == pytest.approx(inner.force(tau), abs=1e-9)
    # in contact from the detection on, touch force first, 50 N on the circle
    assert task.in_contact(t_d) and task.force(t_d) == pytest.approx(1.0)
    assert task.force(inner.circle_start + 0.37) == pytest.approx(50.0)
    # the evaluation window moves with it
    t = np.arange(0.0, task.duration, 1e-3)
    window = task.in_circle(t)
    assert t[window][0] == pytest.approx(inner.circle_start + 0.37, abs=1.5e-3)
    assert t[window][-1] == pytest.approx(inner.circle_end + 0.37, abs=1.5e-3)
    # before the detection the references stay the descent's, and the reach is not shifted
    assert not task.in_contact(t_d - 1e-3)
    for t_before in np.linspace(0.0, inner.contact_time - 1e-3, 23):
        np.testing.assert_array_equal(task.ee_position(t_before), inner.ee_position(t_before))
        assert task.force(t_before) == 0.0 and not task.in_contact(t_before)
    # a later task reads the run's detection back
    again = make_task()
    again.restore_detection(task.detected_at)
    np.testing.assert_array_equal(again.in_circle(t), window)
    with pytest.raises(InputError):
        again.restore_detection(inner.contact_time - 1.0)


def test_force_square_task_is_guarded_too():
    inner = ForceSquareTask(START, TABLE, clearance=0.01, touch=0.3, touch_force=1.0)
    task = GuardedTask(inner, APPROACH)
    task.observe_force(3.0, inner.contact_time + 0.2)
    t = np.arange(0.0, task.duration, 1e-3)
    assert t[task.in_circle(t)][0] == pytest.approx(inner.square_start + 0.2, abs=1.5e-3)
    assert task.force(inner.square_start + 0.2) == pytest.approx(inner.force(inner.square_start))


def test_live_task_reaches_the_guard_and_keeps_its_detection():
    task = make_task()
    live = LiveTask(task)
    assert live.nominal_force == 50.0
    live.observe_force(3.0, task.contact_time + 0.1)  # the MPC's call, through the wrapper
    assert task.detected_at == pytest.approx(task.contact_time + 0.1)
    live.set_phase_weights(PhaseWeights(force=7.0))
    assert live.task is task and task.detected_at is not None  # the log's object, kept
    assert live.reference(task.circle_start + 0.2).force_weight == 7.0
