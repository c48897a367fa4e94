"""The helpers that used to be copied (issue 14, item 4), each now one function: the symmetric
mass matrix, eq 3 one step ahead, the learner-confidence rule and the cycle synchroniser's
clean-up."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.impact.deformation import one_step_impact_force, predicted_force_increase
from ffmpc_core.impact.learner import RecursiveContactLearner, confident
from ffmpc_core.robots import load_robot, mass_matrix

DT = 1e-3


@pytest.mark.parametrize("name", ["iiwa", "panda"])
def test_mass_matrix_is_symmetric_and_maps_accelerations_to_torques(name: str) -> None:
    robot = load_robot(name)
    rng = np.random.default_rng(3)
    q = robot.q_nominal + rng.uniform(-0.3, 0.3, robot.nv)
    M = mass_matrix(robot.model, robot.create_data(), q)
    np.testing.assert_array_equal(M, M.T)
    # column i of M is τ(q, 0, e_i) − τ(q, 0, 0) (inverse dynamics, independent of crba)
    data = robot.create_data()
    zero = np.zeros(robot.nv)
    gravity = pin.rnea(robot.model, data, q, zero, zero).copy()
    columns = [pin.rnea(robot.model, data, q, zero, e) - gravity for e in np.eye(robot.nv)]
    np.testing.assert_allclose(M, np.column_stack(columns), rtol=1e-10, atol=1e-10)


def test_one_step_impact_force_is_eq_3_after_one_step() -> None:
    stiffness, damping, speed = 3000.0, 20.0, 0.25
    z = speed * DT  # one explicit step from the surface
    expected = stiffness * z + damping * speed
    assert one_step_impact_force(stiffness, damping, speed, DT) == pytest.approx(expected)
    assert one_step_impact_force(stiffness, damping, speed, DT, factor=1.5) == pytest.approx(
        1.5 * expected
    )
    assert one_step_impact_force(stiffness, damping, -speed, DT) == 0.0  # moving away
    # the same force as eq 3 one step ahead from z = 0, f = 0
    assert predicted_force_increase(stiffness, damping, 0.0, speed, 0.0, DT) == pytest.approx(
        expected
    )


def _learner(stiffness: float, damping: float, samples: int, seed: int) -> RecursiveContactLearner:
    rng = np.random.default_rng(seed)
    z = np.linspace(0.0, 0.02, samples)
    zd = 0.05 * np.sin(np.linspace(0.0, 6.0, samples))
    f = stiffness * z + damping * zd + rng.normal(0.0, 0.01, samples)
    learner = RecursiveContactLearner()
    learner.update_batch(z, zd, f)
    return learner


def test_confident_estimate_applies_the_one_rule() -> None:
    learner = _learner(3000.0, 20.0, 200, seed=1)
    est = learner.confident_estimate(50, 0.2)
    assert est is not None and confident(est, 50, 0.2)
    assert est.stiffness == pytest.approx(3000.0, rel=1e-2)
    assert learner.confident_estimate(201, 0.2) is None  # too few samples
    assert RecursiveContactLearner().confident_estimate(0, 0.2) is None  # singular, no data
    # a well-determined but implausible stiffness (> 1e6 N/m) is not confident
    stiff = _learner(5e6, 20.0, 200, seed=2)
    assert stiff.estimate().stiffness == pytest.approx(5e6, rel=1e-2)
    assert stiff.confident_estimate(50, 0.2) is None


def test_drop_stale_cycles() -> None:
    from ffmpc_ros.time_grid import drop_stale_cycles

    joints = {k: f"q{k}" for k in range(10)}
    forces = {3: "f3", 8: "f8"}
    drop_stale_cycles((joints, forces), newest=9, keep=4)
    assert sorted(joints) == [5, 6, 7, 8, 9] and sorted(forces) == [8]
