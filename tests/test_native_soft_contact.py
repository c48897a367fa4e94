"""The native (C++) force-feedback node against the Python reference and finite differences.

``ffmpc_core.native.IntegratedActionModelSoftContactNative`` is a port of
``ffmpc_core.soft_contact.IntegratedActionModelSoftContact``: on seeded random states, for both
robots, 1-D (several normal axes) and 3-D contact, both frame types, in and out of contact,
running and terminal nodes, after changing K/B, weights and references in place, every output
of calc/calcDiff must agree to ~1e-10 relative.
"""

from __future__ import annotations

import crocoddyl
import numpy as np
import pytest

from ffmpc_core.config import ContactConfig, NodeReference, OcpConfig
from ffmpc_core.errors import ConfigError, FfmpcError, InputError
from ffmpc_core.model_plant import run_model_closed_loop
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig
from ffmpc_core.native import IntegratedActionModelSoftContactNative, make_native_soft_contact_node
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_core.soft_contact import (
    RESIDUAL_TERMS,
    IntegratedActionModelSoftContact,
    make_soft_contact_node,
)
from ffmpc_core.tasks import PolishingTask
from tests.ocp_helpers import beyond_state_limits, rich_weights

ROBOTS = ("iiwa", "panda")
# (dimension, frame type, normal axis): the 1-D normal along x, y and z of the force frame.
CONTACTS = [
    (1, "LOCAL_WORLD_ALIGNED", 2),
    (1, "LOCAL_WORLD_ALIGNED", 0),
    (3, "LOCAL_WORLD_ALIGNED", 2),
    (1, "LOCAL", 2),
    (1, "LOCAL", 1),
    (3, "LOCAL", 2),
]
FIELDS = ("xnext", "r", "Fx", "Fu", "Lx", "Lu", "Lxx", "Lxu", "Luu")
RTOL = 1e-10


@pytest.fixture(scope="module")
def robots():
    return {name: load_robot(name) for name in ROBOTS}


def _contact(dim: int, frame: str, axis: int) -> ContactConfig:
    K = 1.5e3 if dim == 1 else (1.0e3, 2.0e3, 3.0e3)  # anisotropic: an axis mix-up shows
    B = 60.0 if dim == 1 else (50.0, 60.0, 70.0)
    return ContactConfig(dimension=dim, frame_type=frame, normal_axis=axis, stiffness=K, damping=B)


def _pair(robot, contact, weights, dt, terminal, q_reference=None):
    python = IntegratedActionModelSoftContact(robot, contact, weights, dt, terminal, q_reference)
    native = IntegratedActionModelSoftContactNative(
        robot, contact, weights, dt, terminal, q_reference
    )
    return python, native


def _random_x_u(rng, robot, dim):
    q = robot.q_nominal + 0.3 * rng.standard_normal(robot.nv)
    x = np.concatenate([q, rng.standard_normal(robot.nv), 20.0 * rng.standard_normal(dim)])
    u = robot.gravity(q) + 5.0 * rng.standard_normal(robot.nv)
    return x, u


def _close(actual, expected, what, rtol=RTOL):
    actual, expected = np.asarray(actual), np.asarray(expected)
    assert actual.shape == expected.shape, what
    scale = max(1.0, float(np.max(np.abs(expected), initial=0.0)))
    err = float(np.max(np.abs(actual - expected), initial=0.0))
    assert err <= rtol * scale, f"{what}: max error {err:.2e} (scale {scale:.2e})"


def _compare(python, native, x, u, what):
    """calc + calcDiff of both models (u None: state terms only); every output equal."""
    outputs = []
    for model in (python, native):
        data = model.createData()
        if u is None:
            model.calc(data, x)
            model.calcDiff(data, x)
        else:
            model.calc(data, x, u)
            model.calcDiff(data, x, u)
        outputs.append(data)
    dp, dn = outputs
    assert dn.cost == pytest.approx(dp.cost, rel=RTOL, abs=1e-300), what
    for name in FIELDS:
        _close(getattr(dn, name), getattr(dp, name), f"{what}: {name}")
    if u is not None and not python.terminal:
        _close(dn.dynamics.ddq, dp.dynamics.ddq, f"{what}: ddq")
        _close(dn.dynamics.force_rate, dp.dynamics.force_rate, f"{what}: force_rate")
    return dp, dn


@pytest.mark.parametrize("robot_name", ROBOTS)
@pytest.mark.parametrize(("dim", "frame", "axis"), CONTACTS)
@pytest.mark.parametrize("terminal", [False, True])
def test_native_equals_python_reference(robots, robot_name, dim, frame, axis, terminal):
    robot = robots[robot_name]
    rng = np.random.default_rng([ROBOTS.index(robot_name), dim, axis, int(terminal), len(frame)])
    weights = rich_weights(rng, dim, authors_terms=True)
    contact = _contact(dim, frame, axis)
    q_ref = robot.q_nominal + 0.05 * rng.standard_normal(robot.nv)
    python, native = _pair(robot, contact, weights, 0.01, terminal, q_ref)
    assert native.state.nx == python.state.nx and native.nr == python.nr
    assert native.nu == python.nu and native.nv == python.nv and native.nc == python.nc
    for name in RESIDUAL_TERMS:
        assert native.residual_slice(name) == python.residual_slice(name)
        assert native.weight(name) == python.weight(name)
    np.testing.assert_array_equal(native.u_lb, python.u_lb)
    np.testing.assert_array_equal(native.u_ub, python.u_ub)
    np.testing.assert_array_equal(native.ee_position_reference, python.ee_position_reference)
    np.testing.assert_array_equal(native.rotation_reference, python.rotation_reference)
    np.testing.assert_allclose(
        python.rotation_reference, robot.contact_placement(q_ref).rotation, rtol=0, atol=1e-15
    )

    x, u = _random_x_u(rng, robot, dim)
    _compare(python, native, x, u, "as built")
    _compare(python, native, x, None, "no u")
    x = beyond_state_limits(rng, robot, x)  # the joint-limit barrier active
    dp, _ = _compare(python, native, x, u, "beyond the state limits")
    assert np.abs(dp.r[python.residual_slice("state_limit")]).max() > 1e-3
    _compare(python, native, x, None, "beyond the state limits, no u")

    # In place: references (out of and back into contact), K/B, weights; same objects.
    for in_contact in (False, True):
        p = robot.contact_placement(q_ref).translation + 0.05 * rng.standard_normal(3)
        f = 10.0 * rng.standard_normal(dim)
        posture = robot.q_nominal + 0.1 * rng.standard_normal(robot.nv)
        for model in (python, native):
            model.set_reference_values(p, f, 17.0, 0.3, in_contact, posture)
        assert native.in_contact is in_contact
        x, u = _random_x_u(rng, robot, dim)
        _compare(python, native, x, u, f"in_contact={in_contact}")
        if not in_contact:
            np.testing.assert_array_equal(native.stiffness, np.zeros(dim))
    stiffness = rng.uniform(200.0, 5e3, dim)
    damping = rng.uniform(5.0, 200.0, dim)
    for model in (python, native):
        model.set_contact_parameters(stiffness, damping)
        model.set_weight("force_rate", 3e-3)
        model.set_weight("ee_velocity", 0.5)
        model.set_weight("state_limit", 11.0)
        model.set_weight("ee_rotation", 6.0)
        model.set_weight("ee_angular_velocity", 0.05)
        model.set_state_limit_bounds(*robot.state_limit_bounds(0.6))
    np.testing.assert_array_equal(native.stiffness, stiffness)
    np.testing.assert_array_equal(native.nominal_damping, damping)
    assert native.weight("force_rate") == 3e-3
    assert native.weight("ee_rotation") == 6.0
    np.testing.assert_array_equal(native.state_limit_upper, python.state_limit_upper)
    for k in range(3):
        x, u = _random_x_u(rng, robot, dim)
        if k == 0:
            x = beyond_state_limits(rng, robot, x, fraction=0.6)
        _compare(python, native, x, u, "after K/B, weight and bound changes")


@pytest.mark.parametrize("robot_name", ROBOTS)
@pytest.mark.parametrize("terminal", [False, True])
def test_native_ee_position_diag_per_node(robots, robot_name, terminal):
    """Q4 set per node equals a model built with that Q4; None restores the configured one."""
    robot = robots[robot_name]
    rng = np.random.default_rng(7 + int(terminal))
    contact = _contact(1, "LOCAL_WORLD_ALIGNED", 2)
    weights = rich_weights(rng, 1)
    q4 = np.array([1.0, 1.0, 0.0])
    python_q4, _ = _pair(robot, contact, weights.with_(ee_position_diag=tuple(q4)), 0.01, terminal)
    python_default, native = _pair(robot, contact, weights, 0.01, terminal)
    p = robot.contact_placement(robot.q_nominal).translation + 0.03 * rng.standard_normal(3)
    args = (p, np.array([12.0]), 40.0, 0.4, True)
    python_q4.set_reference_values(*args)
    python_default.set_reference_values(*args)
    native.set_reference_values(*args, ee_position_diag=q4)
    x, u = _random_x_u(rng, robot, 1)
    _compare(python_q4, native, x, u, "Q4 = (1, 1, 0)")
    native.set_reference_values(*args, posture=None, ee_position_diag=None)
    _compare(python_default, native, x, u, "Q4 restored")
    np.testing.assert_array_equal(native.activation("ee_position"), weights.diag("ee_position", 3))


@pytest.mark.parametrize("robot_name", ROBOTS)
@pytest.mark.parametrize(("dim", "frame", "axis"), CONTACTS[::2] + [CONTACTS[3]])
@pytest.mark.parametrize("terminal", [False, True])
def test_native_matches_numdiff(robots, robot_name, dim, frame, axis, terminal):
    robot = robots[robot_name]
    rng = np.random.default_rng([11, dim, axis, int(terminal)])
    node = make_native_soft_contact_node(
        robot,
        _contact(dim, frame, axis),
        rich_weights(rng, dim, authors_terms=True),
        0.01,
        terminal,
    )
    node.set_reference(
        NodeReference(
            ee_position=np.array([0.45, 0.1, 0.35]),
            force=np.linspace(10.0, 20.0, dim),
            ee_position_weight=30.0,
            force_weight=0.5,
            in_contact=True,
            posture=robot.q_nominal + 0.1 * rng.standard_normal(robot.nv),
        )
    )
    model = node.model
    x, u = _random_x_u(rng, robot, dim)
    x = beyond_state_limits(rng, robot, x)  # the joint-limit barrier active
    data = model.createData()
    model.calc(data, x, u)
    model.calcDiff(data, x, u)
    numdiff = crocoddyl.ActionModelNumDiff(model, True)  # Gauss-Newton Hessians from data.r
    ndata = numdiff.createData()
    numdiff.calc(ndata, x, u)
    numdiff.calcDiff(ndata, x, u)
    assert ndata.cost == pytest.approx(data.cost, rel=1e-12)
    assert data.cost == pytest.approx(0.5 * data.r @ data.r, rel=1e-12)
    for name in ("Fx", "Fu", "Lx", "Lu", "Lxx", "Lxu", "Luu"):
        _close(getattr(data, name), getattr(ndata, name), name, rtol=1e-5)
    expected = {"posture", "joint_velocity", "ee_position", "ee_velocity", "force", "state_limit"}
    expected |= {"ee_rotation", "ee_angular_velocity"}
    if not terminal:
        expected |= {"torque", "force_rate"}
    for term in RESIDUAL_TERMS:
        contribution = np.abs(data.r[model.residual_slice(term)]).max()
        assert (contribution > 1e-6) == (term in expected), term


def test_native_model_is_the_solvers_object_and_updates_in_place(robots):
    """The shooting problem holds the very Python object; in-place updates reach the solver."""
    robot = robots["iiwa"]
    config = MpcConfig(ocp=OcpConfig(formulation="force_feedback"))
    p0 = robot.contact_placement(robot.q_nominal).translation
    mpc = ModelPredictiveController(robot, config, PolishingTask.pressing(p0))
    node = mpc.nodes[0]
    assert isinstance(node.model, IntegratedActionModelSoftContactNative)
    assert mpc.problem.runningModels[0] is node.model
    data = mpc.problem.runningDatas[0]
    x = np.concatenate([robot.q_nominal, np.zeros(robot.nv), [5.0]])
    u = robot.gravity(robot.q_nominal)
    node.model.calc(data, x, u)
    before = data.cost
    node.model.set_reference_values(p0, np.array([40.0]), 100.0, 1.0, True)
    node.model.calc(data, x, u)
    assert data.cost != before
    with pytest.raises(ConfigError):
        MpcConfig(backend="fortran")
    python_mpc = ModelPredictiveController(
        robot, MpcConfig(backend="python"), PolishingTask.pressing(p0)
    )
    assert type(python_mpc.nodes[0].model) is IntegratedActionModelSoftContact


def test_native_and_python_backends_give_the_same_closed_loop(robots):
    """Own-dynamics closed loop (plant: the Python model) with either backend in the MPC."""
    robot = robots["iiwa"]
    p0 = robot.contact_placement(robot.q_nominal).translation
    task = PolishingTask.pressing(p0)
    logs = {
        backend: run_model_closed_loop(
            robot,
            MpcConfig(ocp=OcpConfig(formulation="force_feedback"), backend=backend),
            task,
            0.2,
        ).arrays()
        for backend in ("native", "python")
    }
    n, p = logs["native"], logs["python"]
    assert n["force"][-1, -1] > 5.0  # the force is building up
    np.testing.assert_allclose(n["force"], p["force"], rtol=0, atol=1e-6)
    np.testing.assert_allclose(n["ee_position"], p["ee_position"], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(n["iterations"], p["iterations"])


def test_native_closed_loop_reaches_and_holds_50_newtons(robots):
    robot = robots["iiwa"]
    p0 = robot.contact_placement(robot.q_nominal).translation
    task = PolishingTask.pressing(p0)
    config = MpcConfig(ocp=OcpConfig(formulation="force_feedback"), backend="native")
    a = run_model_closed_loop(robot, config, task, task.duration).arrays()
    held = a["t"] > task.duration - 0.3
    force = a["force"][held, -1]
    assert np.all(np.abs(force - 50.0) < 1.0), (force.min(), force.max())
    assert a["force"][0, -1] < 1.0
    assert max(a["iterations"]) <= 8


def test_native_setters_reject_bad_input_and_change_nothing(robots):
    robot = robots["iiwa"]
    contact = _contact(3, "LOCAL_WORLD_ALIGNED", 2)
    weights = rich_weights(np.random.default_rng(3), 3)
    model = IntegratedActionModelSoftContactNative(robot, contact, weights, 0.01)
    p = model.ee_position_reference
    f = np.array([1.0, 2.0, 3.0])
    model.set_reference_values(p, f, 10.0, 0.5, True)
    bad_calls = [
        ((p + np.nan, f, 10.0, 0.5, True), {}),
        ((p[:2], f, 10.0, 0.5, True), {}),
        ((p, f[:2], 10.0, 0.5, True), {}),
        ((p, 5.0, 10.0, 0.5, True), {}),  # a scalar force is one entry, not three
        ((p, f, -1.0, 0.5, True), {}),
        ((p, f, 10.0, np.inf, True), {}),
        ((p, f, 10.0, 0.5, True), {"posture": np.zeros(6)}),
        ((p, f, 10.0, 0.5, True), {"posture": np.full(7, np.nan)}),
        ((p, f, 10.0, 0.5, True), {"ee_position_diag": [1.0, -1.0, 0.0]}),
        ((p, f, 10.0, 0.5, True), {"ee_position_diag": [1.0, 1.0]}),
        ((p, f, 10.0, 0.5, False), {"ee_position_diag": np.ones((3, 1))}),
        ((p, "ten", 10.0, 0.5, False), {}),
    ]
    for args, kwargs in bad_calls:
        with pytest.raises(InputError):
            model.set_reference_values(*args, **kwargs)
        np.testing.assert_array_equal(model.force_reference, f)
        np.testing.assert_array_equal(model.ee_position_reference, p)
        assert model.in_contact and model.weight("ee_position") == 10.0
        np.testing.assert_array_equal(model.q_reference, robot.q_nominal)
    nominal = model.nominal_stiffness
    for stiffness, damping in (([1.0, -2.0, 3.0], 1.0), (np.nan, 1.0), ([1.0, 2.0], 1.0)):
        with pytest.raises(ConfigError):
            model.set_contact_parameters(stiffness, damping)
    np.testing.assert_array_equal(model.nominal_stiffness, nominal)
    with pytest.raises(ConfigError):
        model.set_weight("friction", 1.0)
    with pytest.raises(ConfigError):
        model.set_weight("torque", -1.0)
    with pytest.raises(ConfigError):
        model.weight("friction")
    with pytest.raises(ConfigError):
        IntegratedActionModelSoftContactNative(robot, contact, weights, 0.0)
    with pytest.raises(ConfigError):
        IntegratedActionModelSoftContactNative(robot, contact, weights, 0.01, q_reference=[0.0])
    data = model.createData()
    with pytest.raises(InputError):
        model.calc(data, np.zeros(5), np.zeros(7))
    with pytest.raises(InputError):
        model.calcDiff(data, np.zeros(model.state.nx), np.zeros(3))
    assert issubclass(InputError, FfmpcError)


def test_scenario_selects_the_backend():
    scenario = load_scenario("polishing")
    assert scenario.mpc.backend == "native"
    assert load_scenario("polishing", {"mpc.backend": "python"}).mpc.backend == "python"
    with pytest.raises(ConfigError):
        load_scenario("polishing", {"mpc.backend": "fortran"})


def test_make_soft_contact_node_twins_start_equal(robots):
    robot = robots["panda"]
    contact = _contact(1, "LOCAL_WORLD_ALIGNED", 2)
    weights = rich_weights(np.random.default_rng(5), 1)
    a = make_soft_contact_node(robot, contact, weights, 0.003, False).model
    b = make_native_soft_contact_node(robot, contact, weights, 0.003, False).model
    np.testing.assert_array_equal(b.q_reference, a.q_reference)
    np.testing.assert_array_equal(b.force_reference, a.force_reference)
    x, u = _random_x_u(np.random.default_rng(6), robot, 1)
    _compare(a, b, x, u, "factories")


def test_self_check_compares_native_and_python_and_can_fail(robots, monkeypatch):
    import ffmpc_core.native as native
    from ffmpc_core.selfcheck import check_native_soft_contact

    robot = robots["iiwa"]
    result = check_native_soft_contact(robot, np.random.default_rng(0), samples=3)
    assert result.ok and result.samples == 6 and result.max_error < 1e-11

    class Wrong(native.IntegratedActionModelSoftContactNative):
        """A native model whose contact is twice as stiff: the check must see it."""

        def __init__(self, robot, contact, weights, dt):
            super().__init__(robot, contact, weights, dt)
            self.set_contact_parameters(2.0 * contact.stiffness_vector(), contact.damping_vector())

    monkeypatch.setattr(native, "IntegratedActionModelSoftContactNative", Wrong)
    assert not check_native_soft_contact(robot, np.random.default_rng(0), samples=3).ok
