"""The task's phase weights from the scenario: c4 in contact (``ee_position_phase``), c4 in
free space (``ee_position_free``, following ``ee_position_phase`` unless set) and c6
(``force_phase``), into the schedule the MPC reads and into the MPC node's parameters."""

import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_core.polishing import build_task, scenario_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_core.tasks import PhaseWeights

#: The torque-feedback MPC's weights: the polishing files set neither c4 for it (the classical
#: and force-feedback blocks set both, from the searches), so its free-space c4 follows.
TF = {"mpc.formulation": "torque_feedback"}
W = "mpc.weights.torque_feedback."


def _free_and_contact_weights(scenario):
    """c4 of the task's reference at the stand-still and in the circle (1/m²)."""
    task = build_task(scenario, scenario_robot(scenario))
    task.observe_force(10.0, task.contact_time + 0.05)  # the guarded approach detects contact
    circle = task.reference(task.circle_start + 0.5)
    assert circle.in_contact and not task.reference(0.01).in_contact
    return task.reference(0.01).ee_position_weight, circle.ee_position_weight


def test_free_space_weight_follows_the_contact_weight_unless_set():
    base = load_scenario("polishing", {**TF, W + "ee_position_phase": 5e3})
    assert base.mpc.phase_weights() == PhaseWeights(5e3, 5e3, base.mpc.phase_weights().force)
    assert _free_and_contact_weights(base) == (5e3, 5e3)
    split = load_scenario(
        "polishing", {**TF, W + "ee_position_phase": 5e3, W + "ee_position_free": 800}
    )
    assert split.mpc.phase_weights().free_ee_position == 800.0
    assert split.mpc.phase_weights().contact_ee_position == 5e3
    assert _free_and_contact_weights(split) == (800.0, 5e3)
    # the other formulations keep their file's weights (the force-feedback MPC: both set)
    other = split.mpc.phase_weights("force_feedback")
    assert other == load_scenario("polishing").mpc.phase_weights("force_feedback")
    assert (other.free_ee_position, other.contact_ee_position) == (1000.0, 46070.0)
    untouched = load_scenario("polishing", TF).mpc.phase_weights()
    assert untouched.free_ee_position == untouched.contact_ee_position
    assert untouched.contact_ee_position == PhaseWeights.contact_ee_position


@pytest.mark.parametrize("value", [-1.0, "heavy"])
def test_a_bad_free_space_weight_is_refused(value):
    with pytest.raises(ConfigError, match="ee_position_free"):
        load_scenario("polishing", {W + "ee_position_free": value})


def test_the_mpc_node_parameters_hold_the_free_space_weight():
    """scenario_flat (what every node declares): set, or following ee_position_phase."""
    from ffmpc_ros.params import scenario_flat

    split = scenario_flat(load_scenario("polishing", {W + "ee_position_free": 800}))
    assert split[W + "ee_position_free"] == 800.0
    follows = scenario_flat(load_scenario("polishing", {W + "ee_position_phase": 5e3}))
    assert follows[W + "ee_position_free"] == follows[W + "ee_position_phase"] == 5e3
