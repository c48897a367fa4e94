"""The MPC object: closed loop on its own dynamics, feedback gain, delay predictor."""

from dataclasses import replace

import numpy as np
import pytest

from ffmpc_core.config import FORMULATIONS, OcpConfig
from ffmpc_core.constraints import ConstraintConfig
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.model_plant import ModelPlant, run_model_closed_loop
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig, MpcMeasurement, _interp_rows
from ffmpc_core.tasks import PolishingTask


def press_task(robot, circle=0.0):
    """Contact from t = 0, force ramped to 50 N in 0.3 s, then held (optionally circling)."""
    p0 = robot.contact_placement(robot.q_nominal).translation
    return PolishingTask.pressing(p0, circle=circle)


# Tolerances on the held force, from the perfect-model closed loop. Classical and torque-feedback
# track to round-off: their rigid-contact force is an algebraic output the optimum sets exactly.
# Force-feedback holds a small steady offset (measured 0.15 N): λ is a state moved only through
# K·ṗ + B·p̈, so within a 15 ms horizon the force cost c6 balances the velocity and posture
# terms; 1 N (2 % of the target) bounds it with margin, and a force that stalls (34 N with the
# untuned c6 = 1e-2) fails.
HOLD_TOLERANCE = {"classical": 0.05, "torque_feedback": 0.05, "force_feedback": 1.0}


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_reaches_and_holds_50_newtons_on_its_own_dynamics(robot, formulation):
    task = press_task(robot)
    log = run_model_closed_loop(
        robot, MpcConfig(ocp=OcpConfig(formulation=formulation)), task, task.duration
    )
    a = log.arrays()
    held = a["t"] > task.duration - 0.3
    force = a["force"][held, -1]
    assert np.all(np.abs(force - 50.0) < HOLD_TOLERANCE[formulation]), (force.min(), force.max())
    assert a["force"][0, -1] < 1.0  # it really had to build the force up
    assert max(a["iterations"]) <= 8


@pytest.mark.parametrize("formulation", ["classical", "force_feedback"])
def test_feedback_gain_matches_finite_differences_of_the_policy(robot, formulation):
    """τ(x̂ + δx) ≈ τ(x̂) + G·δx: G is the derivative of the MPC policy along the directions in
    which the dynamics are linear (v, λ; measured error 0.1–0.2 %). Along q the Riccati gain of
    a Gauss-Newton solver omits the dynamics' second-order terms (measured 30 % off for
    force-feedback along q2), so q-directions are only required to be within 50 %.

    The claim is about the unconstrained policy: here the iiwa 14's joint-6 speed reaches the
    hard velocity box (90 % of 135 °/s) within the horizon, and with an active bound the policy
    is clipped while the Riccati gain of ``SolverCSQP`` is the unconstrained one (measured 33 %
    off along v3 with ``constraints.enabled``), so the constraints are off in this test."""
    task = press_task(robot)
    config = MpcConfig(
        ocp=OcpConfig(formulation=formulation, max_iterations=100, kkt_tolerance=1e-12),
        constraints=ConstraintConfig(enabled=False),
    )
    mpc = ModelPredictiveController(robot, config, task)
    base = MpcMeasurement(q=robot.q_nominal, v=np.zeros(7), force=np.array([20.0]))
    t = 0.2
    cmd = mpc.step(base, t)
    assert cmd.converged
    nx = cmd.state.size
    directions = {"v3": (10, 1e-2), "q2": (1, 0.5)}
    if formulation == "force_feedback":
        directions["force"] = (14, 1e-2)
    eps = 1e-5
    for name, (index, tolerance) in directions.items():
        direction = np.eye(nx)[index]
        torques = []
        for sign in (1.0, -1.0):
            x = cmd.state + sign * eps * direction
            meas = MpcMeasurement(q=x[:7], v=x[7:14], force=x[14:] if nx > 14 else None)
            mpc.reset()
            torques.append(mpc.step(meas, t).torque)
        numeric = (torques[0] - torques[1]) / (2 * eps)
        analytic = cmd.feedback_gain @ direction
        error = np.linalg.norm(numeric - analytic) / np.linalg.norm(numeric)
        assert error < tolerance, (name, error)


def test_torque_feedback_command_is_eq15(robot):
    task = press_task(robot)
    config = MpcConfig(ocp=OcpConfig(formulation="torque_feedback"))
    mpc = ModelPredictiveController(robot, config, task)
    q = robot.q_nominal
    tau = robot.gravity(q) + 1.0
    cmd = mpc.step(MpcMeasurement(q=q, v=np.zeros(7), torque=tau), 0.1)
    alpha = np.exp(-2 * np.pi * config.ocp.cutoff_frequency * config.ocp.dt)
    epsilon = config.ocp.period / config.ocp.dt
    tau1 = alpha * tau + (1 - alpha) * cmd.us[0]
    np.testing.assert_allclose(cmd.torque, robot.clip_torque(tau + epsilon * (tau1 - tau)))
    # the gain maps a torque-state deviation through the interpolation
    np.testing.assert_allclose(cmd.feedback_gain.shape, (7, 21))


@pytest.mark.parametrize(
    ("formulation", "torque_state"),
    [(f, "measured") for f in FORMULATIONS] + [("torque_feedback", "commanded")],
)
def test_delay_predictor_integrates_the_commands_in_flight(robot, formulation, torque_state):
    """With δo = 4 ms the MPC solves from x(t + δo), predicted with the commands sent in
    [t − δo, t): the prediction equals a rollout of the model plant with those commands.
    Torque-feedback: τ of the prediction is the measured τ̂ (eq 10/15) or the last τ̃ sent."""
    task = press_task(robot)
    config = MpcConfig(
        ocp=OcpConfig(formulation=formulation),
        command_delay=0.004,
        prediction_step=0.001,
        torque_state=torque_state,
    )
    mpc = ModelPredictiveController(robot, config, task)
    q0 = robot.q_nominal
    v0 = np.full(7, 0.05)
    meas = MpcMeasurement(q=q0, v=v0, force=np.array([5.0]), torque=robot.gravity(q0))
    x0 = mpc.state_from(meas)
    assert np.array_equal(mpc.predict(x0, 0.0), x0)  # nothing sent yet: nothing to predict
    sent = []
    for k in range(3):  # commands at t = 0, 2, 4 ms
        cmd = mpc.step(meas, 0.002 * k)
        sent.append(cmd.torque if formulation == "torque_feedback" else cmd.us[0])
    t = 0.006
    predicted = mpc.predict(x0, t)
    # commands acting during [6, 10) ms were sent at 2, 2, 4, 4 ms (zero-order hold)
    plant_form = "classical" if formulation == "torque_feedback" else formulation
    plant = ModelPlant(robot, plant_form, config.contact, dt=0.001)
    plant.x[:] = x0[: plant.x.size]
    for i, u in enumerate([sent[1], sent[1], sent[2], sent[2]]):
        plant.step(u, task.in_contact(t + i * 0.001))
    expected = plant.x.copy()
    if formulation == "torque_feedback":
        tau = x0[14:] if torque_state == "measured" else sent[2]
        expected = np.concatenate([expected, tau])
    np.testing.assert_allclose(predicted, expected, atol=1e-12)
    assert np.linalg.norm(predicted[:14] - x0[:14]) > 1e-6  # the delay really changes x


@pytest.mark.parametrize("formulation", ["classical", "force_feedback"])
def test_delay_predictor_after_a_tick_without_a_solve(robot, formulation):
    """Solves at 0, 2 and 6 ms (the 4 ms tick dropped, or skipped in real time): from t = 8 ms
    the commands acting during [8, 12) ms are those of 2, 2, 6, 6 ms. (Keeping only commands
    sent within one period before t − δo applied the 6 ms command from 8 ms: with one tick in
    five dropped, joint 5 reached 9× its velocity limit in the polishing run.)"""
    task = press_task(robot)
    config = MpcConfig(
        ocp=OcpConfig(formulation=formulation), command_delay=0.004, prediction_step=0.001
    )
    mpc = ModelPredictiveController(robot, config, task)
    q0 = robot.q_nominal
    meas = MpcMeasurement(q=q0, v=np.full(7, 0.05), force=np.array([5.0]))
    x0 = mpc.state_from(meas)
    sent = {}
    for t in (0.0, 0.002, 0.006):
        sent[t] = mpc.step(meas, t).us[0]
    predicted = mpc.predict(x0, 0.008)
    plant = ModelPlant(robot, formulation, config.contact, dt=0.001)
    plant.x[:] = x0
    for i, u in enumerate([sent[0.002], sent[0.002], sent[0.006], sent[0.006]]):
        plant.step(u, task.in_contact(0.008 + i * 0.001))
    np.testing.assert_allclose(predicted, plant.x, atol=1e-12)
    assert not np.allclose(sent[0.002], sent[0.006])  # the two commands differ


def test_warm_start_shift_interpolates():
    rows = np.arange(12.0).reshape(6, 2)
    out = _interp_rows(rows, np.array([0.5, 1.0, 4.75, 7.0]))
    np.testing.assert_allclose(out, [[1, 2], [2, 3], [9.5, 10.5], [10, 11]])


def test_force_feedback_contact_parameters_change_live(robot):
    task = press_task(robot)
    mpc = ModelPredictiveController(
        robot, MpcConfig(ocp=OcpConfig(formulation="force_feedback")), task
    )
    meas = MpcMeasurement(q=robot.q_nominal, v=np.zeros(7), force=np.array([10.0]))
    soft = mpc.step(meas, 0.1).torque
    mpc.set_contact_parameters(5e3, 2e2)
    mpc.reset()
    stiff = mpc.step(meas, 0.1).torque
    assert np.linalg.norm(stiff - soft) > 1e-3
    with pytest.raises(ConfigError):
        ModelPredictiveController(
            robot, MpcConfig(ocp=OcpConfig(formulation="classical")), task
        ).set_contact_parameters(1e3, 1e2)


def test_bad_measurements_are_rejected(robot):
    mpc = ModelPredictiveController(robot, MpcConfig(), press_task(robot))
    good = dict(q=robot.q_nominal, v=np.zeros(7), force=np.array([1.0]))
    for bad in (
        dict(q=np.full(7, np.nan)),
        dict(v=np.zeros(6)),
        dict(force=None),
        dict(force=np.array([np.inf])),
    ):
        with pytest.raises(InputError):
            mpc.step(MpcMeasurement(**{**good, **bad}), 0.0)
    with pytest.raises(ConfigError):
        MpcConfig(ocp=OcpConfig(formulation="rigid"))
    with pytest.raises(ConfigError):
        replace(MpcConfig(), command_delay=1.0)


def test_schedule_without_reference_into_gives_the_same_commands(robot):
    """The in-place reference path and the allocating fallback drive the MPC identically."""

    class AllocatingSchedule:
        def __init__(self, task):
            self.task = task

        def reference(self, t, dimension=1):
            return self.task.reference(t, dimension)

    task = press_task(robot, circle=0.2)
    config = MpcConfig(ocp=OcpConfig(formulation="force_feedback"), command_delay=0.004)
    a = ModelPredictiveController(robot, config, task)
    b = ModelPredictiveController(robot, config, AllocatingSchedule(task))
    plant = ModelPlant(robot, "force_feedback", config.contact)
    plant.reset(robot.q_nominal)
    for k in range(5):
        t = 0.002 * k
        ca, cb = a.step(plant.measurement(), t), b.step(plant.measurement(), t)
        np.testing.assert_array_equal(ca.torque, cb.torque)
        plant.step(ca.torque, True)
