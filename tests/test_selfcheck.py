"""The start-up self-check passes on the pinned stack and fails on a deliberately wrong model."""

import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.errors import SelfCheckError
from ffmpc_core.robots import ROBOT_NAMES, load_robot
from ffmpc_core.selfcheck import (
    check_crocoddyl_dynamics,
    require_sound_dynamics,
    version_mismatches,
)
from ffmpc_ros.cli import main


@pytest.mark.parametrize("name", ROBOT_NAMES)
def test_crocoddyl_agrees_with_aba(name):
    result = check_crocoddyl_dynamics(load_robot(name), np.random.default_rng(1))
    assert result.ok, result
    require_sound_dynamics(load_robot(name))


def test_pins_are_installed():
    assert version_mismatches() == {}


def test_check_fails_on_a_wrong_model():
    robot = load_robot("iiwa")
    wrong = pin.Model(robot.model)
    inertia = wrong.inertias[4]
    wrong.inertias[4] = pin.Inertia(inertia.mass * 1.5, inertia.lever, inertia.inertia)
    result = check_crocoddyl_dynamics(robot, np.random.default_rng(1), crocoddyl_model=wrong)
    assert not result.ok
    assert result.max_error > 1e-2


def test_cli_check_exit_codes(capsys, monkeypatch):
    assert main(["check", "--samples", "3"]) == 0
    assert "ok" in capsys.readouterr().out
    import ffmpc_core.selfcheck as sc

    original = sc.check_crocoddyl_dynamics

    def broken(robot, rng, samples=10, tolerance=1e-6, crocoddyl_model=None):
        wrong = pin.Model(robot.model)
        wrong.gravity.linear = np.array([0.0, 0.0, -12.0])
        return original(robot, rng, samples, tolerance, crocoddyl_model=wrong)

    monkeypatch.setattr(sc, "check_crocoddyl_dynamics", broken)
    assert main(["check", "--samples", "3"]) == 1
    assert "FAILED" in capsys.readouterr().out


def test_require_sound_dynamics_raises(monkeypatch):
    import ffmpc_core.selfcheck as sc

    robot = load_robot("iiwa")
    wrong = pin.Model(robot.model)
    wrong.gravity.linear = np.array([0.0, 0.0, -12.0])
    original = sc.check_crocoddyl_dynamics
    monkeypatch.setattr(
        sc, "check_crocoddyl_dynamics", lambda r, rng: original(r, rng, crocoddyl_model=wrong)
    )
    with pytest.raises(SelfCheckError, match="disagree"):
        require_sound_dynamics(robot)
