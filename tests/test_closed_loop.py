"""The one closed loop (ffmpc_core.runner.run_scenario): its order, its clock, the zero-order
hold, and that it is the only place where a simulated plant is stepped in the library and the
studies."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from ffmpc_core.errors import ConfigError
from ffmpc_core.runner import LockstepClock, PeriodicController, run_scenario

ROOT = Path(__file__).resolve().parent.parent


class _Plant:
    """A 1-D integrator: x ← x + dt·u; its state is x."""

    def __init__(self, calls: list[str], dt: float = 0.1) -> None:
        self.dt, self.x, self.calls = dt, 0.0, calls

    def reset(self, q: np.ndarray, v: np.ndarray | None = None) -> None:
        self.x = float(q[0])

    def step(self, command: np.ndarray, /) -> None:
        self.calls.append(f"step {float(command[0]):g}")
        self.x += self.dt * float(command[0])

    def state(self) -> float:
        self.calls.append("state")
        return self.x


class _Scenario:
    """Measures x, feeds u = command, stops when the command says so; logs every call."""

    def __init__(self, calls: list[str], stop_at: int | None = None) -> None:
        self.calls, self.stop_at, self.rows = calls, stop_at, []

    def measure(self, k: int, t: float, state: float, /) -> float:
        self.calls.append(f"measure {k}")
        return state

    def actuate(self, k: int, t: float, state: float, command: float, /) -> np.ndarray | None:
        self.calls.append(f"actuate {k}")
        return None if k == self.stop_at else np.array([command])

    def record(self, k, t, state, measurement, command, joint_input, /) -> None:
        self.calls.append(f"record {k}")
        self.rows.append((k, t, state, command, joint_input is None))


class _Gain:
    """u = gain · (target − x): a controller object with reset/step."""

    def __init__(self, calls: list[str], name: str, gain: float, target: float = 0.0) -> None:
        self.calls, self.name, self.gain, self.target = calls, name, gain, target
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1

    def step(self, measurement: float, t: float, /) -> float:
        self.calls.append(f"{self.name} {t:g}")
        return self.gain * (self.target - measurement)


def test_one_cycle_is_state_measure_controllers_in_cascade_actuate_record_step() -> None:
    calls: list[str] = []
    plant, scenario = _Plant(calls), _Scenario(calls)
    plant.reset(np.array([1.0]))
    first, second = _Gain(calls, "outer", 2.0, 3.0), _Gain(calls, "inner", -1.0)
    assert run_scenario(scenario, plant, [first, second], LockstepClock(0.1, 2)) == 2
    assert calls[:7] == [
        "state",
        "measure 0",
        "outer 0",
        "inner 0",
        "actuate 0",
        "record 0",
        # outer: 2·(3 − 1) = 4; inner gets 4 as its measurement: −1·(0 − 4) = 4
        "step 4",
    ]
    # cycle 1 reads x = 1 + 0.1·4 = 1.4: outer 2·(3 − 1.4) = 3.2, inner −1·(0 − 3.2) = 3.2
    assert calls[7:9] == ["state", "measure 1"] and calls[-1] == "step 3.2"
    assert scenario.rows[1][2] == pytest.approx(1.4)


def test_the_scenario_ends_a_run_before_the_plant_moves() -> None:
    calls: list[str] = []
    plant, scenario = _Plant(calls), _Scenario(calls, stop_at=3)
    plant.reset(np.array([0.0]))
    steps = run_scenario(scenario, plant, [_Gain(calls, "c", 1.0, 1.0)], LockstepClock(0.1, 10))
    assert steps == 3
    assert calls.count("record 3") == 1 and calls[-1] == "record 3"
    assert sum(c.startswith("step") for c in calls) == 3
    assert [row[4] for row in scenario.rows] == [False, False, False, True]


def test_the_lockstep_clock_is_k_times_the_step_and_refuses_nonsense() -> None:
    clock = LockstepClock.for_duration(1e-3, 0.01)
    ticks = list(clock)
    assert clock.steps == 10 and ticks[0] == (0, 0.0) and ticks[7] == (7, 7 * 1e-3)
    for bad in (0.0, -1e-3, float("nan")):
        with pytest.raises(ConfigError):
            LockstepClock(bad, 3)
    with pytest.raises(ConfigError):
        LockstepClock(1e-3, -1)
    with pytest.raises(ConfigError, match="at least one controller"):
        run_scenario(_Scenario([]), _Plant([]), [], clock)


def test_a_periodic_controller_holds_its_command_between_its_ticks() -> None:
    calls: list[str] = []
    inner = _Gain(calls, "mpc", 1.0, 10.0)
    held = PeriodicController(inner, 3)
    outputs = [held.step(float(k), 0.1 * k) for k in range(7)]
    assert outputs == [10.0, 10.0, 10.0, 7.0, 7.0, 7.0, 4.0]
    assert calls == ["mpc 0", "mpc 0.3", "mpc 0.6"]
    held.reset()
    assert inner.resets == 1 and held.step(5.0, 1.0) == 5.0  # runs at once after a reset
    with pytest.raises(ConfigError):
        PeriodicController(inner, 0)


def _plant_steps(path: Path) -> list[str]:
    """Functions of a module that call ``<...>plant.step(...)``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for fn in ast.walk(tree):
        if not isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef):
            continue
        for node in ast.walk(fn):
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr == "step"
            ):
                owner = node.func.value
                name = owner.attr if isinstance(owner, ast.Attribute) else getattr(owner, "id", "")
                if name == "plant":
                    found.append(f"{path.relative_to(ROOT)}:{fn.name}")
    return found


def test_run_scenario_is_the_only_closed_loop_of_the_library_and_the_studies() -> None:
    """No function of ffmpc_core, sim_bridge or studies steps a plant but run_scenario (the ROS
    nodes step theirs on messages, one cycle per /clock tick) and the reflex wrapper's own
    ``ReflexPlant.step`` (a plant's step: it steps the plant it wraps once, no loop)."""
    stepping = [
        hit
        for package in ("ffmpc_core", "sim_bridge", "studies")
        for path in sorted((ROOT / package).rglob("*.py"))
        for hit in _plant_steps(path)
    ]
    assert stepping == ["ffmpc_core/reflex.py:step", "ffmpc_core/runner.py:run_cycle"]


def test_the_real_time_loop_steps_its_plant_through_the_cores_cycle_only() -> None:
    """The real-time loop (``ffmpc_ros/realtime*.py``) steps no plant itself: its cycles run
    through ``run_cycle``, whose plant is a wrapper that passes the drives' ``fresh`` flag on
    (``_DrivenPlant.step``: one step of the plant it wraps, no loop)."""
    paths = sorted((ROOT / "ffmpc_ros").glob("realtime*.py"))
    stepping = [hit for path in paths for hit in _plant_steps(path)]
    assert stepping == ["ffmpc_ros/realtime_cycle.py:step"]
