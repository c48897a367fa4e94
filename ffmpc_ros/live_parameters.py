"""A node's live parameters: checked before rclpy applies them, queued, applied at the node's
next computation.

The parameters of :attr:`NodeSpec.live <ffmpc_ros.params.NodeSpec.live>` are writable while the
node runs; every other one is read-only, and ``use_sim_time`` is fixed true (every node runs on
the plant's ``/clock``). A request is checked before rclpy applies its descriptors (a pre-set
callback): the schema's type and range (:data:`ffmpc_core.scenario.SCHEMA`, the one
declaration), then the node's own rule (``check_live`` of the node, e.g. a stiffness for a
formulation without a soft contact). A refused request logs ONE warning line and returns
``successful=False`` with the reason (rclpy's own when the descriptor's range refuses it first,
the schema's otherwise); it is counted in :attr:`LiveParameters.refused`. An accepted one logs
one info line and waits in :attr:`LiveParameters.pending` until the node's next computation: the
MPC's next solve, the PID's next cycle (:meth:`LiveParameters.apply_pending`, recorded in
:attr:`LiveParameters.changes` with the cycle it took effect at). In lockstep that is a
well-defined cycle: the first MPC tick (PID cycle) the node computes after the request was
accepted; which tick that is depends on when the request arrives, and both the accepting log line
(the node's clock) and ``changes`` (the tick) say it.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any, Protocol

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.parameter import Parameter

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_core.scenario import CONTACT_DIMENSION, SCHEMA
from ffmpc_core.values import parse_scalar
from ffmpc_ros.params import NodeSpec, plain_value


class LiveNode(Protocol):
    """What :class:`LiveParameters` uses of its node (an rclpy node with the node's rules)."""

    applies_at: str

    def get_name(self) -> str: ...
    def get_logger(self) -> Any: ...
    def get_clock(self) -> Any: ...
    def has_parameter(self, name: str) -> bool: ...
    def describe_parameter(self, name: str) -> ParameterDescriptor: ...
    def check_live(self, name: str, value: Any) -> str | None: ...
    def apply_live(self, changes: dict[str, Any], k: int) -> None: ...
    def add_pre_set_parameters_callback(self, callback: Callable[..., Any]) -> None: ...
    def add_on_set_parameters_callback(self, callback: Callable[..., Any]) -> Any: ...
    def add_post_set_parameters_callback(self, callback: Callable[..., Any]) -> None: ...


class LiveParameters:
    """The live parameters of ``node`` (module docstring).

    Args:
        node: the node (its parameters, its rules ``check_live`` and ``apply_live``).
        spec: the node's spec (which parameters are live).
        scenario_names: the node's ROS parameter name → its scenario name (the schema's key).
        contact_dimension: the contact model's force dimension (the length of a per-axis value).
    """

    def __init__(
        self,
        node: LiveNode,
        spec: NodeSpec,
        scenario_names: dict[str, str],
        contact_dimension: int,
    ) -> None:
        self._node = node
        self._spec = spec
        self._names = scenario_names
        self._contact_dimension = contact_dimension
        self.refused: Counter[str] = Counter()  # refused requests per parameter
        self.pending: dict[str, Any] = {}  # accepted, not applied yet {ROS name: value}
        self.changes: list[tuple[int, str, Any]] = []  # (cycle applied, ROS name, value)
        node.add_pre_set_parameters_callback(self._check_request)
        node.add_on_set_parameters_callback(self._verdict)
        node.add_post_set_parameters_callback(self._stage)

    def refusal(self, parameters: Sequence[Parameter]) -> str | None:
        """Why a request to set ``parameters`` must be refused, or None when it may go on."""
        node = self._node
        for p in parameters:
            if p.name == "use_sim_time":
                if p.value is not True:
                    return (
                        "use_sim_time is fixed at start: every ffmpc node runs on the plant's "
                        "/clock (simulated time)"
                    )
                continue
            if not node.has_parameter(p.name):
                return f"{p.name}: no such parameter of {node.get_name()}"
            if not self._spec.is_live(p.name):
                if node.describe_parameter(p.name).read_only:
                    return f"{p.name} is fixed at start (read-only); live: {self.names()}"
                continue
            try:
                value = self.value(p.name, plain_value(p.value))
            except FfmpcError as exc:
                return str(exc)
            reason = node.check_live(p.name, value)
            if reason is not None:
                return f"{p.name} = {value!r}: {reason}"
        return None

    def names(self) -> str:
        """The node's live parameters, comma-separated (for messages)."""
        names = [n for n in self._names if self._spec.is_live(n)]
        return ", ".join(sorted(names)) or "none"

    def value(self, name: str, value: Any) -> Any:
        """``value`` of live parameter ``name`` checked against the schema, in its canonical
        type (float, tuple of floats); ConfigError (``name = value: expected …``) otherwise."""
        spec = SCHEMA[self._names[name]]
        length = self._contact_dimension if spec.length == CONTACT_DIMENSION else None
        try:
            return spec.check(value, length)
        except ConfigError as exc:
            raise ConfigError(str(exc).replace(spec.name, name, 1)) from None

    def apply_pending(self, k: int) -> None:
        """Apply the live parameters accepted since the last call, at cycle k (the node's
        ``apply_live``)."""
        if not self.pending:
            return
        changes = dict(self.pending)
        self.pending.clear()
        self._node.apply_live(changes, k)
        self.changes.extend((k, name, value) for name, value in changes.items())

    def _check_request(self, parameters: list[Parameter]) -> list[Parameter]:
        """Pre-set callback (it runs before rclpy's descriptor checks, which refuse without
        calling back): a number given as text to a numeric live parameter becomes the number
        (:meth:`_typed`); then log ONE line for a request :meth:`refusal` refuses (the schema
        has the descriptors' ranges, so rclpy refuses nothing it lets through)."""
        parameters = [self._typed(p) for p in parameters]
        reason = self.refusal(parameters)
        if reason is not None:
            for p in parameters:
                self.refused[p.name] += 1
            self._log_line(f"parameter refused: {reason}", warning=True)
        return list(parameters)

    def _typed(self, param: Parameter) -> Parameter:
        """A live numeric parameter given as text read as ROS 2 reads a number
        (:func:`ffmpc_core.values.parse_scalar`): ``ros2 param set /mpc contact.stiffness 1e4``
        sends the string "1e4" (the ros2 CLI reads values with PyYAML, whose floats need a dot),
        where a parameter file or ``-p contact.stiffness:=1e4`` gives 10000.0. Anything else is
        left as it came (and refused by the schema if it is no number)."""
        name = self._names.get(param.name)
        if name is None or not self._spec.is_live(param.name) or SCHEMA[name].kind == "str":
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

    def _verdict(self, parameters: list[Parameter]) -> SetParametersResult:
        """On-set callback: refuse with the reason of :meth:`refusal`."""
        declared = [p for p in parameters if self._node.has_parameter(p.name)]
        reason = self.refusal(declared)
        return SetParametersResult(successful=reason is None, reason=reason or "")

    def _stage(self, parameters: list[Parameter]) -> None:
        """Post-set callback: queue the accepted live values for the next computation (one
        info line)."""
        staged = []
        for p in parameters:
            if self._spec.is_live(p.name):
                value = self.value(p.name, plain_value(p.value))
                self.pending[p.name] = value
                staged.append(f"{p.name} = {value!r}")
        if staged:
            now = self._node.get_clock().now().nanoseconds * 1e-9
            self._log_line(
                f"parameter accepted: {', '.join(staged)}; applies from the "
                f"{self._node.applies_at} after t = {now:.4f} s"
            )

    def _log_line(self, text: str, warning: bool = False) -> None:
        # (two call sites: rclpy refuses a second severity from the same line of code)
        try:
            if warning:
                self._node.get_logger().warning(text)
            else:
                self._node.get_logger().info(text)
        except Exception:  # noqa: BLE001  (shutting down: the logger's context is gone)
            pass
