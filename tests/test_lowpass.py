"""Torque-feedback (low-pass actuation) OCP nodes: derivatives, eq 13–15, eq 28, switching."""

from __future__ import annotations

import math
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

from ffmpc_core.config import TORQUE_INTEGRATIONS, ContactConfig, CostWeights, NodeReference
from ffmpc_core.errors import ConfigError, InputError, ModelError
from ffmpc_core.lowpass import (
    PAPER_CUTOFF_FREQUENCY,
    IntegratedActionModelLPF,
    interpolate_torque,
    interpolation_epsilon,
    lowpass_alpha,
    make_lowpass_node,
)
from ffmpc_core.rigid_contact import make_differential_model, make_rigid_contact_node
from ffmpc_core.robots import load_robot

DT = 3e-3
CONTACTS = {
    "1d_lwa_z": ContactConfig(dimension=1, frame_type="LOCAL_WORLD_ALIGNED", normal_axis=2),
    "1d_local_y": ContactConfig(dimension=1, frame_type="LOCAL", normal_axis=1),
    "3d_lwa": ContactConfig(dimension=3, frame_type="LOCAL_WORLD_ALIGNED"),
    "3d_local": ContactConfig(dimension=3, frame_type="LOCAL"),
}
MODES = ("contact", "free", "terminal")
#: (mode, torque_integration): a terminal node has no control, the same model in both
MODE_INTEGRATIONS = [(m, "current") for m in MODES] + [("contact", "next"), ("free", "next")]


@pytest.fixture(scope="module", params=["iiwa", "panda"])
def robot(request):
    return load_robot(request.param)


@pytest.mark.parametrize("contact_name", list(CONTACTS))
@pytest.mark.parametrize(("mode", "torque_integration"), MODE_INTEGRATIONS)
def test_derivatives_match_numdiff(robot, contact_name, mode, torque_integration):
    key = f"{robot.name}/{contact_name}/{mode}/{torque_integration}"
    rng = np.random.default_rng(zlib.crc32(key.encode()))
    contact = CONTACTS[contact_name]
    for isotropic in (True, False):
        weights = rich_weights(
            rng, contact.dimension, isotropic, lowpass_input=0.3, authors_terms=True
        )
        node = make_lowpass_node(
            robot,
            contact,
            weights,
            DT,
            mode == "terminal",
            PAPER_CUTOFF_FREQUENCY,
            in_contact=mode == "contact",
            torque_integration=torque_integration,
        )
        node.set_reference(random_reference(rng, robot, contact, mode == "contact"))
        model = node.model
        numdiff = crocoddyl.ActionModelNumDiff(model, False)
        data, nd_data = model.createData(), numdiff.createData()
        for k in range(2):
            x = random_state(rng, robot, with_torque=True)
            if k == 1:  # the joint-limit barrier on (q, v) active on a position and a velocity
                x = beyond_state_limits(rng, robot, x)
                model.calc(data, x)
                assert data.differential.costs.costs["state_limit"].cost > 1e-4
            if mode == "terminal":
                model.calc(data, x)
                model.calcDiff(data, x)
                numdiff.calc(nd_data, x)
                numdiff.calcDiff(nd_data, x)
                assert_close_rel(data.Lx, nd_data.Lx, 1e-4, "Lx")
                assert np.any(data.Lx[2 * robot.nv :] != 0.0)  # the terminal τ term
                continue
            w = x[2 * robot.nv :] + 5.0 * rng.standard_normal(robot.nv)
            model.calc(data, x, w)
            model.calcDiff(data, x, w)
            numdiff.calc(nd_data, x, w)
            numdiff.calcDiff(nd_data, x, w)
            for name in ("Fx", "Fu", "Lx", "Lu"):
                assert_close_rel(getattr(data, name), getattr(nd_data, name), 1e-4, name)


@pytest.mark.parametrize("contact_name", ["1d_lwa_z", "3d_local"])
@pytest.mark.parametrize("in_contact", [True, False])
@pytest.mark.parametrize("torque_integration", TORQUE_INTEGRATIONS)
def test_step_and_cost_match_classical_model_plus_eq28(
    robot, contact_name, in_contact, torque_integration
):
    """Eq 13–14 and 28 against the classical node driven by the filtered torque: the state's τ
    ("current", eq 14a) or τ⁺ = α·τ + (1 − α)·w ("next", the authors' tau_plus_integration)."""
    rng = np.random.default_rng(5)
    contact = CONTACTS[contact_name]
    weights = rich_weights(rng, contact.dimension, lowpass_input=0.3)
    ref = random_reference(rng, robot, contact, in_contact)
    lpf = make_lowpass_node(
        robot,
        contact,
        weights,
        DT,
        False,
        50.0,
        in_contact=in_contact,
        torque_integration=torque_integration,
    )
    classical = make_rigid_contact_node(robot, contact, weights, DT, False, in_contact=in_contact)
    lpf.set_reference(ref)
    classical.set_reference(ref)
    lpf_data, cl_data = lpf.model.createData(), classical.model.createData()
    nv = robot.nv
    alpha = math.exp(-2.0 * math.pi * 50.0 * DT)
    assert lpf.alpha == pytest.approx(alpha, rel=1e-15)
    model, pd = robot.model, robot.create_data()
    for _ in range(3):
        x = random_state(rng, robot, with_torque=True)
        w = 20.0 * rng.standard_normal(nv)
        q, tau = x[:nv], x[2 * nv :]
        tau_next = alpha * tau + (1 - alpha) * w
        tau_a = tau if torque_integration == "current" else tau_next
        lpf.model.calc(lpf_data, x, w)
        classical.model.calc(cl_data, x[: 2 * nv], tau_a)
        np.testing.assert_array_equal(lpf_data.applied_torque, tau_a)
        np.testing.assert_allclose(lpf_data.xnext[: 2 * nv], cl_data.xnext, atol=1e-12)
        np.testing.assert_allclose(lpf_data.xnext[2 * nv :], tau_next)
        lam = lpf.contact_force(lpf_data)
        np.testing.assert_allclose(lam, classical.contact_force(cl_data), atol=1e-10)
        # τ_g(q, λ) = g(q) − Jᵀλ, independently
        tau_g = pin.computeGeneralizedGravity(model, pd, q).copy()
        if in_contact:
            pin.computeJointJacobians(model, pd, q)
            pin.framesForwardKinematics(model, pd, q)
            J = pin.getFrameJacobian(model, pd, robot.contact_frame_id, contact.pin_frame)[:3]
            if contact.dimension == 1:
                J = np.eye(3)[contact.normal_axis][None, :] @ J
            tau_g -= J.T @ lam
        eq28 = weights.lowpass_input * 0.5 * float(np.sum((w - tau_g) ** 2))
        assert lpf_data.cost == pytest.approx(cl_data.cost + DT * eq28, rel=1e-10)


def test_gauss_newton_hessian_of_eq28():
    """The c_w term adds Δt·c_w·(GᵀG, −Gᵀ, I) to Lxx, Lxu, Luu; G = ∂τ_g/∂x (finite differences)."""
    robot = load_robot("iiwa")
    contact = CONTACTS["1d_lwa_z"]
    rng = np.random.default_rng(9)
    cw = 0.3
    weights = rich_weights(rng, 1, lowpass_input=cw)
    with_cw = make_lowpass_node(robot, contact, weights, DT, False, 50.0, in_contact=True)
    without = make_lowpass_node(
        robot, contact, weights.with_(lowpass_input=0.0), DT, False, 50.0, in_contact=True
    )
    ref = random_reference(rng, robot, contact, True)
    with_cw.set_reference(ref)
    without.set_reference(ref)
    d1, d0 = with_cw.model.createData(), without.model.createData()
    x = random_state(rng, robot, with_torque=True)
    w = 10.0 * rng.standard_normal(robot.nv)

    def tau_g(xx):
        with_cw.model.calc(d1, xx, w)
        return w - d1.lowpass_residual

    h = 1e-6
    G = np.column_stack([(tau_g(x + h * e) - tau_g(x - h * e)) / (2 * h) for e in np.eye(x.size)])
    for model, data in ((with_cw.model, d1), (without.model, d0)):
        model.calc(data, x, w)
        model.calcDiff(data, x, w)
    assert_close_rel(d1.Lxx - d0.Lxx, DT * cw * G.T @ G, 1e-6, "Lxx")
    assert_close_rel(d1.Lxu - d0.Lxu, -DT * cw * G.T, 1e-6, "Lxu")
    np.testing.assert_allclose(d1.Luu, DT * cw * np.eye(robot.nv), rtol=1e-14)
    np.testing.assert_allclose(d1.Lxx, d1.Lxx.T, atol=1e-12)


def test_gauss_newton_hessian_next_torque():
    """With q̈ at τ⁺ ("next"): Lxx, Lxu, Luu = Δt·Jᵀ·H0·J of the differential model's
    Gauss-Newton Hessian H0 at (q, v, τ⁺), J = ∂(q, v, τ⁺)/∂(x, w), plus Δt·c_w·DᵀD of eq 28,
    D = ∂r_w/∂(x, w) by central differences."""
    robot = load_robot("iiwa")
    contact = CONTACTS["1d_lwa_z"]
    rng = np.random.default_rng(19)
    cw = 0.3
    weights = rich_weights(rng, 1, lowpass_input=cw)
    nodes = [
        make_lowpass_node(
            robot,
            contact,
            weights.with_(lowpass_input=c),
            DT,
            False,
            50.0,
            in_contact=True,
            torque_integration="next",
        )
        for c in (cw, 0.0)
    ]
    ref = random_reference(rng, robot, contact, True)
    for node in nodes:
        node.set_reference(ref)
    model1, model0 = nodes[0].model, nodes[1].model
    d1, d0 = model1.createData(), model0.createData()
    nv, alpha = robot.nv, nodes[0].alpha
    x = random_state(rng, robot, with_torque=True)
    w = x[2 * nv :] + 10.0 * rng.standard_normal(nv)
    z = np.concatenate((x, w))

    def r_w(zz):
        model1.calc(d1, zz[: 3 * nv], zz[3 * nv :])
        return d1.lowpass_residual.copy()

    h = 1e-6
    D = np.column_stack([(r_w(z + h * e) - r_w(z - h * e)) / (2 * h) for e in np.eye(z.size)])
    for model, data in ((model1, d1), (model0, d0)):
        model.calc(data, x, w)
        model.calcDiff(data, x, w)
    # ℓ0's part: the differential model at (q, v, τ⁺), mapped by J
    dam = model0.differential
    dd = dam.createData()
    tau_next = alpha * x[2 * nv :] + (1 - alpha) * w
    dam.calc(dd, x[: 2 * nv], tau_next)
    dam.calcDiff(dd, x[: 2 * nv], tau_next)
    H0 = np.block([[dd.Lxx, dd.Lxu], [dd.Lxu.T, dd.Luu]])
    J = np.zeros((3 * nv, 4 * nv))
    J[: 2 * nv, : 2 * nv] = np.eye(2 * nv)
    J[2 * nv :, 2 * nv : 3 * nv] = alpha * np.eye(nv)
    J[2 * nv :, 3 * nv :] = (1 - alpha) * np.eye(nv)
    full0 = DT * J.T @ H0 @ J
    m = 3 * nv
    assert_close_rel(d0.Lxx, full0[:m, :m], 1e-12, "Lxx (c_w = 0)")
    assert_close_rel(d0.Lxu, full0[:m, m:], 1e-12, "Lxu (c_w = 0)")
    assert_close_rel(d0.Luu, full0[m:, m:], 1e-12, "Luu (c_w = 0)")
    gn = DT * cw * D.T @ D
    assert_close_rel(d1.Lxx - d0.Lxx, gn[:m, :m], 1e-6, "Lxx")
    assert_close_rel(d1.Lxu - d0.Lxu, gn[:m, m:], 1e-6, "Lxu")
    assert_close_rel(d1.Luu - d0.Luu, gn[m:, m:], 1e-6, "Luu")
    np.testing.assert_allclose(d1.Lxx, d1.Lxx.T, atol=1e-12)
    np.testing.assert_allclose(d1.Luu, d1.Luu.T, atol=1e-12)


def test_torque_integration_is_checked():
    robot = load_robot("iiwa")
    with pytest.raises(ConfigError, match="torque_integration"):
        make_lowpass_node(
            robot, CONTACTS["1d_lwa_z"], CostWeights(), DT, False, 50.0, torque_integration="late"
        )
    with pytest.raises(ConfigError, match="torque_integration"):
        make_lowpass_node(
            robot,
            CONTACTS["1d_lwa_z"],
            CostWeights(),
            DT,
            False,
            50.0,
            backend="python",
            torque_integration="tau_plus",
        )


def test_footnote2_limits_of_the_filter():
    """f_c → ∞: τ_{k+1} = w_k (one-step pure delay); f_c → 0: τ_{k+1} = τ_k (w blocked)."""
    robot = load_robot("iiwa")
    contact = CONTACTS["1d_lwa_z"]
    rng = np.random.default_rng(2)
    nv = robot.nv
    x = random_state(rng, robot, with_torque=True)
    w = 30.0 * rng.standard_normal(nv)
    tau = x[2 * nv :]

    def tau_next(cutoff):
        node = make_lowpass_node(robot, contact, CostWeights(), DT, False, cutoff)
        data = node.model.createData()
        node.model.calc(data, x, w)
        return data.xnext[2 * nv :].copy()

    assert lowpass_alpha(math.inf, DT) == 0.0 and lowpass_alpha(0.0, DT) == 1.0
    np.testing.assert_array_equal(tau_next(math.inf), w)
    np.testing.assert_array_equal(tau_next(0.0), tau)
    gaps_w = [np.max(np.abs(tau_next(f) - w)) for f in (10.0, 100.0, 1e3, 1e4)]
    gaps_tau = [np.max(np.abs(tau_next(f) - tau)) for f in (10.0, 1.0, 0.1, 1e-5)]
    assert np.all(np.diff(gaps_w) < 0) and gaps_w[-1] < 1e-12
    assert np.all(np.diff(gaps_tau) < 0) and gaps_tau[-1] < 1e-4

    # pure delay along a rollout: the torque state is the previous input
    nodes = [
        make_lowpass_node(robot, contact, CostWeights(), DT, k == 4, math.inf) for k in range(5)
    ]
    problem = crocoddyl.ShootingProblem(x, [n.model for n in nodes[:4]], nodes[4].model)
    us = [30.0 * rng.standard_normal(nv) for _ in range(4)]
    xs = problem.rollout(us)
    for k in range(4):
        np.testing.assert_array_equal(xs[k + 1][2 * nv :], us[k])
    # blocked: the torque never moves
    nodes = [make_lowpass_node(robot, contact, CostWeights(), DT, k == 4, 0.0) for k in range(5)]
    problem = crocoddyl.ShootingProblem(x, [n.model for n in nodes[:4]], nodes[4].model)
    for xk in problem.rollout(us):
        np.testing.assert_array_equal(xk[2 * nv :], tau)


def test_set_reference_switches_contact_across_solves():
    robot = load_robot("panda")
    contact = CONTACTS["1d_lwa_z"]
    weights = CostWeights(force=1e-2, torque=1e-3, lowpass_input=1e-3)
    q0 = robot.q_nominal
    x0 = np.concatenate([q0, np.zeros(robot.nv), robot.gravity(q0)])
    p0 = robot.contact_placement(q0).translation

    def ref(in_contact):
        return NodeReference(p0 + [0.0, 0.02, 0.0], np.array([20.0]), 50.0, 1e-2, in_contact)

    def build(in_contact):
        nodes = [
            make_lowpass_node(robot, contact, weights, DT, k == 3, 50.0, in_contact=in_contact)
            for k in range(4)
        ]
        for node in nodes:
            node.set_reference(ref(in_contact))
        problem = crocoddyl.ShootingProblem(x0, [n.model for n in nodes[:3]], nodes[3].model)
        return nodes, problem

    fresh = {status: solve(build(status)[1], x0, x0[14:]) for status in (False, True)}
    assert np.max(np.abs(fresh[True][1] - fresh[False][1])) > 1e-3

    nodes, problem = build(False)
    for status in (True, False, True):
        for k, node in enumerate(nodes):
            if node.set_reference(ref(status)):
                problem.updateModel(k, node.model)
            assert node.model is node._models[status and k < 3]
        xs, us = solve(problem, x0, x0[14:])
        np.testing.assert_allclose(xs, fresh[status][0], atol=1e-9)
        np.testing.assert_allclose(us, fresh[status][1], atol=1e-7)


def test_interpolation_eq15():
    tau0, tau1 = np.array([1.0, -2.0, 3.0]), np.array([4.0, 2.0, 0.0])
    np.testing.assert_array_equal(interpolate_torque(tau0, tau1, 0.0), tau0)
    np.testing.assert_array_equal(interpolate_torque(tau0, tau1, 1.0), tau1)
    np.testing.assert_allclose(interpolate_torque(tau0, tau1, 0.25), [1.75, -1.0, 2.25])
    # paper's rates: MPC at 500 Hz (2 ms) with Δt = 3 ms → two thirds of the first interval
    assert interpolation_epsilon(2e-3, 3e-3) == pytest.approx(2.0 / 3.0)
    assert interpolation_epsilon(1e-3, 1e-3) == 1.0
    assert interpolation_epsilon(5e-3, 1e-3) == 1.0  # clipped: never extrapolate
    for bad in (-0.1, 1.5, math.nan):
        with pytest.raises(InputError):
            interpolate_torque(tau0, tau1, bad)
    with pytest.raises(InputError):
        interpolate_torque(tau0, tau1[:2], 0.5)
    with pytest.raises(InputError):
        interpolate_torque(tau0, np.array([np.nan, 0.0, 0.0]), 0.5)
    with pytest.raises(ConfigError):
        interpolation_epsilon(0.0, 3e-3)


def test_bad_configuration_raises():
    robot = load_robot("iiwa")
    contact = CONTACTS["1d_lwa_z"]
    for cutoff in (-1.0, math.nan):
        with pytest.raises(ConfigError):
            make_lowpass_node(robot, contact, CostWeights(), DT, False, cutoff)
    with pytest.raises(ConfigError):
        make_lowpass_node(robot, contact, CostWeights(), -DT, False, 50.0)
    node = make_lowpass_node(robot, contact, CostWeights(), DT, False, 50.0)
    with pytest.raises(InputError):
        node.set_reference(NodeReference(np.zeros(3), np.zeros(3), 1.0, 1.0, True))
    # a running LPF step needs the torque term (eq 25.3) of a running differential model
    terminal_dam = make_differential_model(
        robot, contact, CostWeights(), in_contact=False, terminal=True
    )
    lpf = IntegratedActionModelLPF(terminal_dam, DT, 50.0, 1e-3)
    data = lpf.createData()
    with pytest.raises(ModelError):
        lpf.calc(data, np.zeros(3 * robot.nv), np.zeros(robot.nv))
