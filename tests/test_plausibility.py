"""Plausibility limits (ffmpc_core.plausibility): absurd finite values are refused, never adopted —
the PID keeps its integral, the tare keeps its offset, the learner's prior is kept."""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core import plausibility as pl
from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.faults import Fault, active_kinds, faults_from, parse_fault
from ffmpc_core.impact.learner import ContactEstimate, confident
from ffmpc_core.pid import TorquePid, TorquePidGains
from ffmpc_core.sensing import ForceTare

LIMIT = np.array([176.0, 176.0, 110.0, 110.0, 110.0, 40.0, 40.0])
DT = 1e-3


def _pid(**kw) -> TorquePid:
    return TorquePid(TorquePidGains.default(LIMIT), DT, delay_cycles=5, torque_limit=LIMIT, **kw)


def test_pid_rejects_an_implausible_measured_torque_and_keeps_its_integral():
    """A measured 1e9 N·m used to pin the integral at its anti-windup bound in one cycle."""
    pid, reference = _pid(), _pid()
    rng = np.random.default_rng(0)
    desired = 10.0 * rng.standard_normal(7)
    for k in range(20):
        measured = desired + rng.standard_normal(7)
        pid.step(measured, desired, k * DT)
        reference.step(measured, desired, k * DT)
    before = pid.integral
    spike = np.full(7, 1e9)
    out = pid.step(spike, desired, 20 * DT)
    assert pid.rejected == 1
    np.testing.assert_array_equal(pid.integral, before)  # kept, not pinned at the bound
    np.testing.assert_allclose(out, desired - pid.gains.ki * before)  # no P/D from the spike
    assert np.all(np.abs(out) < 2 * np.abs(desired) + 1.0)
    # Without the plausibility limit the same sample drives the integral to its bound.
    plain = TorquePid(TorquePidGains.default(LIMIT), DT, delay_cycles=5)
    plain.step(desired, desired, 0.0)
    plain.step(spike, desired, DT)
    np.testing.assert_allclose(np.abs(plain.gains.ki * plain.integral), 0.3 * LIMIT)


def test_pid_integral_is_anti_windup_bounded_and_non_finite_is_an_error():
    pid = _pid()
    for k in range(2000):
        pid.step(np.full(7, 4.0) * LIMIT, np.zeros(7), k * DT)  # plausible, large, persistent
    np.testing.assert_allclose(np.abs(pid.gains.ki * pid.integral), 0.3 * LIMIT)
    state = pid.integral
    with pytest.raises(InputError, match="finite"):
        pid.step(np.full(7, np.nan), np.zeros(7), 2000 * DT)
    np.testing.assert_array_equal(pid.integral, state)


def test_pid_undelayed_reference_bypasses_the_delay_line():
    pid = TorquePid(TorquePidGains.default(LIMIT, kp=0.0, ki=0.0), DT, delay_cycles=5)
    pid.step(np.zeros(7), np.zeros(7), 0.0)
    hold = np.full(7, 3.0)
    np.testing.assert_allclose(pid.step(np.zeros(7), np.ones(7), DT, hold, 0.0), hold)
    mixed = pid.step(np.zeros(7), np.ones(7), 2 * DT, hold, 0.25)
    np.testing.assert_allclose(mixed, 0.25 * 0.0 + 0.75 * hold)  # delayed τ^d is still 0
    with pytest.raises(InputError, match="weight"):
        pid.step(np.zeros(7), np.ones(7), 3 * DT, hold, 1.5)


def test_tare_ignores_implausible_readings_and_refuses_implausible_offsets():
    """−1e9 N then a tare used to turn a 10 N reading into 2e7 N."""
    tare = ForceTare(samples=50, force_dim=1)
    for _ in range(49):
        assert tare.add(np.array([1.5]))
    assert not tare.add(np.array([-1e9]))  # not kept
    assert not tare.add(np.array([np.nan]))
    assert tare.rejected == 2
    np.testing.assert_allclose(tare.tare(in_contact=False), [1.5])
    assert 10.0 - tare.offset[0] == pytest.approx(8.5)
    with pytest.raises(InputError, match="in contact"):
        tare.tare(in_contact=True)
    loaded = ForceTare(samples=5, force_dim=3)
    for _ in range(5):
        loaded.add(np.array([0.0, 0.0, 300.0]))  # plausible reading, but a loaded sensor
    with pytest.raises(InputError, match="exceeds 50 N"):
        loaded.tare(in_contact=False)
    np.testing.assert_array_equal(loaded.offset, np.zeros(3))  # previous offset kept
    with pytest.raises(InputError, match="no plausible"):
        ForceTare(samples=5, force_dim=1).tare(in_contact=False)
    with pytest.raises(ConfigError):
        ForceTare(samples=0, force_dim=1)


def _estimate(stiffness: float, damping: float = 20.0) -> ContactEstimate:
    return ContactEstimate(
        stiffness=stiffness,
        damping=damping,
        stiffness_std=0.01 * stiffness,
        damping_std=0.01 * damping,
        noise_std=0.1,
        samples=500,
        condition=10.0,
    )


@pytest.mark.parametrize(
    ("stiffness", "damping", "ok"),
    [
        (2400.0, 15.0, True),
        (1e-9, 15.0, False),
        (1e12, 15.0, False),
        (2400.0, 1e7, False),
        (pl.STIFFNESS_MIN, 0.0, True),
        (pl.STIFFNESS_MAX, pl.DAMPING_MAX, True),
    ],
)
def test_learned_stiffness_and_damping_outside_their_range_are_refused(stiffness, damping, ok):
    """A confident-looking estimate (1 % standard errors, 500 samples) outside the plausible
    range does not replace the prior (the MPC and impact planner nodes use this rule)."""
    from ffmpc_ros import impact_planner_node, mpc_live

    estimate = _estimate(stiffness, damping)
    assert confident(estimate, 100, 0.2) is ok
    assert mpc_live.confident is confident and impact_planner_node.confident is confident


def test_check_functions_name_the_value_and_unit():
    with pytest.raises(InputError, match="N·m"):
        pl.check_torque(np.full(7, 1e9), LIMIT)
    with pytest.raises(InputError, match="2000 N"):
        pl.check_force(np.array([-1e9]))
    with pytest.raises(InputError, match="N/m"):
        pl.check_contact_parameters(1e12, 10.0)
    assert pl.torque_plausible(4.9 * LIMIT, LIMIT)  # a measurement
    assert not pl.torque_plausible(5.1 * LIMIT, LIMIT)
    np.testing.assert_array_equal(pl.check_torque(50.0 * LIMIT, LIMIT), 50.0 * LIMIT)  # a command
    with pytest.raises(InputError, match="100"):
        pl.check_torque(101.0 * LIMIT, LIMIT)
    assert not pl.torque_plausible(np.append(np.zeros(6), np.inf), LIMIT)


def test_fault_specs_parse_and_activate():
    fault = parse_fault("mpc-dropout@0.6+0.05")
    assert fault == Fault("mpc-dropout", 0.6, 0.05)
    assert str(fault) == "mpc-dropout@0.6+0.05"
    assert not fault.active(0.599) and fault.active(0.6) and fault.active(0.649)
    assert not fault.active(0.65)
    forever = parse_fault("nan-wrench@0.5")
    assert forever.duration is None and forever.active(1e6)
    assert set(active_kinds(faults_from(["torque-spike@0+0.001", forever]), 0.5)) == {"nan-wrench"}
    for bad in ("mpc-dropout", "dropout@1", "mpc-dropout@x", "mpc-dropout@1+0", "mpc-dropout@-1"):
        with pytest.raises(ConfigError):
            parse_fault(bad)


@pytest.mark.parametrize(
    ("joint", "position", "velocity", "ok"),
    [
        (4, -1e300, 0.0, False),  # finite: the fuzz's state that aborted the solver's process
        (4, None, 0.0, True),  # at its upper limit
        (4, "beyond", 0.0, False),  # 0.6 rad beyond its upper limit
        (2, 0.0, 6.0, True),  # 6x its velocity limit: measured with the reflex off
        (2, 0.0, 20.5, False),  # beyond 20x: no motion of this robot
        (2, 0.0, -1e9, False),
    ],
)
def test_the_mpc_refuses_an_implausible_joint_state_before_solving(joint, position, velocity, ok):
    """A joint state that is finite but absurd (q = -1e300 rad) is refused with InputError by
    the MPC before the OCP is built from it: started from it, the constrained solver's line
    search met a NaN cost inside its OpenMP loop and the process aborted (SIGABRT)."""
    from ffmpc_core.mpc import ModelPredictiveController, MpcConfig, MpcMeasurement
    from ffmpc_core.polishing import build_task, mpc_config, mpc_schedule
    from ffmpc_core.robots import load_robot
    from ffmpc_core.scenario import load_scenario

    robot = load_robot("iiwa")
    q = robot.q_nominal.copy()
    if position is None:
        q[joint] = robot.position_upper[joint]
    elif position == "beyond":
        q[joint] = robot.position_upper[joint] + pl.JOINT_POSITION_SLACK + 0.1
    else:
        q[joint] = position
    v = np.zeros(robot.nv)
    v[joint] = velocity * robot.velocity_limit[joint] if abs(velocity) < 100 else velocity
    scenario = load_scenario("polishing")
    config: MpcConfig = mpc_config(scenario)
    mpc = ModelPredictiveController(
        robot, config, mpc_schedule(build_task(scenario, robot), scenario)
    )
    meas = MpcMeasurement(q=q, v=v, force=np.array([0.0]))
    if ok:
        assert np.all(np.isfinite(mpc.state_from(meas)))
    else:
        with pytest.raises(InputError, match="refused"):
            mpc.step(meas, 0.0)
