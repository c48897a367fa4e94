"""The low-level loop (ffmpc_core.lowlevel): plain scheme when the MPC is on time, safe hold,
smooth blend, stale-command fallback, Riccati feedback — and a hold that really holds the robot
in the simulated plant."""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.lowlevel import (
    LowLevelCommand,
    LowLevelConfig,
    LowLevelController,
    LowLevelMeasurement,
    LowLevelMode,
)
from ffmpc_core.pid import PidConfig, TorquePid, TorquePidGains
from ffmpc_core.tasks import min_jerk

DT = 1e-3


def _pid(robot, delay=5):
    return TorquePid(TorquePidGains.default(robot.torque_limit), DT, delay_cycles=delay)


def _meas(robot, rng, q=None):
    q = robot.q_nominal + 0.01 * rng.standard_normal(7) if q is None else q
    return LowLevelMeasurement(q, 0.05 * rng.standard_normal(7), 5.0 * rng.standard_normal(7))


def _command(robot, rng, nx=14, scale=1.0):
    return LowLevelCommand(
        torque=robot.gravity(robot.q_nominal) + scale * rng.standard_normal(7),
        state=np.concatenate([robot.q_nominal, np.zeros(nx - 7)]),
        feedback_gain=0.1 * rng.standard_normal((7, nx)),
    )


@pytest.mark.parametrize("riccati", [False, True])
def test_on_time_mpc_gives_the_plain_scheme(robot, riccati):
    """Commands every 2 cycles from cycle 0: τ^d is τ* on a command cycle, τ* (or τ* + G·Δx)
    in between, and τ^m is eq 33 of an independent PID on that τ^d."""
    rng = np.random.default_rng(1)
    cfg = LowLevelConfig(formulation="classical", riccati_feedback=riccati)
    low = LowLevelController(robot, cfg, _pid(robot))
    reference_pid = _pid(robot)
    for k in range(40):
        t = k * DT
        if k % 2 == 0:
            cmd = _command(robot, rng)
            low.set_command(cmd, t)
        meas = _meas(robot, rng)
        out = low.step(meas, t)
        if k % 2 == 0 or not riccati:
            expected = cmd.torque
        else:
            dx = np.concatenate([meas.q, meas.v]) - cmd.state
            expected = robot.clip_torque(cmd.torque + cmd.feedback_gain @ dx)
        np.testing.assert_array_equal(out.desired_torque, expected)
        motor = robot.clip_torque(reference_pid.step(meas.torque, expected, t))
        np.testing.assert_array_equal(out.motor_torque, motor)
        assert out.mode == LowLevelMode.TRACK and out.blend == 1.0


def test_hold_before_the_first_command_brakes_then_holds_with_the_full_mass_matrix(robot):
    """Moving: brake, τ = g − K_d·M(q̂)·q̇̂; at rest: the posture is latched and
    τ = g + M_h·(−K_p·(q̂ − q_h) − K_d·q̇̂) with the FULL mass matrix M_h = M(q_h); the hold
    torque goes straight to the motors (the PID's δo delay line is bypassed)."""
    rng = np.random.default_rng(2)
    cfg = LowLevelConfig(
        formulation="classical", pid=PidConfig(hold_frequency=2.0, hold_damping_ratio=0.7)
    )
    low = LowLevelController(robot, cfg, _pid(robot, delay=5))
    omega = 2 * np.pi * 2.0
    kp, kd = omega**2, 2 * 0.7 * omega
    data = robot.create_data()
    moving = _meas(robot, rng)
    moving.v = np.full(7, 0.2)  # above the 0.05 rad/s settle velocity: brake
    out = low.step(moving, 0.0)
    assert out.mode == LowLevelMode.HOLD and out.blend == 0.0
    assert low.hold_posture is None
    mass = pin.crba(robot.model, data, moving.q)
    expected = robot.gravity(moving.q) - kd * mass @ moving.v
    np.testing.assert_allclose(out.desired_torque, expected, rtol=1e-12)
    # To the motors through the PID with the hold torque as its reference, undelayed.
    direct = TorquePid(TorquePidGains.default(robot.torque_limit), DT, delay_cycles=0)
    np.testing.assert_allclose(
        out.motor_torque, direct.step(moving.torque, out.desired_torque, 0.0), rtol=1e-12
    )
    at_rest = LowLevelMeasurement(moving.q + 0.001, np.full(7, 0.01), moving.torque)
    out = low.step(at_rest, DT)  # through a 5-cycle delay line this would still be cycle 0's
    np.testing.assert_allclose(
        out.motor_torque, direct.step(at_rest.torque, out.desired_torque, DT), rtol=1e-12
    )
    np.testing.assert_array_equal(low.hold_posture, at_rest.q)
    mass_h = pin.crba(robot.model, data, at_rest.q)
    assert abs(mass_h[0, 2]) > 0.1  # the coupling the diagonal hold ignored
    meas = LowLevelMeasurement(at_rest.q + 0.002, np.full(7, -0.02), moving.torque)
    out = low.step(meas, 2 * DT)
    expected = robot.gravity(meas.q) + mass_h @ (-kp * (meas.q - at_rest.q) - kd * meas.v)
    np.testing.assert_allclose(out.desired_torque, expected, rtol=1e-12)


def test_hold_braking_is_scaled_within_the_torque_budget(robot):
    """A fast robot: the braking torque is scaled down (same direction) so that every joint
    stays within hold_torque_fraction of its limit — never a saturated, distorted PD."""
    rng = np.random.default_rng(3)
    cfg = LowLevelConfig(formulation="classical", hold_torque_fraction=0.75)
    low = LowLevelController(robot, cfg, _pid(robot))
    q = robot.q_nominal
    v = 3.0 * robot.velocity_limit * np.sign(rng.standard_normal(7))
    out = low.step(LowLevelMeasurement(q, v, np.zeros(7)), 0.0)
    gravity = robot.gravity(q)
    full = -low._kd * pin.crba(robot.model, robot.create_data(), q) @ v
    brake = out.desired_torque - gravity
    scale = brake @ full / (full @ full)
    assert 0.0 < scale < 1.0
    np.testing.assert_allclose(brake, scale * full, rtol=1e-9, atol=1e-9)
    assert np.all(np.abs(out.desired_torque) <= 0.75 * robot.torque_limit + 1e-9)
    assert np.isclose(np.max(np.abs(out.desired_torque) / robot.torque_limit), 0.75)
    assert v @ brake < 0  # q̇ᵀ(τ − g) < 0: the kinetic energy decreases


def test_blend_from_hold_to_mpc_is_a_minimum_jerk_ramp(robot):
    rng = np.random.default_rng(3)
    cfg = LowLevelConfig(formulation="classical", pid=PidConfig(blend_duration=0.02))
    low = LowLevelController(robot, cfg, _pid(robot))
    q = robot.q_nominal.copy()
    still = LowLevelMeasurement(q, np.zeros(7), robot.gravity(q))
    for k in range(5):
        assert low.step(still, k * DT).mode == LowLevelMode.HOLD
    hold = robot.gravity(q)
    cmd = _command(robot, rng, scale=20.0)
    weights = []
    for k in range(5, 40):
        t = k * DT
        if k % 2 == 1:
            cmd = LowLevelCommand(cmd.torque, cmd.state, cmd.feedback_gain)
            low.set_command(cmd, t)
        out = low.step(still, t)
        s = min_jerk((t - 5 * DT) / 0.02)
        np.testing.assert_allclose(
            out.desired_torque, robot.clip_torque((1 - s) * hold + s * cmd.torque), atol=1e-9
        )
        weights.append(out.blend)
        assert out.mode == (LowLevelMode.BLEND if s < 1 else LowLevelMode.TRACK)
    assert weights[0] == 0.0 and weights[-1] == 1.0 and np.all(np.diff(weights) >= 0)


def test_stale_mpc_falls_back_to_hold_within_two_control_periods(robot):
    """MPC period 2 ms, stale_timeout 2 periods: after the last command at t_c the loop tracks
    until t_c + 4 ms and holds from the next cycle on; fresh commands blend back in."""
    rng = np.random.default_rng(4)
    cfg = LowLevelConfig(
        formulation="classical", pid=PidConfig(stale_timeout=0.004), mpc_period=0.002
    )
    low = LowLevelController(robot, cfg, _pid(robot))
    modes = {}
    last_command = 0.020
    for k in range(60):
        t = k * DT
        if k % 2 == 0 and (t <= last_command + 1e-12 or t >= 0.040 - 1e-12):
            low.set_command(_command(robot, rng), t)
        modes[k] = low.step(_meas(robot, rng), t).mode
    assert all(modes[k] == LowLevelMode.TRACK for k in range(0, 25))  # age <= 4 ms
    assert modes[25] == LowLevelMode.FALLBACK  # first cycle with age 5 ms > 4 ms
    assert all(modes[k] == LowLevelMode.FALLBACK for k in range(25, 40))
    assert modes[40] == LowLevelMode.BLEND  # commands are back: blend from the hold


def test_fallback_hold_torque_is_around_the_posture_at_fallback(robot):
    rng = np.random.default_rng(5)
    cfg = LowLevelConfig(formulation="classical")
    low = LowLevelController(robot, cfg, _pid(robot, delay=0))
    low.set_command(_command(robot, rng), 0.0)
    for k in range(5):
        low.step(_meas(robot, rng), k * DT)
    at_fallback = _meas(robot, rng)
    out = low.step(at_fallback, 5 * DT)
    assert out.mode == LowLevelMode.FALLBACK
    zero_velocity = LowLevelMeasurement(at_fallback.q, np.zeros(7), at_fallback.torque)
    out = low.step(zero_velocity, 6 * DT)
    np.testing.assert_allclose(out.desired_torque, robot.gravity(at_fallback.q), atol=1e-9)


def test_malformed_commands_are_refused_and_the_previous_one_kept(robot):
    rng = np.random.default_rng(6)
    low = LowLevelController(robot, LowLevelConfig(formulation="classical"), _pid(robot))
    good = _command(robot, rng)
    low.set_command(good, 0.002)
    with pytest.raises(InputError, match="state"):
        low.set_command(LowLevelCommand(good.torque, np.zeros(21), good.feedback_gain), 0.004)
    with pytest.raises(InputError, match="feedback_gain"):
        low.set_command(LowLevelCommand(good.torque, good.state, np.zeros((7, 21))), 0.004)
    with pytest.raises(InputError, match="not after"):
        low.set_command(good, 0.002)
    assert low.command_time == 0.002
    out = low.step(_meas(robot, rng), 0.003)
    np.testing.assert_array_equal(out.desired_torque, good.torque)
    with pytest.raises(InputError, match="increasing"):
        low.step(_meas(robot, rng), 0.003)


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf, 1e9])
def test_non_finite_or_absurd_command_torque_engages_the_safe_hold_at_once(robot, value):
    """A failed MPC (NaN, ±inf, 1e9 N·m) is never clipped to 0 or to the limit: the command is
    refused AND dropped, and the very next cycle is the safe hold; a valid command resumes."""
    rng = np.random.default_rng(6)
    low = LowLevelController(robot, LowLevelConfig(formulation="classical"), _pid(robot))
    good = _command(robot, rng)
    low.set_command(good, 0.0)
    assert low.step(_meas(robot, rng), 0.0).mode == LowLevelMode.TRACK
    bad = LowLevelCommand(good.torque.copy(), good.state, good.feedback_gain)
    bad.torque[3] = value
    with pytest.raises(InputError, match="torque"):
        low.set_command(bad, 0.002)
    assert low.invalid_commands == 1
    meas = _meas(robot, rng)
    out = low.step(meas, 0.002)  # the same cycle the command was due: hold
    assert out.mode == LowLevelMode.FALLBACK
    assert np.all(np.isfinite(out.motor_torque))
    assert np.all(np.abs(out.desired_torque) <= robot.torque_limit)
    assert not np.allclose(out.desired_torque, good.torque)
    low.set_command(good, 0.004)
    assert low.step(meas, 0.004).mode == LowLevelMode.BLEND


def test_clip_torque_refuses_non_finite_and_absurd_torques(robot):
    limit = robot.torque_limit
    np.testing.assert_array_equal(robot.clip_torque(2.0 * limit), limit)
    for value in (np.nan, np.inf, -np.inf, 1e9):
        tau = np.zeros(7)
        tau[0] = value
        with pytest.raises(InputError, match="torque"):
            robot.clip_torque(tau)


def test_desired_and_motor_torques_are_saturated(robot):
    rng = np.random.default_rng(7)
    low = LowLevelController(robot, LowLevelConfig(formulation="classical"), _pid(robot, 0))
    above = LowLevelCommand(3.0 * robot.torque_limit, np.zeros(14), np.zeros((7, 14)))
    low.set_command(above, 0.0)
    out = low.step(_meas(robot, rng), 0.0)
    np.testing.assert_array_equal(out.desired_torque, robot.torque_limit)
    assert np.all(np.abs(out.motor_torque) <= robot.torque_limit)


def test_config_is_validated():
    with pytest.raises(ConfigError, match="must exceed the MPC period"):
        LowLevelConfig(pid=PidConfig(stale_timeout=0.002), mpc_period=0.002)
    with pytest.raises(ConfigError):
        LowLevelConfig(formulation="rigid")
    with pytest.raises(ConfigError):
        PidConfig(blend_duration=-1.0)


def _in_pybullet(robot, overrides: dict, seed: int, cycles: int, command=None):
    """Yield (k, true plant state before the step, the low level's output, the low level) for
    ``cycles`` 1 kHz cycles in PyBullet (no table) from q_nominal at rest: the polishing
    scenario's joint sensing, actuation bias/noise/friction and torque PID (δo = 5 ms) around
    its low level. ``command(k, q̂, q̇̂)`` may return an MPC command to set before the step."""
    from ffmpc_core.polishing import (
        actuation_model,
        draw_run,
        joint_sensing_model,
        lowlevel_controller,
        spawn_generators,
    )
    from ffmpc_core.scenario import load_scenario
    from sim_bridge.plant import Plant, PlantConfig

    scenario = load_scenario("polishing", overrides)
    draw_rng, joint_rng, _, act_rng, _ = spawn_generators(seed)
    draws = draw_run(scenario, robot, draw_rng)
    sensing = joint_sensing_model(scenario, robot.nv, joint_rng)
    actuation = actuation_model(scenario, robot, draws, act_rng)
    low = lowlevel_controller(scenario, robot)
    with Plant(robot, PlantConfig(table=None)) as plant:
        plant.reset(robot.q_nominal)
        tau_hat = robot.gravity(robot.q_nominal)
        for k in range(cycles):
            s = plant.state()
            q_hat, v_hat = sensing.step(s.q, s.v)
            sent = None if command is None else command(k, q_hat, v_hat)
            if sent is not None:
                low.set_command(sent, k * DT)
            out = low.step(LowLevelMeasurement(q_hat, v_hat, tau_hat), k * DT)
            tau_hat = actuation.step(out.motor_torque, s.v)
            plant.step(tau_hat)
            yield k, s, out, low


def _hold_drift(robot, overrides: dict, seed: int = 4) -> tuple[float, float]:
    """Max and final displacement (m) of the contact frame during 1 s of safe hold in PyBullet,
    with the study's sensing noise, actuation bias/noise/friction and torque PID (δo = 5 ms)."""
    start = robot.contact_placement(robot.q_nominal).translation
    data = robot.create_data()
    drift = []
    for _, s, out, _ in _in_pybullet(robot, overrides, seed, 1000):
        assert out.mode == LowLevelMode.HOLD
        assert np.all(np.abs(out.motor_torque) <= robot.torque_limit)
        position = robot.contact_placement(s.q, data).translation
        drift.append(float(np.linalg.norm(position - start)))
    return max(drift), drift[-1]


def test_hold_keeps_the_simulated_robot_in_place(robot):
    """The PD of the hold matters: with it (4 Hz, full mass matrix) the tool moves < 20 mm while
    the delay-free PID's integral removes the actuation bias and it ends within 8 mm; gravity
    compensation alone (hold_frequency 0) lets it sag by more than 5 cm. Measured with the
    default PID gains (K_P 0.1, K_I 20/s, δo bypassed): 11.8 mm peak, 1.4 mm final; gravity only
    275 mm (the diagonal hold through the 5 ms delay line measured 14.6 / 4.8 mm here)."""
    peak, final = _hold_drift(robot, {})
    assert peak < 20e-3 and final < 8e-3, (peak, final)
    peak_gravity_only, _ = _hold_drift(robot, {"pid.hold_frequency": 0.0})
    assert peak_gravity_only > 50e-3


def test_hold_goes_back_to_brake_when_pushed_and_latches_again_at_rest(robot):
    """Latched at rest; a push (kinetic energy > 4× the settle energy) unlatches it — brake, no
    PD pulling back at full torque — and it latches again where the robot comes to rest."""
    cfg = LowLevelConfig(formulation="classical")
    low = LowLevelController(robot, cfg, _pid(robot))
    q0 = robot.q_nominal.copy()
    torque = robot.gravity(q0)
    low.step(LowLevelMeasurement(q0, np.zeros(7), torque), 0.0)
    np.testing.assert_array_equal(low.hold_posture, q0)
    pushed = LowLevelMeasurement(q0 + 0.05, np.full(7, 0.3), torque)
    out = low.step(pushed, DT)
    assert low.hold_posture is None  # braking
    brake = -low._kd * pin.crba(robot.model, robot.create_data(), pushed.q) @ pushed.v
    np.testing.assert_allclose(out.desired_torque, robot.gravity(pushed.q) + brake, rtol=1e-12)
    low.step(LowLevelMeasurement(pushed.q, np.zeros(7), torque), 2 * DT)
    np.testing.assert_array_equal(low.hold_posture, pushed.q)


def test_engage_hold_drops_the_command_and_hold_parameters_are_validated(robot):
    rng = np.random.default_rng(8)
    low = LowLevelController(robot, LowLevelConfig(formulation="classical"), _pid(robot))
    low.set_command(_command(robot, rng), 0.0)
    assert low.step(_meas(robot, rng), 0.0).mode == LowLevelMode.TRACK
    low.engage_hold()
    assert low.step(_meas(robot, rng), DT).mode == LowLevelMode.FALLBACK
    with pytest.raises(ConfigError):
        LowLevelConfig(hold_settle_energy=0.0)
    with pytest.raises(ConfigError):
        LowLevelConfig(hold_torque_fraction=1.5)


def test_missing_force_is_held_for_force_hold_time_then_the_feedback_goes_without_it(robot):
    """Force-feedback with Riccati feedback: a cycle whose λ̂ is missing (None) or not finite
    uses the newest finite λ̂ while it is at most ``force_hold_time`` old, then τ* alone."""
    rng = np.random.default_rng(3)
    cfg = LowLevelConfig(
        formulation="force_feedback",
        riccati_feedback=True,
        pid=PidConfig(stale_timeout=1.0),
        force_hold_time=3e-3,
    )
    low = LowLevelController(robot, cfg, _pid(robot))
    cmd = _command(robot, rng, nx=15)
    cmd.state[-1] = 10.0  # λ at the solve, N
    low.set_command(cmd, 0.0)
    q, v, tau = robot.q_nominal, np.zeros(7), np.zeros(7)

    def feedback(force):
        dx = np.concatenate([q, v, [force]]) - cmd.state
        return robot.clip_torque(cmd.torque + cmd.feedback_gain @ dx)

    low.step(LowLevelMeasurement(q, v, tau, np.array([12.0])), 0.0)  # first use: τ* alone
    out = low.step(LowLevelMeasurement(q, v, tau, np.array([12.0])), DT)
    np.testing.assert_array_equal(out.desired_torque, feedback(12.0))
    for k, force in ((2, None), (3, np.array([np.nan])), (4, None)):  # held: 1–3 ms old
        out = low.step(LowLevelMeasurement(q, v, tau, force), k * DT)
        np.testing.assert_array_equal(out.desired_torque, feedback(12.0))
    out = low.step(LowLevelMeasurement(q, v, tau, None), 5 * DT)  # 4 ms old: τ* alone
    np.testing.assert_array_equal(out.desired_torque, cmd.torque)
    out = low.step(LowLevelMeasurement(q, v, tau, np.array([9.0])), 6 * DT)  # back
    np.testing.assert_array_equal(out.desired_torque, feedback(9.0))
    with pytest.raises(ConfigError, match="force_hold_time"):
        LowLevelConfig(force_hold_time=-1.0)


def test_velocity_guard_drops_a_command_when_a_joint_is_too_fast(robot):
    """Guard 0.9: a measured speed above 0.9 × a joint's velocity limit drops the command (one
    trip), that cycle is the safe hold's brake, and the next command blends in from the hold;
    the same speed with the guard off (0, the default) is tracked."""
    rng = np.random.default_rng(9)
    fast = robot.velocity_limit * np.array([0, 0, 0, 0, 0.95, 0, 0])
    modes = {}
    for guard in (0.0, 0.9):
        cfg = LowLevelConfig(formulation="classical", pid=PidConfig(velocity_guard=guard))
        low = LowLevelController(robot, cfg, _pid(robot))
        for k in range(8):
            if k % 2 == 0:
                low.set_command(_command(robot, rng), k * DT)
            meas = _meas(robot, rng)
            if k == 4:
                meas.v = meas.v * 0.0 + fast
            out = low.step(meas, k * DT)
            modes[guard, k] = out.mode
            if guard and k == 4:
                hold = LowLevelController(robot, cfg, _pid(robot)).hold_torque(meas.q, meas.v)
                np.testing.assert_allclose(out.desired_torque, robot.clip_torque(hold))
        assert low.velocity_guard_trips == (1 if guard else 0)
    assert all(modes[0.0, k] == LowLevelMode.TRACK for k in range(8))
    assert [modes[0.9, k] for k in range(4, 8)] == [LowLevelMode.FALLBACK] * 2 + [
        LowLevelMode.BLEND
    ] * 2
    with pytest.raises(ConfigError, match="velocity_guard"):
        PidConfig(velocity_guard=1.5)


def _runaway_peak(robot, guard: float) -> tuple[float, int]:
    """Max |q̇|/limit over 0.6 s in PyBullet (no table) when every MPC command (2 ms) asks the
    wrist joint A5 for 9.3 N·m beyond gravity (about a quarter of its velocity limit more per
    cycle), with the study's sensing, actuation and PID; and the guard's trips. (The push was
    10 N·m against the iiwa 7's 140°/s; scaled with the iiwa 14's 130°/s data-sheet limit.)"""
    push = np.array([0, 0, 0, 0, 9.3, 0, 0])

    def command(k: int, q_hat: np.ndarray, v_hat: np.ndarray) -> LowLevelCommand | None:
        if k % 2:
            return None
        return LowLevelCommand(
            robot.gravity(q_hat) + push, np.concatenate([q_hat, v_hat]), np.zeros((7, 14))
        )

    overrides = {"pid.velocity_guard": guard, "mpc.formulation": "classical"}
    peak, trips = 0.0, 0
    for _, s, _, low in _in_pybullet(robot, overrides, 5, 600, command):
        peak = max(peak, float(np.max(np.abs(s.v) / robot.velocity_limit)))
        trips = low.velocity_guard_trips
    return peak, trips


def test_velocity_guard_keeps_a_runaway_command_within_the_velocity_limits(robot):
    """An MPC that keeps accelerating the wrist: without the guard the joint passes its velocity
    limit; with the guard at 0.9 it is braked each time its predicted speed passes 0.9 and stays
    below 1 (measured: 0.963 with the iiwa 14's limits; 0.96 with the iiwa 7's; compared
    without the prediction, the speed reached 1.43)."""
    peak_off, trips_off = _runaway_peak(robot, 0.0)
    peak_on, trips_on = _runaway_peak(robot, 0.9)
    assert peak_off > 1.2 and trips_off == 0, peak_off
    assert peak_on < 1.0 and trips_on >= 1, (peak_on, trips_on)
