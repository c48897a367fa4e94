"""The per-node activation Q4 of the end-effector position cost (``NodeReference.ee_position_diag``)
in the three formulations: in contact the tasks give (1, 1, 0), so an error along the world z
axis costs nothing, while with (1, 1, 1) it costs c4·½·Δt·z² (crocoddyl's convention)."""

from __future__ import annotations

import crocoddyl  # noqa: F401,I001 (crocoddyl first: it loads the boost libraries)
import numpy as np
import pytest

from ffmpc_core.config import ContactConfig, CostWeights, NodeReference
from ffmpc_core.errors import InputError
from ffmpc_core.lowpass import make_lowpass_node
from ffmpc_core.native import make_native_soft_contact_node
from ffmpc_core.rigid_contact import make_rigid_contact_node
from ffmpc_core.soft_contact import make_soft_contact_node

DT = 0.01
C4 = 40.0
DZ = 0.02  # m, the z error of the reference
FORMULATIONS = ("classical", "torque_feedback", "force_feedback", "force_feedback_native")


def _node(robot, formulation: str, terminal: bool = False):
    contact = ContactConfig()
    weights = CostWeights(ee_position_diag=(2.0, 3.0, 4.0))  # the default Q4 of these nodes
    if formulation == "classical":
        return make_rigid_contact_node(robot, contact, weights, DT, terminal, in_contact=True)
    if formulation == "torque_feedback":
        return make_lowpass_node(robot, contact, weights, DT, terminal, 50.0, in_contact=True)
    if formulation == "force_feedback_native":  # the C++ model the MPC runs by default
        return make_native_soft_contact_node(robot, contact, weights, DT, terminal)
    return make_soft_contact_node(robot, contact, weights, DT, terminal)


def _state(robot, formulation: str, rng: np.random.Generator) -> np.ndarray:
    q = robot.q_nominal + 0.05 * rng.standard_normal(robot.nq)
    v = 0.1 * rng.standard_normal(robot.nv)
    extra = {"classical": [], "torque_feedback": [robot.gravity(q)], "force_feedback": [[20.0]]}
    return np.concatenate([q, v, *extra[formulation.removesuffix("_native")]])


def _cost(node, x, u, ref: NodeReference, terminal: bool) -> float:
    """The node's cost at (x, u) after ``set_reference(ref)``, from a data created afterwards."""
    node.set_reference(ref)
    model = node.model
    data = model.createData()
    if terminal:
        model.calc(data, x)
    else:
        model.calc(data, x, u)
    return float(data.cost)


@pytest.mark.parametrize("formulation", FORMULATIONS)
@pytest.mark.parametrize("terminal", [False, True])
def test_z_error_costs_nothing_in_contact_and_c4_half_dt_z2_otherwise(robot, formulation, terminal):
    rng = np.random.default_rng(7)
    node = _node(robot, formulation, terminal)
    x = _state(robot, formulation, rng)
    u = robot.gravity(x[: robot.nq]) + rng.standard_normal(robot.nv)
    p = robot.contact_placement(x[: robot.nq]).translation.copy()

    def ref(z_offset: float, diag) -> NodeReference:
        return NodeReference(
            ee_position=p + np.array([0.0, 0.0, z_offset]),
            force=np.array([30.0]),
            ee_position_weight=C4,
            force_weight=0.1,
            in_contact=True,
            ee_position_diag=None if diag is None else np.array(diag, dtype=float),
        )

    scale = 1.0 if terminal else DT  # running costs are × Δt; the terminal node's are not
    on_surface = _cost(node, x, u, ref(0.0, (1.0, 1.0, 0.0)), terminal)
    assert _cost(node, x, u, ref(DZ, (1.0, 1.0, 0.0)), terminal) == pytest.approx(
        on_surface, rel=1e-12, abs=1e-12
    )
    on_surface = _cost(node, x, u, ref(0.0, (1.0, 1.0, 1.0)), terminal)
    off = _cost(node, x, u, ref(DZ, (1.0, 1.0, 1.0)), terminal)
    assert off - on_surface == pytest.approx(C4 * 0.5 * scale * DZ**2, rel=1e-9)
    # None restores CostWeights.ee_position_diag (z entry 4).
    on_surface = _cost(node, x, u, ref(0.0, None), terminal)
    off = _cost(node, x, u, ref(DZ, None), terminal)
    assert off - on_surface == pytest.approx(4.0 * C4 * 0.5 * scale * DZ**2, rel=1e-9)


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_q4_change_reaches_an_existing_data(robot, formulation):
    """As in the MPC: one data per model, alive across the change of Q4 (crocoddyl copies the
    activation Hessian at the next calcDiff)."""
    rng = np.random.default_rng(3)
    node = _node(robot, formulation)
    x = _state(robot, formulation, rng)
    u = robot.gravity(x[: robot.nq])
    p = robot.contact_placement(x[: robot.nq]).translation + np.array([0.01, -0.02, 0.03])
    refs = [
        NodeReference(p, np.array([30.0]), C4, 0.1, True, ee_position_diag=np.array(d))
        for d in ((1.0, 1.0, 1.0), (1.0, 1.0, 0.0))
    ]
    node.set_reference(refs[0])
    data = node.model.createData()
    node.model.calc(data, x, u)
    node.model.calcDiff(data, x, u)
    node.set_reference(refs[1])
    node.model.calc(data, x, u)
    node.model.calcDiff(data, x, u)
    fresh = node.model.createData()
    node.model.calc(fresh, x, u)
    node.model.calcDiff(fresh, x, u)
    assert data.cost == pytest.approx(fresh.cost, rel=1e-12)
    np.testing.assert_allclose(data.Lx, fresh.Lx, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(data.Lxx, fresh.Lxx, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_bad_q4_is_refused(robot, formulation):
    node = _node(robot, formulation)
    p = robot.contact_placement(robot.q_nominal).translation
    for bad in ([1.0, 1.0], [1.0, -1.0, 0.0], [1.0, np.nan, 0.0]):
        ref = NodeReference(p, np.array([1.0]), C4, 0.1, True, ee_position_diag=np.array(bad))
        with pytest.raises(InputError):
            node.set_reference(ref)


def test_soft_contact_keyword_signature(robot):
    """The force-feedback model's method keeps the interface the C++ port mirrors."""
    model = _node(robot, "force_feedback").model
    p = robot.contact_placement(robot.q_nominal).translation
    model.set_reference_values(p, [5.0], C4, 0.1, True, posture=None, ee_position_diag=[1, 1, 0])
    sl = model.residual_slice("ee_position")
    np.testing.assert_allclose(model._w_running[sl], DT * C4 * np.array([1.0, 1.0, 0.0]))
    model.set_reference_values(p, [5.0], C4, 0.1, True)
    np.testing.assert_allclose(model._w_running[sl], DT * C4 * np.array([2.0, 3.0, 4.0]))
