"""What the live parameters change in ffmpc_core: the MPC's cost weights and contact in place,
the PID's gains, and the LiveTask retargets (bit-identical until changed, minimum-jerk blend)."""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.config import FORMULATIONS, NodeReference, OcpConfig
from ffmpc_core.errors import ConfigError, InputError, SolverError
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig, MpcMeasurement
from ffmpc_core.pid import TorquePid, TorquePidGains
from ffmpc_core.tasks import RETARGET_BLEND, ForceSquareTask, LiveTask, PolishingTask, min_jerk


def _task(robot):
    p0 = robot.contact_placement(robot.q_nominal).translation
    return PolishingTask(p0 + [0, 0, 0.05], p0, still=0.05, reach=0.2, force_ramp=0.3)


def test_live_task_is_the_task_until_changed_then_blends_with_a_minimum_jerk(robot):
    task = _task(robot)
    live = LiveTask(task)
    times = np.linspace(0.0, task.duration, 97)
    for t in times:
        a, b = task.reference(t), live.reference(t)
        assert a.ee_position.tobytes() == b.ee_position.tobytes()  # bit for bit
        assert a.force.tobytes() == b.force.tobytes() and a.in_contact == b.in_contact
    assert live.duration == task.duration and live.force_setpoint == 50.0

    t0 = 0.8
    live.set_position_offset([0.02, -0.04, 0.0], t0)
    live.set_force(30.0, t0)
    for t, s in ((t0, 0.0), (t0 + RETARGET_BLEND / 2, 0.5), (t0 + 0.1, min_jerk(0.2))):
        ref = live.reference_into(t, NodeReference.empty(1))
        np.testing.assert_allclose(
            ref.ee_position - task.ee_position(t), s * np.array([0.02, -0.04, 0.0]), atol=1e-15
        )
        assert ref.force[0] == pytest.approx(task.force(t) * (1 - s * 0.4))
    late = t0 + RETARGET_BLEND + 0.01
    assert live.reference(late).force[0] == pytest.approx(30.0)
    # a second change starts from where the blend is, not from its end
    t1 = t0 + RETARGET_BLEND / 2
    live.set_force(45.0, t1)
    assert live.reference(t1).force[0] == pytest.approx(40.0)  # midway from 50 to 30 N
    assert live.reference(t1 + RETARGET_BLEND).force[0] == pytest.approx(45.0)
    assert live.force_setpoint == 45.0


def test_live_task_refuses_what_it_cannot_do(robot):
    p0 = robot.contact_placement(robot.q_nominal).translation
    square = LiveTask(ForceSquareTask(p0, p0))
    assert square.force_setpoint is None
    with pytest.raises(InputError, match="no single positive force"):
        square.set_force(30.0, 0.0)
    live = LiveTask(_task(robot))
    with pytest.raises(InputError):
        live.set_force(float("nan"), 0.0)
    with pytest.raises(InputError):
        live.set_position_offset([0.0, np.inf, 0.0], 0.0)
    with pytest.raises(ConfigError):
        LiveTask(_task(robot), position_offset=[0.0, 0.0])


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_cost_weights_change_in_place_in_every_formulation(robot, formulation):
    """set_cost_weight changes the cost of the next solve without rebuilding the problem: the
    problem's cost at the same (xs, us) moves, and the model objects stay the same."""
    config = MpcConfig(ocp=OcpConfig(formulation=formulation), command_delay=0.005)
    mpc = ModelPredictiveController(robot, config, _task(robot))
    force = np.array([10.0]) if formulation == "force_feedback" else None
    meas = MpcMeasurement(robot.q_nominal, np.full(7, 0.1), force, robot.gravity(robot.q_nominal))
    mpc.step(meas, 0.4)
    problem, models = mpc.problem, [n.model for n in mpc.nodes]
    xs, us = list(mpc.solver.xs), list(mpc.solver.us)
    before = problem.calc(xs, us)
    mpc.set_cost_weight("joint_velocity", 10.0)
    assert problem.calc(xs, us) > before + 1e-6
    assert mpc.problem is problem and [n.model for n in mpc.nodes] == models
    assert mpc.config.weights.joint_velocity == 10.0
    for bad in ("ee_position", "force", "lowpass_input", "posture_diag"):
        with pytest.raises(ConfigError):
            mpc.set_cost_weight(bad, 1.0)
    with pytest.raises(ConfigError):
        mpc.set_cost_weight("posture", -1.0)
    if formulation != "force_feedback":
        with pytest.raises(ConfigError, match="force-rate"):
            mpc.set_cost_weight("force_rate", 1.0)
        with pytest.raises(ConfigError, match="visco-elastic"):
            mpc.set_contact_parameters(1500.0, 100.0)
        return
    mpc.set_contact_parameters(1500.0, 80.0)
    for node in (*mpc.nodes, mpc.terminal_node, mpc._predictor):
        assert list(node.model.nominal_stiffness) == [1500.0]
        assert list(node.model.nominal_damping) == [80.0]
    with pytest.raises(ConfigError):
        mpc.set_contact_parameters(-1.0, 80.0)
    assert mpc.config.contact.stiffness == 1500.0  # a refused change changes nothing


def test_pid_gains_change_in_place_and_the_integral_is_clamped_to_the_new_bound():
    limit = np.full(3, 100.0)
    pid = TorquePid(TorquePidGains.default(limit, kp=0.1, ki=20.0), 1e-3, delay_cycles=0)
    for k in range(100):  # a constant error of 10 N·m winds the integral up to 1 N·m·s
        pid.step(np.full(3, 10.0), np.zeros(3), k * 1e-3)
    assert pid.integral == pytest.approx(np.full(3, 1.0))  # (bound 0.3 · 100 / 20 = 1.5)
    pid.set_gains(ki=60.0)  # bound 0.3 · 100 / 60 = 0.5 N·m·s
    assert pid.integral == pytest.approx(np.full(3, 0.5))
    tau = pid.step(np.full(3, 10.0), np.zeros(3), 0.2)
    assert tau == pytest.approx(np.full(3, -0.1 * 10.0 - 60.0 * 0.5))  # eq 33, clamped
    with pytest.raises(ConfigError):
        pid.set_gains(kp=-1.0)
    assert pid.gains.kp == pytest.approx(np.full(3, 0.1))


def test_a_diverged_solve_or_prediction_never_reaches_the_next_command(robot):
    """A solve whose torque is non-finite raises and records nothing as sent (the δo prediction
    never integrates it) and the next solve starts cold; a non-finite prediction raises, forgets
    the commands in flight, and the next solve starts from the measured state."""
    config = MpcConfig(ocp=OcpConfig(formulation="force_feedback"), command_delay=0.005)
    mpc = ModelPredictiveController(robot, config, _task(robot))
    q = robot.q_nominal
    meas = MpcMeasurement(q, np.zeros(7), np.array([5.0]), robot.gravity(q))
    mpc.step(meas, 0.4)
    sent = list(mpc._sent)
    good_command = mpc._command
    mpc._command = lambda x0, xs, us: (np.full(7, np.nan), np.zeros((7, 15)))
    with pytest.raises(InputError):
        mpc.step(meas, 0.402)
    assert mpc._sent == sent and mpc._prev_xs is None
    mpc._command = good_command
    mpc._sent.append((0.402, np.full(7, 1e300)))  # as a diverged solve would have sent
    with pytest.raises(SolverError, match="prediction"):
        mpc.step(meas, 0.404)
    assert mpc._sent == []
    command = mpc.step(meas, 0.406)
    assert np.all(np.isfinite(command.state)) and np.all(np.isfinite(command.torque))
