"""The real-time loop's cycle (ffmpc_ros.realtime_cycle) is the core's closed loop on a wall clock.

Driven by a scripted wall clock (no sleeping, no ROS): one that never misses gives the log of
``ffmpc_core.runner.run_scenario`` on the lockstep clock, bit for bit, for the same scenario,
seeds and MPC commands; one that makes the loop late shows what only real time adds — the
motor drives hold the torque through the steps a late torque missed and through missed cycles,
and tell the robot's communication reflex that no new torque came.
"""

from __future__ import annotations

import numpy as np
import pytest

from ffmpc_core.lowlevel import LowLevelCommand, LowLevelMode
from ffmpc_core.polishing import (
    PolishingLog,
    force_pipeline,
    joint_sensing_model,
    lowlevel_controller,
    scenario_robot,
    spawn_generators,
    steps_per_mpc_period,
)
from ffmpc_core.polishing_loop import LowLevelStage, MpcDecision, PolishingLoop
from ffmpc_core.runner import LockstepClock, run_scenario
from ffmpc_core.scenario import load_scenario
from ffmpc_ros.realtime_cycle import MotorDrives, WallClock, WallClockCycles, initial_output
from sim_bridge.scenes import simulated_robot

STEPS = 60


class ScriptedMpc:
    """An MPC stage that sends, on every MPC tick, a torque scripted from the reading (gravity
    of q̂ plus a tick-dependent offset) with a Riccati gain: enough to move the robot and to
    exercise the low level's tracking and feedback, without an OCP."""

    def __init__(self, loop: PolishingLoop, nx: int, every: int, on_step=None) -> None:
        self.loop, self.nx, self.every = loop, nx, every
        self.on_step = on_step

    def reset(self) -> None:
        pass

    def step(self, reading, t, /):
        k = round(t / 1e-3)  # the cycle (the scenario's Δt)
        if self.on_step is not None:
            self.on_step(k)
        if k % self.every:
            return MpcDecision(reading, None, False)
        robot = self.loop.robot
        torque = robot.gravity(reading.q) + 0.5 * np.sin(0.1 * k + np.arange(robot.nv))
        state = np.zeros(self.nx)
        state[: 2 * robot.nv] = np.concatenate([reading.q, reading.v])
        gain = -0.1 * np.eye(robot.nv, self.nx)
        return MpcDecision(reading, LowLevelCommand(torque, state, gain), False)


def _parts(formulation: str):
    """A fresh polishing loop, plant and low level of the scenario (seed 5)."""
    scenario = load_scenario("polishing", {"seed": 5, "mpc.formulation": formulation})
    robot = scenario_robot(scenario)
    draw, joint, force, act, calibration = spawn_generators(scenario.seed)
    sim = simulated_robot(scenario, robot, draw, act)
    every = steps_per_mpc_period(scenario)
    loop = PolishingLoop(
        robot,
        scenario.mpc.contact,
        joint_sensing_model(scenario, robot.nv, joint),
        force_pipeline(scenario, robot, force, calibration, 0.0),
        sim.actuation,
        PolishingLog(STEPS, robot, sim.task),
        every,
        initial_torque=robot.gravity(robot.q_nominal),
        disturbance=sim.push_if_due,
    )
    return sim, loop, lowlevel_controller(scenario, robot), every


class ScriptedTime:
    """A wall clock: waiting for a release jumps to it (plus a scripted overrun), ``advance``
    stands for work that takes wall time."""

    def __init__(self, overrun_at_release: dict[int, float] | None = None, dt: float = 1e-3):
        self.t = 100.0
        self.dt = dt
        self.overrun = overrun_at_release or {}
        self.releases = 0

    def now(self) -> float:
        return self.t

    def wait(self, release: float) -> None:
        self.t = max(self.t, release) + self.overrun.get(self.releases, 0.0) * self.dt
        self.releases += 1

    def advance(self, periods: float) -> None:
        self.t += periods * self.dt


def _wall_clock_run(formulation: str, time: ScriptedTime, late_at: dict[int, float]):
    """The real-time cycle on the scripted clock: the MPC stage's work at cycle k takes
    ``late_at[k]`` periods. Returns (loop, times, the low level's own outputs, fresh flags,
    the reflex's report)."""
    sim, loop, lowlevel, every = _parts(formulation)
    clock = WallClock(sim.plant.dt, STEPS, now=time.now, wait=time.wait)
    computed = {}

    class SpyStage(LowLevelStage):
        def step(self, decision, t, /):
            out = super().step(decision, t)
            computed[clock.k] = out
            return out

    drives = MotorDrives(
        SpyStage(lowlevel), clock, initial_output(loop.tau_hat.copy()), reject=pytest.fail
    )
    mpc = ScriptedMpc(loop, lowlevel.nx, every, lambda k: time.advance(late_at.get(k, 0.0)))
    fresh_flags: list[bool] = []
    plant = sim.reflex_plant
    plant_step = plant.step

    def spy(joint_input, /, *, fresh: bool = True) -> None:
        fresh_flags.append(fresh)
        plant_step(joint_input, fresh=fresh)

    plant.step = spy
    try:
        times = WallClockCycles(loop, plant, mpc, drives).run()
    finally:
        sim.plant.close()
    return loop, times, computed, fresh_flags, plant.reflex.report()


@pytest.mark.parametrize("formulation", ["classical", "force_feedback"])
def test_a_wall_clock_that_never_misses_runs_the_lockstep_loop_bit_for_bit(formulation):
    """The same scenario, seeds and MPC commands: run_scenario on the lockstep clock and the
    real-time cycle on a wall clock that is never late give the same log, traces and reflex
    report (the MPC stage's commands go through the same LowLevelStage in both)."""
    sim, loop, lowlevel, every = _parts(formulation)
    stages = [ScriptedMpc(loop, lowlevel.nx, every), LowLevelStage(lowlevel)]
    try:
        run_scenario(loop, sim.reflex_plant, stages, LockstepClock(sim.plant.dt, STEPS))
        lockstep_reflex = sim.reflex_plant.reflex.report()
    finally:
        sim.plant.close()
    real, times, _, fresh, reflex = _wall_clock_run(formulation, ScriptedTime(), {})
    assert reflex == lockstep_reflex
    assert not times.missed.any() and np.all(times.latency == 0.0) and all(fresh)
    for name, lockstep in loop.log.arrays.items():
        assert np.array_equal(real.log.arrays[name], lockstep), name
    for name in ("trace_v", "trace_tau", "trace_applied", "trace_mode"):
        assert np.array_equal(getattr(real, name), getattr(loop, name)), name
    assert np.ptp(loop.log.arrays["tau_motor"], axis=0).max() > 0.1  # the commands drove it
    tracked = (int(LowLevelMode.BLEND), int(LowLevelMode.TRACK))
    assert np.isin(loop.trace_mode, tracked).any()


def test_a_late_torque_and_missed_cycles_hold_the_torque_last_sent():
    """Cycle 10's work takes 2.5 periods: its torque misses steps 10 and 11 (they run under
    cycle 9's, cycle 11 is missed) and is delivered for step 12 — which the loop reaches
    1.2 periods late (missed): step 12 runs under cycle 10's torque. Cycle 13 runs on time.
    Every held step tells the reflex that no new torque came (fresh=False)."""
    time = ScriptedTime({12: 1.2})
    loop, times, computed, fresh, _ = _wall_clock_run("classical", time, {10: 2.5})
    tau = loop.log.arrays["tau_motor"]
    assert list(np.flatnonzero(times.missed)) == [11, 12]
    assert times.latency[10] == pytest.approx(2.5e-3) and np.isinf(times.latency[11:13]).all()
    assert np.array_equal(tau[9], computed[9].motor_torque)  # on time: applied at once
    assert np.array_equal(tau[10], tau[9]) and np.array_equal(tau[11], tau[9])
    assert not np.array_equal(computed[10].motor_torque, tau[9])
    assert np.array_equal(tau[12], computed[10].motor_torque)  # delivered at last
    assert np.array_equal(tau[13], computed[13].motor_torque)
    assert sorted(computed) == [k for k in range(STEPS) if k not in (11, 12)]
    # a missed cycle keeps the newest desired torque and mode; the sensors sample on
    desired = loop.log.arrays["tau_desired"]
    assert np.array_equal(desired[11], computed[10].desired_torque)
    assert np.array_equal(desired[12], computed[10].desired_torque)
    assert fresh[9] and not any(fresh[10:13]) and all(fresh[13:])
    assert np.all(np.isfinite(loop.log.arrays["force_measured"]))


def test_the_command_inbox_applies_each_command_one_mpc_period_after_its_tick():
    """The real-time MPC stage's transport (``realtime.CommandInbox``): a command is taken when
    it arrives and handed to the low level one MPC period after the tick it was solved from,
    never earlier (the fixed latency); a duplicate, a stamp from the future and an implausible
    torque are rejected, each with its kind, and change nothing."""
    from types import SimpleNamespace

    from ffmpc_ros.command_msg import command_message
    from ffmpc_ros.realtime import CommandInbox, real_time_pid_settings
    from ffmpc_ros.time_grid import cycle_at, stamp_at, stamp_ns

    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    robot = scenario_robot(scenario)
    low = lowlevel_controller(real_time_pid_settings(scenario), robot)
    names = list(robot.joint_names)

    def message(tick: int, torque_scale: float = 1.0):
        command = SimpleNamespace(
            torque=torque_scale * robot.gravity(robot.q_nominal),
            state=np.concatenate([robot.q_nominal, np.zeros(robot.nv)]),
            feedback_gain=np.zeros((robot.nv, 2 * robot.nv)),
            iterations=1,
            kkt=0.0,
            solve_time=4e-4,
            converged=True,
        )
        return command_message(stamp_at(tick, 1_000_000), "classical", names, tick, command)

    arriving = {1: [message(0)], 2: [message(2), message(0), message(9)], 3: [message(4, 1e3)]}
    queue: list = []
    rejected: list[str] = []
    inbox = CommandInbox(
        lambda: queue.pop(0) if queue else None,
        low,
        lambda stamp: cycle_at(stamp_ns(stamp), 1_000_000),
        lambda kind, _message: rejected.append(kind),
        steps=20,
        every=2,
        time_step=1e-3,
        topic="/mpc/command",
    )
    used = {}
    for k in range(6):
        queue.extend(arriving.get(k, []))
        inbox.sent(k)
        inbox.take(k)
        inbox.release(k)
        used[k] = low.command_time
    assert list(inbox.arrival[:5]) == [1, -1, 2, -1, -1]
    assert used == {0: -np.inf, 1: -np.inf, 2: 0.0, 3: 0.0, 4: 2e-3, 5: 2e-3}
    assert rejected == ["/mpc/command:stamp", "/mpc/command:stamp", "/mpc/command:value"]
    assert inbox.solve_times == [4e-4, 4e-4]
