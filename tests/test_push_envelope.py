"""The external push of the polishing scenarios (``plant.push_*``, Experiment 3.3): a step on and
off, or a hand's push whose force rises and falls along a raised cosine over
``plant.push_rise_time`` (``sim_bridge.scenes.push_envelope``), with the impulse that shape
gives, applied at the right cycles only."""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import load_scenario
from sim_bridge.scenes import SimulatedRobot, push_envelope


class _RecordingPlant:
    """The push side of a plant: records each ``apply_external_push`` (force N, steps)."""

    def __init__(self) -> None:
        self.pushes: list[tuple[int, np.ndarray, int]] = []
        self.k = 0

    def apply_external_push(self, force: np.ndarray, steps: int, link: str | None = None) -> None:
        self.pushes.append((self.k, np.array(force, dtype=float), int(steps)))


def _robot(plant: _RecordingPlant, rise_steps: int) -> SimulatedRobot:
    return SimulatedRobot(
        draws=None,  # type: ignore[arg-type]  # the push needs none of the rest
        task=None,  # type: ignore[arg-type]
        actuation=None,  # type: ignore[arg-type]
        plant=plant,  # type: ignore[arg-type]
        reflex_plant=None,  # type: ignore[arg-type]
        push_at=2000,
        push_steps=200,
        push_force=np.array([0.0, 40.0, 0.0]),
        push_rise_steps=rise_steps,
    )


def _forces(rise_steps: int) -> tuple[_RecordingPlant, np.ndarray]:
    """The force (N) applied at each 1 ms step of cycles 0–2999 (a push held over its steps)."""
    plant = _RecordingPlant()
    robot = _robot(plant, rise_steps)
    applied = np.zeros((3000, 3))
    for k in range(3000):
        plant.k = k
        robot.push_if_due(k)
    for k, force, steps in plant.pushes:
        applied[k : k + steps] += force
    return plant, applied


def test_the_envelope_rises_and_falls_along_a_raised_cosine():
    env = np.array([push_envelope(i, 200, 50) for i in range(200)])
    assert np.all((env > 0.0) & (env <= 1.0))
    assert np.allclose(env, env[::-1])  # the fall mirrors the rise
    assert np.all(np.diff(env[:50]) > 0.0) and np.all(env[50:150] == 1.0)
    assert env[24] == pytest.approx(0.5 - 0.5 * np.cos(np.pi * 24.5 / 50))
    assert env.sum() == pytest.approx(200 - 50)  # each ramp gives half its length
    assert all(push_envelope(i, 200, 0) == 1.0 for i in range(200))  # a step


@pytest.mark.parametrize("rise_steps", [0, 50])
def test_the_push_acts_over_its_steps_only_with_the_impulse_of_its_shape(rise_steps):
    plant, applied = _forces(rise_steps)
    active = np.flatnonzero(np.abs(applied).sum(axis=1))
    assert active[0] == 2000 and active[-1] == 2199  # push_time 2.0 s, duration 0.2 s
    impulse = applied.sum(axis=0) * 1e-3  # N·s
    assert np.allclose(impulse, [0.0, 40.0 * (0.2 - rise_steps * 1e-3), 0.0])
    assert np.abs(applied).max() == pytest.approx(40.0)  # the same peak force
    if rise_steps == 0:
        assert len(plant.pushes) == 1  # one request for the whole step push
    else:
        assert len(plant.pushes) == 200 and applied[2000, 1] < 0.1 < applied[2010, 1] < 40.0


def test_the_push_scenario_rises_over_0_05_s_and_a_rise_longer_than_half_is_refused():
    assert load_scenario("push").plant.push_rise_time == 0.05
    with pytest.raises(ConfigError, match=r"plant.push_rise_time = 0.15: expected at most half"):
        load_scenario("push", {"plant.push_rise_time": 0.15})
    load_scenario("polishing", {"plant.push_rise_time": 0.15})  # no push: nothing to fit
