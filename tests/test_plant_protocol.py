"""One plant shape (ffmpc_core.plant.Plant) for the PyBullet plant and the model plant."""

from __future__ import annotations

import numpy as np

from ffmpc_core.config import ContactConfig
from ffmpc_core.model_plant import ModelPlant
from ffmpc_core.plant import Plant
from sim_bridge.plant import Plant as BulletPlant
from sim_bridge.plant import PlantConfig


def _hold_by_gravity(plant: Plant, robot, q0: np.ndarray, steps: int) -> np.ndarray:
    """The same closed loop on any plant: gravity compensation from the true q (rad)."""
    plant.reset(q0)
    q = q0.copy()
    for _ in range(steps):
        plant.step(robot.gravity(q))
        q = np.asarray(plant.state().q, dtype=float)
    return q


def test_both_plants_have_the_shape_and_run_the_same_loop(robot):
    q0 = robot.q_nominal.copy()
    model_plant = ModelPlant(robot, "force_feedback", ContactConfig())
    assert isinstance(model_plant, Plant)
    q_model = _hold_by_gravity(model_plant, robot, q0, 50)
    with BulletPlant(robot, PlantConfig(table=None)) as bullet:
        assert isinstance(bullet, Plant)
        q_bullet = _hold_by_gravity(bullet, robot, q0, 50)
    # gravity compensation holds the arm in both (no contact, no tool mass)
    np.testing.assert_allclose(q_model, q0, atol=1e-6)
    np.testing.assert_allclose(q_bullet, q0, atol=1e-4)
    # a plant without the shape is told apart
    assert not isinstance(object(), Plant)


def test_model_plant_keeps_its_contact_mode_when_not_told(robot):
    q0 = robot.q_nominal.copy()
    tau = robot.gravity(q0) + 0.5
    explicit = ModelPlant(robot, "force_feedback", ContactConfig())
    explicit.reset(q0)
    implicit = ModelPlant(robot, "force_feedback", ContactConfig())
    implicit.reset(q0)
    implicit.set_contact(False)
    for _ in range(20):
        explicit.step(tau, False)
        implicit.step(tau)
    np.testing.assert_array_equal(explicit.state().q, implicit.state().q)
    np.testing.assert_array_equal(explicit.state().v, implicit.measurement().v)
