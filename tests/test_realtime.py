"""Real-time mode (ffmpc_ros.realtime) and ``ffmpc run --json``.

The statistics are checked on hand-made per-cycle records (deadline counting, fallback time and
fault windows, the failure rule); ``ffmpc run --json`` is checked on a short lockstep run (its
metrics equal the ROS-free runner's, every deadline met, no fallback) and on a ≈1 s real-time
run, where only the structure and the consistency of the statistics are asserted: the deadline
fraction depends on the machine's load and belongs to a printed measurement, not a test.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from ffmpc_core.errors import InputError
from ffmpc_core.lowlevel import LowLevelCommand, LowLevelMeasurement, LowLevelMode
from ffmpc_core.polishing import lowlevel_controller, steps_per_mpc_period
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_ros.cli import main
from ffmpc_ros.realtime import (
    fallback_time,
    real_time_pid_settings,
    timing_failures,
    timing_report,
)
from studies.polishing import run_polishing

TIMING_KEYS = (
    "deadline_met_fraction",
    "fallback_time_s",
    "latency_p50_ms",
    "latency_p99_ms",
    "latency_max_ms",
)
FALLBACK, TRACK = int(LowLevelMode.FALLBACK), int(LowLevelMode.TRACK)


def test_fallback_time_counts_cycles_and_excuses_fault_windows():
    modes = np.full(100, TRACK)
    modes[10:20] = FALLBACK  # t = 0.010 ... 0.019 s
    modes[50:55] = FALLBACK  # t = 0.050 ... 0.054 s
    assert fallback_time(modes, 1e-3) == pytest.approx((0.015, 0.0))
    assert fallback_time(modes, 1e-3, [(0.049, 0.060)]) == pytest.approx((0.010, 0.005))
    assert fallback_time(modes, 1e-3, [(0.0, 1.0)]) == pytest.approx((0.0, 0.015))
    with pytest.raises(InputError):
        fallback_time(modes, 1e-3, [(0.5, 0.1)])


def _real_time_modes(skipped_ticks: set[int], cycles: int = 40) -> dict[int, LowLevelMode]:
    """Modes of the real-time loop's low-level controller when the MPC solves every tick but
    ``skipped_ticks`` (cycles) and each command is applied ``every`` cycles after its tick,
    stamped with its tick's time (as ``realtime.CommandInbox.release`` does)."""
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    robot = load_robot(scenario.robot)
    settings = real_time_pid_settings(scenario)
    every, dt = steps_per_mpc_period(scenario), scenario.plant.time_step
    low = lowlevel_controller(settings, robot)
    nx = 2 * robot.nv
    command = LowLevelCommand(
        robot.gravity(robot.q_nominal),
        np.concatenate([robot.q_nominal, np.zeros(robot.nv)]),
        np.zeros((robot.nv, nx)),
    )
    meas = LowLevelMeasurement(robot.q_nominal, np.zeros(robot.nv), np.zeros(robot.nv))
    modes = {}
    for k in range(cycles):
        tick = k - every
        if tick >= 0 and tick % every == 0 and tick not in skipped_ticks:
            low.set_command(command, tick * dt)
        modes[k] = low.step(meas, k * dt).mode
    return modes


def test_real_time_stale_timeout_counts_the_fixed_mpc_latency():
    """Commands are applied one MPC period after their tick: the stale timeout counts that
    period, so one missed solve is tolerated as in lockstep, and two give the safe hold."""
    scenario = load_scenario("polishing", {"mpc.formulation": "classical"})
    settings = real_time_pid_settings(scenario)
    every = steps_per_mpc_period(scenario)
    assert every == 2
    assert settings.pid.stale_timeout == pytest.approx(scenario.pid.stale_timeout + 2e-3)
    assert settings.pid.delay_cycles == max(0, scenario.pid.delay_cycles - every)
    used = (LowLevelMode.BLEND, LowLevelMode.TRACK)  # the MPC's command in use
    modes = _real_time_modes(skipped_ticks=set())
    assert all(modes[k] in used for k in range(every, 40))
    one_missed = _real_time_modes(skipped_ticks={20})
    assert all(one_missed[k] in used for k in range(every, 40))
    two_missed = _real_time_modes(skipped_ticks={20, 22})
    # the command of tick 18, used from cycle 20: stale once older than 4 + 2 ms (cycle 25);
    # tick 24's command, applied at cycle 26, ends the hold
    assert all(two_missed[k] in used for k in range(every, 25))
    assert two_missed[25] == LowLevelMode.FALLBACK and two_missed[26] in used


def _report(latency, arrival, modes=None, windows=()):
    n = latency.size
    return timing_report(
        time_step=1e-3,
        every=2,
        cycle_latency=latency,
        modes=np.full(n, TRACK) if modes is None else modes,
        command_arrival=arrival,
        command_latency=np.where(arrival >= 0, 1.5e-3, np.nan),
        solve_times=np.full(3, 5e-4),
        fault_windows=windows,
    )


def test_deadlines_are_counted_as_defined():
    """Loop: cycle latency ≤ Δt. MPC: the command of tick k taken by cycle k + 2 (every = 2);
    the last tick, whose deadline falls after the run, is not counted."""
    latency = np.full(10, 0.5e-3)
    latency[3] = 1.2e-3  # late
    latency[4] = 1.0e-3  # exactly on time
    arrival = np.full(10, -1)
    arrival[0], arrival[2], arrival[4], arrival[6] = 2, 5, 6, 9  # ticks 0..6 (8: after the run)
    report = _report(latency, arrival)
    assert report["loop"]["deadlines_met"] == 9 and report["loop"]["cycles"] == 10
    assert report["deadline_met_fraction"]["loop"] == pytest.approx(0.9)
    assert report["mpc"]["ticks"] == 4 and report["mpc"]["solved"] == 4
    assert report["mpc"]["deadlines_met"] == 2  # tick 2 arrived at 5, tick 6 at 9
    assert report["deadline_met_fraction"]["mpc"] == pytest.approx(0.5)
    assert report["latency_max_ms"] == pytest.approx(1.2)
    assert report["latency_p50_ms"] == pytest.approx(0.5)
    assert report["fallback_time_s"] == 0.0
    failures = timing_failures(report)
    assert len(failures) == 2 and "mpc" in failures[0] and "loop" in failures[1]
    # the machine's share: the late cycle 3 inside a fault window is the fault's
    assert report["loop"]["deadline_met_fraction_outside_faults"] == pytest.approx(0.9)
    in_window = _report(latency, arrival, windows=[(0.003, 0.004)])
    assert in_window["loop"]["deadline_met_fraction_outside_faults"] == 1.0
    assert in_window["loop"]["deadline_met_fraction"] == pytest.approx(0.9)  # unchanged
    everything = _report(latency, arrival, windows=[(0.0, 1.0)])
    assert everything["loop"]["deadline_met_fraction_outside_faults"] is None


def test_a_run_fails_on_fallback_outside_fault_windows_only():
    latency = np.full(20, 0.5e-3)
    arrival = np.where(np.arange(20) % 2 == 0, np.arange(20) + 2, -1)
    modes = np.full(20, TRACK)
    modes[8:12] = FALLBACK
    assert timing_failures(_report(latency, arrival)) == []
    failing = _report(latency, arrival, modes)
    assert failing["fallback_time_s"] == pytest.approx(0.004)
    assert timing_failures(failing) == ["0.004 s in fallback outside fault windows"]
    excused = _report(latency, arrival, modes, windows=[(0.008, 0.011)])
    assert excused["fallback_time_s"] == 0.0
    assert excused["fallback_excused_s"] == pytest.approx(0.004)
    assert timing_failures(excused) == []


def test_lockstep_run_json_has_the_runner_metrics_and_every_deadline(tmp_path):
    path = tmp_path / "run.json"
    args = ["run", "polishing", "--duration", "0.1", "--single-process", "--seed", "3"]
    args += ["--set", "mpc.formulation=classical", "--json", str(path)]
    assert main(args) == 0
    doc = json.loads(path.read_text())
    runner = run_polishing(
        load_scenario("polishing", {"seed": 3, "mpc.formulation": "classical"}), duration=0.1
    )
    assert doc["mode"] == "lockstep" and doc["seed"] == 3
    assert doc["metrics_true"] == runner.metrics_true.to_dict()
    assert doc["metrics_measured"] == runner.metrics_measured.to_dict()
    assert doc["deadline_met_fraction"] == {"mpc": 1.0, "loop": 1.0}
    assert doc["fallback_time_s"] == 0.0
    assert 0.0 < doc["latency_p50_ms"] <= doc["latency_p99_ms"] <= doc["latency_max_ms"]
    assert doc["timing"]["mode_cycles"]["track"] == 100
    assert doc["command_line"].startswith("ffmpc run polishing")


def test_real_time_run_json_is_consistent(tmp_path):
    """≈1 s on the wall clock: structure and consistency, not a deadline target."""
    path = tmp_path / "rt.json"
    args = ["run", "polishing", "--real-time", "--duration", "1.0"]
    args += ["--set", "mpc.formulation=classical", "--json", str(path), "--timeout", "180"]
    code = main(args)
    doc = json.loads(path.read_text())
    assert doc["mode"] == "real_time" and set(TIMING_KEYS) <= set(doc)
    for name in ("metrics_true", "metrics_measured"):
        assert set(doc[name]) >= {"position_mae_mm", "force_mae", "max_force"}
    timing = doc["timing"]
    loop, mpc = timing["loop"], timing["mpc"]
    assert loop["cycles"] == 1000 and mpc["ticks"] == 499  # the last tick's deadline is t = 1 s
    assert 0 <= mpc["deadlines_met"] <= mpc["solved"] <= mpc["ticks"]
    assert doc["deadline_met_fraction"]["loop"] == pytest.approx(loop["deadlines_met"] / 1000)
    assert doc["deadline_met_fraction"]["mpc"] == pytest.approx(mpc["deadlines_met"] / 499)
    assert 0.0 < doc["latency_p50_ms"] <= doc["latency_p99_ms"] <= doc["latency_max_ms"]
    assert doc["latency_p50_ms"] == loop["latency_p50_ms"]
    assert sum(timing["mode_cycles"].values()) == 1000
    assert doc["fallback_time_s"] == pytest.approx(timing["mode_cycles"]["fallback"] * 1e-3)
    assert mpc["solved"] == 0 or 0.0 < mpc["solve_p50_ms"] <= mpc["solve_max_ms"]
    assert doc["wall_time_s"] >= 0.99  # paced by the wall clock
    # the joint-limit check of lockstep runs holds in real time too
    assert len(doc["max_velocity_ratio"]) == 7 and len(doc["max_torque_ratio"]) == 7
    assert 0.0 < max(doc["max_velocity_ratio"]) and 0.0 < max(doc["max_torque_ratio"])
    assert 0.0 <= doc["max_velocity_ratio_at_s"] < 1.0
    broken = max(doc["max_velocity_ratio"] + doc["max_torque_ratio"]) > 1.0
    assert doc["safe_hold_s"] >= timing["mode_cycles"]["fallback"] * 1e-3
    # the robot's reflexes ran in the loop (a loaded machine's long miss or a joint over its
    # limit would have stopped it: exit 3, ffmpc_ros.cli.EXIT_ABORTED)
    assert doc["reflex"]["enabled"] and doc["aborted"] == doc["reflex"]["aborted"]
    assert code == (3 if doc["aborted"] else 1 if timing_failures(timing) or broken else 0)


def _stalled_run(fault: str, overrides: dict | None = None):
    from ffmpc_ros.bringup import GraphOptions, run_graph

    scenario = load_scenario("polishing", overrides)  # the force-feedback MPC
    return run_graph(
        scenario, GraphOptions(lockstep=False, duration=1.0, faults=[fault], timeout=180.0)
    )


@pytest.mark.xfail(
    reason=(
        "known, open: on a loaded 2-core machine (load average 7-20) this run is stopped by a "
        "reflex before the stall is injected in 6 of 9 runs (communication at 0.02-0.09 s: the "
        "first ticks' commands arrive late; or the wrist's velocity at 0.13 s); the same run "
        "from a script reached the stall in 12 of 13 runs"
    ),
    strict=False,
)
def test_a_stalled_loop_misses_its_cycles_and_the_plant_steps_on_under_the_held_torque():
    """loop-stall@0.5+0.03: the loop thread sleeps 30 ms wall in cycle 500, after publishing its
    measurement. The plant is physical: it does not wait, so its steps 500-529 run under the motor
    torque of cycle 499 (zero-order hold: cycle 500's torque missed their start), cycles ~501-529
    are missed, and the loop resumes on its grid. (Before: the missed cycles ran back to back and
    the MPC fell behind its plant; this stall gave 4.96x a velocity limit.) 30 ms without a
    command is more than the robot tolerates: its communication reflex stops it after 20 ms
    (``ffmpc_core.reflex``), the run is aborted — the safe outcome."""
    result = _stalled_run("loop-stall@0.5+0.03")
    log, timing = result.log, result.timing
    missed = log["missed"]
    # the stall is injected in the first cycle at or after 0.5 s that runs (500 unless a loaded
    # machine made the loop miss cycle 500 itself)
    stalled = 500 + int(np.flatnonzero(~missed[500:])[0])
    assert missed.size == 1000 and missed[stalled + 2 : stalled + 28].all(), np.flatnonzero(missed)
    assert np.isinf(log["cycle_latency"][missed]).all() and log["cycle_latency"][stalled] >= 0.03
    resumed = stalled + 1 + int(np.flatnonzero(~missed[stalled + 1 :])[0])
    held = log["tau_motor"][stalled:resumed]  # the stalled cycle's step and the missed ones
    assert held.shape[0] >= 28
    # one torque held through the stall (zero-order hold): the one last sent before it (which
    # cycle's that is, the stalled cycle's own or an earlier one, depends on the wall-clock
    # timing of the loop and the PID: a fresh-clone run under OPENBLAS_CORETYPE=Haswell held
    # another than cycle stalled - 1's)
    assert np.array_equal(held[:29], np.broadcast_to(held[0], (min(29, len(held)), 7)))
    assert np.all(np.isfinite(held[0]))
    assert timing["loop"]["missed_cycles"] == int(missed.sum()) >= 26
    assert result.wall_time >= 0.99  # paced by the wall clock: the stall did not stretch it
    (record,) = result.safety["faults"]
    t_stall = stalled * 1e-3
    assert record["fault"] == "loop-stall@0.5+0.03"
    assert record["injected_at"] == pytest.approx(t_stall)
    assert record["ended_at"] == pytest.approx(t_stall + 0.03)
    # the injected fault excuses the fallback it causes (its window plus FAULT_RECOVERY)
    assert timing["fault_windows"] == [[0.5, pytest.approx(0.58)]]
    # 30 ms without a command is longer than the robot waits (the data sheet's 20 ms): its
    # communication reflex stopped it — the safe outcome of this fault, as on the real robot
    event = result.safety["reflex"]["event"]
    assert result.aborted and event["kind"] == "communication" and event["stopped"], event
    assert t_stall < event["t"] < t_stall + 0.03


#: Fraction of the loop's cycles outside the fault windows that must meet their deadline for a
#: real-time run to judge the controller (``realtime.MAX_MISSED_FRACTION``'s rule).
TIMELY_FRACTION = 0.99
#: Real-time runs tried before a test that needs a timely one is skipped.
TIMELY_ATTEMPTS = 3


def _timely_stalled_run(fault: str, overrides: dict):
    """A real-time run of ``fault`` on a machine that kept the loop's deadlines outside the fault
    window (up to TIMELY_ATTEMPTS runs), or a skip that says what the machine did. Whether the
    loop keeps a 1 ms period is the machine's doing, not the controller's: on the shared 2-core
    VM the loop's median cycle latency was 0.8–1.4 ms for a while (0.5 ms measured before,
    docs/explanation/ros.md
    "Overruns"), the plant then stepped on under held torques for tens of ms and a joint reached
    1.8× its velocity limit; a fresh-clone .ci/run failed on this test then (joint A3 1.06×)."""
    fractions = []
    for _ in range(TIMELY_ATTEMPTS):
        result = _stalled_run(fault, overrides)
        fractions.append(result.timing["loop"]["deadline_met_fraction_outside_faults"])
        if fractions[-1] >= TIMELY_FRACTION:
            return result
    pytest.skip(
        f"this machine did not keep real time: the loop met {fractions} of its deadlines outside "
        f"the fault window in {TIMELY_ATTEMPTS} runs (< {TIMELY_FRACTION})"
    )


def test_a_stalled_mpc_gives_the_safe_hold_then_the_mpc_takes_over_again():
    """mpc-stall@0.4+0.1: the MPC process is stopped (SIGSTOP) for 100 ms. Its ticks are not
    solved, the loop falls back to the safe hold once its command is older than the stale
    timeout, and tracks again once the MPC is back (SIGCONT): within the limits throughout,
    with the velocity guard of a robot cell on (without it, the force-feedback MPC's chatter on
    the wrist, not the stall, once reached 1.05× joint A5's velocity limit on a CI machine).
    Judged on a run whose loop kept real time outside the stall (``_timely_stalled_run``)."""
    result = _timely_stalled_run("mpc-stall@0.4+0.1", {"pid.velocity_guard": 0.9})
    mode, timing = result.log["mode"], result.timing
    fallback = np.flatnonzero(mode == FALLBACK)
    during = fallback[(fallback >= 400) & (fallback < 520)]
    assert during.size >= 80, fallback  # ~100 ms of hold, from ~6 ms after the stall
    # blended back and tracking: the MPC drives the loop again on most cycles after the stall
    # (not all: on a loaded machine a late command can give a cycle of fallback and a blend)
    assert (mode[520:] == TRACK).any() and np.mean(mode[650:] == TRACK) >= 0.5
    assert timing["fallback_excused_s"] >= 0.08
    assert max(result.safety["max_velocity_ratio"]) < 1.0, result.safety
    assert max(result.safety["max_torque_ratio"]) <= 1.0
    assert result.safety["velocity_guard_trips"] >= 0  # reported (how many: the machine's load)
    assert result.safety["faults"][0]["fault"] == "mpc-stall@0.4+0.1"


def test_lockstep_timing_counts_the_excused_mpc_ticks_not_the_excused_seconds():
    """The lockstep probe's timing: ``excused_mpc_ticks`` counts the MPC ticks inside the fault
    windows (it once counted the excused fallback seconds, a float, as 0 or 1 tick)."""
    from ffmpc_ros.bringup import _PidStatusProbe

    class _NoNode:  # the probe only subscribes to /pid/status; timing() reads its arrays
        def create_subscription(self, *args: object, **kwargs: object) -> None:
            return None

    dt, every = 1e-3, 2
    probe = _PidStatusProbe(_NoNode(), steps=20, time_step=dt)
    probe.mode[:] = TRACK
    probe.mode[8:12] = FALLBACK
    probe.command_age[:] = 0.0
    status = {"deadline_misses": 0, "latency_p50": 1e-4, "latency_p99": 2e-4, "latency_max": 3e-4}
    # ticks 0, 2, ..., 18 at t = 0, 2, ..., 18 ms; the window [7.5, 12.5) ms holds 8, 10 and 12
    timing = probe.timing(every, status, [(0.0075, 0.0125)])
    assert timing["excused_mpc_ticks"] == 3
    assert timing["fallback_excused_s"] == pytest.approx(0.004)
    assert timing["fallback_time_s"] == 0.0
    assert probe.timing(every, status, [])["excused_mpc_ticks"] == 0


def test_a_loop_late_from_its_first_cycle_runs_on(monkeypatch):
    """The loop process reached its first release a whole period late (a loaded machine): cycles
    0-1 are missed, the plant steps on under the start torque, and the loop goes on with its
    observer topics checked (it once read an unset subscriber table there: KeyError 'clock')."""
    import time

    import rclpy
    from rclpy.context import Context

    from ffmpc_ros import realtime, realtime_cycle
    from ffmpc_ros.graph_nodes import graph_parameters

    late = {"first": True}
    sleep_until = realtime_cycle.sleep_until

    def _late_start(deadline: float) -> None:
        if late.pop("first", False):
            deadline += 0.0025  # 2.5 periods past the first release
        sleep_until(deadline)

    monkeypatch.setattr(realtime_cycle, "sleep_until", _late_start)
    params = graph_parameters(load_scenario("polishing"), lockstep=False, duration=0.03)
    context = Context()
    rclpy.init(context=context)
    loop = None
    try:
        loop = realtime.RealtimeLoop(params, context)
        start = time.perf_counter()
        rec = loop.run()
    finally:
        if loop is not None:
            loop.close()
        rclpy.shutdown(context=context)
    assert rec["missed"][:2].all() and not rec["missed"][2:].all()
    assert time.perf_counter() - start >= 0.03
    assert np.all(np.isfinite(rec["v"])) and np.all(rec["mode"] == int(LowLevelMode.HOLD))
