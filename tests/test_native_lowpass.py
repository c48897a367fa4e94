"""Native (C++) torque-feedback integrator and custom residuals against their Python references.

``ffmpc_core._native.IntegratedActionModelLPF`` (cpp/lowpass.cpp) must give the same step, cost
and derivatives as :class:`ffmpc_core.lowpass.IntegratedActionModelLPF`, and the C++ residuals
(cpp/residuals.cpp) the same r, Rx, Ru as the Python ones of :mod:`ffmpc_core.rigid_contact`, to
round-off (1e-10 relative), on seeded random states of both arms, in and out of contact, 1-D and
3-D contact, running and terminal. Their derivatives are also checked against finite differences
(crocoddyl's NumDiff and central differences of the residuals), and the MPC closed loop on its own
dynamics gives the same run with either backend.
"""

from __future__ import annotations

import zlib

import crocoddyl  # noqa: I001 (crocoddyl first: it registers the base classes of _native)
import numpy as np
import pytest
from ocp_helpers import (
    assert_close_rel,
    beyond_state_limits,
    random_reference,
    random_state,
    rich_weights,
)

from ffmpc_core import _native
from ffmpc_core.config import (
    BACKENDS,
    ContactConfig,
    CostWeights,
    OcpConfig,
)
from ffmpc_core.errors import ConfigError, InputError, ModelError
from ffmpc_core.lowpass import IntegratedActionModelLPF, make_lowpass_model, make_lowpass_node
from ffmpc_core.model_plant import run_model_closed_loop
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig, problem_bounds
from ffmpc_core.rigid_contact import (
    COST_EE_VELOCITY,
    COST_TORQUE,
    CommonCostHandles,
    ResidualModelContactGravityTorque,
    ResidualModelFrameLinearVelocityWorld,
    make_differential_model,
    make_rigid_contact_node,
)
from ffmpc_core.robots import load_robot
from ffmpc_core.tasks import PolishingTask

DT = 3e-3
CUTOFF = 50.0
RTOL = 1e-10  # native vs Python: the same formulas, round-off only
CONTACTS = {
    "1d_lwa_z": ContactConfig(dimension=1, frame_type="LOCAL_WORLD_ALIGNED", normal_axis=2),
    "1d_local_y": ContactConfig(dimension=1, frame_type="LOCAL", normal_axis=1),
    "3d_lwa": ContactConfig(dimension=3, frame_type="LOCAL_WORLD_ALIGNED"),
    "3d_local": ContactConfig(dimension=3, frame_type="LOCAL"),
}
MODES = ("contact", "free", "terminal")
#: (mode, torque_integration): a terminal node has no control, the same model in both
MODE_INTEGRATIONS = [(m, "current") for m in MODES] + [("contact", "next"), ("free", "next")]
ACTION_FIELDS = ("xnext", "Fx", "Fu", "Lx", "Lu", "Lxx", "Lxu", "Luu")
DIFFERENTIAL_FIELDS = ("xout", "Fx", "Fu", "Lx", "Lu", "Lxx", "Lxu", "Luu")


@pytest.fixture(scope="module", params=["iiwa", "panda"])
def robot(request):
    return load_robot(request.param)


def _rng(*keys) -> np.random.Generator:
    return np.random.default_rng(zlib.crc32("/".join(map(str, keys)).encode()))


def _node(robot, contact, weights, mode: str, torque_integration: str, backend: str):
    """A torque-feedback node of ``mode`` (contact, free or terminal) at Δt = DT, f_c = CUTOFF."""
    return make_lowpass_node(
        robot,
        contact,
        weights,
        DT,
        mode == "terminal",
        CUTOFF,
        in_contact=mode == "contact",
        backend=backend,
        torque_integration=torque_integration,
    )


def _assert_same(native, python, fields, what) -> None:
    for name in fields:
        expected = np.asarray(getattr(python, name))
        assert_close_rel(np.asarray(getattr(native, name)), expected, RTOL, f"{what} {name}")
    assert native.cost == pytest.approx(python.cost, rel=RTOL, abs=RTOL)


@pytest.mark.parametrize("contact_name", list(CONTACTS))
@pytest.mark.parametrize(("mode", "torque_integration"), MODE_INTEGRATIONS)
def test_lowpass_native_equals_python(robot, contact_name, mode, torque_integration):
    """calc/calcDiff of the C++ integrator = the Python reference (xnext, cost, F*, L*), with
    q̈ at the state's τ (eq 14a) and at τ⁺ (tau_plus)."""
    rng = _rng(robot.name, contact_name, mode, torque_integration)
    contact = CONTACTS[contact_name]
    terminal, in_contact = mode == "terminal", mode == "contact"
    nv = robot.nv
    for isotropic in (True, False):  # LOCAL velocity residual / world-velocity residual
        weights = rich_weights(
            rng, contact.dimension, isotropic, lowpass_input=0.3, authors_terms=True
        )
        ref = random_reference(rng, robot, contact, in_contact)
        nodes = {b: _node(robot, contact, weights, mode, torque_integration, b) for b in BACKENDS}
        assert isinstance(nodes["native"].model, _native.IntegratedActionModelLPF)
        assert isinstance(nodes["python"].model, IntegratedActionModelLPF)
        for node in nodes.values():
            node.set_reference(ref)
        native, python = nodes["native"].model, nodes["python"].model
        assert native.alpha == python.alpha and native.dt == python.dt
        assert native.lowpass_input_weight == python.lowpass_input_weight
        assert native.torque_integration == python.torque_integration == torque_integration
        d_nat, d_py = native.createData(), python.createData()
        for k in range(3):
            x = random_state(rng, robot, with_torque=True)
            if k == 0:  # the joint-limit barrier active
                x = beyond_state_limits(rng, robot, x)
            if terminal:
                native.calc(d_nat, x)
                native.calcDiff(d_nat, x)
                python.calc(d_py, x)
                python.calcDiff(d_py, x)
                _assert_same(d_nat, d_py, ("xnext", "Fx", "Fu", "Lx", "Lxx"), mode)
                continue
            w = x[2 * nv :] + 5.0 * rng.standard_normal(nv)
            native.calc(d_nat, x, w)
            native.calcDiff(d_nat, x, w)
            python.calc(d_py, x, w)
            python.calcDiff(d_py, x, w)
            _assert_same(d_nat, d_py, ACTION_FIELDS, mode)
            assert_close_rel(
                np.asarray(d_nat.lowpass_residual), d_py.lowpass_residual, RTOL, "w - tau_g"
            )
            assert_close_rel(np.asarray(d_nat.applied_torque), d_py.applied_torque, RTOL, "tau_a")
            assert_close_rel(
                nodes["native"].contact_force(d_nat),
                nodes["python"].contact_force(d_py),
                RTOL,
                "contact force",
            )


def _differential_pair(robot, contact, weights, ref_rng, *, in_contact, terminal):
    """The same differential model with native and with Python residuals, same references."""
    dams = {
        b: make_differential_model(
            robot, contact, weights, in_contact=in_contact, terminal=terminal, backend=b
        )
        for b in BACKENDS
    }
    ref = random_reference(ref_rng, robot, contact, in_contact)
    for dam in dams.values():
        CommonCostHandles(dam, robot.nv, weights.diag("ee_position", 3)).apply(ref)
    return dams


@pytest.mark.parametrize("contact_name", list(CONTACTS))
@pytest.mark.parametrize("mode", MODES)
def test_residuals_native_equal_python(robot, contact_name, mode):
    """r, Rx, Ru of the C++ residuals (eq 25.3 in contact, eq 25.5 world velocity) = Python,
    through the differential model (live contact force), with and without control."""
    rng = _rng("residuals", robot.name, contact_name, mode)
    contact = CONTACTS[contact_name]
    in_contact, terminal = mode == "contact", mode == "terminal"
    weights = rich_weights(rng, contact.dimension, isotropic_velocity=False)
    dams = _differential_pair(
        robot, contact, weights, rng, in_contact=in_contact, terminal=terminal
    )
    native_costs = dams["native"].costs.costs
    python_costs = dams["python"].costs.costs
    checked = [COST_EE_VELOCITY]
    assert isinstance(
        native_costs[COST_EE_VELOCITY].cost.residual, _native.ResidualModelFrameLinearVelocityWorld
    )
    assert isinstance(
        python_costs[COST_EE_VELOCITY].cost.residual, ResidualModelFrameLinearVelocityWorld
    )
    if in_contact:
        checked.append(COST_TORQUE)
        assert isinstance(
            native_costs[COST_TORQUE].cost.residual, _native.ResidualModelContactGravityTorque
        )
        assert isinstance(
            python_costs[COST_TORQUE].cost.residual, ResidualModelContactGravityTorque
        )
    data = {b: dam.createData() for b, dam in dams.items()}
    nv = robot.nv
    for _ in range(3):
        x = random_state(rng, robot)
        u = robot.gravity(x[:nv]) + 10.0 * rng.standard_normal(nv)
        for with_control in (False,) if terminal else (True, False):
            for b, dam in dams.items():
                args = (x, u) if with_control else (x,)
                dam.calc(data[b], *args)
                dam.calcDiff(data[b], *args)
            what = f"{mode} {'(x, u)' if with_control else '(x)'}"
            for name in checked:
                r_nat = data["native"].costs.costs[name].residual
                r_py = data["python"].costs.costs[name].residual
                for field in ("r", "Rx", "Ru"):
                    expected = np.asarray(getattr(r_py, field))
                    got = np.asarray(getattr(r_nat, field))
                    assert_close_rel(got, expected, RTOL, f"{what} {name}.{field}")
            fields = DIFFERENTIAL_FIELDS if with_control else ("Lx", "Lxx")
            _assert_same(data["native"], data["python"], fields, what)


@pytest.mark.parametrize("contact_name", ["1d_lwa_z", "3d_lwa", "3d_local"])
def test_native_residual_jacobians_match_finite_differences(robot, contact_name):
    """Rx, Ru of the C++ residuals against central differences of r through the contact model
    (so λ^r(x, u) moves with x and u, as the derivatives claim)."""
    rng = _rng("fd", robot.name, contact_name)
    contact = CONTACTS[contact_name]
    weights = rich_weights(rng, contact.dimension, isotropic_velocity=False)
    dam = _differential_pair(robot, contact, weights, rng, in_contact=True, terminal=False)[
        "native"
    ]
    data = dam.createData()
    nv, h = robot.nv, 1e-6
    x = random_state(rng, robot)
    u = robot.gravity(x[:nv]) + 10.0 * rng.standard_normal(nv)

    def residuals(xx, uu):
        dam.calc(data, xx, uu)
        return {
            n: np.array(data.costs.costs[n].residual.r) for n in (COST_TORQUE, COST_EE_VELOCITY)
        }

    dam.calc(data, x, u)
    dam.calcDiff(data, x, u)
    jac = {
        n: (np.array(data.costs.costs[n].residual.Rx), np.array(data.costs.costs[n].residual.Ru))
        for n in (COST_TORQUE, COST_EE_VELOCITY)
    }
    fd_x = {n: np.zeros_like(j[0]) for n, j in jac.items()}
    fd_u = {n: np.zeros_like(j[1]) for n, j in jac.items()}
    for i, e in enumerate(np.eye(2 * nv)):
        plus, minus = residuals(x + h * e, u), residuals(x - h * e, u)
        for n in jac:
            fd_x[n][:, i] = (plus[n] - minus[n]) / (2 * h)
    for i, e in enumerate(np.eye(nv)):
        plus, minus = residuals(x, u + h * e), residuals(x, u - h * e)
        for n in jac:
            fd_u[n][:, i] = (plus[n] - minus[n]) / (2 * h)
    for n in jac:
        assert_close_rel(jac[n][0], fd_x[n], 1e-6, f"{n} Rx")
        assert_close_rel(jac[n][1], fd_u[n], 1e-6, f"{n} Ru")
    assert np.max(np.abs(fd_u[COST_TORQUE] - np.eye(nv))) > 1e-3  # λ^r really depends on u


@pytest.mark.parametrize("contact_name", ["1d_lwa_z", "3d_local"])
@pytest.mark.parametrize(("mode", "torque_integration"), MODE_INTEGRATIONS)
def test_native_models_match_numdiff(robot, contact_name, mode, torque_integration):
    """crocoddyl's NumDiff on the C++ integrator (Fx, Fu, Lx, Lu) and on a differential model
    with the C++ residuals (Fx, Fu, Lx, Lu)."""
    rng = _rng("numdiff", robot.name, contact_name, mode, torque_integration)
    contact = CONTACTS[contact_name]
    terminal, in_contact = mode == "terminal", mode == "contact"
    weights = rich_weights(
        rng, contact.dimension, isotropic_velocity=False, lowpass_input=0.3, authors_terms=True
    )
    node = _node(robot, contact, weights, mode, torque_integration, "native")
    node.set_reference(random_reference(rng, robot, contact, in_contact))
    model = node.model
    numdiff = crocoddyl.ActionModelNumDiff(model, False)
    data, nd_data = model.createData(), numdiff.createData()
    nv = robot.nv
    x = beyond_state_limits(rng, robot, random_state(rng, robot, with_torque=True))
    w = x[2 * nv :] + 5.0 * rng.standard_normal(nv)
    args = (x,) if terminal else (x, w)
    for m, d in ((model, data), (numdiff, nd_data)):
        m.calc(d, *args)
        m.calcDiff(d, *args)
    # (NumDiff's calcDiff(x) leaves Fx at zero; the terminal Fx = I is checked against Python)
    for name in ("Lx",) if terminal else ("Fx", "Fu", "Lx", "Lu"):
        assert_close_rel(getattr(data, name), getattr(nd_data, name), 1e-4, f"LPF {name}")

    dam = model.differential
    dnum = crocoddyl.DifferentialActionModelNumDiff(dam, False)
    dd, dnd = dam.createData(), dnum.createData()
    xq = x[: 2 * nv]
    args = (xq,) if terminal else (xq, x[2 * nv :])
    for m, d in ((dam, dd), (dnum, dnd)):
        m.calc(d, *args)
        m.calcDiff(d, *args)
    for name in ("Lx",) if terminal else ("Fx", "Fu", "Lx", "Lu"):
        assert_close_rel(getattr(dd, name), getattr(dnd, name), 1e-4, f"DAM {name}")
    assert dd.costs.costs["state_limit"].cost > 1e-4  # the joint-limit barrier is active


def test_classical_node_native_equals_python(robot):
    """The classical node (Euler integrator of crocoddyl) with C++ vs Python residuals."""
    rng = _rng("classical", robot.name)
    contact = CONTACTS["1d_lwa_z"]
    weights = rich_weights(rng, 1, isotropic_velocity=False, authors_terms=True)
    ref = random_reference(rng, robot, contact, True)
    nodes = {
        b: make_rigid_contact_node(robot, contact, weights, DT, False, in_contact=True, backend=b)
        for b in BACKENDS
    }
    for node in nodes.values():
        node.set_reference(ref)
    data = {b: n.model.createData() for b, n in nodes.items()}
    for _ in range(3):
        x = random_state(rng, robot)
        u = robot.gravity(x[: robot.nq]) + 10.0 * rng.standard_normal(robot.nv)
        for b, node in nodes.items():
            node.model.calc(data[b], x, u)
            node.model.calcDiff(data[b], x, u)
        _assert_same(data["native"], data["python"], ACTION_FIELDS, "classical")


@pytest.mark.parametrize(
    ("formulation", "torque_integration"),
    [("classical", "current"), ("torque_feedback", "current"), ("torque_feedback", "next")],
)
def test_closed_loop_on_own_dynamics_native_equals_python(formulation, torque_integration):
    """The MPC on its own dynamics (press to 50 N) runs the native nodes by default, and gives
    the same run as with the Python reference nodes."""
    robot = load_robot("iiwa")
    p0 = robot.contact_placement(robot.q_nominal).translation
    task = PolishingTask.pressing(p0, force_ramp=0.1, circle=10.0, stop=0.0)
    config = MpcConfig(
        ocp=OcpConfig(formulation=formulation, torque_integration=torque_integration)
    )
    mpc = ModelPredictiveController(robot, config, task)
    native_type = {
        "classical": crocoddyl.IntegratedActionModelEuler,
        "torque_feedback": _native.IntegratedActionModelLPF,
    }[formulation]
    assert all(isinstance(n.model, native_type) for n in mpc.nodes)
    if formulation == "classical":
        in_contact = mpc.nodes[0]._models[True]
        torque = in_contact.differential.costs.costs[COST_TORQUE].cost.residual
        assert isinstance(torque, _native.ResidualModelContactGravityTorque)

    bounds = problem_bounds(robot, config)  # the constraints are on by default

    def python_nodes(terminal):
        args = (robot, config.contact, config.weights, config.ocp.dt, terminal)
        if formulation == "classical":
            return make_rigid_contact_node(*args, backend="python", bounds=bounds)
        return make_lowpass_node(
            *args,
            config.ocp.cutoff_frequency,
            backend="python",
            bounds=bounds,
            torque_integration=torque_integration,
        )

    duration = 0.2
    logs = {
        "native": run_model_closed_loop(robot, config, task, duration).arrays(),
        "python": run_model_closed_loop(
            robot, config, task, duration, node_factory=python_nodes
        ).arrays(),
    }
    np.testing.assert_array_equal(logs["native"]["iterations"], logs["python"]["iterations"])
    np.testing.assert_allclose(logs["native"]["force"], logs["python"]["force"], atol=1e-6)
    np.testing.assert_allclose(
        logs["native"]["ee_position"], logs["python"]["ee_position"], atol=1e-9
    )
    assert logs["native"]["force"][-1, -1] > 20.0  # it really pressed


def test_native_errors_are_ffmpc_errors(robot):
    contact = CONTACTS["1d_lwa_z"]
    nv = robot.nv
    with pytest.raises(ConfigError):
        make_lowpass_node(robot, contact, CostWeights(), DT, False, CUTOFF, backend="cuda")
    with pytest.raises(ConfigError):
        make_rigid_contact_node(robot, contact, CostWeights(), DT, False, backend="")
    terminal_dam = make_differential_model(
        robot, contact, CostWeights(), in_contact=False, terminal=True
    )
    for cutoff, dt, cw in (
        (-1.0, DT, 0.0),
        (np.nan, DT, 0.0),
        (CUTOFF, 0.0, 0.0),
        (CUTOFF, DT, -1),
    ):
        with pytest.raises(ConfigError):
            make_lowpass_model(terminal_dam, dt, cutoff, cw, backend="native")
        with pytest.raises(ConfigError):  # the C++ constructor checks too
            _native.IntegratedActionModelLPF(
                terminal_dam, dt, cutoff, cw, COST_TORQUE, np.zeros((0, 3 * nv)), np.ones(nv), False
            )
    # a running step needs the torque term (eq 25.3) of a running differential model
    lpf = make_lowpass_model(terminal_dam, DT, CUTOFF, 1e-3, backend="native")
    data = lpf.createData()
    assert data.torque_residual is None
    with pytest.raises(ModelError):
        lpf.calc(data, np.zeros(3 * nv), np.zeros(nv))
    lpf.calc(data, np.zeros(3 * nv))  # terminal use is fine
    with pytest.raises(InputError):
        lpf.calc(data, np.zeros(2 * nv))
    running = make_lowpass_node(robot, contact, CostWeights(), DT, False, CUTOFF).model
    rdata = running.createData()
    with pytest.raises(InputError):
        running.calc(rdata, np.zeros(3 * nv), np.zeros(nv + 1))
    # the contact residual needs the data of a contact model
    state = crocoddyl.StateMultibody(robot.model)
    costs = crocoddyl.CostModelSum(state, nv)
    residual = _native.ResidualModelContactGravityTorque(state, nv, True, "contact")
    costs.addCost("torque", crocoddyl.CostModelResidual(state, residual), 1.0)
    free = crocoddyl.DifferentialActionModelFreeFwdDynamics(
        state, crocoddyl.ActuationModelFull(state), costs
    )
    with pytest.raises(ModelError):
        free.createData()
    with pytest.raises(ConfigError):
        _native.ResidualModelFrameLinearVelocityWorld(state, len(robot.model.frames), nv)
