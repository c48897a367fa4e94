"""What every ffmpc node shares: parameters from the scenario, simulated-time stamps, input
validation with one throttled log line per kind of rejection, and the executable's ``main``.

Time. Every stamp of the graph is a plant cycle: t_k = k·``plant.time_step`` (the plant publishes
the state of cycle k with stamp t_k, and everything computed from it carries the same stamp).
Nodes turn a stamp back into the cycle index k and compute t as ``k * time_step``, exactly as
the ROS-free runner does, so both paths hand bit-identical times to the controllers. A stamp
off the grid (a driver's own clock: t_k + 0.37 ms) belongs to the newest cycle at or before it,
t_k ≤ stamp < t_{k+1}, a stamp less than :data:`GRID_TOLERANCE_NS` before t_{k+1} counting as
cycle k + 1 (:func:`cycle_at`); the controllers then take it as the measurement of t_k. Its own
stamp, not t_k, is judged against the node's clock (stale, from the future).

Rejections. A message is rejected when it is malformed (NaN/Inf, wrong length, unknown or
missing joint names, wrong frame_id), stamped with no time (negative, nanosec ≥ 10⁹), of a cycle
not after the last accepted one from the same topic (out of order, duplicate, or a second sample
within one cycle), older than ``max_input_age`` on the node's
simulated clock (stale), or stamped more than :data:`MAX_FUTURE_STAMP` ahead of the node's clock
(from the future: never adopted, so a spoofed or corrupted stamp cannot make every genuine
message look old). A rejected message changes nothing; the node logs one warning per kind of
rejection and per :data:`LOG_THROTTLE` seconds (wall time), and counts every rejection in
:attr:`GraphNode.rejected`.

Fixed at start. Every node runs on the plant's ``/clock``: ``use_sim_time`` is forced true at
construction and a later change is refused with a reason.

Live parameters. The parameters of :attr:`NodeSpec.live <ffmpc_ros.params.NodeSpec.live>` are
writable while the node runs; every other one is read-only. A request is checked before rclpy
applies its descriptors (a pre-set callback): the schema's type and range
(:data:`ffmpc_core.scenario.SCHEMA`, the one declaration), then the node's own rule
(:meth:`GraphNode.check_live`, e.g. a stiffness for a formulation without a soft contact). A
refused request logs ONE warning line and returns ``successful=False`` with the reason (rclpy's
own when the descriptor's range refuses it first, the schema's otherwise); it is counted in
:attr:`GraphNode.refused_parameters`. An accepted one logs one info line and waits in
:attr:`GraphNode.pending_parameters` until the node's next computation: the MPC's next solve, the
PID's next cycle (:meth:`GraphNode.apply_pending`, recorded in :attr:`GraphNode.live_changes`
with the cycle it took effect at). In lockstep that is a well-defined cycle: the first MPC tick
(PID cycle) the node computes after the request was accepted; which tick that is depends on when
the request arrives, and both the accepting log line (the node's clock) and ``live_changes``
(the tick) say it.

Diagnostics. Every node publishes ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, the
topic ``diagnostic_aggregator`` and ``rqt_robot_monitor`` read) every
:data:`DIAGNOSTICS_PERIOD` s of wall time: one status named after the node, with the rate of
each input it accepted over the period (Hz, wall time), its rejections (total and in the
period) and what :meth:`GraphNode.diagnostic_values` adds (the MPC's solve times, the PID's
mode); level WARN when an input was rejected in the period, ERROR for what
:meth:`GraphNode.diagnostic_problems` reports (the PID in its safe hold, a failed solve).

Lifecycle. Every node is a ROS 2 managed node (``rclpy.lifecycle.LifecycleNode``: the services
``<node>/change_state``, ``get_state``, ... that ``ros2 lifecycle`` and launch_ros use). Its
resources (parameters, models, the OCP, publishers, subscriptions) are built at construction,
as ros2/examples do; the states say what the node does with them:

* unconfigured → ``configure`` → inactive: :meth:`GraphNode.configure` checks the node may run
  (a refusal fails the transition with one log line and the node stays unconfigured);
* inactive → ``activate`` → active: the node processes its inputs and publishes (the plant
  starts its first cycle only when active);
* ``deactivate``: back to inactive; ``cleanup``: back to unconfigured; ``shutdown``: finalized,
  the executable exits (:meth:`GraphNode.finished`).

While not active, every stamped input is rejected (kind ``<topic>:inactive``, one throttled
log line) and nothing is computed from it. A node with ``autostart`` true (the default: ``ros2
run``, ``ffmpc launch``, tests) configures and activates itself once constructed, before it
can receive anything; the bring-up of ``ffmpc run`` starts its processes with ``autostart``
false and drives the transitions itself, the plant last (:func:`ffmpc_ros.bringup.run_graph`).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import WrenchStamped
from numpy.typing import ArrayLike
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType, ROSClock
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import QoSCompatibility, QoSPolicyKind, QoSProfile, qos_check_compatible
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions
from rclpy.subscription import Subscription
from rclpy.time_source import TimeSource
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Empty

from ffmpc_core.errors import ConfigError, FfmpcError, InputError
from ffmpc_core.scenario import CONTACT_DIMENSION, SCHEMA, Scenario
from ffmpc_ros import topics
from ffmpc_ros.discovery import check_ros_environment, ensure_local_discovery
from ffmpc_ros.node_results import write_node_results
from ffmpc_ros.params import (
    NODE_SPECS,
    declare_node_parameters,
    node_scenario_names,
    plain_value,
    scenario_flat,
    scenario_from_parameters,
)
from ffmpc_ros.topics import WRENCH_FRAME

#: The QoS policies every ffmpc publisher and subscription lets ROS 2's override parameters set
#: (``qos_overrides.<topic>.<publisher|subscription>.<policy>``): rclpy's defaults (history,
#: depth, reliability, ``QoSOverridingOptions.with_default_policies``) and durability, which
#: a user may set (nothing of the graph is transient local but its latched topics).
_OVERRIDABLE = QoSOverridingOptions(
    [*QoSOverridingOptions.with_default_policies().policy_kinds, QoSPolicyKind.DURABILITY]
)
#: Minimum wall time between two log lines of the same kind of rejection, s.
LOG_THROTTLE = 2.0
#: A stamp less than this before a cycle belongs to that cycle (a driver's clock rounded to the
#: grid), ns; every other stamp belongs to the newest cycle at or before it.
GRID_TOLERANCE_NS = 1000
#: A stamp more than this ahead of the node's clock is rejected (from the future), s. Ten plant
#: cycles: far above the reordering of ``/clock`` and data topics between two processes (at most
#: a cycle or two in lockstep), far below any delay a spoofed stamp could hide behind.
MAX_FUTURE_STAMP = 0.01
#: Start of the line a node executable prints on stderr at exit: its rejections as JSON.
REJECTED_MARKER = "ffmpc-rejected: "
#: Wall time between two /diagnostics reports of a node, s (1 Hz, as diagnostic_updater).
DIAGNOSTICS_PERIOD = 1.0
#: The standard diagnostics topic (absolute: the aggregator listens there).
DIAGNOSTICS_TOPIC = topics.DIAGNOSTICS
#: Wall time between two checks of a node's side of the lockstep start barrier, s.
BARRIER_PERIOD = 0.01


def _ignore(msg: Empty) -> None:
    """The start barrier's token reader takes nothing (nobody publishes ``lockstep/ready``)."""


class _Constructed(type):
    """Metaclass of :class:`GraphNode`: once a node of any subclass is fully constructed (the
    most derived ``__init__`` returned), it

    * subscribes its reliable /clock reader (:meth:`GraphNode._subscribe_clock`), its last
      entity. The start handshake of the lockstep graph rests on it: the plant publishes cycle
      0 only once ``start_clock_subscribers`` /clock readers are matched to it, and a node's
      second reader exists only after its data readers do (an MPC that builds its OCP for
      seconds after its time source subscribed no longer lets the plant start before it reads
      the joint states);
    * in a lockstep graph, subscribes ``lockstep/member``, its membership marker (its very
      last reader), and arms its side of the start barrier (:meth:`GraphNode.writers_matched`);
    * then starts its lifecycle (``_after_construction``: autostart must not run a transition
      on a half-built node)."""

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        # cls is a GraphNode class; mypy types cls.__new__ in a metaclass as type.__new__
        node_class: Any = cls
        node = node_class.__new__(node_class)
        try:
            node.__init__(*args, **kwargs)
            node._subscribe_clock()
            node._join_lockstep()
            node._arm_start_barrier()
            node._after_construction()
        except BaseException:
            # a node refused at construction (a bad parameter or QoS override) leaves the ROS
            # graph now, not when its context ends (a later graph saw it as foreign)
            with contextlib.suppress(Exception):
                node.destroy_node()
            raise
        return node


class GraphNode(LifecycleNode, metaclass=_Constructed):
    """An rclpy managed node that runs part of a scenario (see the module docstring).

    Args:
        spec: key of :data:`ffmpc_ros.params.NODE_SPECS` (also the default node name).
        context: the rclpy context (tests make their own).
        parameter_overrides: parameter values (what ``ffmpc run`` passes); with ``ros2 run``
            they come from ``--params-file``.
        node_name: a different node name.
        cli_args: ROS arguments of this node only (``["--ros-args", "--params-file", f]``).
    """

    joint_names: list[str]  # the robot's joints, in its order (set by nodes that read joints)

    def __init__(
        self,
        spec: str,
        *,
        context: Context | None = None,
        parameter_overrides: Sequence[Parameter] | None = None,
        node_name: str | None = None,
        cli_args: Sequence[str] | None = None,
    ) -> None:
        overrides = [p for p in (parameter_overrides or []) if p.name != "use_sim_time"]
        overrides.append(Parameter("use_sim_time", value=True))
        super().__init__(
            node_name or spec,
            context=context,
            parameter_overrides=overrides,
            cli_args=list(cli_args) if cli_args is not None else None,
        )
        # the writers the lockstep start barrier waits for (create_publisher, writers_matched)
        self._barrier_writers: list[Publisher] = []
        self.start_ready = False  # this node's lockstep/ready reader exists (writers_matched)
        # from here on, every publisher and subscription takes ROS 2's QoS override parameters
        # (rclpy's own, made in Node.__init__, keep rclpy's profiles, as in any rclpy node)
        self._qos_overridable = True
        self.spec = NODE_SPECS[spec]
        self.params = declare_node_parameters(self, self.spec)
        self.lifecycle_state = "unconfigured"  # the state machine's label (module docstring)
        self._refusal: str | None = None  # the last refused configure's reason
        self._start_ready_since: float | None = None  # wall s the start handshake holds since
        self.scenario: Scenario = scenario_from_parameters(self.spec, self.params, self.get_name())
        self.time_step = self.scenario.plant.time_step
        self.step_ns = int(round(self.time_step * 1e9))
        self.rejected: Counter[str] = Counter()
        self._names: dict[str, str] = {}
        self.log_lines: Counter[str] = Counter()
        self._last_log: dict[str, float] = {}
        self._last_cycle: dict[str, int] = {}
        self.max_input_age = float(self.params.get("max_input_age", math.inf))
        self.refused_parameters: Counter[str] = Counter()  # refused requests per parameter
        self.pending_parameters: dict[str, Any] = {}  # accepted, not applied yet {ROS name: value}
        self.live_changes: list[tuple[int, str, Any]] = []  # (cycle applied, ROS name, value)
        self._scenario_names = node_scenario_names(self.spec, scenario_flat(Scenario("defaults")))
        self.add_pre_set_parameters_callback(self._check_parameter_request)
        self.add_on_set_parameters_callback(self._parameter_verdict)
        self.add_post_set_parameters_callback(self._stage_parameters)
        # rclpy's time source reads /clock BEST_EFFORT: a sample reaches a reader only once the
        # reader has matched the plant's writer too, so a node whose side of the match came late
        # judged its first inputs by a clock still at 0 and rejected them as from the future
        # (lockstep never publishes that cycle's /clock again). A RELIABLE reader gets what the
        # writer sent since the writer matched it (resent until acknowledged); it feeds the node's
        # clock through a second TimeSource (public rclpy API).
        self._reliable_time = TimeSource()
        self._reliable_time.ros_time_is_active = True
        clock = self.get_clock()
        assert isinstance(clock, ROSClock)  # a node's clock is always a ROSClock (rclpy Node)
        self._reliable_time.attach_clock(clock)
        # the reliable reader got a /clock sample (the best-effort one moves the clock off 0)
        self._clock_received = False
        # The reliable reader itself is the node's LAST entity (_Constructed, once the subclass's
        # __init__ is done): the plant waits for every node's two /clock readers
        # (``start_clock_subscribers``), so it starts only once every node has all its readers.
        self.accepted: Counter[str] = Counter()  # accepted inputs per topic
        self._diagnosed = (time.monotonic(), Counter[str](), 0)  # (wall s, accepted, rejected)
        self._pub_diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
        self._diagnostics_timer = self.create_timer(
            DIAGNOSTICS_PERIOD,
            self.publish_diagnostics,
            clock=Clock(clock_type=ClockType.STEADY_TIME),
        )

    # -- lifecycle (module docstring) -------------------------------------------------------------
    @property
    def active(self) -> bool:
        """Whether the node is in the lifecycle state ``active`` (it processes its inputs)."""
        return self.lifecycle_state == "active"

    def _after_construction(self) -> None:
        """Autostart (parameter ``autostart``): configure, then activate; a refused configure
        raises ConfigError (the executable exits 2 with that line)."""
        if not self.params.get("autostart", True):
            self.get_logger().info("unconfigured: waiting for the configure transition")
            return
        if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
            raise ConfigError(f"{self.get_name()}: configure refused: {self._refusal}")
        self.trigger_activate()

    def start_handshake(self, joints: Publisher, clock: Publisher, ready: bool = True) -> bool:
        """A plant's start rule (lockstep graphs): True once the node is active (lifecycle:
        the bring-up activates the plant last), ``start_subscribers`` readers are matched to
        its joint-state writer ``joints`` and ``start_clock_subscribers`` to its /clock writer
        ``clock`` (a node's reliable /clock reader is its last entity, ``_Constructed``, so
        the count means every node has all its readers), ``start_nodes`` nodes (the plant
        included) passed the start barrier (:meth:`writers_matched`: every writer of the graph
        is matched to every reader, so the reliable, volatile topics lose nothing from cycle 0
        on, with no replay), ``ready`` holds (the plant's own extra condition), and all of it
        has held for ``start_delay`` wall s. Call it from a timer until it is True."""
        holds = (
            ready
            and self.active
            and joints.get_subscription_count() >= int(self.params["start_subscribers"])
            and clock.get_subscription_count() >= int(self.params["start_clock_subscribers"])
            and self.count_subscribers(self._ready_topic) >= int(self.params["start_nodes"])
        )
        if not holds:
            self._start_ready_since = None
            return False
        if self._start_ready_since is None:
            self._start_ready_since = time.monotonic()
        return time.monotonic() - self._start_ready_since >= float(self.params["start_delay"])

    def destroy_node(self) -> None:
        """Destroy the node and its lifecycle state machine: rclpy's LifecycleNode (7.1.6) leaves
        the state machine, which holds the node's handle, so the node stayed on the ROS graph
        after its context shut down (seen by the next graph of the same process as foreign)."""
        super().destroy_node()
        self._state_machine.destroy_when_not_in_use()

    def configure(self) -> str | None:
        """Why the node may not run (the configure transition then fails), or None. A node
        overrides it to check what must hold before it runs; the base has nothing to check."""
        return None

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._refusal = self.configure()
        if self._refusal is not None:
            self.get_logger().error(f"configure refused: {self._refusal}")
            return TransitionCallbackReturn.FAILURE
        return self._enter("inactive", "configured")

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._enter("active", "active: processing inputs")

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._enter("inactive", "deactivated: inputs are ignored until activate")

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._enter("unconfigured", "cleaned up")

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._enter("finalized", "shut down")

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.get_logger().error(f"lifecycle error in {state.label}")
        return self._enter("unconfigured", "back to unconfigured after an error")

    def _enter(self, label: str, message: str) -> TransitionCallbackReturn:
        self.lifecycle_state = label
        self.get_logger().info(message)
        return TransitionCallbackReturn.SUCCESS

    # -- QoS (ffmpc_ros.topics) -----------------------------------------------------------------
    def create_publisher(
        self, msg_type: Any, topic: str, qos_profile: QoSProfile | int, **kwargs: Any
    ) -> Publisher:
        """rclpy's, with ROS 2's QoS override parameters (history, depth, reliability:
        ``qos_overrides.<topic>.publisher.<policy>``) unless the caller chose its own options;
        ConfigError for an override rclpy cannot apply."""
        ours = getattr(self, "_qos_overridable", False)  # not rclpy's own (parameter events)
        if ours:
            kwargs.setdefault("qos_overriding_options", _OVERRIDABLE)
        with _qos_override_errors(self, topic, "publisher"):
            publisher = super().create_publisher(msg_type, topic, qos_profile, **kwargs)
        if ours and topics.barrier_writer(topic):
            self._barrier_writers.append(publisher)
        return publisher

    def create_subscription(
        self,
        msg_type: Any,
        topic: str,
        callback: Callable[[Any], None],
        qos_profile: QoSProfile | int,
        **kwargs: Any,
    ) -> Subscription:
        """rclpy's, with ROS 2's QoS override parameters (history, depth, reliability:
        ``qos_overrides.<topic>.subscription.<policy>``) unless the caller chose its own
        options; ConfigError for an override rclpy cannot apply."""
        if getattr(self, "_qos_overridable", False):  # not rclpy's own (its time source)
            kwargs.setdefault("qos_overriding_options", _OVERRIDABLE)
        with _qos_override_errors(self, topic, "subscription"):
            return super().create_subscription(msg_type, topic, callback, qos_profile, **kwargs)

    def graph_publisher(self, msg_type: Any, topic: str) -> Publisher:
        """A publisher of graph topic ``topic``, its class's profile (``topics.publisher_qos``)."""
        return self.create_publisher(msg_type, topic, topics.publisher_qos(topic))

    # -- live parameters (module docstring) -----------------------------------------------------
    def parameter_refusal(self, parameters: Sequence[Parameter]) -> str | None:
        """Why a request to set ``parameters`` must be refused, or None when it may go on."""
        for p in parameters:
            if p.name == "use_sim_time":
                if p.value is not True:
                    return (
                        "use_sim_time is fixed at start: every ffmpc node runs on the plant's "
                        "/clock (simulated time)"
                    )
                continue
            if not self.has_parameter(p.name):
                return f"{p.name}: no such parameter of {self.get_name()}"
            if not self.spec.is_live(p.name):
                if self.describe_parameter(p.name).read_only:
                    return f"{p.name} is fixed at start (read-only); live: {self.live_names()}"
                continue
            try:
                value = self.live_value(p.name, plain_value(p.value))
            except FfmpcError as exc:
                return str(exc)
            reason = self.check_live(p.name, value)
            if reason is not None:
                return f"{p.name} = {value!r}: {reason}"
        return None

    def live_names(self) -> str:
        """The node's live parameters, comma-separated (for messages)."""
        names = [n for n in self._scenario_names if self.spec.is_live(n)]
        return ", ".join(sorted(names)) or "none"

    def live_value(self, name: str, value: Any) -> Any:
        """``value`` of live parameter ``name`` checked against the schema, in its canonical
        type (float, tuple of floats); ConfigError (``name = value: expected …``) otherwise."""
        spec = SCHEMA[self._scenario_names[name]]
        length = self.scenario.mpc.contact.dimension if spec.length == CONTACT_DIMENSION else None
        try:
            return spec.check(value, length)
        except ConfigError as exc:
            raise ConfigError(str(exc).replace(spec.name, name, 1)) from None

    def check_live(self, name: str, value: Any) -> str | None:
        """The node's own rule for live parameter ``name`` (value already schema-checked):
        the reason to refuse it, or None. Nodes with live parameters override it."""
        return None

    def apply_live(self, changes: dict[str, Any], k: int) -> None:
        """Apply accepted live parameters ``{ROS name: value}`` at cycle k (before computing
        it). Nodes with live parameters override it."""

    def apply_pending(self, k: int) -> None:
        """Apply the live parameters accepted since the last call, at cycle k."""
        if not self.pending_parameters:
            return
        changes, self.pending_parameters = self.pending_parameters, {}
        self.apply_live(changes, k)
        self.live_changes += [(k, name, value) for name, value in changes.items()]

    def _check_parameter_request(self, parameters: list[Parameter]) -> list[Parameter]:
        """Pre-set callback (it runs before rclpy's descriptor checks, which refuse without
        calling back): a number given as text to a numeric live parameter becomes the number
        (:meth:`_typed`); then log ONE line for a request :meth:`parameter_refusal` refuses
        (the schema has the descriptors' ranges, so rclpy refuses nothing it lets through)."""
        parameters = [self._typed(p) for p in parameters]
        reason = self.parameter_refusal(parameters)
        if reason is not None:
            for p in parameters:
                self.refused_parameters[p.name] += 1
            self._log_line(f"parameter refused: {reason}", warning=True)
        return list(parameters)

    def _typed(self, param: Parameter) -> Parameter:
        """A live numeric parameter given as text read as ROS 2 reads a number
        (:func:`ffmpc_core.values.parse_scalar`): ``ros2 param set /mpc contact.stiffness 1e4``
        sends the string "1e4" (the ros2 CLI reads values with PyYAML, whose floats need a dot),
        where a parameter file or ``-p contact.stiffness:=1e4`` gives 10000.0. Anything else is
        left as it came (and refused by the schema if it is no number)."""
        from ffmpc_core.values import parse_scalar

        name = self._scenario_names.get(param.name)
        if name is None or not self.spec.is_live(param.name) or SCHEMA[name].kind == "str":
            return param
        value = plain_value(param.value)
        if isinstance(value, str):
            texts, scalar = [value], True
        elif isinstance(value, list) and value and all(isinstance(v, str) for v in value):
            texts, scalar = value, False
        else:
            return param
        numbers = [parse_scalar(t.strip()) for t in texts]
        if not all(isinstance(n, int | float) and not isinstance(n, bool) for n in numbers):
            return param
        floats = [float(n) for n in numbers]
        return Parameter(param.name, value=floats[0] if scalar else floats)

    def _parameter_verdict(self, parameters: list[Parameter]) -> SetParametersResult:
        """On-set callback: refuse with the reason of :meth:`parameter_refusal`."""
        declared = [p for p in parameters if self.has_parameter(p.name)]
        reason = self.parameter_refusal(declared)
        return SetParametersResult(successful=reason is None, reason=reason or "")

    def _stage_parameters(self, parameters: list[Parameter]) -> None:
        """Post-set callback: queue the accepted live values for the next computation (one
        info line)."""
        staged = []
        for p in parameters:
            if self.spec.is_live(p.name):
                value = self.live_value(p.name, plain_value(p.value))
                self.pending_parameters[p.name] = value
                staged.append(f"{p.name} = {value!r}")
        if staged:
            now = self.get_clock().now().nanoseconds * 1e-9
            self._log_line(
                f"parameter accepted: {', '.join(staged)}; applies from the {self.applies_at} "
                f"after t = {now:.4f} s"
            )

    #: When an accepted live parameter takes effect (for the log line).
    applies_at = "next cycle"

    def _log_line(self, text: str, warning: bool = False) -> None:
        # (two call sites: rclpy refuses a second severity from the same line of code)
        try:
            if warning:
                self.get_logger().warning(text)
            else:
                self.get_logger().info(text)
        except Exception:  # noqa: BLE001  (shutting down: the logger's context is gone)
            pass

    # -- names -----------------------------------------------------------------------------
    def name_of(self, topic: str) -> str:
        """The fully qualified name of a graph topic for this node: the relative names of
        ``ffmpc_ros.topics`` expanded in the node's namespace (``/arm1/mpc/command``), remap
        rules NOT applied — the name a bag records and the key of :attr:`rejected` and
        :attr:`accepted` (``/mpc/command:stale`` at the root, as before names were relative)."""
        name = self._names.get(topic)
        if name is None:
            name = self._names[topic] = self.resolve_topic_name(topic, only_expand=True)
        return name

    # -- time ------------------------------------------------------------------------------
    def cycle_of(self, stamp: TimeMsg) -> int | None:
        """The cycle k a stamp belongs to (module docstring, "Time"): the newest cycle at or
        before it, t_k ≤ stamp < t_{k+1}, a stamp less than :data:`GRID_TOLERANCE_NS` before
        t_{k+1} counting as cycle k + 1 (a driver's clock rounded to the grid); None for a stamp
        no ROS time can be (negative, or nanosec ≥ 10⁹)."""
        ns = stamp_ns(stamp)
        return None if ns is None else cycle_at(ns, self.step_ns)

    def cycle_of_time(self, t: float) -> int | None:
        """The cycle k of a time t = k·time_step (s), or None when t is off the grid (or not a
        time a ROS stamp can hold: negative, non-finite, or 2³¹ s and beyond)."""
        if not math.isfinite(t) or t < 0 or t >= 2.0**31:
            return None
        k = int(round(t / self.time_step))
        return k if abs(t - k * self.time_step) <= 1e-6 * self.time_step else None

    def stamp_of(self, k: int) -> TimeMsg:
        """The stamp of cycle k (t_k = k·time_step)."""
        return stamp_at(k, self.step_ns)

    def t_of(self, k: int) -> float:
        """t_k = k·time_step, s (the runner's float, bit for bit)."""
        return k * self.time_step

    # -- rejections --------------------------------------------------------------------------
    def reject(self, kind: str, message: str) -> None:
        """Count a rejection and log it (at most one line per kind per LOG_THROTTLE s)."""
        self.rejected[kind] += 1
        self._throttled_log(
            kind,
            lambda: f"rejected {kind}: {message} ({self.rejected[kind]} so far; output kept safe)",
            warning=True,
        )

    def inform(self, kind: str, message: str) -> None:
        """Log an info line, at most one per kind per LOG_THROTTLE s (counted in log_lines)."""
        self._throttled_log(kind, lambda: message, warning=False)

    def _throttled_log(self, kind: str, text: Callable[[], str], warning: bool) -> None:
        """Log ``text()`` (a warning or an info line), at most one line per kind per
        LOG_THROTTLE s, counted in log_lines; nothing while shutting down."""
        now = time.monotonic()
        last = self._last_log.get(kind)
        if last is None or now - last >= LOG_THROTTLE:
            self._last_log[kind] = now
            self.log_lines[kind] += 1
            try:
                logger = self.get_logger()
                (logger.warning if warning else logger.info)(text())
            except Exception:  # noqa: BLE001  (shutting down: the logger's context is gone)
                pass

    def check_stamp(self, topic: str, stamp: TimeMsg) -> int | None:
        """The cycle of an input's stamp (:meth:`cycle_of`) if :meth:`check_cycle` accepts it
        (judged by the stamp itself: from the future, stale); otherwise reject it and return
        None. Call :meth:`accept_cycle` once the whole message is accepted."""
        topic = self.name_of(topic)
        if not self.active:
            self.reject(f"{topic}:inactive", f"{topic} ignored: the node is {self.lifecycle_state}")
            return None
        ns = stamp_ns(stamp)
        if ns is None:
            self.reject(f"{topic}:stamp", f"stamp {stamp.sec}.{stamp.nanosec:09d} is no time")
            return None
        k = cycle_at(ns, self.step_ns)
        return k if self.check_cycle(topic, k, ns) else None

    def _subscribe_clock(self) -> None:
        """The node's reliable /clock reader (see __init__ and :class:`_Constructed`)."""
        self._clock_reader = self.create_subscription(
            ClockMsg, topics.CLOCK, self._on_clock, topics.clock_reader_qos()
        )

    # -- the lockstep start barrier (ffmpc_ros.topics.START_READY) --------------------------------
    @property
    def start_members(self) -> int:
        """Members of the lockstep graph (``start_clock_subscribers`` counts two /clock readers
        per member: each node, the recorder); 0 outside a lockstep graph."""
        clock_readers = int(self.params.get("start_clock_subscribers", 0))
        return clock_readers // topics.CLOCK_READERS_PER_NODE

    def _join_lockstep(self) -> None:
        """The membership marker (``lockstep/member``), this node's last reader."""
        self._member_topic = self.resolve_topic_name(topics.START_MEMBER)
        if self.start_members > 0:
            self.create_subscription(
                Empty,
                topics.START_MEMBER,
                _ignore,
                topics.start_ready_qos(),
                qos_overriding_options=None,
            )

    def _arm_start_barrier(self) -> None:
        """Check :meth:`writers_matched` now and every :data:`BARRIER_PERIOD` wall s until it
        holds; then subscribe ``lockstep/ready`` (the node's token, counted by the plant)."""
        self._ready_topic = self.resolve_topic_name(topics.START_READY)
        self._barrier_timer = self.create_timer(
            BARRIER_PERIOD, self._start_barrier, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self._start_barrier()

    def _start_barrier(self) -> None:
        if self.start_ready or not self.writers_matched():
            return
        self._barrier_timer.cancel()
        if self.start_members <= 0:
            self.start_ready = True  # no graph to wait for: no token either (ros2 run, re-runs)
            return
        self.create_subscription(
            Empty,
            topics.START_READY,
            _ignore,
            topics.start_ready_qos(),
            qos_overriding_options=None,
        )
        self.start_ready = True
        matched = sum(w.get_subscription_count() for w in self._barrier_writers)
        self.get_logger().info(
            f"start barrier passed: {len(self._barrier_writers)} writers matched to "
            f"{matched} readers"
        )

    def writers_matched(self) -> bool:
        """This node's side of the lockstep start barrier: it has discovered the membership
        marker (``lockstep/member``) of each of the graph's :attr:`start_members` members (a
        member's marker is its last reader, and a participant announces its readers in the
        order it creates them, so every reader of the graph is then known here; readers of
        /clock outside the graph, a live view's or a ``ros2 topic echo``'s, do not count), and
        each of its writers (those
        :func:`ffmpc_ros.topics.barrier_writer` names) has matched every reader discovered on
        its topic whose QoS is compatible with it. A reliable, volatile writer delivers every
        sample it sends after it matched a reader: once every node holds this, nothing sent
        from cycle 0 on is lost. True at once when ``start_clock_subscribers`` is 0 (no graph
        to wait for: ``ros2 run`` of one node, a re-run from a bag); the node then makes no
        token."""
        members = self.start_members
        if members <= 0:
            return True
        if self.count_subscribers(self._member_topic) < members:
            return False
        for writer in self._barrier_writers:
            readers = self.get_subscriptions_info_by_topic(writer.topic_name)
            compatible = sum(
                1
                for r in readers
                if qos_check_compatible(writer.qos_profile, r.qos_profile)[0]
                != QoSCompatibility.ERROR
            )
            if writer.get_subscription_count() < compatible:
                return False
        return True

    def _on_clock(self, msg: ClockMsg) -> None:
        self._clock_received = True
        self._reliable_time.clock_callback(msg)

    def check_cycle(
        self, topic: str, k: int, stamp: int | None = None, ordered: bool = True
    ) -> bool:
        """Whether an input of cycle k (time k·time_step) stamped ``stamp`` (ns; default t_k)
        may be used: of a cycle after the last accepted one from ``topic`` (unless not
        ``ordered``: the caller keeps its own order, the PID's commands), stamped at most
        :data:`MAX_FUTURE_STAMP` ahead of this node's clock and at most ``max_input_age`` behind
        it. Rejects it (one throttled log line) otherwise."""
        topic = self.name_of(topic)
        last = self._last_cycle.get(topic)
        if ordered and last is not None and k <= last:
            self.reject(f"{topic}:order", f"cycle {k} is not after the last accepted {last}")
            return False
        now_ns = self.get_clock().now().nanoseconds
        stamp = k * self.step_ns if stamp is None else stamp
        ahead = (stamp - now_ns) * 1e-9
        # A node that has no time yet (no /clock sample on either reader, the clock at 0) cannot
        # tell a stamp from the future: it judges from its first /clock on. Seen: a lockstep
        # MPC whose clock stayed at 0 for 11 cycles rejected genuine inputs, and the run
        # diverged from the runner (3 of 20 launches under load).
        no_time_yet = now_ns == 0 and not self._clock_received
        if ahead > MAX_FUTURE_STAMP and not no_time_yet:
            self.reject(
                f"{topic}:future",
                f"stamp {stamp * 1e-9:.6f} s is {ahead:.4f} s ahead of this node's clock "
                f"({now_ns * 1e-9:.6f} s; tolerance {MAX_FUTURE_STAMP} s)",
            )
            return False
        if now_ns > 0 and -ahead > self.max_input_age:
            self.reject(f"{topic}:stale", f"stamp {stamp * 1e-9:.6f} s is {-ahead:.4f} s old")
            return False
        return True

    def accept_cycle(self, topic: str, k: int) -> None:
        """Record an accepted input of cycle k (the newest cycle accepted from ``topic``)."""
        topic = self.name_of(topic)
        self._last_cycle[topic] = max(k, self._last_cycle.get(topic, k))
        self.accepted[topic] += 1

    # -- diagnostics -------------------------------------------------------------------------
    def diagnostic_values(self, period: float) -> dict[str, str]:
        """Node-specific values of the diagnostics report over the last ``period`` wall s."""
        return {}

    def diagnostic_problems(self) -> list[str]:
        """Node-specific faults now (each makes the report an ERROR)."""
        return []

    def diagnostic_status(self) -> DiagnosticStatus:
        """This node's status since the previous report (module docstring) and a new period."""
        now = time.monotonic()
        since, accepted, rejected = self._diagnosed
        period = max(now - since, 1e-9)
        total = sum(self.rejected.values())
        self._diagnosed = (now, Counter(self.accepted), total)
        values = {
            f"input_rate_hz {topic}": f"{(n - accepted[topic]) / period:.1f}"
            for topic, n in sorted(self.accepted.items())
        }
        values["rejected_total"] = str(total)
        values["rejected_in_period"] = str(total - rejected)
        values["period_s"] = f"{period:.3f}"
        values.update(self.diagnostic_values(period))
        problems = self.diagnostic_problems()
        if problems:
            level, message = DiagnosticStatus.ERROR, "; ".join(problems)
        elif total > rejected:
            kinds = ", ".join(sorted(self.rejected))
            level, message = DiagnosticStatus.WARN, f"{total - rejected} inputs rejected ({kinds})"
        else:
            level, message = DiagnosticStatus.OK, "ok"
        return DiagnosticStatus(
            level=level,
            name=self.get_fully_qualified_name(),
            message=message,
            hardware_id="ffmpc",
            values=[KeyValue(key=k, value=v) for k, v in values.items()],
        )

    def publish_diagnostics(self) -> None:
        """Publish :meth:`diagnostic_status` on /diagnostics (stamped with this node's clock)."""
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = [self.diagnostic_status()]
        self._pub_diagnostics.publish(msg)

    def receive(self, topic: str, msg: Any, parse: Callable[[Any], Any]) -> tuple[int, Any] | None:
        """Check the stamp of ``msg``, parse it, accept its cycle: ``(k, parse(msg))``, or None
        when the stamp or the values are rejected (one throttled log line, see :meth:`reject`)."""
        topic = self.name_of(topic)
        k = self.check_stamp(topic, msg.header.stamp)
        if k is None:
            return None
        try:
            value = parse(msg)
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            return None
        self.accept_cycle(topic, k)
        return k, value

    def joint_fields(self, *fields: str) -> Callable[[Any], list[np.ndarray]]:
        """A parser of JointState messages into ``fields`` in the robot's joint order."""
        return lambda msg: self.joint_arrays(msg, self.joint_names, fields)

    def vector(self, values: ArrayLike, n: int, name: str) -> np.ndarray:
        """A float array of n finite values (InputError otherwise)."""
        arr = np.asarray(values, dtype=float)
        if arr.shape != (n,):
            raise InputError(f"{name} has {arr.size} values, expected {n}")
        if not np.all(np.isfinite(arr)):
            raise InputError(f"{name} is not finite: {arr}")
        return arr

    def joint_arrays(
        self, msg: JointState, joint_names: Sequence[str], fields: Sequence[str]
    ) -> list[np.ndarray]:
        """The requested JointState fields in the robot's joint order (any order of names is
        accepted); InputError on unknown, missing or repeated names and bad values."""
        names = list(msg.name)
        if len(names) != len(set(names)) or set(names) != set(joint_names):
            unknown = sorted(set(names) - set(joint_names))
            missing = sorted(set(joint_names) - set(names))
            raise InputError(f"joint names: unknown {unknown}, missing {missing}")
        order = [names.index(n) for n in joint_names]
        out = []
        for f in fields:
            raw = np.asarray(getattr(msg, f), dtype=float)
            if raw.shape != (len(names),):
                raise InputError(f"{f} has {raw.size} values for {len(names)} joints")
            out.append(self.vector(raw[order], len(joint_names), f))
        return out

    def wrench_array(self, msg: WrenchStamped) -> np.ndarray:
        """[f; m] of a WrenchStamped in :data:`WRENCH_FRAME` (InputError otherwise)."""
        if msg.header.frame_id != WRENCH_FRAME:
            raise InputError(f"frame_id {msg.header.frame_id!r}, expected {WRENCH_FRAME!r}")
        f, m = msg.wrench.force, msg.wrench.torque
        return self.vector([f.x, f.y, f.z, m.x, m.y, m.z], 6, "wrench")

    def finished(self) -> bool:
        """True when the node has nothing left to do (its executable may exit)."""
        return False


@contextlib.contextmanager
def _qos_override_errors(node: Node, topic: str, role: str) -> Iterator[None]:
    """A QoS override parameter rclpy cannot apply (``reliability:=bogus``, a depth of 0 on
    KEEP_LAST) becomes a ConfigError naming the parameter (one line, exit 2 from ``run_node``)."""
    try:
        yield
    except (RuntimeError, InvalidQosOverridesError, ValueError, TypeError) as exc:
        text = str(exc)
        if "override" not in text.lower() and "qos" not in text.lower():
            raise
        name = f"qos_overrides.{node.resolve_topic_name(topic)}.{role}"
        raise ConfigError(f"{name}: {_first_line(exc)}") from None


def interfaces_of(node: GraphNode) -> str:
    """The node's graph parameter ``interfaces`` (``topics.INTERFACES``: ffmpc's own topics or
    ros2_control's terms); ConfigError for another value."""
    value = str(node.params["interfaces"])
    if value not in topics.INTERFACES:
        raise ConfigError(f"interfaces must be one of {list(topics.INTERFACES)}, got {value!r}")
    return value


def stamp_ns(stamp: TimeMsg) -> int | None:
    """A ROS stamp in ns, or None when it is no time (negative, or nanosec ≥ 10⁹)."""
    sec, nanosec = int(stamp.sec), int(stamp.nanosec)
    if sec < 0 or not 0 <= nanosec < 1_000_000_000:
        return None
    return sec * 1_000_000_000 + nanosec


def joint_state_message(
    stamp: TimeMsg,
    names: Sequence[str],
    q: np.ndarray | None,
    v: np.ndarray | None,
    effort: np.ndarray,
) -> JointState:
    """A JointState of one cycle: q (rad), q̇ (rad/s), effort (N·m); q or q̇ None: left empty
    (a torque-only message)."""
    msg = JointState()
    msg.header.stamp = stamp
    msg.name = list(names)
    if q is not None:
        msg.position = np.asarray(q, dtype=float).tolist()
    if v is not None:
        msg.velocity = np.asarray(v, dtype=float).tolist()
    msg.effort = np.asarray(effort, dtype=float).tolist()
    return msg


def wrench_stamped(
    stamp: TimeMsg, force: ArrayLike, moment: ArrayLike | None = None
) -> WrenchStamped:
    """A WrenchStamped in :data:`WRENCH_FRAME`: force (N, 3 values), moment (N·m, 3 values; None:
    zero). The inverse of :meth:`GraphNode.wrench_array`."""
    msg = WrenchStamped()
    msg.header.stamp = stamp
    msg.header.frame_id = WRENCH_FRAME
    f = msg.wrench.force
    f.x, f.y, f.z = (float(x) for x in np.asarray(force).reshape(-1))
    if moment is not None:
        m = msg.wrench.torque
        m.x, m.y, m.z = (float(x) for x in np.asarray(moment).reshape(-1))
    return msg


def force_on_axes(axes: Sequence[int], force: ArrayLike) -> list[float]:
    """The 3-D force (N, world) of a force measured on ``axes`` (the contact model's: its normal
    axis, or all three); the other axes 0."""
    full = [0.0, 0.0, 0.0]
    for axis, value in zip(axes, np.asarray(force).reshape(-1), strict=True):
        full[axis] = float(value)
    return full


def stamp_at(k: int, step_ns: int) -> TimeMsg:
    """The stamp of cycle k on a grid of ``step_ns`` (t_k = k·step_ns ns): the inverse of
    :func:`cycle_at`."""
    sec, nanosec = divmod(k * step_ns, 1_000_000_000)
    return TimeMsg(sec=int(sec), nanosec=int(nanosec))


def cycle_at(ns: int, step_ns: int) -> int:
    """The cycle a time of ``ns`` ≥ 0 belongs to on a grid of ``step_ns``: the newest cycle at
    or before it, within :data:`GRID_TOLERANCE_NS` (module docstring, "Time")."""
    return (ns + GRID_TOLERANCE_NS) // step_ns


def drop_stale_cycles(stores: Iterable[dict[int, Any]], newest: int, keep: int) -> None:
    """The cycle synchroniser's clean-up: delete from each per-cycle store (cycle k → input)
    every entry of a cycle before ``newest − keep``, an input whose partners never came."""
    oldest = newest - keep
    for store in stores:
        for old in [c for c in store if c < oldest]:
            del store[old]


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def run_node(
    factory: Callable[..., GraphNode], description: str, argv: Sequence[str] | None = None
) -> int:
    """``main`` of a node executable: ``--help``, then spin until shutdown (Ctrl-C).

    Bad parameters or ROS arguments: one line on stderr naming the parameter, exit 2."""
    argv = list(sys.argv if argv is None else argv)
    try:
        user_args = rclpy.utilities.remove_ros_args(argv)[1:]
    except Exception as exc:  # rcl refuses malformed --ros-args (RCLInvalidROSArgsError)
        name = argv[0].rsplit("/", 1)[-1] if argv else "node"
        print(f"{name}: error: bad ROS arguments: {_first_line(exc)}", file=sys.stderr)
        return 2
    parser = argparse.ArgumentParser(
        prog=argv[0].rsplit("/", 1)[-1],
        description=description,
        epilog="ROS arguments: --ros-args --params-file SCENARIO.yaml [-p name:=value] "
        "(scenario files: ffmpc_core/scenarios/; see msgs_notes/).",
    )
    parser.parse_args(user_args)
    prog = parser.prog
    try:  # ROS_DOMAIN_ID, the discovery range: one line before rcl or Fast DDS fail their way
        check_ros_environment()
    except ConfigError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    discovery = ensure_local_discovery()
    try:
        rclpy.init(args=argv)
    except Exception as exc:  # rcl refuses malformed --ros-args (RCLError): one line, exit 2
        print(f"{prog}: error: bad ROS arguments: {_first_line(exc)}", file=sys.stderr)
        return 2
    node = None
    try:
        try:
            node = factory()
        except (FfmpcError, ParameterException) as exc:  # bad parameters: one line, exit 2
            print(f"{prog}: error: {_first_line(exc)}", file=sys.stderr)
            return 2
        node.get_logger().info(
            f"started: ROS_DOMAIN_ID {os.environ.get('ROS_DOMAIN_ID', '0')}, discovery {discovery}"
        )
        from rclpy.experimental import EventsExecutor

        spin_realtime = getattr(node, "spin_realtime", None)
        if spin_realtime is not None and not node.params.get("lockstep", True):
            spin_realtime()  # real time: the node's own wait loop, no executor
        else:
            executor = EventsExecutor()
            executor.add_node(node)
            # SIGINT ends the loop between callbacks, not as a KeyboardInterrupt inside one:
            # raised in rclpy's C++ (a callback, the executor, the teardown after a second
            # SIGINT: Ctrl-C of ros2 launch reaches every node from the terminal and from the
            # launcher) it logged FATAL, left a RuntimeError or aborted the process (exit -6).
            stop: list[int] = []
            _on_sigint(lambda signum, _frame: stop.append(signum))
            while (
                rclpy.ok()
                and not stop
                and not node.finished()
                and node.lifecycle_state != "finalized"
            ):
                executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        # Shutting down, to the end of the process (run_node is its main): SIGINT is ignored.
        _on_sigint(signal.SIG_IGN)
        if node is not None:
            # One line for the log's reader; the bring-up reads the results file.
            print(
                REJECTED_MARKER + json.dumps({"node": node.get_name(), **dict(node.rejected)}),
                file=sys.stderr,
                flush=True,
            )
            results_file = str(node.params.get("results_file", ""))
            if results_file:
                write_node_results(results_file, node.get_name(), node.rejected)
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
        _on_sigint(signal.SIG_IGN)  # rclpy.shutdown put back the handler rclpy.init replaced
    return 0


def _on_sigint(handler: Any) -> None:
    """Set the SIGINT handler (in the main thread; elsewhere nothing)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, handler)
