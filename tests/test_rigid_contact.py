"""Classical (rigid contact) OCP nodes: derivatives, KKT force, eq 25 costs, contact switching."""

from __future__ import annotations

import zlib

import crocoddyl  # noqa: I001 (crocoddyl first: it loads the boost libraries mim_solvers needs)
import numpy as np
import pinocchio as pin
import pytest
from ocp_helpers import (
    assert_close_rel,
    beyond_state_limits,
    random_reference,
    random_state,
    rich_weights,
    solve,
)

from ffmpc_core.config import ContactConfig, CostWeights, NodeReference
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.rigid_contact import (
    DEFAULT_BAUMGARTE_VELOCITY_GAIN,
    make_rigid_contact_node,
)
from ffmpc_core.robots import load_robot

DT = 3e-3
CONTACTS = {
    "1d_lwa_z": ContactConfig(dimension=1, frame_type="LOCAL_WORLD_ALIGNED", normal_axis=2),
    "1d_local_x": ContactConfig(dimension=1, frame_type="LOCAL", normal_axis=0),
    "3d_lwa": ContactConfig(dimension=3, frame_type="LOCAL_WORLD_ALIGNED"),
    "3d_local": ContactConfig(dimension=3, frame_type="LOCAL"),
}
MODES = ("contact", "free", "terminal")


@pytest.fixture(scope="module", params=["iiwa", "panda"])
def robot(request):
    return load_robot(request.param)


def build_node(robot, contact, mode, rng, isotropic_velocity=False, authors_terms=False):
    weights = rich_weights(rng, contact.dimension, isotropic_velocity, authors_terms=authors_terms)
    node = make_rigid_contact_node(
        robot, contact, weights, DT, mode == "terminal", in_contact=mode == "contact"
    )
    node.set_reference(random_reference(rng, robot, contact, mode == "contact"))
    return node, weights


@pytest.mark.parametrize("contact_name", list(CONTACTS))
@pytest.mark.parametrize("mode", MODES)
def test_derivatives_match_numdiff(robot, contact_name, mode):
    rng = np.random.default_rng(zlib.crc32(f"{robot.name}/{contact_name}/{mode}".encode()))
    contact = CONTACTS[contact_name]
    for isotropic in (True, False):
        node, _ = build_node(
            robot, contact, mode, rng, isotropic_velocity=isotropic, authors_terms=not isotropic
        )
        model = node.model
        numdiff = crocoddyl.ActionModelNumDiff(model, False)
        data, nd_data = model.createData(), numdiff.createData()
        for k in range(2):
            x = random_state(rng, robot)
            if k == 1:  # the joint-limit barrier active on a position and a velocity
                x = beyond_state_limits(rng, robot, x)
                model.calc(data, x)
                assert data.differential.costs.costs["state_limit"].cost > 1e-4
            if mode == "terminal":
                model.calc(data, x)
                model.calcDiff(data, x)
                numdiff.calc(nd_data, x)
                numdiff.calcDiff(nd_data, x)
                assert_close_rel(data.Lx, nd_data.Lx, 1e-4, "Lx")
                assert data.cost == pytest.approx(nd_data.cost, rel=1e-12)
                continue
            u = 5.0 * rng.standard_normal(robot.nv)
            model.calc(data, x, u)
            model.calcDiff(data, x, u)
            numdiff.calc(nd_data, x, u)
            numdiff.calcDiff(nd_data, x, u)
            for name in ("Fx", "Fu", "Lx", "Lu"):
                assert_close_rel(getattr(data, name), getattr(nd_data, name), 1e-4, name)


def kkt_solution(robot, contact, x, tau, gain):
    """Independent eq 4 with numpy: M, h, J, J̇q̇ from pinocchio, Baumgarte −K_d·J·q̇."""
    model, data = robot.model, robot.create_data()
    nq = robot.nq
    q, v = x[:nq], x[nq:]
    M = pin.crba(model, data, q)
    M = np.triu(M) + np.triu(M, 1).T
    h = pin.nonLinearEffects(model, data, q, v)
    pin.computeJointJacobians(model, data, q)
    pin.framesForwardKinematics(model, data, q)
    J = pin.getFrameJacobian(model, data, robot.contact_frame_id, contact.pin_frame)[:3]
    pin.forwardKinematics(model, data, q, v, np.zeros(robot.nv))
    drift = pin.getFrameClassicalAcceleration(
        model, data, robot.contact_frame_id, contact.pin_frame
    ).linear
    if contact.dimension == 1:
        axis = np.eye(3)[contact.normal_axis]
        J, drift = axis[None, :] @ J, np.array([axis @ drift])
    m = J.shape[0]
    kkt = np.block([[M, J.T], [J, np.zeros((m, m))]])
    rhs = np.concatenate([tau - h, -drift - gain * (J @ v)])
    sol = np.linalg.solve(kkt, rhs)
    return sol[: robot.nv], -sol[robot.nv :], J, drift


@pytest.mark.parametrize("contact_name", list(CONTACTS))
@pytest.mark.parametrize("gain", [0.0, DEFAULT_BAUMGARTE_VELOCITY_GAIN])
def test_contact_force_is_the_kkt_dual(robot, contact_name, gain):
    rng = np.random.default_rng(7)
    contact = CONTACTS[contact_name]
    node = make_rigid_contact_node(
        robot, contact, CostWeights(), DT, False, in_contact=True, baumgarte_velocity_gain=gain
    )
    data = node.model.createData()
    for _ in range(3):
        x = random_state(rng, robot)
        tau = 20.0 * rng.standard_normal(robot.nv)
        node.model.calc(data, x, tau)
        ddq, lam, J, drift = kkt_solution(robot, contact, x, tau, gain)
        np.testing.assert_allclose(node.contact_force(data), lam, rtol=1e-8, atol=1e-8)
        a = data.differential.xout
        np.testing.assert_allclose(a, ddq, rtol=1e-8, atol=1e-8)
        v = x[robot.nq :]
        # constraint (3b), with the Baumgarte velocity term when K_d > 0
        np.testing.assert_allclose(J @ a + drift, -gain * (J @ v), atol=1e-8)
        # eq 8a: semi-implicit Euler
        v_next = v + DT * a
        np.testing.assert_allclose(data.xnext[robot.nq :], v_next, atol=1e-12)
        np.testing.assert_allclose(data.xnext[: robot.nq], x[: robot.nq] + DT * v_next, atol=1e-12)
    # free dynamics: no force
    node.set_reference(random_reference(rng, robot, contact, in_contact=False))
    free_data = node.model.createData()
    node.model.calc(free_data, x, tau)
    np.testing.assert_array_equal(node.contact_force(free_data), np.zeros(contact.dimension))


def eq25_cost(robot, contact, weights, ref, x, tau, lam, terminal):
    """Independent ℓ0 (eq 25) in crocoddyl's c·½·Σ Q r² convention."""
    model, data = robot.model, robot.create_data()
    nq = robot.nq
    q, v = x[:nq], x[nq:]
    pin.forwardKinematics(model, data, q, v)
    pin.updateFramePlacements(model, data)
    fid = robot.contact_frame_id
    p = data.oMf[fid].translation
    pdot = pin.getFrameVelocity(model, data, fid, pin.LOCAL_WORLD_ALIGNED).linear

    def term(c, name, r):
        diag = weights.diag(name, r.size)
        if name == "ee_position" and ref.ee_position_diag is not None:
            diag = np.asarray(ref.ee_position_diag, dtype=float)  # the node's own Q4
        return c * 0.5 * float(np.sum(diag * r**2))

    cost = term(weights.posture, "posture", q - ref.posture)
    cost += term(weights.joint_velocity, "joint_velocity", v)
    cost += term(ref.ee_position_weight, "ee_position", p - ref.ee_position)
    cost += term(weights.ee_velocity, "ee_velocity", pdot)
    # The joint-limit barrier: the excess of (q, v) beyond the bounds, hand-written.
    lower, upper = robot.state_limit_bounds(weights.state_limit_fraction)
    excess = np.maximum(x - upper, 0.0) + np.minimum(x - lower, 0.0)
    cost += weights.state_limit * 0.5 * float(excess @ excess)
    if terminal:
        return cost
    g = pin.computeGeneralizedGravity(model, data, q)
    if lam is None:
        tau_g = g
    else:
        pin.computeJointJacobians(model, data, q)
        J = pin.getFrameJacobian(model, data, fid, contact.pin_frame)[:3]
        if contact.dimension == 1:
            J = np.eye(3)[contact.normal_axis][None, :] @ J
        tau_g = g - J.T @ lam
        cost += term(ref.force_weight, "force", lam - ref.force)
    cost += term(weights.torque, "torque", tau - tau_g)
    return cost


@pytest.mark.parametrize("contact_name", ["1d_lwa_z", "3d_local"])
@pytest.mark.parametrize("mode", MODES)
def test_cost_is_eq25(robot, contact_name, mode):
    rng = np.random.default_rng(11)
    contact = CONTACTS[contact_name]
    for isotropic in (True, False):
        weights = rich_weights(rng, contact.dimension, isotropic)
        node = make_rigid_contact_node(
            robot, contact, weights, DT, mode == "terminal", in_contact=mode == "contact"
        )
        ref = random_reference(rng, robot, contact, mode == "contact")
        node.set_reference(ref)
        data = node.model.createData()
        x = random_state(rng, robot)
        if isotropic:  # and the joint-limit barrier active
            x = beyond_state_limits(rng, robot, x)
        tau = 20.0 * rng.standard_normal(robot.nv)
        if mode == "terminal":
            node.model.calc(data, x)
            expected = eq25_cost(robot, contact, weights, ref, x, tau, None, True)
        else:
            node.model.calc(data, x, tau)
            lam = None
            if mode == "contact":
                lam = kkt_solution(robot, contact, x, tau, DEFAULT_BAUMGARTE_VELOCITY_GAIN)[1]
            expected = DT * eq25_cost(robot, contact, weights, ref, x, tau, lam, False)
        assert data.cost == pytest.approx(expected, rel=1e-9)


def test_set_reference_switches_contact_across_solves():
    robot = load_robot("iiwa")
    contact = CONTACTS["1d_lwa_z"]
    rng = np.random.default_rng(3)
    weights = CostWeights(force=1e-2, torque=1e-3)
    x0 = np.concatenate([robot.q_nominal, 0.05 * rng.standard_normal(robot.nv)])
    p0 = robot.contact_placement(robot.q_nominal).translation

    def ref(in_contact):
        return NodeReference(p0 + [0.02, 0.0, 0.0], np.array([30.0]), 50.0, 1e-2, in_contact)

    def build(in_contact):
        nodes = [
            make_rigid_contact_node(robot, contact, weights, DT, k == 3, in_contact=in_contact)
            for k in range(4)
        ]
        for node in nodes:
            node.set_reference(ref(in_contact))
        problem = crocoddyl.ShootingProblem(x0, [n.model for n in nodes[:3]], nodes[3].model)
        return nodes, problem

    fresh_free = solve(build(False)[1], x0, np.zeros(robot.nv))
    fresh_contact = solve(build(True)[1], x0, np.zeros(robot.nv))
    assert np.max(np.abs(fresh_free[1] - fresh_contact[1])) > 1.0  # the contact matters

    nodes, problem = build(False)
    for _cycle in range(2):
        for status, expected in ((True, fresh_contact), (False, fresh_free)):
            for k, node in enumerate(nodes):
                old = node.model
                changed = node.set_reference(ref(status))
                assert changed == (k < 3) and changed == (node.model is not old)
                if changed:
                    problem.updateModel(k, node.model)
                # same reference again: no switch
                assert node.set_reference(ref(status)) is False
            xs, us = solve(problem, x0, np.zeros(robot.nv))
            np.testing.assert_allclose(xs, expected[0], atol=1e-9)
            np.testing.assert_allclose(us, expected[1], atol=1e-7)
            forces = [nodes[k].contact_force(problem.runningDatas[k]) for k in range(3)]
            if status:
                assert all(f[0] > 1.0 for f in forces)  # pushing on the table
            else:
                assert all(np.all(f == 0.0) for f in forces)


def test_set_reference_updates_in_place():
    robot = load_robot("panda")
    contact = CONTACTS["3d_lwa"]
    node = make_rigid_contact_node(robot, contact, CostWeights(), DT, False, in_contact=True)
    data = node.model.createData()
    x = np.concatenate([robot.q_nominal, np.zeros(robot.nv)])
    p = robot.contact_placement(robot.q_nominal).translation
    tau = robot.gravity(robot.q_nominal)
    costs = []
    for offset, c4 in ((0.0, 10.0), (0.1, 10.0), (0.1, 20.0)):
        model = node.model
        node.set_reference(NodeReference(p + [0.0, 0.0, offset], np.zeros(3), c4, 0.0, True))
        assert node.model is model
        node.model.calc(data, x, tau)
        costs.append(data.cost)
    dcost = DT * 0.5 * 0.1**2
    assert costs[1] - costs[0] == pytest.approx(10.0 * dcost, rel=1e-6)
    assert costs[2] - costs[0] == pytest.approx(20.0 * dcost, rel=1e-6)


def test_bad_input_raises():
    robot = load_robot("iiwa")
    contact = CONTACTS["1d_lwa_z"]
    node = make_rigid_contact_node(robot, contact, CostWeights(), DT, False)
    good = NodeReference(np.zeros(3), np.array([1.0]), 1.0, 1.0, True)
    node.set_reference(good)
    bad = [
        NodeReference(np.zeros(3), np.array([1.0, 2.0]), 1.0, 1.0, True),
        NodeReference(np.array([0.0, np.nan, 0.0]), np.array([1.0]), 1.0, 1.0, True),
        NodeReference(np.zeros(3), np.array([1.0]), -1.0, 1.0, True),
        NodeReference(np.zeros(3), np.array([1.0]), 1.0, 1.0, True, posture=np.zeros(3)),
    ]
    for ref in bad:
        with pytest.raises(InputError):
            node.set_reference(ref)
    with pytest.raises(ConfigError):
        make_rigid_contact_node(robot, contact, CostWeights(), 0.0, False)
    with pytest.raises(ConfigError):
        make_rigid_contact_node(
            robot, contact, CostWeights(), DT, False, baumgarte_velocity_gain=-1.0
        )


@pytest.mark.parametrize("contact_name", ["1d_lwa_z", "3d_lwa"])
def test_every_reference_change_reaches_the_cost(contact_name):
    """The node writes c4, λ̄, c6 and Q4 into crocoddyl only when they change: a sequence of
    changes (and returns to earlier values) gives the cost of a node built afresh each time."""
    robot = load_robot("iiwa")
    contact = CONTACTS[contact_name]
    nc = contact.dimension
    node = make_rigid_contact_node(robot, contact, CostWeights(), DT, False, in_contact=True)
    data = node.model.createData()
    x = np.concatenate([robot.q_nominal + 0.01, np.zeros(robot.nv)])
    tau = robot.gravity(robot.q_nominal) + 1.0
    p = robot.contact_placement(robot.q_nominal).translation + 0.01
    sequence = [
        (10.0, 0.1, 5.0, (1.0, 1.0, 1.0)),
        (10.0, 0.1, 20.0, (1.0, 1.0, 1.0)),
        (10.0, 0.3, 20.0, (1.0, 1.0, 0.0)),
        (30.0, 0.3, 20.0, (1.0, 1.0, 0.0)),
        (10.0, 0.1, 5.0, (1.0, 1.0, 1.0)),
    ]
    for c4, c6, force, diag in sequence:
        ref = NodeReference(p, np.full(nc, force), c4, c6, True, ee_position_diag=np.array(diag))
        node.set_reference(ref)
        node.model.calc(data, x, tau)
        fresh = make_rigid_contact_node(robot, contact, CostWeights(), DT, False, in_contact=True)
        fresh.set_reference(ref)
        fresh_data = fresh.model.createData()
        fresh.model.calc(fresh_data, x, tau)
        assert data.cost == pytest.approx(fresh_data.cost, rel=1e-12)
