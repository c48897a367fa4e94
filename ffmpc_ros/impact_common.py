"""What the impact nodes share (Dehio & Kheddar 2020): the measured joint state and wrench of
each cycle paired by stamp, and the learner's estimate on the wire (layout ``contact_estimate``).
The rule that says when an estimate is confident enough to be used is
``ffmpc_core.impact.learner.confident``.

Pairing. The impact planner and the contact learner read ``/joint_sensor/joint_states`` (q̂, q̇̂)
and ``/ft_sensor/wrench`` (λ̂, frame ``contact_world_aligned``). A cycle k is processed once both
messages stamped t_k are accepted, and only if k is after the last processed cycle (the
controllers need non-decreasing time); incomplete cycles more than :data:`KEEP` cycles older
than the newest are dropped. Input checks are the ones of :class:`~ffmpc_ros.base.GraphNode`.
"""

from __future__ import annotations

import time
from collections import deque
from typing import TYPE_CHECKING, Any

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.impact.deformation import unit_direction
from ffmpc_core.impact.learner import ContactEstimate, RecursiveContactLearner, confident
from ffmpc_ros import layouts, topics

if TYPE_CHECKING:
    pass
from ffmpc_ros.base import GraphNode
from ffmpc_ros.message_parsing import joint_arrays, wrench_array
from ffmpc_ros.time_grid import drop_stale_cycles

#: Cycles an incomplete measurement waits for its partner before it is dropped: the publishers'
#: history, so that a reader that lags (its process behind) can pair all it is handed at once.
KEEP = topics.PUBLISHER_DEPTH
#: Largest |d_a − d_b| (per component) of two motion directions that count as the same.
DIRECTION_TOLERANCE = 1e-6


def direction_parameter(value: object) -> np.ndarray:
    """The ``direction`` parameter as a unit 3-vector (world frame); ConfigError otherwise."""
    try:
        return unit_direction(np.asarray(value, dtype=float))
    except InputError as exc:
        raise ConfigError(f"parameter direction: {exc}") from None


class ReceivedEstimates(RecursiveContactLearner):
    """The contact learner node's estimates where a core controller expects its learner (the
    impact controller node's :class:`ImpactTaskController`, the planner node's touch-first
    controller): :meth:`update` counts the samples the learner node is fed (the controller
    feeds by the same rule from the same measurement; the node does the eq 19–21 arithmetic),
    :meth:`receive` takes the node's newest estimate, and :meth:`confident_estimate` applies
    the one confidence rule (``ffmpc_core.impact.learner.confident``) to it."""

    def reset(self) -> None:
        super().reset()
        self.current: ContactEstimate | None = None

    def update(self, deformation: float, deformation_rate: float, force: float) -> None:
        self.samples += 1

    def receive(self, estimate: ContactEstimate) -> None:
        """The learner node's newest estimate."""
        self.current = estimate

    def estimate(self) -> ContactEstimate:
        if self.current is None:
            raise InputError("no estimate from the contact learner node yet")
        return self.current

    def confident_estimate(
        self, min_samples: int, max_relative_std: float
    ) -> ContactEstimate | None:
        if self.samples < min_samples or self.current is None:
            return None
        return self.current if confident(self.current, min_samples, max_relative_std) else None


def estimate_message(
    estimate: ContactEstimate,
    t: float,
    sample: tuple[float, float, float],
    direction: np.ndarray,
    surface: np.ndarray,
) -> Float64MultiArray:
    """The ``contact_estimate`` array of an estimate, its time t (s), the newest sample
    (z m, ż m/s, f N), the direction d and the surface point (m, world frame)."""
    z, zd, f = sample
    return layouts.CONTACT_ESTIMATE.pack(
        {
            "t": t,
            "stiffness": estimate.stiffness,
            "damping": estimate.damping,
            "stiffness_std": estimate.stiffness_std,
            "damping_std": estimate.damping_std,
            "noise_std": estimate.noise_std,
            "samples": float(estimate.samples),
            "condition": estimate.condition,
            "deformation": z,
            "deformation_rate": zd,
            "force": f,
            "direction": direction,
            "surface": surface,
        }
    )


def estimate_from_message(msg: Float64MultiArray) -> tuple[ContactEstimate, float, np.ndarray]:
    """(estimate, t s, direction d) of a ``contact_estimate`` array; InputError when the layout,
    a value or the direction is wrong."""
    fields = layouts.CONTACT_ESTIMATE.unpack(msg)
    samples = fields["samples"]
    if samples < 0 or samples != int(samples):
        raise InputError(f"samples must be a non-negative integer, got {samples}")
    if min(fields["stiffness_std"], fields["damping_std"], fields["noise_std"]) < 0:
        raise InputError("standard errors must be ≥ 0")
    direction = unit_direction(fields["direction"])
    estimate = ContactEstimate(
        stiffness=fields["stiffness"],
        damping=fields["damping"],
        stiffness_std=fields["stiffness_std"],
        damping_std=fields["damping_std"],
        noise_std=fields["noise_std"],
        samples=int(samples),
        condition=fields["condition"],
    )
    return estimate, fields["t"], direction


def reference_fields(node: GraphNode, msg: Float64MultiArray) -> tuple[dict, int]:
    """The fields of an ``impact_planner/reference`` message (layout ``impact_reference``) and
    the cycle of its time; InputError for a malformed message or a time off the grid."""
    fields = layouts.IMPACT_REFERENCE.unpack(msg)
    k = node.grid.cycle_of_time(fields["t"])
    if k is None:
        raise InputError(f"reference time {fields['t']} s off the grid")
    return fields, k


def receive_estimate(
    node: GraphNode, msg: Float64MultiArray
) -> tuple[int, ContactEstimate, np.ndarray] | None:
    """A learner estimate message checked like any input: values, cycle on the grid, after the
    last accepted one, neither from the future nor stale (``InputGate.check_cycle``).
    ``(k, estimate, direction)``, or None after one throttled log line. The caller accepts the
    cycle (``node.accept_cycle``) once it has used the estimate."""
    topic = node.name_of(topics.CONTACT_ESTIMATE)
    try:
        estimate, t, direction = estimate_from_message(msg)
    except InputError as exc:
        node.reject(f"{topic}:value", str(exc))
        return None
    k = node.grid.cycle_of_time(t)
    if k is None:
        node.reject(f"{topic}:stamp", f"estimate time {t} s off the grid")
        return None
    if not node.gate.check_cycle(topic, k):
        return None
    return k, estimate, direction


class MeasuredCycleNode(GraphNode):
    """A GraphNode that processes the measured joint state and wrench of each cycle together
    (see the module docstring). Subclasses set ``joint_names``, call
    :meth:`subscribe_measurements`, and implement :meth:`process_cycle`; :meth:`input_failed` is
    called for every rejected measurement except duplicates and out-of-order ones.

    Attributes:
        step_times: wall time of each :meth:`process_cycle`, s (the newest 100 000).
        processed: cycles processed.
    """

    joint_names: list[str]

    def __init__(self, spec: str, **kwargs: Any) -> None:
        super().__init__(spec, **kwargs)
        self._joints: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._wrenches: dict[int, np.ndarray] = {}
        self.last_processed: int | None = None
        self.processed = 0
        self.step_times: deque[float] = deque(maxlen=100_000)

    def subscribe_measurements(self, lockstep: bool) -> None:
        """Subscribe the measured joint state and wrench (SENSOR QoS, ``ffmpc_ros.topics``)."""
        for msg_type, topic, callback in (
            (JointState, topics.SENSED_JOINT_STATES, self.on_joints),
            (WrenchStamped, topics.SENSED_WRENCH, self.on_wrench),
        ):
            self.create_subscription(
                msg_type, topic, callback, topics.subscriber_qos(lockstep, topic)
            )

    # -- hooks -------------------------------------------------------------------------------
    def process_cycle(self, k: int, q: np.ndarray, v: np.ndarray, wrench: np.ndarray) -> None:
        """Cycle k's q (rad), q̇ (rad/s) and wrench [f; m] (N, N·m, ``contact_world_aligned``)."""
        raise NotImplementedError

    def input_failed(self, k: int | None) -> None:
        """A measurement was rejected (k: its cycle when its stamp is on the grid)."""

    # -- inputs ------------------------------------------------------------------------------
    def _checked_cycle(self, topic: str, stamp: TimeMsg) -> int | None:
        k_msg = self.cycle_of(stamp)
        k = self.gate.check_stamp(topic, stamp)
        if k is None:
            if not (k_msg is not None and k_msg <= self.gate.last_cycle(topic)):
                self.input_failed(k_msg)
        return k

    def on_joints(self, msg: JointState) -> None:
        topic = self.name_of(topics.SENSED_JOINT_STATES)
        k = self._checked_cycle(topic, msg.header.stamp)
        if k is None:
            return
        try:
            q, v = joint_arrays(msg, self.joint_names, ("position", "velocity"))
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            self.input_failed(k)
            return
        self.gate.accept(topic, k)
        self._joints[k] = (q, v)
        self._try_cycle(k)

    def on_wrench(self, msg: WrenchStamped) -> None:
        topic = self.name_of(topics.SENSED_WRENCH)
        k = self._checked_cycle(topic, msg.header.stamp)
        if k is None:
            return
        try:
            wrench = wrench_array(msg)
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            self.input_failed(k)
            return
        self.gate.accept(topic, k)
        self._wrenches[k] = wrench
        self._try_cycle(k)

    def _try_cycle(self, k: int) -> None:
        drop_stale_cycles((self._joints, self._wrenches), k, KEEP)
        if k not in self._joints or k not in self._wrenches:
            return
        q, v = self._joints.pop(k)
        wrench = self._wrenches.pop(k)
        if self.last_processed is not None and k <= self.last_processed:
            return  # completed after a later cycle: the controllers need time to go forward
        self.last_processed = k
        start = time.perf_counter()
        self.process_cycle(k, q, v, wrench)
        self.step_times.append(time.perf_counter() - start)
        self.processed += 1
