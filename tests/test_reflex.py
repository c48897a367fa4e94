"""The robots' data sheets and the reflex model (``ffmpc_core.datasheet``, ``ffmpc_core.reflex``):
the tables and their use by ``RobotModel``; every limit kind driven through a stop within one
cycle, the run marked; the communication reflex after its stated time; the stop (brake, then
hold) dissipative and at rest; a reflex that is off records the raw excess and stops nothing;
the ROS-free runner's plant stepped through the reflex (``run_scenario`` and the polishing run).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from ffmpc_core.datasheet import IIWA14_R820, PANDA, DataSheet, datasheet
from ffmpc_core.errors import ConfigError
from ffmpc_core.reflex import ReflexConfig, ReflexPlant, RobotReflex, reflex_plant
from ffmpc_core.robots import load_robot, mass_matrix
from ffmpc_core.runner import LockstepClock, run_scenario

DT = 1e-3


@pytest.fixture(scope="module")
def panda():
    return load_robot("panda")


def _pybullet(robot):
    from sim_bridge.plant import Plant, PlantConfig

    plant = Plant(robot, PlantConfig(table=None))
    plant.reset(robot.q_nominal)
    return plant


def _sheet(robot, **changes) -> DataSheet:
    """The robot's data sheet with ``changes`` (e.g. a narrower range, another ``stops``)."""
    return replace(robot.datasheet, **changes)


def _drive(stepped: ReflexPlant, command, steps: int = 2000) -> int:
    """Step ``command(state)`` until the robot stopped itself; the number of steps taken."""
    for k in range(steps):
        if stepped.stopped:
            return k
        stepped.step(command(stepped.state()))
    return steps


def _energy(robot, data, state) -> float:
    return 0.5 * float(state.v @ mass_matrix(robot.model, data, state.q) @ state.v)


# -- the data sheets -----------------------------------------------------------------------------
def test_the_iiwa_is_the_lbr_iiwa_14_r820_of_its_data_sheet(robot):
    sheet = datasheet("iiwa")
    assert sheet is IIWA14_R820 and robot.datasheet is sheet
    np.testing.assert_allclose(
        np.rad2deg(sheet.position_upper), [170, 120, 170, 120, 170, 120, 175], rtol=1e-12
    )
    np.testing.assert_allclose(sheet.position_lower, -sheet.position_upper)
    np.testing.assert_allclose(np.rad2deg(sheet.velocity), [85, 85, 100, 75, 130, 135, 135])
    np.testing.assert_array_equal(sheet.torque, [320, 320, 176, 176, 110, 40, 40])
    assert sheet.acceleration is None and sheet.torque_rate is None
    assert sheet.stops == {"position", "velocity"}
    # RobotModel's limits and its pinocchio model's are the data sheet's
    np.testing.assert_array_equal(robot.torque_limit, sheet.torque)
    np.testing.assert_array_equal(robot.velocity_limit, sheet.velocity)
    np.testing.assert_array_equal(robot.position_lower, sheet.position_lower)
    np.testing.assert_array_equal(robot.model.effortLimit, sheet.torque)
    np.testing.assert_array_equal(robot.model.upperPositionLimit, sheet.position_upper)
    # the URDF (pybullet_data kuka_iiwa) has the same joint ranges
    import pinocchio as pin

    urdf = pin.buildModelFromUrdf(robot.urdf_path)
    np.testing.assert_allclose(urdf.upperPositionLimit, sheet.position_upper, atol=1e-9)


def test_the_panda_data_sheet_is_franka_s_and_its_urdf_agrees(panda):
    import example_robot_data as erd

    sheet = datasheet("panda")
    assert sheet is PANDA and panda.datasheet is sheet
    urdf = erd.load("panda").model  # example-robot-data: 7 arm joints, then the fingers
    np.testing.assert_array_equal(sheet.position_lower, urdf.lowerPositionLimit[:7])
    np.testing.assert_array_equal(sheet.position_upper, urdf.upperPositionLimit[:7])
    np.testing.assert_array_equal(sheet.velocity, urdf.velocityLimit[:7])
    np.testing.assert_array_equal(sheet.torque, urdf.effortLimit[:7])
    np.testing.assert_array_equal(sheet.acceleration, [15, 7.5, 10, 12.5, 15, 20, 20])
    np.testing.assert_array_equal(sheet.jerk, [7500, 3750, 5000, 6250, 7500, 10000, 10000])
    np.testing.assert_array_equal(sheet.torque_rate, np.full(7, 1000.0))
    assert sheet.stops == {"position", "velocity"} and sheet.command_timeout == 0.02
    rows = sheet.table()
    assert [r[0].split(" ")[0] for r in rows] == [
        "position",
        "velocity",
        "acceleration",
        "jerk",
        "torque",
        "torque_rate",
        "commands",
    ]
    assert all(r[3] for r in rows)  # every row cites its source


def test_a_data_sheet_refuses_what_it_cannot_be(robot):
    with pytest.raises(ConfigError, match="no torque_rate limit"):
        _sheet(robot, stops=frozenset({"torque_rate"}))
    with pytest.raises(ConfigError, match="unknown kinds"):
        _sheet(robot, stops=frozenset({"jerk"}))
    with pytest.raises(ConfigError, match="> 0"):
        _sheet(robot, velocity=np.zeros(7))
    with pytest.raises(ConfigError, match="no data sheet"):
        datasheet("ur5")


# -- each limit kind: a stop within one cycle, the run marked -------------------------------------
def _stop_case(robot, kind: str):
    """(data sheet that stops on ``kind``, command(state) that drives the robot over it)."""
    g = robot.gravity
    if kind == "position":  # joint 4 pushed into a range narrowed to q_nominal + 0.01 rad
        upper = robot.datasheet.position_upper.copy()
        upper[3] = robot.q_nominal[3] + 0.01
        sheet = _sheet(robot, position_upper=upper)
        return sheet, lambda s: g(s.q) + np.array([0, 0, 0, 10.0, 0, 0, 0])
    if kind == "velocity":
        return _sheet(robot), lambda s: g(s.q) + np.array([0, 0, 0, 60.0, 0, 0, 0])
    if kind == "acceleration":  # 5 rad/s² on every joint, and a 60 N·m push on joint 4
        sheet = _sheet(robot, acceleration=np.full(7, 5.0), stops=frozenset({"acceleration"}))
        return sheet, lambda s: g(s.q) + np.array([0, 0, 0, 60.0, 0, 0, 0])
    if kind == "torque":  # joint 2 asked for 1.2× its limit after 10 steps of gravity
        sheet = _sheet(robot, stops=frozenset({"torque"}))
        count = iter(range(10**6))

        def torque(s):
            tau = g(s.q)
            if next(count) >= 10:
                tau[1] = 1.2 * robot.torque_limit[1]
            return tau

        return sheet, torque
    if kind == "torque_rate":  # 1000 N·m/s on every joint; a 2 N·m step on joint 1 at step 10
        sheet = _sheet(robot, torque_rate=np.full(7, 1000.0), stops=frozenset({"torque_rate"}))
        count = iter(range(10**6))
        return sheet, lambda s: g(s.q) + (next(count) >= 10) * np.array([2.0, 0, 0, 0, 0, 0, 0])
    raise AssertionError(kind)


@pytest.mark.parametrize("kind", ["position", "velocity", "acceleration", "torque", "torque_rate"])
def test_a_plant_driven_over_a_limit_stops_within_one_cycle_and_the_run_is_marked(robot, kind):
    sheet, command = _stop_case(robot, kind)
    with _pybullet(robot) as plant:
        stepped = ReflexPlant(plant, RobotReflex(robot, DT, sheet=sheet))
        steps = _drive(stepped, command)
        event = stepped.reflex.event
        assert event is not None and event.kind == kind and event.stopped and stepped.stopped
        assert event.ratio > 1.0 and abs(event.value) > abs(event.limit) or kind == "position"
        assert event.t == pytest.approx(steps * DT)  # the sample of the step that crossed
        assert event.joint is not None and event.joint_name == robot.joint_names[event.joint]
        if kind == "position":
            assert event.joint == 3 and event.value > event.limit == sheet.position_upper[3]
        report = stepped.reflex.report()
        assert report["aborted"] and report["event"]["kind"] == kind
        assert kind in report["crossings"]
        # From the very next step the command is ignored: the drives brake, whatever is asked
        # (the kinetic energy only decreases; at rest, the hold's µJ exchanges aside).
        data = robot.create_data()
        energy = [_energy(robot, data, stepped.state())]
        for _ in range(300):
            stepped.step(command(stepped.state()) + 50.0)  # a command that would accelerate
            energy.append(_energy(robot, data, stepped.state()))
        assert energy[1] < energy[0] and np.max(np.diff(energy)) < 1e-6, np.max(np.diff(energy))
        assert (
            stepped.reflex.stop_cycles == 300 and report["event"] == stepped.reflex.event.to_dict()
        )


def test_the_communication_reflex_stops_the_robot_after_its_stated_time(robot):
    """Commands missing (``fresh=False``: the drives hold the newest one) for the data sheet's
    20 ms: the 21st step without a command is the first under the stop."""
    with _pybullet(robot) as plant:
        stepped = reflex_plant(plant, robot)
        assert stepped.reflex.command_timeout == IIWA14_R820.command_timeout == 0.02
        held = robot.gravity(robot.q_nominal)
        for _ in range(5):
            stepped.step(held)
        for k in range(20):
            stepped.step(held, fresh=False)
            assert not stepped.stopped, k
        stepped.step(held, fresh=False)
        event = stepped.reflex.event
        assert stepped.stopped and event is not None and event.kind == "communication"
        assert event.joint is None and event.value == pytest.approx(0.021)
        assert event.t == pytest.approx(0.025) and event.ratio == pytest.approx(1.05)
        assert stepped.reflex.stop_cycles == 1
        stepped.step(held)  # a command that comes back does not restart the robot
        assert stepped.stopped and stepped.reflex.stop_cycles == 2
    # a stated timeout of the run's config replaces the data sheet's
    with _pybullet(robot) as plant:
        stepped = reflex_plant(plant, robot, config=ReflexConfig(command_timeout=0.005))
        for _ in range(6):
            stepped.step(robot.gravity(robot.q_nominal), fresh=False)
        assert stepped.stopped and stepped.reflex.event.kind == "communication"


def test_the_stop_brakes_to_rest_and_holds_without_ever_adding_energy(robot, panda):
    """From 0.9× every velocity limit (alternating signs), commands ignored: the kinetic energy
    never increases (per-joint saturated brake), the robot comes to rest and the drives hold
    the posture they latched. On both robots (the Panda from the impact start pose, where a
    brake on the diagonal of M diverged)."""
    from ffmpc_core.impact.scenario import ImpactStudyConfig, start_pose
    from sim_bridge.plant import Plant, PlantConfig
    from sim_bridge.scenes import impact_plant_config

    cfg = ImpactStudyConfig()
    for model, config, q0 in (
        (robot, PlantConfig(table=None), robot.q_nominal),
        (panda, impact_plant_config(cfg), start_pose(cfg, panda)),
    ):
        with Plant(model, config) as plant:
            plant.reset(q0, 0.9 * model.velocity_limit * np.array([1, -1, 1, -1, 1, -1, 1]))
            stepped = reflex_plant(plant, model, config=ReflexConfig(command_timeout=1e-3))
            data = model.create_data()
            energy = []
            for _ in range(3000):
                stepped.step(np.zeros(7), fresh=False)  # no command at all: the stop at once
                energy.append(_energy(model, data, stepped.state()))
            assert stepped.reflex.event.kind == "communication"
            assert np.max(np.diff(energy)) < 1e-6, (model.name, np.max(np.diff(energy)))
            held = stepped.reflex.hold_posture
            assert held is not None, model.name
            np.testing.assert_allclose(stepped.state().q, held, atol=5e-3)
            assert np.max(np.abs(stepped.state().v)) < 1e-2
            assert np.all(np.abs(plant.state().tau) <= model.torque_limit + 1e-9)


def test_the_drives_saturate_a_torque_and_the_panda_reports_its_torque_rate(robot, panda):
    """The default data sheets: a torque over the limit is saturated and reported, not a stop;
    the Panda's τ̇ (libfranka's necessary condition, rate-limited by libfranka ≤ 0.9 itself) is
    reported with its first crossing, not a stop."""
    with _pybullet(robot) as plant:
        stepped = reflex_plant(plant, robot)
        tau = robot.gravity(robot.q_nominal)
        tau[1] = 1.2 * robot.torque_limit[1]
        stepped.step(tau)
        assert not stepped.stopped and stepped.reflex.event is None
        assert plant.state().tau[1] == robot.torque_limit[1]  # saturated by the drives
        assert stepped.reflex.max_ratio["torque"][1] == pytest.approx(1.2)
        assert stepped.reflex.report()["crossings"]["torque"]["joint"] == 1
    from sim_bridge.plant import Plant, PlantConfig

    with Plant(panda, PlantConfig(table=None)) as plant:
        plant.reset(panda.q_nominal)
        stepped = reflex_plant(plant, panda)
        g = panda.gravity(panda.q_nominal)
        stepped.step(g)
        stepped.step(g + np.array([0, 3.0, 0, 0, 0, 0, 0]))  # 3000 N·m/s
        assert not stepped.stopped
        crossing = stepped.reflex.report()["crossings"]["torque_rate"]
        assert crossing["joint"] == 1 and crossing["ratio"] == pytest.approx(3.0)
        assert crossing["t"] == pytest.approx(2 * DT)


def test_with_the_reflex_off_nothing_stops_and_the_raw_excess_is_reported(robot):
    command = _stop_case(robot, "velocity")[1]
    with _pybullet(robot) as plant:
        stepped = reflex_plant(plant, robot, enabled=False)
        for _ in range(60):
            stepped.step(command(stepped.state()))
        event = stepped.reflex.event
        assert event is not None and event.kind == "velocity" and not event.stopped
        assert not stepped.stopped and stepped.reflex.stop_cycles == 0
        assert "reflex off" in event.describe()
        peak = stepped.reflex.max_ratio["velocity"][3]
        assert peak > 2.0 * event.ratio  # the joint went on accelerating well past the limit
        report = stepped.reflex.report()
        assert not report["aborted"] and not report["enabled"] and report["event"] is not None


def test_the_stop_s_gains_keep_their_loops_from_overshooting_at_the_plant_s_step(robot):
    """Δt·gain·n < 1: at 1 kHz the configured brake (140 s⁻¹) and hold (5 Hz); at 2 ms the brake
    is halved to 70 s⁻¹ (the hold's 2ω = 63 s⁻¹ stays under its bound of 70 s⁻¹)."""
    fast = RobotReflex(robot, 1e-3)
    assert fast.brake_rate == pytest.approx(140.0) and fast._omega == pytest.approx(2 * np.pi * 5)
    slow = RobotReflex(robot, 2e-3)
    assert slow.brake_rate == pytest.approx(0.98 / (7 * 2e-3)) == pytest.approx(70.0)
    assert 2 * slow._omega * 2e-3 * 7 <= 0.98
    slower = RobotReflex(robot, 5e-3)
    assert slower.brake_rate * 5e-3 * 7 == pytest.approx(0.98)
    assert 2 * slower._omega * 5e-3 * 7 == pytest.approx(0.98)


def test_the_reflex_refuses_a_plant_of_another_time_step(robot):
    from sim_bridge.plant import Plant, PlantConfig

    with Plant(robot, PlantConfig(table=None, time_step=2e-3)) as plant:
        with pytest.raises(ConfigError, match="time step"):
            ReflexPlant(plant, RobotReflex(robot, DT))
    with pytest.raises(ConfigError):
        ReflexConfig(command_timeout=0.0)


# -- the ROS-free runner -----------------------------------------------------------------------
class _Push:
    """A scenario of ``run_scenario``: the plant's true state in, gravity + 60 N·m on joint 4
    out; logs every cycle (what the plant reflex did is in its report)."""

    def __init__(self, robot) -> None:
        self.robot, self.states, self.inputs = robot, [], []

    def measure(self, k, t, state):
        self.states.append(state)
        return state

    def actuate(self, k, t, state, command):
        return command

    def record(self, k, t, state, measurement, command, joint_input):
        self.inputs.append(joint_input)


class _Controller:
    def __init__(self, robot) -> None:
        self.robot = robot

    def reset(self) -> None:
        pass

    def step(self, state, t):
        return self.robot.gravity(state.q) + np.array([0, 0, 0, 60.0, 0, 0, 0])


def test_run_scenario_steps_the_plant_through_the_reflex_to_the_end_of_the_run(robot):
    """The runner's closed loop on a reflex plant: the loop runs to the end of its clock (as the
    node graph does), the controller's commands go on, and from the cycle after the crossing
    the robot brakes instead."""
    scenario = _Push(robot)
    with _pybullet(robot) as plant:
        stepped = reflex_plant(plant, robot)
        cycles = run_scenario(scenario, stepped, [_Controller(robot)], LockstepClock(DT, 300))
        event = stepped.reflex.event
    assert cycles == 300 and len(scenario.inputs) == 300
    assert event is not None and event.kind == "velocity" and event.joint == 3
    k = int(round(event.t / DT))  # the state of cycle k crossed; cycle k's step is the stop's
    v4 = [abs(s.v[3]) for s in scenario.states]
    assert v4[k] > robot.velocity_limit[3] > v4[k - 1]
    assert v4[k + 1] < v4[k] and v4[-1] < 0.01  # braked from the next cycle on, to rest
    assert stepped.reflex.stop_cycles == 300 - k


def test_a_polishing_run_over_a_limit_is_aborted_and_says_where(robot):
    """A 100 N push on the tool for 50 ms: joint A5 passes its velocity limit 2 ms after the push
    starts; the run is aborted (the robot at rest at its end); with ``plant.reflex: false`` the
    same run goes on, reports the raw excess and would have been aborted at the same sample."""
    from ffmpc_core.scenario import load_scenario
    from studies.polishing import run_polishing

    push = {
        "plant.push_enabled": True,
        "plant.push_time": 0.05,
        "plant.push_force": (0.0, 100.0, 0.0),
        "plant.push_duration": 0.05,
    }
    on = run_polishing(load_scenario("polishing", push), duration=0.4)
    off = run_polishing(load_scenario("polishing", {**push, "plant.reflex": False}), duration=0.4)
    assert on.aborted and not off.aborted
    summary = on.summary()
    assert summary["aborted"] and summary["reflex"]["event"]["kind"] == "velocity"
    event = on.reflex["event"]
    assert event["joint"] == 4 and event["t"] == pytest.approx(0.052) and event["ratio"] > 1.0
    assert off.reflex["event"] == {
        **event,
        "stopped": False,
        "message": off.reflex["event"]["message"],
    }
    assert np.max(np.abs(on.safety_log["v"][-1])) < 0.05  # at rest under the robot's stop
    assert np.max(np.abs(off.safety_log["v"][-1])) > 0.1  # the controllers still catching up
    assert on.reflex["stop_time_s"] == pytest.approx(0.4 - 0.052, abs=1.5e-3)
    # before the crossing both runs are the same run
    k = int(round(event["t"] / DT))
    np.testing.assert_array_equal(on.safety_log["v"][: k + 1], off.safety_log["v"][: k + 1])


# -- how the studies report it ---------------------------------------------------------------
def test_the_study_helpers_count_and_describe_aborted_runs():
    from studies.paper import _aborted_lines
    from studies.reflexes import aborted_count, reflex_cell, reflex_note, reflexes_enabled

    event = {"kind": "velocity", "joint": 3, "t": 0.634, "stopped": True, "message": "velocity ..."}
    on = {"enabled": True, "aborted": True, "event": event}
    off = {"enabled": False, "aborted": False, "event": {**event, "stopped": False}}
    clean = {"enabled": True, "aborted": False, "event": None}
    assert aborted_count([on, clean, None, {}]) == 1
    assert reflexes_enabled([on, clean]) is True and reflexes_enabled([off]) is False
    assert reflexes_enabled([on, off]) is None and reflexes_enabled([None]) is None
    assert reflex_cell(on) == "aborted: velocity joint 4 at 0.634 s"
    assert reflex_cell(off) == "would abort: velocity joint 4 at 0.634 s"
    assert reflex_cell(clean) == "—" and reflex_cell(None) == "—"
    comm = {**on, "event": {**event, "kind": "communication", "joint": None}}
    assert reflex_cell(comm) == "aborted: communication at 0.634 s"
    assert reflex_note([on, clean]).endswith("1 of 2 runs.")
    assert reflex_note([off, off]).startswith(
        "Reflexes OFF"
    ) and "2 of 2 runs would" in reflex_note([off, off])
    assert "(reflexes on in some runs only)" in reflex_note([on, off])
    runs = [
        (
            "Experiment 1",
            {"formulation": "classical", "pid_enabled": True, "seed": 3, "reflex": on},
        ),
        (
            "Experiment 1",
            {"formulation": "classical", "pid_enabled": True, "seed": 4, "reflex": clean},
        ),
    ]
    lines = _aborted_lines(runs)
    assert "- Experiment 1: Classical, PID on, seed 3: velocity ..." in lines
    assert not any("seed 4" in line for line in lines)
