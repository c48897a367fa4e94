"""Force-feedback OCP model (paper section V): dynamics, derivatives, costs, node updates."""

from __future__ import annotations

import crocoddyl
import mim_solvers
import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.config import ContactConfig, CostWeights, NodeReference
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.robots import load_robot
from ffmpc_core.soft_contact import (
    RESIDUAL_TERMS,
    IntegratedActionModelSoftContact,
    SoftContactDynamics,
    make_soft_contact_node,
    soft_contact_state,
    visco_elastic_force,
)
from tests.ocp_helpers import beyond_state_limits

ROBOTS = ("iiwa", "panda")
CONTACTS = [
    (1, "LOCAL_WORLD_ALIGNED"),
    (3, "LOCAL_WORLD_ALIGNED"),
    (1, "LOCAL"),
    (3, "LOCAL"),
]


@pytest.fixture(scope="module")
def robots():
    return {name: load_robot(name) for name in ROBOTS}


def _contact(dim: int, frame: str, normal_axis: int = 2) -> ContactConfig:
    # Anisotropic K, B for 3-D so that an axis mix-up shows.
    K = 1.5e3 if dim == 1 else (1.0e3, 2.0e3, 3.0e3)
    B = 60.0 if dim == 1 else (50.0, 60.0, 70.0)
    return ContactConfig(
        dimension=dim, frame_type=frame, normal_axis=normal_axis, stiffness=K, damping=B
    )


def _random_point(robot, dim: int, rng: np.random.Generator):
    q = robot.q_nominal + 0.3 * rng.standard_normal(robot.nv)
    v = rng.standard_normal(robot.nv)
    force = 20.0 * rng.standard_normal(dim)  # non-zero λ, N
    tau = robot.gravity(q) + 5.0 * rng.standard_normal(robot.nv)
    return q, v, force, tau


def _stacked_outputs(dyn: SoftContactDynamics, data, z: np.ndarray) -> np.ndarray:
    nv, nc = dyn.nv, dyn.nc
    q, v, f, tau = z[:nv], z[nv : 2 * nv], z[2 * nv : 2 * nv + nc], z[2 * nv + nc :]
    dyn.calc(data, q, v, f, tau)
    dyn.calc_gravity_compensation(data, q)
    return np.concatenate(
        [data.ddq, data.force_rate, data.gravity_compensation, data.ee_velocity, data.position]
    )


def _central_fd(dyn: SoftContactDynamics, z: np.ndarray, h: float = 1e-6) -> np.ndarray:
    data = dyn.create_data()
    cols = []
    for i in range(z.size):
        e = np.zeros(z.size)
        e[i] = h
        plus = _stacked_outputs(dyn, data, z + e)
        minus = _stacked_outputs(dyn, data, z - e)
        cols.append((plus - minus) / (2.0 * h))
    return np.array(cols).T


@pytest.mark.parametrize("robot_name", ROBOTS)
@pytest.mark.parametrize(("dim", "frame"), CONTACTS)
def test_dynamics_derivatives_match_central_finite_differences(robots, robot_name, dim, frame):
    """Eq 22 and 23a–d (and ∂τ_g, ∂ṗ, ∂p) against central differences of calc itself."""
    robot = robots[robot_name]
    dyn = SoftContactDynamics(robot, _contact(dim, frame))
    rng = np.random.default_rng(1000 + 10 * dim + len(frame))
    nv, nc = dyn.nv, dyn.nc
    for _ in range(2):
        q, v, force, tau = _random_point(robot, dim, rng)
        z = np.concatenate([q, v, force, tau])
        numeric = _central_fd(dyn, z)

        data = dyn.create_data()
        dyn.calc(data, q, v, force, tau)
        dyn.calc_diff(data, q, v, force, tau)
        dyn.calc_gravity_compensation(data, q)
        dyn.calc_gravity_compensation_diff(data, q)
        analytic = np.zeros_like(numeric)
        analytic[:nv] = data.ddq_dxu
        analytic[nv : nv + nc] = data.force_rate_dxu
        o = nv + nc
        analytic[o : o + nv, :nv] = data.gravity_compensation_dq
        analytic[o : o + nv, 2 * nv : 2 * nv + nc] = data.gravity_compensation_dforce
        o += nv
        analytic[o : o + 3, : 2 * nv] = data.ee_velocity_dqv
        analytic[o + 3 : o + 6, :nv] = data.position_dq

        blocks = {
            "ddq": slice(0, nv),
            "force_rate": slice(nv, nv + nc),
            "gravity_compensation": slice(nv + nc, 2 * nv + nc),
            "ee_velocity": slice(2 * nv + nc, 2 * nv + nc + 3),
            "position": slice(2 * nv + nc + 3, 2 * nv + nc + 6),
        }
        for name, rows in blocks.items():
            scale = max(1.0, np.abs(numeric[rows]).max())
            err = np.abs(numeric[rows] - analytic[rows]).max()
            assert err <= 1e-8 * scale, f"{name}: error {err:.2e} (scale {scale:.1e})"
        # ∂q̈/∂τ is M⁻¹ (symmetric), ∂q̈/∂λ = M⁻¹Jᵀ (eq 22).
        np.testing.assert_allclose(data.ddq_dtau, data.ddq_dtau.T, atol=1e-9)
        np.testing.assert_allclose(
            data.ddq_dforce, data.ddq_dtau @ data.contact_jacobian.T, rtol=1e-10, atol=1e-10
        )


def test_world_fixed_force_correction_sign(robots):
    """computeABADerivatives holds the force fixed in the joint frame; a world-fixed force adds
    +M⁻¹ J_linᵀ [Rᵀf]× J_ang to ∂q̈/∂q (J in LOCAL): check the sign against finite differences."""
    robot = robots["iiwa"]
    dyn = SoftContactDynamics(robot, _contact(3, "LOCAL_WORLD_ALIGNED"))
    rng = np.random.default_rng(7)
    q, v, force, tau = _random_point(robot, 3, rng)
    force = np.array([30.0, -20.0, 60.0])
    data = dyn.create_data()
    dyn.calc(data, q, v, force, tau)
    raw = pin.computeABADerivatives(dyn.pin_model, data.pinocchio, q, v, tau, data.fext)[0].copy()
    numeric = _central_fd(dyn, np.concatenate([q, v, force, tau]))[: dyn.nv, : dyn.nv]

    J = pin.computeFrameJacobian(dyn.pin_model, data.pinocchio, q, dyn.frame_id, pin.LOCAL)
    R = data.rotation
    correction = np.linalg.inv(pin.crba(dyn.pin_model, data.pinocchio, q)) @ (
        J[:3].T @ pin.skew(R.T @ force) @ J[3:]
    )
    assert np.abs(correction).max() > 1e-2  # the term matters for this force
    np.testing.assert_allclose(raw + correction, numeric, atol=1e-6)
    assert np.abs(raw - correction - numeric).max() > 1e-2


def _weights() -> CostWeights:
    return CostWeights(
        posture=0.3,
        posture_diag=tuple(np.linspace(1.0, 2.0, 7)),
        joint_velocity=0.2,
        torque=1e-2,
        torque_diag=tuple(np.linspace(0.5, 1.5, 7)),
        ee_position=50.0,
        ee_position_diag=(1.0, 2.0, 3.0),
        ee_velocity=2.0,
        ee_velocity_diag=(3.0, 2.0, 1.0),
        force=0.1,
        force_rate=1e-3,
        state_limit=2.0,
        ee_rotation=3.0,
        ee_angular_velocity=0.4,
    )


@pytest.mark.parametrize("robot_name", ROBOTS)
@pytest.mark.parametrize(("dim", "frame"), [(1, "LOCAL_WORLD_ALIGNED"), (3, "LOCAL_WORLD_ALIGNED"),
                                            (1, "LOCAL")])  # fmt: skip
@pytest.mark.parametrize("terminal", [False, True])
def test_action_model_matches_numdiff(robots, robot_name, dim, frame, terminal):
    robot = robots[robot_name]
    rng = np.random.default_rng(42 + dim + 2 * terminal)
    node = make_soft_contact_node(robot, _contact(dim, frame), _weights(), 0.01, terminal)
    q_bar = robot.q_nominal + 0.1 * rng.standard_normal(robot.nv)
    assert not node.set_reference(
        NodeReference(
            ee_position=np.array([0.45, 0.1, 0.35]),
            force=np.linspace(10.0, 20.0, dim),
            ee_position_weight=30.0,
            force_weight=0.5,
            in_contact=True,
            posture=q_bar,
            ee_position_diag=np.array([1.5, 0.5, 0.25]),  # differs from _weights()' Q4
        )
    )
    model = node.model
    np.testing.assert_array_equal(model.q_reference, q_bar)
    q, v, force, tau = _random_point(robot, dim, rng)
    # The joint-limit barrier active on a position and a velocity (bounds: fraction 0.9).
    x = beyond_state_limits(rng, robot, node.state(q, v, force), fraction=0.9)

    data = model.createData()
    model.calc(data, x, tau)
    model.calcDiff(data, x, tau)
    numdiff = crocoddyl.ActionModelNumDiff(model, True)  # Gauss-Newton Hessians from data.r
    ndata = numdiff.createData()
    numdiff.calc(ndata, x, tau)
    numdiff.calcDiff(ndata, x, tau)

    assert data.cost == pytest.approx(0.5 * data.r @ data.r, rel=1e-12)
    assert ndata.cost == pytest.approx(data.cost, rel=1e-12)
    for name in ("Fx", "Fu", "Lx", "Lu", "Lxx", "Lxu", "Luu"):
        ours, ref = getattr(data, name), getattr(ndata, name)
        scale = max(1.0, np.abs(ref).max())
        err = np.abs(ours - ref).max()
        assert err <= 1e-5 * scale, f"{name}: error {err:.2e} (scale {scale:.1e})"

    # Every term of this node contributes (so the check above covers each one).
    expected = {"posture", "joint_velocity", "ee_position", "ee_velocity", "force", "state_limit"}
    expected |= {"ee_rotation", "ee_angular_velocity"}
    if not terminal:
        expected |= {"torque", "force_rate"}
    for term in RESIDUAL_TERMS:
        contribution = np.abs(data.r[model.residual_slice(term)]).max()
        if term in expected:
            assert contribution > 1e-6, term
        else:
            assert contribution == 0.0, term
    if terminal:
        np.testing.assert_array_equal(data.xnext, x)
        np.testing.assert_array_equal(data.Fx, np.eye(model.state.ndx))
        assert not np.any(data.Fu) and not np.any(data.Lu) and not np.any(data.Luu)
    else:
        # Running costs are scaled by Δt; the state-only evaluation (u=None) is not.
        d2 = model.createData()
        model.calc(d2, x)
        np.testing.assert_array_equal(d2.xnext, x)
        state_only = sum(
            0.5 * float(data.r[model.residual_slice(t)] @ data.r[model.residual_slice(t)])
            for t in (
                "posture",
                "joint_velocity",
                "ee_position",
                "ee_velocity",
                "force",
                "state_limit",
                "ee_rotation",
                "ee_angular_velocity",
            )
        )
        assert d2.cost == pytest.approx(state_only / model.dt, rel=1e-10)


@pytest.mark.parametrize("robot_name", ROBOTS)
@pytest.mark.parametrize("dim", [1, 3])
def test_zero_stiffness_matches_free_dynamics(robots, robot_name, dim):
    """K = B = 0 and λ = 0: the (q, v) part is crocoddyl's free forward dynamics + Euler."""
    robot = robots[robot_name]
    dt = 0.01
    rng = np.random.default_rng(5 + dim)
    node = make_soft_contact_node(
        robot, _contact(dim, "LOCAL_WORLD_ALIGNED"), _weights(), dt, False
    )
    node.set_contact_parameters(0.0, 0.0)
    model = node.model
    state = crocoddyl.StateMultibody(robot.model)
    actuation = crocoddyl.ActuationModelFull(state)
    costs = crocoddyl.CostModelSum(state, actuation.nu)
    dam = crocoddyl.DifferentialActionModelFreeFwdDynamics(state, actuation, costs)
    free = crocoddyl.IntegratedActionModelEuler(dam, dt)
    free_data = free.createData()
    data = model.createData()
    nv = robot.nv
    for _ in range(3):
        q, v, _, tau = _random_point(robot, dim, rng)
        x = node.state(q, v, np.zeros(dim))
        model.calc(data, x, tau)
        model.calcDiff(data, x, tau)
        free.calc(free_data, np.concatenate([q, v]), tau)
        free.calcDiff(free_data, np.concatenate([q, v]), tau)
        ddq = pin.aba(robot.model, robot.create_data(), q, v, tau)
        np.testing.assert_allclose(data.dynamics.ddq, ddq, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(data.xnext[: 2 * nv], free_data.xnext, rtol=1e-10, atol=1e-10)
        np.testing.assert_allclose(
            data.xnext[: 2 * nv], [*(q + dt * v + dt**2 * ddq), *(v + dt * ddq)]
        )
        np.testing.assert_array_equal(data.xnext[2 * nv :], np.zeros(dim))
        np.testing.assert_allclose(data.Fx[: 2 * nv, : 2 * nv], free_data.Fx, atol=1e-8)
        np.testing.assert_allclose(data.Fu[: 2 * nv], free_data.Fu, atol=1e-10)
        # λ stays constant whatever its value when K = B = 0.
        lam = np.linspace(5.0, 9.0, dim)
        model.calc(data, node.state(q, v, lam), tau)
        np.testing.assert_array_equal(data.xnext[2 * nv :], lam)


def _independent_fext(robot, q: np.ndarray, world_force: np.ndarray) -> pin.StdVec_Force:
    """A pure force (N, world axes) at the contact point, as pinocchio joint forces."""
    data = robot.create_data()
    pin.framesForwardKinematics(robot.model, data, q)
    p = data.oMf[robot.contact_frame_id].translation
    joint = robot.model.frames[robot.contact_frame_id].parentJoint
    fext = pin.StdVec_Force()
    for _ in range(robot.model.njoints):
        fext.append(pin.Force.Zero())
    world = pin.Force(world_force, np.cross(p, world_force))  # about the world origin
    fext[joint] = data.oMi[joint].actInv(world)
    return fext


@pytest.mark.parametrize("robot_name", ROBOTS)
@pytest.mark.parametrize(("dim", "frame"), CONTACTS)
def test_acceleration_with_force_matches_aba_with_external_force(robots, robot_name, dim, frame):
    robot = robots[robot_name]
    contact = _contact(dim, frame, normal_axis=1 if dim == 1 and frame == "LOCAL" else 2)
    dyn = SoftContactDynamics(robot, contact)
    rng = np.random.default_rng(11)
    q, v, force, tau = _random_point(robot, dim, rng)
    data = dyn.create_data()
    dyn.calc(data, q, v, force, tau)

    pdata = robot.create_data()
    pin.framesForwardKinematics(robot.model, pdata, q)
    R = pdata.oMf[robot.contact_frame_id].rotation
    in_frame = np.zeros(3)
    in_frame[dyn.rows] = force
    world_force = in_frame if frame == "LOCAL_WORLD_ALIGNED" else R @ in_frame
    ddq_ref = pin.aba(robot.model, pdata, q, v, tau, _independent_fext(robot, q, world_force))
    np.testing.assert_allclose(data.ddq, ddq_ref, rtol=1e-9, atol=1e-9)
    # Same with M⁻¹(τ − h + J_worldᵀ f_world) from crba/nle.
    M = pin.crba(robot.model, pdata, q)
    h = pin.nonLinearEffects(robot.model, pdata, q, v)
    J = pin.computeFrameJacobian(
        robot.model, pdata, q, robot.contact_frame_id, pin.LOCAL_WORLD_ALIGNED
    )
    np.testing.assert_allclose(
        data.ddq, np.linalg.solve(M, tau - h + J[:3].T @ world_force), rtol=1e-8, atol=1e-8
    )
    # τ_g(q, λ) = g(q) − Jᵀλ.
    dyn.calc_gravity_compensation(data, q)
    np.testing.assert_allclose(
        data.gravity_compensation,
        robot.gravity(q) - J[:3].T @ world_force,
        rtol=1e-9,
        atol=1e-9,
    )


def _anchor_for(dyn: SoftContactDynamics, data, q, v, force) -> np.ndarray:
    """p_c such that eq 16 gives ``force`` at (q, v) (LOCAL_WORLD_ALIGNED, world frame)."""
    dyn.calc_kinematics(data, q, v)
    anchor = data.position.copy()
    r = dyn.rows
    anchor[r] += (force + dyn.damping * data.ee_velocity[r]) / dyn.stiffness
    return anchor


@pytest.mark.parametrize("robot_name", ROBOTS)
@pytest.mark.parametrize("dim", [1, 3])
def test_force_rate_is_time_derivative_of_visco_elastic_force(robots, robot_name, dim):
    """Eq 18 is d/dt of eq 16 along the motion: instantaneously, and along a rollout."""
    robot = robots[robot_name]
    dyn = SoftContactDynamics(robot, _contact(dim, "LOCAL_WORLD_ALIGNED"))
    rng = np.random.default_rng(3 + dim)
    q0, v0, force0, _ = _random_point(robot, dim, rng)
    v0 *= 0.3
    tau = robot.gravity(q0)
    data = dyn.create_data()
    anchor = _anchor_for(dyn, data, q0, v0, force0)
    np.testing.assert_allclose(
        dyn.visco_elastic_contact_force(data, q0, v0, anchor), force0, rtol=1e-12, atol=1e-9
    )

    # Instantaneous: q(t) = q0 + t v0 + ½t² q̈, v(t) = v0 + t q̈; central difference of eq 16.
    dyn.calc(data, q0, v0, force0, tau)
    ddq, force_rate = data.ddq.copy(), data.force_rate.copy()
    h = 1e-6
    plus = dyn.visco_elastic_contact_force(
        data, q0 + h * v0 + 0.5 * h * h * ddq, v0 + h * ddq, anchor
    )
    minus = dyn.visco_elastic_contact_force(
        data, q0 - h * v0 + 0.5 * h * h * ddq, v0 - h * ddq, anchor
    )
    np.testing.assert_allclose((plus - minus) / (2 * h), force_rate, rtol=1e-6, atol=1e-4)

    # Rollout with the model's own integrator (eq 24): λ stays on eq 16, first-order in Δt.
    def rollout_gap(dt: float, duration: float = 0.02) -> tuple[float, float]:
        weights = CostWeights()
        model = IntegratedActionModelSoftContact(
            robot, _contact(dim, "LOCAL_WORLD_ALIGNED"), weights, dt
        )
        d = model.createData()
        x = soft_contact_state(q0, v0, force0)
        gap = 0.0
        for _ in range(round(duration / dt)):
            model.calc(d, x, tau)
            x = d.xnext.copy()
            q, v, lam = x[: robot.nv], x[robot.nv : 2 * robot.nv], x[2 * robot.nv :]
            gap = max(gap, np.abs(lam - dyn.visco_elastic_contact_force(data, q, v, anchor)).max())
        return gap, np.abs(x[2 * robot.nv :] - force0).max()

    gap_coarse, change = rollout_gap(1e-3)
    gap_fine, _ = rollout_gap(5e-4)
    assert change > 1.0  # the force really evolves (N)
    assert gap_coarse < 0.1 * change  # a wrong λ̇ gives a gap of the order of the change
    assert 1.6 < gap_coarse / gap_fine < 2.5  # first-order convergence of semi-implicit Euler


def test_local_force_rate_without_rotation(robots):
    """LOCAL: λ̇ is eq 16 differentiated in the contact axes; exact when ω = 0 at the instant."""
    robot = robots["iiwa"]
    contact = _contact(3, "LOCAL")
    dyn = SoftContactDynamics(robot, contact)
    rng = np.random.default_rng(9)
    q0, _, force0, tau = _random_point(robot, 3, rng)
    data = dyn.create_data()
    J = pin.computeFrameJacobian(dyn.pin_model, data.pinocchio, q0, dyn.frame_id, pin.LOCAL)
    null = np.linalg.svd(J[3:])[2][3:]  # v with J_ang v = 0: the frame translates only
    v0 = null.T @ rng.standard_normal(null.shape[0])
    dyn.calc_kinematics(data, q0, v0)
    assert np.abs(data.angular_velocity_local).max() < 1e-12
    anchor = data.position + data.rotation @ (
        (force0 + dyn.damping * data.linear_velocity_local) / dyn.stiffness
    )
    np.testing.assert_allclose(
        dyn.visco_elastic_contact_force(data, q0, v0, anchor), force0, atol=1e-9
    )
    dyn.calc(data, q0, v0, force0, tau)
    ddq, force_rate = data.ddq.copy(), data.force_rate.copy()
    h = 1e-6
    plus = dyn.visco_elastic_contact_force(
        data, q0 + h * v0 + 0.5 * h * h * ddq, v0 + h * ddq, anchor
    )
    minus = dyn.visco_elastic_contact_force(
        data, q0 - h * v0 + 0.5 * h * h * ddq, v0 - h * ddq, anchor
    )
    np.testing.assert_allclose((plus - minus) / (2 * h), force_rate, rtol=1e-6, atol=1e-4)


@pytest.mark.parametrize("dim", [1, 3])
def test_stiffness_and_damping_change_in_place(robots, dim):
    robot = robots["iiwa"]
    node = make_soft_contact_node(
        robot, _contact(dim, "LOCAL_WORLD_ALIGNED"), _weights(), 0.01, False
    )
    model = node.model
    stiffness_array = model.dynamics.stiffness
    data = model.createData()
    rng = np.random.default_rng(21)
    q, v, force, tau = _random_point(robot, dim, rng)
    x = node.state(q, v, force)

    # Independent ṗ and p̈ (world axes): pinocchio kinematics with q̈ from pin.aba.
    pdata = robot.create_data()
    in_frame = np.zeros(3)
    pin.framesForwardKinematics(robot.model, pdata, q)
    in_frame[[2] if dim == 1 else [0, 1, 2]] = force
    ddq = pin.aba(robot.model, pdata, q, v, tau, _independent_fext(robot, q, in_frame))
    pin.forwardKinematics(robot.model, pdata, q, v, ddq)
    fid = robot.contact_frame_id
    vel = pin.getFrameVelocity(robot.model, pdata, fid, pin.LOCAL_WORLD_ALIGNED).linear
    acc = pin.getFrameClassicalAcceleration(robot.model, pdata, fid, pin.LOCAL_WORLD_ALIGNED).linear
    rows = [2] if dim == 1 else [0, 1, 2]

    def force_rate_after_calc():
        model.calc(data, x, tau)
        model.calcDiff(data, x, tau)
        return data.dynamics.force_rate.copy(), data.Fx[2 * robot.nv :].copy()

    K1, B1 = model.dynamics.stiffness.copy(), model.dynamics.damping.copy()
    rate1, Fx1 = force_rate_after_calc()
    np.testing.assert_allclose(rate1, -K1 * vel[rows] - B1 * acc[rows], rtol=1e-9, atol=1e-6)

    K2 = np.linspace(300.0, 700.0, dim)
    B2 = np.linspace(5.0, 15.0, dim)
    node.set_contact_parameters(K2, B2)
    rate2, Fx2 = force_rate_after_calc()
    assert model is node.model and model.dynamics.stiffness is stiffness_array
    np.testing.assert_allclose(rate2, -K2 * vel[rows] - B2 * acc[rows], rtol=1e-9, atol=1e-6)
    assert np.abs(rate2 - rate1).max() > 1.0
    assert np.abs(Fx2 - Fx1).max() > 1e-3  # the derivatives follow too

    # Out of contact: K = B = 0 and no force cost; back in contact restores the nominal K, B.
    ref = NodeReference(np.zeros(3), np.full(dim, 10.0), 1.0, 2.0, in_contact=False)
    assert node.set_reference(ref) is False
    rate_off, _ = force_rate_after_calc()
    np.testing.assert_array_equal(rate_off, np.zeros(dim))
    assert not np.any(data.r[model.residual_slice("force")])
    node.set_contact_parameters(K1, B1)  # a learner update while out of contact is kept
    ref.in_contact = True
    node.set_reference(ref)
    rate_on, _ = force_rate_after_calc()
    np.testing.assert_allclose(rate_on, rate1, rtol=1e-12)
    np.testing.assert_allclose(
        data.r[model.residual_slice("force")],
        np.sqrt(2.0 * model.dt) * (force - 10.0),
        rtol=1e-12,
    )


def test_solver_drives_predicted_force_to_reference(robots):
    """In an OCP (mim_solvers SQP), the predicted force rises to λ̄ by pushing down (λ > 0)."""
    robot = robots["iiwa"]
    contact = ContactConfig(dimension=1, stiffness=1e3, damping=50.0)
    weights = CostWeights(force=1e-2, force_rate=1e-6)
    horizon, dt = 20, 0.01
    nodes = [make_soft_contact_node(robot, contact, weights, dt, False) for _ in range(horizon)]
    nodes.append(make_soft_contact_node(robot, contact, weights, dt, True))
    p0 = robot.contact_placement(robot.q_nominal).translation
    for node in nodes:
        node.set_reference(NodeReference(p0, np.array([20.0]), 1e2, 1e-2, in_contact=True))
    x0 = soft_contact_state(robot.q_nominal, np.zeros(robot.nv), [0.0])
    problem = crocoddyl.ShootingProblem(x0, [n.model for n in nodes[:-1]], nodes[-1].model)
    solver = mim_solvers.SolverSQP(problem)
    assert solver.solve([x0] * (horizon + 1), [robot.gravity(robot.q_nominal)] * horizon, 30)
    forces = np.array([x[-1] for x in solver.xs])
    assert forces[0] == 0.0
    assert np.all(forces[6:] > 17.0) and np.all(forces < 21.0)
    q_end = solver.xs[-1][: robot.nv]
    assert robot.contact_placement(q_end).translation[2] < p0[2]  # pushed into the surface


def test_visco_elastic_force_and_input_validation(robots):
    # Eq 16: 1 cm below the anchor, moving down at 0.1 m/s: λ = 1000·0.01 + 50·0.1 = 15 N.
    np.testing.assert_allclose(
        visco_elastic_force([0.0, 0.0, -0.01], [0.0, 0.0, -0.1], 1e3, 50.0), [0.0, 0.0, 15.0]
    )
    np.testing.assert_allclose(
        visco_elastic_force([0.01, 0.02], [0.0, 0.0], [100.0, 200.0], 0.0), [-1.0, -4.0]
    )
    with pytest.raises(ConfigError):
        visco_elastic_force([0.0], [0.0], -1.0, 0.0)
    with pytest.raises(InputError):
        visco_elastic_force([np.nan], [0.0], 1.0, 0.0)

    robot = robots["iiwa"]
    node = make_soft_contact_node(
        robot, _contact(1, "LOCAL_WORLD_ALIGNED"), CostWeights(), 0.01, False
    )
    with pytest.raises(ConfigError):
        node.set_contact_parameters(-1.0, 1.0)
    with pytest.raises(ConfigError):
        node.set_contact_parameters([1.0, 2.0], 1.0)  # 1-D contact: one K
    with pytest.raises(InputError):
        node.set_reference(NodeReference(np.array([0.0, np.nan, 0.0]), np.zeros(1), 1.0, 1.0, True))
    with pytest.raises(InputError):
        node.set_reference(NodeReference(np.zeros(3), np.zeros(3), 1.0, 1.0, True))
    with pytest.raises(InputError):
        node.set_reference(NodeReference(np.zeros(3), np.zeros(1), -1.0, 1.0, True))
    with pytest.raises(InputError):
        node.state(np.zeros(7), np.zeros(7), np.zeros(3))
    with pytest.raises(InputError):
        soft_contact_state(np.zeros(7), np.zeros(6), np.zeros(1))
    with pytest.raises(ConfigError):
        make_soft_contact_node(robot, _contact(1, "LOCAL"), CostWeights(), 0.0, False)
    # Failed updates leave the node unchanged.
    np.testing.assert_array_equal(node.model.dynamics.stiffness, [1.5e3])
    assert node.model.weight("ee_position") == CostWeights().ee_position
