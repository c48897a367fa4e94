"""The parts every node composes, each alone (no ROS graph): the time grid, the input gate and
its throttled log, the diagnostics report, the start barrier's rules, the live parameters."""

from __future__ import annotations

from collections import Counter
from typing import Any

import pytest
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.parameter import Parameter
from std_msgs.msg import Header

from ffmpc_core.errors import InputError
from ffmpc_ros.input_gate import LOG_THROTTLE, MAX_FUTURE_STAMP, InputGate, ThrottledLog
from ffmpc_ros.live_parameters import LiveParameters
from ffmpc_ros.node_diagnostics import NodeDiagnostics
from ffmpc_ros.params import NODE_SPECS, node_scenario_names, scenario_flat
from ffmpc_ros.time_grid import GRID_TOLERANCE_NS, TimeGrid

STEP = 1e-3  # s


class _Clock:
    """Wall or node time that a test moves by hand."""

    def __init__(self, now: float = 0.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


class _Logger:
    def __init__(self) -> None:
        self.lines: list[tuple[str, str]] = []

    def warning(self, text: str) -> None:
        self.lines.append(("warning", text))

    def info(self, text: str) -> None:
        self.lines.append(("info", text))


class _Msg:
    """A stamped message (only its header matters to the gate)."""

    def __init__(self, stamp: TimeMsg, data: Any = None) -> None:
        self.header = Header(stamp=stamp)
        self.data = data


def test_time_grid_maps_stamps_cycles_and_times_both_ways() -> None:
    grid = TimeGrid(STEP)
    assert grid.step_ns == 1_000_000
    for k in (0, 1, 999, 1000, 123_456):
        assert grid.cycle_of(grid.stamp_of(k)) == k
        assert grid.t_of(k) == k * STEP  # the runner's float, bit for bit
        assert grid.cycle_of_time(grid.t_of(k)) == k
    # a driver's stamp off the grid belongs to the newest cycle at or before it ...
    assert grid.cycle_of(TimeMsg(sec=0, nanosec=5_370_000)) == 5
    # ... unless it is less than the tolerance before the next one
    assert grid.cycle_of(TimeMsg(sec=0, nanosec=6_000_000 - GRID_TOLERANCE_NS + 1)) == 6
    assert grid.cycle_of(TimeMsg(sec=-1, nanosec=0)) is None  # no time
    assert grid.cycle_of(TimeMsg(sec=0, nanosec=1_000_000_000)) is None
    assert grid.cycle_of_time(0.0005) is None  # off the grid
    assert grid.cycle_of_time(float("nan")) is None and grid.cycle_of_time(-STEP) is None


def test_throttled_log_writes_one_line_per_kind_per_period() -> None:
    wall, logger = _Clock(), _Logger()
    log = ThrottledLog(lambda: logger, wall)
    assert log.line("a", lambda: "first", warning=True)
    assert not log.line("a", lambda: "second", warning=True)  # throttled
    assert log.line("b", lambda: "other kind", warning=False)
    wall.now = LOG_THROTTLE
    assert log.line("a", lambda: "third", warning=True)
    assert logger.lines == [("warning", "first"), ("info", "other kind"), ("warning", "third")]
    assert log.lines == Counter({"a": 2, "b": 1})

    def broken() -> Any:
        raise RuntimeError("context gone")

    assert ThrottledLog(broken, wall).line("a", lambda: "x", warning=True)  # no crash


def _gate(state: str = "active", now_ns: int = 0, has_time: bool = True, age: float = 0.05):
    logger, node_time = _Logger(), _Clock(now_ns)
    gate = InputGate(
        TimeGrid(STEP),
        ThrottledLog(lambda: logger, _Clock()),
        name_of=lambda topic: topic if topic.startswith("/") else "/" + topic,
        now_ns=lambda: int(node_time.now),
        has_time=lambda: has_time,
        state=lambda: state,
        max_input_age=age,
    )
    return gate, logger, node_time


def test_input_gate_accepts_in_order_and_rejects_each_kind_once_logged() -> None:
    gate, logger, node_time = _gate(now_ns=10 * 1_000_000)
    grid = gate.grid
    parse = lambda msg: float(msg.data)  # noqa: E731
    assert gate.receive("in", _Msg(grid.stamp_of(10), 1.5), parse) == (10, 1.5)
    assert gate.last_cycle("in") == 10 and gate.accepted["/in"] == 1
    assert gate.receive("in", _Msg(grid.stamp_of(10), 2.0), parse) is None  # duplicate
    assert gate.receive("in", _Msg(grid.stamp_of(9), 2.0), parse) is None  # out of order
    ahead = int(round(MAX_FUTURE_STAMP / STEP)) + 11
    assert gate.receive("in", _Msg(grid.stamp_of(ahead), 2.0), parse) is None  # future
    node_time.now = 200 * 1_000_000  # 0.2 s: cycle 100 is 0.1 s old
    assert gate.receive("in", _Msg(grid.stamp_of(100), 2.0), parse) is None  # stale
    assert gate.receive("in", _Msg(TimeMsg(sec=-1), 2.0), parse) is None  # no time

    def bad(msg: _Msg) -> float:
        raise InputError("not finite")

    assert gate.receive("in", _Msg(grid.stamp_of(199), 2.0), bad) is None  # bad value
    assert gate.rejected == Counter(
        {"/in:order": 2, "/in:future": 1, "/in:stale": 1, "/in:stamp": 1, "/in:value": 1}
    )
    assert gate.last_cycle("in") == 10  # nothing rejected was taken
    warnings = [text for level, text in logger.lines if level == "warning"]
    assert len(warnings) == 5  # one line per kind (the second :order throttled)
    assert "rejected /in:value: not finite (1 so far; output kept safe)" in warnings
    assert gate.last_cycle("other") == -1


def test_input_gate_rejects_everything_while_inactive_and_trusts_a_clock_without_time() -> None:
    gate, _, _ = _gate(state="inactive")
    assert gate.check_stamp("in", gate.grid.stamp_of(0)) is None
    assert gate.rejected == Counter({"/in:inactive": 1})
    ahead = int(round(MAX_FUTURE_STAMP / STEP)) + 1
    fresh, _, _ = _gate(now_ns=0, has_time=False)
    assert fresh.check_cycle("in", ahead)  # no /clock yet: cannot tell the future
    started, _, _ = _gate(now_ns=0, has_time=True)
    assert not started.check_cycle("in", ahead)
    assert started.check_cycle("in", 5, ordered=False) and started.check_cycle("in", 4, False)


def test_diagnostics_report_rates_rejections_and_problems() -> None:
    wall = _Clock(0.0)
    accepted, rejected = Counter[str](), Counter[str]()
    problems: list[str] = []
    diag = NodeDiagnostics(
        "/arm1/pid",
        accepted,
        rejected,
        lambda period: {"mode": "track", "period_seen": f"{period:.1f}"},
        lambda: list(problems),
        wall,
    )
    accepted["/in"] += 500
    wall.now = 0.5
    status = diag.status()
    values = {kv.key: kv.value for kv in status.values}
    assert status.level == DiagnosticStatus.OK and status.name == "/arm1/pid"
    assert values["input_rate_hz /in"] == "1000.0" and values["period_seen"] == "0.5"
    rejected["/in:stale"] += 3
    wall.now = 1.5
    status = diag.status()
    assert (
        status.level == DiagnosticStatus.WARN and "3 inputs rejected (/in:stale)" in status.message
    )
    values = {kv.key: kv.value for kv in status.values}
    assert values["rejected_total"] == "3" and values["rejected_in_period"] == "3"
    wall.now = 2.5
    assert diag.status().level == DiagnosticStatus.OK  # none in this period
    problems.append("safe hold")
    assert diag.status().level == DiagnosticStatus.ERROR


class _BarrierNode:
    """What the start barrier asks of a node's graph, answered by the test."""

    def __init__(self) -> None:
        self.subscribers: dict[str, int] = {}
        self.created: list[str] = []

    def resolve_topic_name(self, topic: str) -> str:
        return "/" + topic

    def count_subscribers(self, topic: str) -> int:
        return self.subscribers.get(topic, 0)

    def create_subscription(self, msg_type: Any, topic: str, *args: Any, **kwargs: Any) -> None:
        self.created.append(topic)


class _Writer:
    def __init__(self, readers: int = 0) -> None:
        self.readers = readers

    def get_subscription_count(self) -> int:
        return self.readers


def test_the_plant_starts_once_every_condition_held_for_the_start_delay() -> None:
    from ffmpc_ros import topics
    from ffmpc_ros.start_barrier import StartBarrier

    node, wall = _BarrierNode(), _Clock(0.0)
    params = {
        "start_clock_subscribers": 3 * topics.CLOCK_READERS_PER_NODE,
        "start_subscribers": 2,
        "start_nodes": 3,
        "start_delay": 0.5,
    }
    barrier = StartBarrier(node, params, wall)  # type: ignore[arg-type]
    assert barrier.members == 3
    joints, clock = _Writer(2), _Writer(6)
    assert not barrier.handshake(True, joints, clock)  # no tokens yet  # type: ignore[arg-type]
    node.subscribers["/" + topics.START_READY] = 3
    assert not barrier.handshake(False, joints, clock)  # not active  # type: ignore[arg-type]
    assert not barrier.handshake(True, joints, clock)  # holds from now  # type: ignore[arg-type]
    wall.now = 0.4
    assert not barrier.handshake(True, joints, clock, ready=True)  # type: ignore[arg-type]
    wall.now = 0.6
    assert barrier.handshake(True, joints, clock)  # type: ignore[arg-type]
    joints.readers = 1  # a reader left: the delay starts again
    assert not barrier.handshake(True, joints, clock)  # type: ignore[arg-type]
    # outside a lockstep graph: no barrier, no marker
    alone = StartBarrier(node, {"start_clock_subscribers": 0}, wall)  # type: ignore[arg-type]
    assert alone.members == 0 and alone.writers_matched()
    alone.join()
    assert node.created == []


class _LiveNode:
    """A node's side of the live parameters: its parameters, rules and applications."""

    applies_at = "next cycle"

    def __init__(self, declared: dict[str, Any], read_only: set[str]) -> None:
        self.declared, self.read_only = declared, read_only
        self.applied: list[tuple[dict, int]] = []
        self.logger = _Logger()
        self.callbacks: list[Any] = []

    def get_name(self) -> str:
        return "pid"

    def get_logger(self) -> _Logger:
        return self.logger

    def get_clock(self) -> Any:
        class _Now:
            nanoseconds = 2_000_000

        return type("C", (), {"now": staticmethod(lambda: _Now())})()

    def has_parameter(self, name: str) -> bool:
        return name in self.declared

    def describe_parameter(self, name: str) -> Any:
        return type("D", (), {"read_only": name in self.read_only})()

    def check_live(self, name: str, value: Any) -> str | None:
        return "too soft" if name == "kp" and value == 0.0 else None

    def apply_live(self, changes: dict[str, Any], k: int) -> None:
        self.applied.append((changes, k))

    def add_pre_set_parameters_callback(self, callback: Any) -> None:
        self.callbacks.append(callback)

    add_on_set_parameters_callback = add_pre_set_parameters_callback
    add_post_set_parameters_callback = add_pre_set_parameters_callback


def test_live_parameters_check_type_range_and_rule_then_apply_at_the_next_cycle() -> None:
    from ffmpc_core.scenario import Scenario

    spec = NODE_SPECS["pid"]
    names = node_scenario_names(spec, scenario_flat(Scenario("defaults")))
    assert spec.is_live("kp")
    fixed = next(n for n in names if not spec.is_live(n))
    node = _LiveNode({n: None for n in names} | {"use_sim_time": True}, {fixed})
    live = LiveParameters(node, spec, names, 1)  # type: ignore[arg-type]
    pre, verdict, stage = node.callbacks
    assert live.refusal([Parameter("use_sim_time", value=False)]) is not None
    assert "no such parameter" in str(live.refusal([Parameter("nope", value=1.0)]))
    assert "read-only" in str(live.refusal([Parameter(fixed, value=1.0)]))
    assert "too soft" in str(live.refusal([Parameter("kp", value=0.0)]))
    # ros2 param set sends "1e-1" as text: read as the number it is
    (typed,) = pre([Parameter("kp", value="1e-1")])
    assert typed.value == pytest.approx(0.1)
    assert verdict([typed]).successful
    stage([typed])
    assert live.pending == {"kp": pytest.approx(0.1)}
    assert (
        node.logger.lines[-1][0] == "info"
        and "applies from the next cycle" in (node.logger.lines[-1][1])
    )
    pre([Parameter("kp", value=0.0)])
    assert (
        live.refused == Counter({"kp": 1}) and not verdict([Parameter("kp", value=0.0)]).successful
    )
    live.apply_pending(42)
    live.apply_pending(43)  # nothing pending: nothing applied
    assert node.applied == [({"kp": pytest.approx(0.1)}, 42)]
    assert live.changes == [(42, "kp", pytest.approx(0.1))] and live.pending == {}


def test_every_node_class_creates_its_entities_then_joins_the_graph_last() -> None:
    """No set-up after ``__init__``: each node class passes ``join=False`` to the base and ends
    its own ``__init__`` with ``self.join_graph()`` (its reliable /clock reader and lockstep
    marker must be its last readers: the plant's start counts on them)."""
    import ast
    from pathlib import Path

    import ffmpc_ros

    checked = []
    for path in sorted(Path(ffmpc_ros.__file__).parent.glob("*_node.py")):
        for cls in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(cls, ast.ClassDef):
                continue
            bases = {b.id for b in cls.bases if isinstance(b, ast.Name)}
            if not bases & {"GraphNode", "MeasuredCycleNode"}:
                continue
            init = next(
                f for f in cls.body if isinstance(f, ast.FunctionDef) and f.name == "__init__"
            )
            first = init.body[0].value  # super().__init__(SPEC, join=False, **kwargs)
            assert isinstance(first, ast.Call) and first.func.attr == "__init__", cls.name
            joins = [k for k in first.keywords if k.arg == "join"]
            assert joins and joins[0].value.value is False, cls.name
            last = init.body[-1].value
            assert isinstance(last, ast.Call) and last.func.attr == "join_graph", cls.name
            checked.append(cls.name)
    assert {"MpcNode", "PidNode", "PlantNode", "MetricsNode", "ImpactPlannerNode"} <= set(checked)
