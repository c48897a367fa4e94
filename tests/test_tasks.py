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


def _same_reference(a, b):
    np.testing.assert_array_equal(a.ee_position, b.ee_position)
    np.testing.assert_array_equal(a.force, b.force)
    np.testing.assert_array_equal(a.ee_position_diag, b.ee_position_diag)
    assert (a.ee_position_weight, a.force_weight, a.in_contact, a.posture) == (
        b.ee_position_weight,
        b.force_weight,
        b.in_contact,
        b.posture,
    )


@pytest.mark.parametrize("dimension", [1, 3])
def test_reference_into_writes_what_reference_returns(dimension):
    """The MPC's in-place path gives the same references as ``reference`` at every phase, and
    writes into the given arrays (no new ones)."""
    from ffmpc_core.config import NodeReference
    from ffmpc_core.tasks import PressTask

    polishing = make_task(ee_z_weight_in_contact=0.25)
    square = ForceSquareTask(np.array([0.5, 0.0, 0.45]), np.array([0.55, 0.0, 0.30]))
    press = PressTask(np.array([0.5, 0.1, 0.2]), force=30.0)
    ref = NodeReference.empty(dimension)
    arrays = (ref.ee_position, ref.force, ref.ee_position_diag)
    for task, end in ((polishing, polishing.duration), (square, square.duration), (press, 1.0)):
        for t in np.linspace(0.0, end + 0.1, 97):
            out = task.reference_into(float(t), ref)
            assert out is ref
            now = (ref.ee_position, ref.force, ref.ee_position_diag)
            assert all(a is b for a, b in zip(arrays, now, strict=True))
            _same_reference(ref, task.reference(float(t), dimension))
            np.testing.assert_array_equal(ref.ee_position, task.ee_position(float(t)))
    contact = polishing.reference(polishing.circle_start + 0.1)
    np.testing.assert_array_equal(contact.ee_position_diag, [1.0, 1.0, 0.25])


def test_reference_into_needs_an_ee_position_diag():
    """The tasks write Q4 in place: a reference without one is refused, not a TypeError."""
    from ffmpc_core.config import NodeReference
    from ffmpc_core.errors import InputError
    from ffmpc_core.tasks import PressTask

    for task in (make_task(), PressTask(np.array([0.5, 0.0, 0.3]))):
        ref = NodeReference(np.zeros(3), np.zeros(1), 0.0, 0.0, False)
        with pytest.raises(InputError, match="ee_position_diag"):
            task.reference_into(1.0, ref)
        ref = NodeReference.empty(1)
        assert task.reference_into(1.0, ref) is ref


def test_circle_ramp_starts_and_ends_the_circle_at_rest_with_a_minimum_jerk_speed():
    """circle_ramp T: the angular velocity (central differences of circle_angle) is
    ω·s(τ/T) over the first T s, ω in between, ω·s((C − τ)/T) over the last T s (s: minimum
    jerk), the angle is continuous and reaches ω·(C − T); T = 0 is the paper's ω·τ exactly."""
    from ffmpc_core.tasks import min_jerk

    omega, ramp = 3.0, 0.2
    circle = 4 * np.pi / omega + ramp
    plain, ramped = make_task(circle=circle), make_task(circle=circle, circle_ramp=ramp)
    taus = np.linspace(0.0, circle, 4001)
    np.testing.assert_array_equal([plain.circle_angle(t) for t in taus], omega * taus)
    h = 1e-6
    inner = taus[1:-1]
    speed = [(ramped.circle_angle(t + h) - ramped.circle_angle(t - h)) / (2 * h) for t in inner]
    expected = [omega * min(min_jerk(t / ramp), min_jerk((circle - t) / ramp)) for t in inner]
    np.testing.assert_allclose(speed, expected, atol=1e-6)
    assert ramped.circle_angle(circle) == pytest.approx(4 * np.pi)  # two whole turns
    assert ramped.circle_angle(0.0) == 0.0 and ramped.circle_angle(circle + 1.0) == 4 * np.pi
    # the reference's tangential speed: 0 at the start with the ramp, a step to ω·r without
    t0 = ramped.circle_start
    step = np.linalg.norm(plain.ee_position(t0 + 1e-4) - plain.ee_position(t0)) / 1e-4
    soft = np.linalg.norm(ramped.ee_position(t0 + 1e-4) - ramped.ee_position(t0)) / 1e-4
    assert step == pytest.approx(0.07 * omega, rel=1e-3) and soft < 1e-6
    with pytest.raises(ConfigError, match="circle_ramp"):
        make_task(circle=0.3, circle_ramp=0.2)


def test_scenario_circle_ramp_lengthens_the_circle_by_the_ramp():
    """task.circle_ramp from a scenario: the circle phase is circle_ramp s longer, so the same
    whole turns are drawn and the tool ends the circle where it started."""
    from ffmpc_core.polishing import build_task
    from ffmpc_core.robots import load_robot
    from ffmpc_core.scenario import load_scenario

    robot = load_robot("iiwa")
    plain = build_task(load_scenario("polishing", {"task.circle_ramp": 0.0}), robot)
    ramped = build_task(load_scenario("polishing", {"task.circle_ramp": 0.25}), robot)
    assert ramped.circle == pytest.approx(plain.circle + 0.25)
    assert ramped.duration == pytest.approx(plain.duration + 0.25)
    np.testing.assert_allclose(
        ramped.ee_position(ramped.circle_end), ramped.ee_position(ramped.circle_start), atol=1e-12
    )


def test_touch_phase_reaches_above_the_table_then_touches_under_a_light_force():
    plain = make_task()
    task = make_task(clearance=0.01, touch=0.3, touch_force=1.0)
    # the reach ends 1 cm above the believed table point, at the same time as the paper's
    np.testing.assert_allclose(task.ee_position(task.contact_time - 1e-9), [0.55, 0.0, 0.31])
    np.testing.assert_allclose(task.approach_target(), [0.55, 0.0, 0.31])
    assert task.contact_time == plain.contact_time
    # the touch phase: in contact (the nodes switch), the light force, the x-y point held
    for t in (task.contact_time, task.contact_time + 0.15, task.force_start - 1e-9):
        ref = task.reference(t)
        assert ref.in_contact and ref.force[0] == pytest.approx(1.0)
        np.testing.assert_allclose(ref.ee_position[:2], [0.55, 0.0])
        np.testing.assert_allclose(ref.ee_position_diag, [1, 1, 0])  # z free in contact
    assert task.force(task.contact_time - 1e-6) == 0.0
    # the ramp runs from the touch force to the polishing force, then the circle as before
    assert task.force_start == pytest.approx(plain.contact_time + 0.3)
    assert task.force(task.force_start) == pytest.approx(1.0)
    mid = task.force(task.force_start + 0.5 * task.force_ramp)
    assert mid == pytest.approx(1.0 + 0.5 * 49.0)
    assert task.force(task.circle_start) == pytest.approx(50.0)
    assert task.circle_start == pytest.approx(plain.circle_start + 0.3)
    assert task.duration == pytest.approx(plain.duration + 0.3)
    shift = 0.3
    for t in np.linspace(plain.circle_start, plain.circle_end, 7):
        np.testing.assert_allclose(task.ee_position(t + shift), plain.ee_position(t), atol=1e-12)


def test_touch_phase_zero_is_the_papers_schedule():
    plain, zero = make_task(), make_task(clearance=0.0, touch=0.0, touch_force=0.0)
    for t in np.linspace(0.0, plain.duration, 301):
        assert zero.force(t) == plain.force(t)
        np.testing.assert_array_equal(zero.ee_position(t), plain.ee_position(t))


@pytest.mark.parametrize("name", ["clearance", "touch", "touch_force"])
def test_touch_phase_rejects_negative_or_nan(name):
    for bad in (-0.1, float("nan")):
        with pytest.raises(ConfigError, match=name):
            make_task(**{name: bad})
        with pytest.raises(ConfigError, match=name):
            ForceSquareTask(np.array([0.5, 0, 0.45]), np.array([0.55, 0, 0.3]), **{name: bad})


def test_force_square_touch_phase_ramps_from_the_touch_force():
    task = ForceSquareTask(
        np.array([0.5, 0, 0.45]),
        np.array([0.55, 0, 0.3]),
        clearance=0.01,
        touch=0.2,
        touch_force=1.0,
    )
    assert task.force(task.contact_time + 0.1) == pytest.approx(1.0)
    assert task.square_start == pytest.approx(task.contact_time + 0.2 + task.force_ramp)
    assert task.force(task.square_start - 1e-9) == pytest.approx(20.0, abs=1e-6)
