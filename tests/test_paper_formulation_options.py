"""The options of issue 11 that bring the formulations to the paper's (and the authors' code's)
choices: measured τ̂ in the torque-feedback state (eq 10/15), the authors' orientation and
angular-velocity costs, the low-pass model's terminal torque term, the Baumgarte gain K_d and the
in-contact Q4 as scenario parameters. Costs are checked against values computed by hand here
(crocoddyl's convention c·½·Σ Q_i r_i², running terms × Δt)."""

from __future__ import annotations

import crocoddyl  # noqa: F401,I001 (crocoddyl first: it loads the boost libraries)
import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.config import ContactConfig, CostWeights, OcpConfig
from ffmpc_core.errors import ConfigError
from ffmpc_core.lowpass import make_lowpass_node
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig, MpcMeasurement
from ffmpc_core.native import make_native_soft_contact_node
from ffmpc_core.polishing import build_task, mpc_config
from ffmpc_core.rigid_contact import make_rigid_contact_node
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_core.soft_contact import make_soft_contact_node
from ffmpc_core.tasks import PolishingTask

DT = 0.003
#: ε·(1 − α) of eq 13 and 15 for the paper's settings, by hand: ε = period/Δt = 2 ms / 3 ms,
#: α = exp(−2π·50 Hz·3 ms) = exp(−0.3π) = 0.3896611; (2/3)·(1 − 0.3896611) = 0.4068926.
EPS_ONE_MINUS_ALPHA = 0.4068926


def _press(robot) -> PolishingTask:
    p0 = robot.contact_placement(robot.q_nominal).translation
    return PolishingTask.pressing(p0, force_ramp=0.05, circle=1.0, stop=0.0)


@pytest.mark.parametrize("delay", [0.0, 0.004])
def test_measured_torque_state_is_eq10_and_eq15_step_by_step(robot, delay):
    """torque_state "measured": every solve starts from τ₀ = τ̂ (eq 10: the measured joint torque
    is the state) and sends τ̃ = τ̂ + ε(τ₁* − τ̂) with τ₁* = ατ̂ + (1 − α)w₀* (eq 13, 15), with
    or without the δo prediction of (q, v)."""
    config = MpcConfig(ocp=OcpConfig(formulation="torque_feedback"), command_delay=delay)
    assert config.torque_state == "measured"  # the paper's choice is the default
    mpc = ModelPredictiveController(robot, config, _press(robot))
    q, v = robot.q_nominal, np.zeros(robot.nv)
    g = robot.gravity(q)
    nv = robot.nv
    for k, offset in enumerate((0.0, 3.0, -2.0, 5.0)):  # a different τ̂ at every step
        tau_hat = g + offset * np.linspace(-1.0, 1.0, nv)
        cmd = mpc.step(MpcMeasurement(q=q, v=v, torque=tau_hat), 0.002 * k)
        np.testing.assert_array_equal(cmd.state[2 * nv :], tau_hat)
        np.testing.assert_array_equal(cmd.xs[0][2 * nv :], tau_hat)
        w0 = cmd.us[0]
        expected = tau_hat + EPS_ONE_MINUS_ALPHA * (w0 - tau_hat)
        np.testing.assert_allclose(cmd.torque, expected, rtol=0, atol=1e-6 * (1 + abs(w0).max()))
        assert np.abs(w0 - tau_hat).max() > 1e-3  # the example is not trivial


def test_next_torque_integration_sends_the_first_filtered_torque(robot):
    """torque_integration "next" (the authors' tau_plus_integration): q̈ of node 0 is computed at
    τ₁* = ατ̂ + (1 − α)w₀*, the torque the plan applies from now on, and that is what the MPC
    sends (ε = 1 in eq 15); the first predicted state is the classical step driven by τ₁*."""
    config = MpcConfig(
        ocp=OcpConfig(formulation="torque_feedback", torque_integration="next"),
        command_delay=0.0,
    )
    mpc = ModelPredictiveController(robot, config, _press(robot))
    q, v = robot.q_nominal, np.zeros(robot.nv)
    nv = robot.nv
    alpha = np.exp(-2.0 * np.pi * config.ocp.cutoff_frequency * config.ocp.dt)
    tau_hat = robot.gravity(q) + 2.0 * np.linspace(-1.0, 1.0, nv)
    cmd = mpc.step(MpcMeasurement(q=q, v=v, torque=tau_hat), 0.0)
    w0 = cmd.us[0]
    tau1 = alpha * tau_hat + (1.0 - alpha) * w0
    np.testing.assert_allclose(cmd.torque, tau1, rtol=0, atol=1e-9 * (1 + abs(w0).max()))
    np.testing.assert_allclose(cmd.xs[1][2 * nv :], tau1, rtol=0, atol=1e-9)
    # the free-space classical step at τ₁* gives the plan's (q₁, v₁)
    classical = make_rigid_contact_node(
        robot, config.contact, config.weights, config.ocp.dt, False, in_contact=False
    )
    data = classical.model.createData()
    classical.model.calc(data, np.concatenate((q, v)), tau1)
    np.testing.assert_allclose(cmd.xs[1][: 2 * nv], data.xnext, atol=1e-6)  # SQP gaps
    assert np.abs(w0 - tau_hat).max() > 1e-3  # the example is not trivial
    with pytest.raises(ConfigError, match="torque_integration"):
        OcpConfig(formulation="torque_feedback", torque_integration="plus")


def test_commanded_torque_state_uses_the_last_torque_sent(robot):
    """torque_state "commanded" (the former behaviour): with a δo, τ₀ is the last τ̃ sent."""
    config = MpcConfig(
        ocp=OcpConfig(formulation="torque_feedback"), command_delay=0.004, torque_state="commanded"
    )
    mpc = ModelPredictiveController(robot, config, _press(robot))
    q, v = robot.q_nominal, np.zeros(robot.nv)
    tau_hat = robot.gravity(q) + 1.0
    nv = robot.nv
    first = mpc.step(MpcMeasurement(q=q, v=v, torque=tau_hat), 0.0)
    np.testing.assert_array_equal(first.state[2 * nv :], tau_hat)  # nothing sent yet
    second = mpc.step(MpcMeasurement(q=q, v=v, torque=tau_hat), 0.002)
    np.testing.assert_allclose(second.state[2 * nv :], first.torque, atol=1e-12)
    assert np.abs(first.torque - tau_hat).max() > 1e-3
    with pytest.raises(ConfigError):
        MpcConfig(ocp=OcpConfig(formulation="torque_feedback"), torque_state="predicted")


def _running_cost(node, x, u) -> float:
    data = node.model.createData()
    node.model.calc(data, x, u)
    return float(data.cost)


@pytest.mark.parametrize("formulation", ["classical", "torque_feedback"])
def test_orientation_and_angular_velocity_costs_by_hand(robot, formulation):
    """c_R·½‖log(R̄ᵀR)‖² + c_ω·½‖ω‖² (× Δt in a running node) is what the two options add."""
    rng = np.random.default_rng(5)
    q = robot.q_nominal + 0.2 * rng.standard_normal(robot.nq)
    v = 0.5 * rng.standard_normal(robot.nv)
    c_rot, c_ang = 10.0, 0.7
    contact = ContactConfig()

    def node(weights):
        if formulation == "classical":
            return make_rigid_contact_node(robot, contact, weights, DT, False)
        return make_lowpass_node(robot, contact, weights, DT, False, 50.0)

    x = np.concatenate([q, v] + ([robot.gravity(q)] if formulation == "torque_feedback" else []))
    u = robot.gravity(q) + rng.standard_normal(robot.nv)
    base = _running_cost(node(CostWeights()), x, u)
    with_terms = _running_cost(
        node(CostWeights(ee_rotation=c_rot, ee_angular_velocity=c_ang)), x, u
    )
    by_hand = DT * _orientation_terms_by_hand(robot, q, v, c_rot, c_ang)
    assert with_terms - base == pytest.approx(by_hand, rel=1e-9)
    assert by_hand > 1e-4  # both terms matter here


def _orientation_terms_by_hand(robot, q, v, c_rot, c_ang) -> float:
    """c_R·½‖log3(R̄ᵀR(q))‖² + c_ω·½‖ω‖², R̄ the contact frame's orientation at the nominal
    posture, ω its LOCAL angular velocity (rad/s), from pinocchio's kinematics."""
    data = robot.create_data()
    pin.forwardKinematics(robot.model, data, q, v)
    pin.updateFramePlacements(robot.model, data)
    fid = robot.contact_frame_id
    r_bar = robot.contact_placement(robot.q_nominal).rotation
    log_r = pin.log3(r_bar.T @ data.oMf[fid].rotation)
    omega = pin.getFrameVelocity(robot.model, data, fid, pin.LOCAL).angular
    return c_rot * 0.5 * float(log_r @ log_r) + c_ang * 0.5 * float(omega @ omega)


@pytest.mark.parametrize("robot_name", ["iiwa", "panda"])
@pytest.mark.parametrize("make", [make_soft_contact_node, make_native_soft_contact_node])
@pytest.mark.parametrize("terminal", [False, True])
def test_force_feedback_orientation_and_angular_velocity_costs_by_hand(robot_name, make, terminal):
    """The force-feedback model (Python and C++) adds the same two terms as the classical and
    torque-feedback ones: × Δt in a running node, unscaled in the terminal node."""
    robot = load_robot(robot_name)
    rng = np.random.default_rng(6)
    q = robot.q_nominal + 0.2 * rng.standard_normal(robot.nq)
    v = 0.5 * rng.standard_normal(robot.nv)
    x = np.concatenate([q, v, [15.0]])
    u = robot.gravity(q) + rng.standard_normal(robot.nv)
    c_rot, c_ang = 20.0, 0.05  # the authors' soft-contact polishing weights
    contact = ContactConfig()
    base = _running_cost(make(robot, contact, CostWeights(), DT, terminal), x, u)
    weights = CostWeights(ee_rotation=c_rot, ee_angular_velocity=c_ang)
    with_terms = _running_cost(make(robot, contact, weights, DT, terminal), x, u)
    by_hand = (1.0 if terminal else DT) * _orientation_terms_by_hand(robot, q, v, c_rot, c_ang)
    assert with_terms - base == pytest.approx(by_hand, rel=1e-9)
    assert by_hand > 1e-3 * DT  # both terms matter here
    # A state whose two terms are known in closed form: only the last joint (its axis fixed in
    # the contact frame) moved by θ from q̄ and turning at ω₇, so ‖log3(R̄ᵀR)‖ = |θ| and
    # ‖ω‖ = |ω₇|: the terms are c_R·½θ² + c_ω·½ω₇² (here 20·½·0.09 + 0.05·½·0.64 = 0.916).
    theta, omega7 = 0.3, 0.8
    q1 = robot.q_nominal.copy()
    q1[-1] += theta
    v1 = np.zeros(robot.nv)
    v1[-1] = omega7
    x1 = np.concatenate([q1, v1, [15.0]])
    u1 = robot.gravity(q1)
    node = make(robot, contact, weights, DT, terminal)
    data = node.model.createData()
    node.model.calc(data, x1, u1)
    scale = 1.0 if terminal else DT
    for name, value in (
        ("ee_rotation", c_rot * 0.5 * theta**2),
        ("ee_angular_velocity", c_ang * 0.5 * omega7**2),
    ):
        r = data.r[node.model.residual_slice(name)]
        assert 0.5 * float(r @ r) == pytest.approx(scale * value, rel=1e-12), name
    assert 20.0 * 0.5 * theta**2 + 0.05 * 0.5 * omega7**2 == pytest.approx(0.916)
    # At the reference orientation and at rest, the two terms vanish.
    x0 = np.concatenate([robot.q_nominal, np.zeros(robot.nv), [15.0]])
    node.model.calc(data, x0, u)
    for name in ("ee_rotation", "ee_angular_velocity"):
        assert np.abs(data.r[node.model.residual_slice(name)]).max() < 1e-12


@pytest.mark.parametrize("backend", ["native", "python"])
def test_lowpass_terminal_torque_regularisation_by_hand(robot, backend):
    """The torque-feedback terminal node costs c·½·Σ Q3_i (τ − g(q))_i² more with the term (not
    × Δt); the classical terminal node (no τ in its state) is unchanged by the option."""
    rng = np.random.default_rng(9)
    q = robot.q_nominal + 0.1 * rng.standard_normal(robot.nq)
    v = 0.3 * rng.standard_normal(robot.nv)
    tau = robot.gravity(q) + 4.0 * rng.standard_normal(robot.nv)
    x = np.concatenate([q, v, tau])
    q3 = rng.uniform(0.5, 2.0, robot.nv)
    c = 0.05

    def terminal_cost(weight: float, formulation: str) -> float:
        weights = CostWeights(torque_diag=tuple(q3), lowpass_terminal_torque=weight)
        if formulation == "classical":
            node = make_rigid_contact_node(
                robot, ContactConfig(), weights, DT, True, backend=backend
            )
            xs = x[: 2 * robot.nv]
        else:
            node = make_lowpass_node(
                robot, ContactConfig(), weights, DT, True, 50.0, backend=backend
            )
            xs = x
        data = node.model.createData()
        node.model.calc(data, xs)
        return float(data.cost)

    r = tau - robot.gravity(q)
    by_hand = c * 0.5 * float(np.sum(q3 * r * r))
    extra = terminal_cost(c, "torque_feedback") - terminal_cost(0.0, "torque_feedback")
    assert extra == pytest.approx(by_hand, rel=1e-9)
    assert terminal_cost(c, "classical") == terminal_cost(0.0, "classical")
    assert CostWeights().lowpass_terminal_torque == 1e-4  # the authors' terminal weight


def test_scenario_options_reach_the_models(robot):
    """mpc.torque_state, mpc.contact.baumgarte_velocity_gain, the new weights and
    task.ee_z_weight_in_contact flow from the scenario file into the MPC and the task."""
    # the time-based switch: in contact at the circle's start without a measured force
    s = load_scenario("polishing", {"mpc.formulation": "torque_feedback", "task.approach_speed": 0})
    assert s.mpc.torque_state == "commanded"  # the polishing files' (MpcConfig: "measured")
    assert s.task.ee_z_weight_in_contact == 0.0
    ref = build_task(s, robot).reference(build_task(s, robot).circle_start + 0.1)
    np.testing.assert_array_equal(ref.ee_position_diag, [1.0, 1.0, 0.0])  # the paper's Q4
    s = s.with_overrides(
        {
            "mpc.torque_state": "measured",
            "mpc.contact.baumgarte_velocity_gain": 12.5,
            "mpc.weights.torque_feedback.ee_rotation": 3.0,
            "task.ee_z_weight_in_contact": 1.0,
        }
    )
    config = mpc_config(s)
    assert config.torque_state == "measured"
    assert config.weights.ee_rotation == 3.0
    task = build_task(s, robot)
    np.testing.assert_array_equal(task.reference(task.circle_start).ee_position_diag, [1, 1, 1])
    mpc = ModelPredictiveController(robot, config, task)
    node = mpc.nodes[0]
    model = node._models[True].differential  # the in-contact model of a running node
    np.testing.assert_array_equal(model.contacts.contacts["contact"].contact.gains, [0.0, 12.5])
    assert "ee_rotation" in model.costs.costs
    with pytest.raises(ConfigError):
        s.with_overrides({"mpc.torque_state": "both"})
