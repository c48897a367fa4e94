"""The MPC node's rules for what changes its OCP while it runs: its live parameters, its
reference topics and the learner's contact estimates (:mod:`ffmpc_ros.mpc_node`). Plain
functions and one small class over the core's controller and schedule; no rclpy."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np

from ffmpc_core.impact.learner import confident
from ffmpc_core.mpc import ModelPredictiveController, MpcConfig
from ffmpc_core.scenario import PHASE_WEIGHT_NAMES, SCHEMA
from ffmpc_core.tasks import PhaseWeights
from ffmpc_ros.impact_common import DIRECTION_TOLERANCE
from ffmpc_ros.input_gate import MAX_FUTURE_STAMP
from ffmpc_ros.topics import WORLD_FRAME


class Refusal(NamedTuple):
    """Why an input is rejected: its kind (``frame``, ``future``, ``value``, ``workspace``,
    ``direction``) and the reason."""

    kind: str
    reason: str


def live_refusal(
    name: str, value: Any, formulation: str, task: str, nominal_force: bool, force: float
) -> str | None:
    """The MPC's own rule for live parameter ``name`` = ``value`` (already schema-checked):
    which formulation and task can take it (``task``: its name, ``nominal_force``: whether it
    has one positive force set-point, ``force``: ``task.normal_force`` at start, N)."""
    if name.startswith("contact.") and formulation != "force_feedback":
        return f"the {formulation} formulation has no visco-elastic contact (K, B unused)"
    if name.startswith("weights."):
        form, _, term = name[len("weights.") :].partition(".")
        if form != formulation:
            return f"this node runs the {formulation} formulation, not {form}"
        if term == "force_rate" and formulation != "force_feedback":
            return "only the force-feedback formulation has the force-rate cost"
    if name == "task.normal_force" and not nominal_force:
        return (
            f"the {task} task has no single positive force set-point "
            f"(task.normal_force is {force} N at start)"
        )
    return None


def apply_live_changes(
    mpc: ModelPredictiveController,
    schedule: Any,
    changes: dict[str, Any],
    t_task: float,
    phase_weights: Callable[[], PhaseWeights],
) -> None:
    """Apply accepted live parameters ``{ROS name: value}`` in place, before a solve at task
    time ``t_task`` (s): contact K (N/m), B (N·s/m), cost weights, the phase weights
    (``phase_weights()``: the node's phase weights now), the force set-point
    (N) and the position offset (m, world), both blended in from ``t_task``. FfmpcError when
    the core refuses a value."""
    contact = mpc.config.contact
    if "contact.stiffness" in changes or "contact.damping" in changes:
        mpc.set_contact_parameters(
            changes.get("contact.stiffness", contact.stiffness),
            changes.get("contact.damping", contact.damping),
        )
    phase = False
    for name, value in changes.items():
        if name.startswith("weights."):
            term = name.rpartition(".")[2]
            if term in PHASE_WEIGHT_NAMES:
                phase = True
            else:
                mpc.set_cost_weight(term, value)
    if phase:
        schedule.set_phase_weights(phase_weights())
    if "task.normal_force" in changes:
        schedule.set_force(changes["task.normal_force"], t_task)
    if "position_offset" in changes:
        schedule.set_position_offset(changes["position_offset"], t_task)


def reference_offset(msg: Any, nominal_target: np.ndarray, now_ns: int) -> np.ndarray | Refusal:
    """The ``position_offset`` (m, world) a ``PoseStamped`` target of the contact frame asks
    for (target − the task's ``nominal_target``), or why it is refused: a frame other than
    ``world``, a stamp more than MAX_FUTURE_STAMP ahead of ``now_ns`` (the node's clock), a
    target that is not finite or farther than the schema's bound on ``mpc.position_offset``."""
    if msg.header.frame_id != WORLD_FRAME:
        return Refusal("frame", f"frame_id {msg.header.frame_id!r}, expected {WORLD_FRAME!r}")
    stamp_ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
    ahead = (stamp_ns - now_ns) * 1e-9
    if ahead > MAX_FUTURE_STAMP:
        return Refusal("future", f"stamp {stamp_ns * 1e-9:.6f} s is {ahead:.4f} s ahead")
    p = msg.pose.position
    target = np.array([p.x, p.y, p.z], dtype=float)
    if not np.all(np.isfinite(target)):
        return Refusal("value", f"target position is not finite: {target}")
    offset = target - nominal_target
    bound = SCHEMA["mpc.position_offset"].range
    assert bound is not None  # the schema bounds it
    if np.any(offset < bound[0]) or np.any(offset > bound[1]):
        return Refusal(
            "workspace",
            f"target {np.round(target, 4).tolist()} m is {np.round(offset, 4).tolist()} m "
            f"from the task's {np.round(nominal_target, 4).tolist()} m (bound "
            f"[{bound[0]:g}, {bound[1]:g}] m per axis)",
        )
    return offset


class LearnedContact:
    """The OCP's contact K (N/m) and B (N·s/m) per force entry, the normal-axis entry set from
    the learner's confident estimates (the MPC node's module docstring, "Learned contact").

    Args:
        config: the MPC's configuration (its contact model).
        min_samples: ``learner_min_samples``.
        max_relative_std: ``learner_max_relative_std``.
    """

    def __init__(self, config: MpcConfig, min_samples: int, max_relative_std: float) -> None:
        contact = config.contact
        self._contact = contact
        self.stiffness = contact.stiffness_vector().copy()  # N/m, per force entry
        self.damping = contact.damping_vector().copy()  # N·s/m
        self._entry = 0 if contact.dimension == 1 else contact.normal_axis
        self.min_samples = min_samples
        self.max_relative_std = max_relative_std
        self.updates = 0  # estimates applied

    def direction_refusal(self, direction: np.ndarray) -> Refusal | None:
        """A LOCAL_WORLD_ALIGNED contact takes estimates along ±its normal axis only."""
        contact = self._contact
        if contact.frame_type != "LOCAL_WORLD_ALIGNED":
            return None
        along = abs(float(direction[contact.normal_axis]))
        if along < 1.0 - DIRECTION_TOLERANCE:
            return Refusal(
                "direction",
                f"estimate along {direction}, the contact model's axis is {contact.normal_axis}",
            )
        return None

    def apply(self, mpc: ModelPredictiveController, estimate: Any) -> bool:
        """Set the OCP's contact from a confident ``estimate`` (False: not confident, nothing
        changed); FfmpcError when the core refuses it."""
        if not confident(estimate, self.min_samples, self.max_relative_std):
            return False
        stiffness, damping = self.stiffness.copy(), self.damping.copy()
        stiffness[self._entry] = estimate.stiffness
        damping[self._entry] = estimate.damping
        mpc.set_contact_parameters(stiffness, damping)
        self.stiffness, self.damping = stiffness, damping
        self.updates += 1
        return True

    def follow(self, mpc: ModelPredictiveController) -> None:
        """Take the OCP's contact as it is now (after a live parameter set it)."""
        self.stiffness = mpc.config.contact.stiffness_vector().copy()
        self.damping = mpc.config.contact.damping_vector().copy()
