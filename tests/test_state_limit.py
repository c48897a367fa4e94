"""The joint-limit barrier (``CostWeights.state_limit``) of the three formulations: its bounds,
its value on hand-made states, its configuration from the scenario files and ``--set``.

Its derivatives are covered by the NumDiff tests of each formulation (test_rigid_contact,
test_lowpass, test_native_lowpass, test_soft_contact, test_native_soft_contact), whose states
are pushed beyond the bounds with ``ocp_helpers.beyond_state_limits``; the native force-feedback
model's equality with the Python one by test_native_soft_contact. The closed loop on the default
polishing scenario is in test_runner.
"""

from __future__ import annotations

import dataclasses

import crocoddyl  # noqa: F401, I001 (crocoddyl first: it registers the base classes of _native)
import numpy as np
import pytest

from ffmpc_core.config import ContactConfig, CostWeights
from ffmpc_core.errors import ConfigError
from ffmpc_core.lowpass import make_lowpass_node
from ffmpc_core.mpc import ModelPredictiveController
from ffmpc_core.native import make_native_soft_contact_node
from ffmpc_core.polishing import build_task, mpc_config
from ffmpc_core.rigid_contact import COST_STATE_LIMIT, make_rigid_contact_node
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import SCHEMA, load_scenario
from ffmpc_core.soft_contact import make_soft_contact_node
from ffmpc_ros.cli_args import parse_overrides

DT = 3e-3
FRACTION = 0.75  # not the default 0.9: a bound computed with the wrong fraction shows
WEIGHT = 7.0
#: Each formulation's node, and whether its state has a third block after (q, v) (τ or λ).
FORMULATIONS = ("classical", "torque_feedback", "force_feedback_python", "force_feedback_native")


@pytest.fixture(scope="module")
def iiwa():
    return load_robot("iiwa")


def test_bounds_are_the_fraction_of_the_position_range_and_velocity_limits(iiwa):
    """Hand-computed for joint 2 of the iiwa (±120°, ±85°/s): the middle of the range ± the
    fraction of its half, ± the fraction of the velocity limit; infinite limits stay ±inf."""
    lower, upper = iiwa.state_limit_bounds(FRACTION)
    assert lower.shape == upper.shape == (2 * iiwa.nv,)
    np.testing.assert_allclose(upper[1], FRACTION * np.deg2rad(120.0), rtol=1e-6)
    np.testing.assert_allclose(lower[1], -FRACTION * np.deg2rad(120.0), rtol=1e-6)
    np.testing.assert_allclose(upper[iiwa.nv + 1], FRACTION * np.deg2rad(85.0), rtol=1e-12)
    np.testing.assert_allclose(lower[iiwa.nv :], -upper[iiwa.nv :], rtol=0)
    np.testing.assert_allclose(upper[iiwa.nv :], FRACTION * iiwa.velocity_limit, rtol=1e-15)
    # An asymmetric range (the Panda's joint 4: [-3.0718, -0.0698] rad) is centred on its middle.
    panda = load_robot("panda")
    lo, hi = panda.state_limit_bounds(0.5)
    middle, half = (-3.0718 - 0.0698) / 2, (-0.0698 + 3.0718) / 2
    np.testing.assert_allclose([lo[3], hi[3]], [middle - 0.5 * half, middle + 0.5 * half])
    # A joint without finite limits has no bound.
    unlimited = dataclasses.replace(
        iiwa,
        position_lower=np.where(np.arange(7) == 2, -np.inf, iiwa.position_lower),
        position_upper=np.where(np.arange(7) == 4, 1.8e308, iiwa.position_upper),
        velocity_limit=np.where(np.arange(7) == 6, np.inf, iiwa.velocity_limit),
    )
    lo, hi = unlimited.state_limit_bounds(FRACTION)
    assert lo[2] == lo[4] == lo[iiwa.nv + 6] == -np.inf
    assert hi[2] == hi[4] == hi[iiwa.nv + 6] == np.inf
    np.testing.assert_array_equal(lo[[0, 1, 3]], lower[[0, 1, 3]])
    for bad in (0.0, -0.5, 1.01, np.nan):
        with pytest.raises(ConfigError, match="state_limit_fraction"):
            iiwa.state_limit_bounds(bad)


def _node(formulation: str, robot, weights: CostWeights, terminal: bool):
    contact = ContactConfig()
    if formulation == "classical":
        return make_rigid_contact_node(robot, contact, weights, DT, terminal, in_contact=True)
    if formulation == "torque_feedback":
        return make_lowpass_node(robot, contact, weights, DT, terminal, 50.0, in_contact=True)
    if formulation == "force_feedback_python":
        return make_soft_contact_node(robot, contact, weights, DT, terminal)
    return make_native_soft_contact_node(robot, contact, weights, DT, terminal)


def _node_cost(formulation, robot, weights, terminal, q, v) -> float:
    """The cost of one node at (q, v) (τ = g(q) in the state of torque-feedback, λ = 20 N in
    that of force-feedback) and u = g(q) (running) or no u (terminal)."""
    model = _node(formulation, robot, weights, terminal).model
    third = {"torque_feedback": robot.gravity(q), "classical": np.zeros(0)}
    x = np.concatenate([q, v, third.get(formulation, np.array([20.0]))])
    data = model.createData()
    if terminal:
        model.calc(data, x)
    else:
        model.calc(data, x, robot.gravity(q))
    return float(data.cost)


@pytest.mark.parametrize("formulation", FORMULATIONS)
@pytest.mark.parametrize("terminal", [False, True])
def test_barrier_is_zero_inside_and_half_weighted_squared_excess_outside(
    iiwa, formulation, terminal
):
    """The node cost with the barrier minus the same node without it (c_lim = 0), on hand-made
    states: 0 strictly inside the bounds (entries up to 0.999 of a bound), and
    ½·c_lim·‖excess‖² outside (× Δt in a running node), the excess written out by hand."""
    weights = CostWeights(state_limit=WEIGHT, state_limit_fraction=FRACTION)
    without = weights.with_(state_limit=0.0)
    v_bound = FRACTION * iiwa.velocity_limit
    q_upper = FRACTION * iiwa.position_upper  # the iiwa's ranges are symmetric about 0
    scale = 1.0 if terminal else DT

    # Strictly inside: every velocity at ±0.999 of its bound, joint 2's position too.
    q_in = iiwa.q_nominal.copy()
    q_in[1] = 0.999 * q_upper[1]
    v_in = 0.999 * v_bound * np.array([1, -1, 1, -1, 1, -1, 1])
    inside = _node_cost(formulation, iiwa, weights, terminal, q_in, v_in)
    assert inside == pytest.approx(
        _node_cost(formulation, iiwa, without, terminal, q_in, v_in), rel=1e-12, abs=1e-12
    )

    # Outside: joint 3's velocity 0.2 rad/s above its bound, joint 5's 0.1 rad/s below its
    # negative bound, joint 4's position 0.05 rad below its lower bound; the rest inside.
    q_out = iiwa.q_nominal.copy()
    q_out[3] = -q_upper[3] - 0.05
    v_out = 0.5 * v_bound
    v_out[2] = v_bound[2] + 0.2
    v_out[4] = -v_bound[4] - 0.1
    excess = np.array([0.05, 0.2, 0.1])
    with_barrier = _node_cost(formulation, iiwa, weights, terminal, q_out, v_out)
    no_barrier = _node_cost(formulation, iiwa, without, terminal, q_out, v_out)
    expected = scale * 0.5 * WEIGHT * float(excess @ excess)
    assert with_barrier - no_barrier == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize("formulation", ["classical", "torque_feedback"])
def test_crocoddyl_formulations_use_crocoddyls_barrier(iiwa, formulation):
    """Classical and torque-feedback: the term is crocoddyl's ResidualModelState under an
    ActivationModelQuadraticBarrier with the robot's bounds, weight c_lim, in running and
    terminal nodes."""
    weights = CostWeights(state_limit=WEIGHT, state_limit_fraction=FRACTION)
    lower, upper = iiwa.state_limit_bounds(FRACTION)
    for terminal in (False, True):
        model = _node(formulation, iiwa, weights, terminal).model
        item = model.differential.costs.costs[COST_STATE_LIMIT]
        assert item.weight == WEIGHT
        assert isinstance(item.cost.residual, crocoddyl.ResidualModelState)
        assert isinstance(item.cost.activation, crocoddyl.ActivationModelQuadraticBarrier)
        np.testing.assert_allclose(item.cost.activation.bounds.lb, lower, rtol=1e-15)
        np.testing.assert_allclose(item.cost.activation.bounds.ub, upper, rtol=1e-15)


@pytest.mark.parametrize("backend", ["python", "native"])
def test_force_feedback_bounds_setter_validates_and_changes_nothing_on_error(iiwa, backend):
    make = make_soft_contact_node if backend == "python" else make_native_soft_contact_node
    model = make(iiwa, ContactConfig(), CostWeights(), DT, False).model
    lower, upper = iiwa.state_limit_bounds(0.9)
    np.testing.assert_array_equal(model.state_limit_lower, lower)
    np.testing.assert_array_equal(model.state_limit_upper, upper)
    nan = np.full(2 * iiwa.nv, np.nan)
    for lo, hi in ((lower[:7], upper), (upper, lower), (nan, upper), (lower, upper[:-1])):
        with pytest.raises(ConfigError, match="state-limit bounds"):
            model.set_state_limit_bounds(lo, hi)
        np.testing.assert_array_equal(model.state_limit_lower, lower)
        np.testing.assert_array_equal(model.state_limit_upper, upper)
    model.set_state_limit_bounds(np.full(14, -np.inf), np.full(14, np.inf))  # no bound: allowed
    assert np.all(np.isinf(model.state_limit_upper))


def test_weight_and_fraction_flow_from_the_scenario_and_set_to_every_node(iiwa):
    """The shipped scenario sets c_lim per formulation; ``--set`` overrides reach the nodes of
    the MPC (the force-feedback nodes' weight and bounds); bad values are refused."""
    scenario = load_scenario("polishing")
    for form in ("classical", "torque_feedback", "force_feedback"):
        assert "state_limit" in scenario.mpc.weights[form]
        assert (
            scenario.mpc.cost_weights(form).state_limit == scenario.mpc.weights[form]["state_limit"]
        )
    overrides = parse_overrides(
        [
            "mpc.weights.force_feedback.state_limit=123.5",
            "mpc.weights.force_feedback.state_limit_fraction=0.7",
        ]
    )
    scenario = load_scenario("polishing", overrides)
    weights = scenario.mpc.cost_weights()
    assert (weights.state_limit, weights.state_limit_fraction) == (123.5, 0.7)
    mpc = ModelPredictiveController(iiwa, mpc_config(scenario), build_task(scenario, iiwa))
    lower, upper = iiwa.state_limit_bounds(0.7)
    for node in mpc.nodes:
        assert node.model.weight("state_limit") == 123.5
        np.testing.assert_array_equal(node.model.state_limit_upper, upper)
        np.testing.assert_array_equal(node.model.state_limit_lower, lower)
    assert SCHEMA["mpc.weights.classical.state_limit"].unit == "1/rad², s²/rad²"
    for name, value in (
        ("mpc.weights.classical.state_limit", -1.0),
        ("mpc.weights.classical.state_limit", "high"),
        ("mpc.weights.torque_feedback.state_limit_fraction", 1.5),
        ("mpc.weights.torque_feedback.state_limit_fraction", 0.0),
    ):
        with pytest.raises(ConfigError, match=name.replace(".", r"\.")):
            load_scenario("polishing", {name: value})
