"""The base of every ffmpc node, and the executable's ``main``.

:class:`GraphNode` is an rclpy managed node that runs part of a scenario. It composes the parts
every node shares, each in its own module:

* :class:`~ffmpc_ros.time_grid.TimeGrid` (``node.grid``): stamps ↔ plant cycles ↔ time, bit for
  bit the runner's times;
* :class:`~ffmpc_ros.input_gate.InputGate` (``node.gate``): the checks every input passes
  (lifecycle, stamp, order, age) with one throttled log line per kind of rejection, and the counts
  (``node.rejected``, ``node.accepted``); the parsers of :mod:`ffmpc_ros.message_parsing`;
* :class:`~ffmpc_ros.live_parameters.LiveParameters` (``node.live``): the live parameters,
  checked against the schema and the node's :meth:`GraphNode.check_live`, applied by its
  :meth:`GraphNode.apply_live`;
* :class:`~ffmpc_ros.start_barrier.StartBarrier` (``node.barrier``): the lockstep start barrier
  and a plant's start rule;
* :class:`~ffmpc_ros.node_diagnostics.NodeDiagnostics` (``node.diagnostics``): ``/diagnostics``
  at 1 Hz with the node's :meth:`GraphNode.diagnostic_values` and
  :meth:`GraphNode.diagnostic_problems`;
* :class:`~ffmpc_ros.reliable_clock.ReliableClock`: the node's reliable /clock reader.

A node class creates everything in its ``__init__``, as ros2/examples do: ``super().__init__``
with ``join=False``, its models, publishers and subscriptions, then :meth:`GraphNode.join_graph`
as its last line (the reliable /clock reader, the start barrier's marker, then autostart).

Fixed at start. Every node runs on the plant's ``/clock``: ``use_sim_time`` is forced true at
construction and a later change is refused with a reason.

QoS. Every publisher and subscription of a node takes ROS 2's QoS override parameters
(``qos_overrides.<topic>.<publisher|subscription>.<policy>``); an override rclpy cannot apply is
a ConfigError naming the parameter.

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
false and drives the transitions itself, the plant last (:mod:`ffmpc_ros.bringup`).
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
from collections.abc import Callable, Iterator, Sequence
from typing import Any, NoReturn

import numpy as np
import rclpy
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import WrenchStamped
from numpy.typing import ArrayLike
from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import QoSPolicyKind, QoSProfile
from rclpy.qos_overriding_options import InvalidQosOverridesError, QoSOverridingOptions
from rclpy.subscription import Subscription
from sensor_msgs.msg import JointState

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_core.scenario import Scenario
from ffmpc_ros import topics
from ffmpc_ros.discovery import check_ros_environment, ensure_local_discovery
from ffmpc_ros.input_gate import InputGate, ThrottledLog
from ffmpc_ros.live_parameters import LiveParameters
from ffmpc_ros.node_diagnostics import NodeDiagnostics
from ffmpc_ros.node_results import write_node_results
from ffmpc_ros.params import (
    NODE_SPECS,
    declare_node_parameters,
    node_scenario_names,
    scenario_flat,
    scenario_from_parameters,
)
from ffmpc_ros.reliable_clock import ReliableClock
from ffmpc_ros.start_barrier import StartBarrier
from ffmpc_ros.time_grid import TimeGrid
from ffmpc_ros.time_grid import stamp_at as stamp_at  # (re-exported: ffmpc_ros.realtime)
from ffmpc_ros.topics import WRENCH_FRAME

#: The QoS policies every ffmpc publisher and subscription lets ROS 2's override parameters set
#: (``qos_overrides.<topic>.<publisher|subscription>.<policy>``): rclpy's defaults (history,
#: depth, reliability, ``QoSOverridingOptions.with_default_policies``) and durability, which
#: a user may set (nothing of the graph is transient local but its latched topics).
_OVERRIDABLE = QoSOverridingOptions(
    [*QoSOverridingOptions.with_default_policies().policy_kinds, QoSPolicyKind.DURABILITY]
)
#: Start of the line a node executable prints on stderr at exit: its rejections as JSON.
REJECTED_MARKER = "ffmpc-rejected: "


class GraphNode(LifecycleNode):
    """An rclpy managed node that runs part of a scenario (see the module docstring).

    Args:
        spec: key of :data:`ffmpc_ros.params.NODE_SPECS` (also the default node name).
        context: the rclpy context (tests make their own).
        parameter_overrides: parameter values (what ``ffmpc run`` passes); with ``ros2 run``
            they come from ``--params-file``.
        node_name: a different node name.
        cli_args: ROS arguments of this node only (``["--ros-args", "--params-file", f]``).
        join: call :meth:`join_graph` now (a bare GraphNode: the real-time loop's carriers of
            publishers); a node class passes False and calls it as the last line of its own
            ``__init__``, once its readers exist.
    """

    joint_names: list[str]  # the robot's joints, in its order (set by nodes that read joints)
    #: When an accepted live parameter takes effect (for the log line).
    applies_at = "next cycle"

    def __init__(
        self,
        spec: str,
        *,
        context: Context | None = None,
        parameter_overrides: Sequence[Parameter] | None = None,
        node_name: str | None = None,
        cli_args: Sequence[str] | None = None,
        join: bool = True,
    ) -> None:
        overrides = [p for p in (parameter_overrides or []) if p.name != "use_sim_time"]
        overrides.append(Parameter("use_sim_time", value=True))
        super().__init__(
            node_name or spec,
            context=context,
            parameter_overrides=overrides,
            cli_args=list(cli_args) if cli_args is not None else None,
        )
        try:
            self.lifecycle_state = "unconfigured"  # the state machine's label (module docstring)
            self._refusal: str | None = None  # the last refused configure's reason
            self._names: dict[str, str] = {}
            self.spec = NODE_SPECS[spec]
            self.params = declare_node_parameters(self, self.spec)
            self.scenario: Scenario = scenario_from_parameters(
                self.spec, self.params, self.get_name()
            )
            self.grid = TimeGrid(self.scenario.plant.time_step)
            self.time_step, self.step_ns = self.grid.time_step, self.grid.step_ns
            self.clock_reader = ReliableClock(self)
            self.gate = InputGate(
                self.grid,
                ThrottledLog(self.get_logger),
                name_of=self.name_of,
                now_ns=lambda: self.get_clock().now().nanoseconds,
                has_time=lambda: self.clock_reader.received,
                state=lambda: self.lifecycle_state,
                max_input_age=float(self.params.get("max_input_age", math.inf)),
            )
            # the counts, as every caller reads them (the diagnostics, the results file, tests)
            self.rejected, self.accepted = self.gate.rejected, self.gate.accepted
            self.log_lines = self.gate.log.lines
            scenario_names = node_scenario_names(self.spec, scenario_flat(Scenario("defaults")))
            self.live = LiveParameters(
                self, self.spec, scenario_names, self.scenario.mpc.contact.dimension
            )
            self.barrier = StartBarrier(self, self.params)
            # from here on, every publisher and subscription takes ROS 2's QoS override
            # parameters (rclpy's own, made in Node.__init__, keep rclpy's profiles)
            self._qos_overridable = True
            self.diagnostics = NodeDiagnostics(
                self.get_fully_qualified_name(),
                self.accepted,
                self.rejected,
                self.diagnostic_values,
                self.diagnostic_problems,
            )
            self.diagnostics.publish_from(self)
        except BaseException:  # (a bad parameter) the node leaves the graph now, see refuse
            with contextlib.suppress(Exception):
                self.destroy_node()
            raise
        if join:
            self.join_graph()

    def join_graph(self) -> None:
        """Complete the node once its data readers exist (a node class's last call in its
        ``__init__``):

        * its reliable /clock reader (:mod:`ffmpc_ros.reliable_clock`). The start handshake of
          the lockstep graph rests on it: the plant publishes cycle 0 only once
          ``start_clock_subscribers`` /clock readers are matched to it, and a node's second
          reader exists only after its data readers do (an MPC that builds its OCP for seconds
          after its time source subscribed no longer lets the plant start before it reads the
          joint states);
        * in a lockstep graph, ``lockstep/member``, its membership marker (its very last
          reader), and its side of the start barrier (:mod:`ffmpc_ros.start_barrier`);
        * then its lifecycle: with ``autostart`` true, configure, then activate; a refused
          configure raises ConfigError (the executable exits 2 with that line).

        A node refused here (a bad QoS override, a refused configure) leaves the ROS graph at
        once, not when its context ends (a later graph saw it as foreign)."""
        try:
            self.clock_reader.subscribe()
            self.barrier.join()
            self.barrier.arm()
            if not self.params.get("autostart", True):
                self.get_logger().info("unconfigured: waiting for the configure transition")
                return
            if self.trigger_configure() != TransitionCallbackReturn.SUCCESS:
                self.refuse(f"{self.get_name()}: configure refused: {self._refusal}")
            self.trigger_activate()
        except BaseException:  # (a bad parameter) the node leaves the graph now, see refuse
            with contextlib.suppress(Exception):
                self.destroy_node()
            raise

    # -- lifecycle (module docstring) -------------------------------------------------------------
    @property
    def active(self) -> bool:
        """Whether the node is in the lifecycle state ``active`` (it processes its inputs)."""
        return self.lifecycle_state == "active"

    def destroy_node(self) -> None:
        """Destroy the node and its lifecycle state machine: rclpy's LifecycleNode (7.1.6) leaves
        the state machine, which holds the node's handle, so the node stayed on the ROS graph
        after its context shut down (seen by the next graph of the same process as foreign)."""
        super().destroy_node()
        self._state_machine.destroy_when_not_in_use()

    def refuse(self, reason: str) -> NoReturn:
        """Refuse to construct this node: destroy it (it leaves the ROS graph now, not when its
        context ends: a later graph saw it as foreign) and raise ConfigError(reason) (the
        executable exits 2 with that line)."""
        with contextlib.suppress(Exception):
            self.destroy_node()
        raise ConfigError(reason) from None

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

    def finished(self) -> bool:
        """True when the node has nothing left to do (its executable may exit)."""
        return False

    # -- QoS (ffmpc_ros.topics) -----------------------------------------------------------------
    def create_publisher(
        self, msg_type: Any, topic: str, qos_profile: QoSProfile | int, **kwargs: Any
    ) -> Publisher:
        """rclpy's, with ROS 2's QoS override parameters (history, depth, reliability:
        ``qos_overrides.<topic>.publisher.<policy>``) unless the caller chose its own options;
        ConfigError for an override rclpy cannot apply. A writer the start barrier waits for
        (``topics.barrier_writer``) joins it."""
        ours = getattr(self, "_qos_overridable", False)  # not rclpy's own (parameter events)
        if ours:
            kwargs.setdefault("qos_overriding_options", _OVERRIDABLE)
        with _qos_override_errors(self, topic, "publisher"):
            publisher = super().create_publisher(msg_type, topic, qos_profile, **kwargs)
        if ours and topics.barrier_writer(topic):
            self.barrier.add_writer(publisher)
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

    # -- names, time, rejections (ffmpc_ros.time_grid, ffmpc_ros.input_gate) --------------------
    def name_of(self, topic: str) -> str:
        """The fully qualified name of a graph topic for this node: the relative names of
        ``ffmpc_ros.topics`` expanded in the node's namespace (``/arm1/mpc/command``), remap
        rules NOT applied — the name a bag records and the key of :attr:`rejected` and
        :attr:`accepted` (``/mpc/command:stale`` at the root)."""
        name = self._names.get(topic)
        if name is None:
            name = self._names[topic] = self.resolve_topic_name(topic, only_expand=True)
        return name

    def cycle_of(self, stamp: TimeMsg) -> int | None:
        """The cycle a stamp belongs to (:meth:`ffmpc_ros.time_grid.TimeGrid.cycle_of`)."""
        return self.grid.cycle_of(stamp)

    def reject(self, kind: str, message: str) -> None:
        """Count a rejection and log it (:meth:`ffmpc_ros.input_gate.InputGate.reject`)."""
        self.gate.reject(kind, message)

    # -- what a node adds (overridden by the nodes) ---------------------------------------------
    def diagnostic_values(self, period: float) -> dict[str, str]:
        """Node-specific values of the diagnostics report over the last ``period`` wall s."""
        return {}

    def diagnostic_problems(self) -> list[str]:
        """Node-specific faults now (each makes the report an ERROR)."""
        return []

    def check_live(self, name: str, value: Any) -> str | None:
        """The node's own rule for live parameter ``name`` (value already schema-checked):
        the reason to refuse it, or None. Nodes with live parameters override it."""
        return None

    def apply_live(self, changes: dict[str, Any], k: int) -> None:
        """Apply accepted live parameters ``{ROS name: value}`` at cycle k (before computing
        it). Nodes with live parameters override it."""


@contextlib.contextmanager
def _qos_override_errors(node: GraphNode, topic: str, role: str) -> Iterator[None]:
    """A QoS override parameter rclpy cannot apply (``reliability:=bogus``, a depth of 0 on
    KEEP_LAST) becomes a ConfigError naming the parameter (one line, exit 2 from ``run_node``)."""
    try:
        yield
    except (RuntimeError, InvalidQosOverridesError, ValueError, TypeError) as exc:
        text = str(exc)
        if "override" not in text.lower() and "qos" not in text.lower():
            raise
        name = f"qos_overrides.{node.resolve_topic_name(topic)}.{role}"
        node.refuse(f"{name}: {_first_line(exc)}")


def interfaces_of(node: GraphNode) -> str:
    """The node's graph parameter ``interfaces`` (``topics.INTERFACES``: ffmpc's own topics or
    ros2_control's terms); another value refuses the node (:meth:`GraphNode.refuse`)."""
    value = str(node.params["interfaces"])
    if value not in topics.INTERFACES:
        node.refuse(f"interfaces must be one of {list(topics.INTERFACES)}, got {value!r}")
    return value


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
    zero). The inverse of :func:`ffmpc_ros.message_parsing.wrench_array`."""
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
