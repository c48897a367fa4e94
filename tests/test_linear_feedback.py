"""The linear_feedback_controller's loop, ROS-free (ffmpc_core.linear_feedback): the safe hold
before the first control, upstream's linear transition to the law, the law saturated, the
fallback when the control goes stale or is implausible, and the gravity removal."""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.linear_feedback import (
    LinearFeedbackCommand,
    LinearFeedbackLoop,
    linear_feedback_torque,
)
from ffmpc_core.lowlevel import LowLevelMode
from ffmpc_core.polishing import lowlevel_controller
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario

DT = 1e-3


@pytest.fixture(scope="module")
def robot():
    return load_robot("iiwa")


def _loop(robot, **kwargs) -> LinearFeedbackLoop:
    scenario = load_scenario("polishing")
    return LinearFeedbackLoop(robot, lowlevel_controller(scenario, robot), 0.004, **kwargs)


def _command(robot, rng) -> LinearFeedbackCommand:
    q0 = robot.q_nominal
    gain = np.hstack((np.diag(rng.uniform(50, 100, 7)), np.diag(rng.uniform(5, 10, 7))))
    return LinearFeedbackCommand(robot.gravity(q0), gain, q0.copy(), np.zeros(7))


def test_hold_then_linear_transition_then_the_law(robot):
    loop = _loop(robot, transition_duration=0.01)
    reference = lowlevel_controller(load_scenario("polishing"), robot)
    q = robot.q_nominal + 0.02
    v = np.zeros(7)
    out = loop.step(q, v, 0.0)
    assert out.mode == LowLevelMode.HOLD
    np.testing.assert_allclose(out.motor_torque, reference.hold_torque(q, v))
    cmd = _command(robot, np.random.default_rng(0))
    law = linear_feedback_torque(robot.model, cmd, q, v)
    loop.set_command(cmd, DT)
    for k in range(1, 12):
        out = loop.step(q, v, k * DT)
        weight = min(1.0, (k - 1) / 10)  # the transition starts at the first control's cycle
        if weight < 1.0:
            assert out.mode == LowLevelMode.BLEND and out.blend == pytest.approx(weight)
            expected = (1 - weight) * reference.hold_torque(q, v) + weight * law
            np.testing.assert_allclose(out.motor_torque, expected, atol=1e-9)
        if k < 11:
            loop.set_command(cmd, (k + 0.5) * DT)  # keep the control fresh
    assert out.mode == LowLevelMode.TRACK
    np.testing.assert_allclose(out.motor_torque, law)


def test_the_law_is_saturated_and_goes_stale_into_the_safe_hold(robot):
    loop = _loop(robot)
    cmd = _command(robot, np.random.default_rng(1))
    loop.set_command(cmd, 0.0)
    far = robot.q_nominal - 5.0  # K·Δq (50 to 100 N·m/rad × 5 rad) beyond every limit
    out = loop.step(far, np.zeros(7), 0.0)
    assert out.mode == LowLevelMode.TRACK  # nothing was sent before: the law at once
    np.testing.assert_allclose(np.abs(out.motor_torque), robot.torque_limit)
    out = loop.step(robot.q_nominal, np.zeros(7), 0.004)  # 4 ms old: still fresh
    assert out.mode == LowLevelMode.TRACK
    out = loop.step(robot.q_nominal, np.zeros(7), 0.005)  # older than stale_timeout
    assert out.mode == LowLevelMode.FALLBACK and out.command_age == pytest.approx(0.005)


def test_a_bad_control_is_refused_and_an_absurd_one_drops_the_current(robot):
    loop = _loop(robot)
    rng = np.random.default_rng(2)
    cmd = _command(robot, rng)
    loop.set_command(cmd, 0.0)
    with pytest.raises(InputError, match="feedback_gain"):
        loop.set_command(
            LinearFeedbackCommand(cmd.feedforward, cmd.feedback_gain[:, :7], cmd.q0, cmd.v0), 1e-3
        )
    with pytest.raises(InputError, match="not after"):
        loop.set_command(cmd, 0.0)
    assert loop.step(robot.q_nominal, np.zeros(7), 1e-3).mode == LowLevelMode.TRACK  # kept
    absurd = LinearFeedbackCommand(cmd.feedforward * 1e6, cmd.feedback_gain, cmd.q0, cmd.v0)
    with pytest.raises(InputError, match="feedforward"):
        loop.set_command(absurd, 2e-3)
    assert loop.step(robot.q_nominal, np.zeros(7), 2e-3).mode == LowLevelMode.FALLBACK
    assert loop.invalid_commands == 1
    with pytest.raises(ConfigError):
        _loop(robot, transition_duration=-1.0)


def test_gravity_is_removed_for_drives_that_add_it(robot):
    cmd = _command(robot, np.random.default_rng(3))
    q = robot.q_nominal + 0.01
    plain, removed = _loop(robot), _loop(robot, remove_gravity=True)
    for loop in (plain, removed):
        loop.set_command(cmd, 0.0)
    a = plain.step(q, np.zeros(7), 0.0).motor_torque
    b = removed.step(q, np.zeros(7), 0.0).motor_torque
    np.testing.assert_allclose(a - b, robot.gravity(q), atol=1e-12)
