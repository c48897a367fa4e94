"""The contact learner node: online stiffness and damping of the touched material (Dehio &
Kheddar 2020, Sec. V, eq 19–21) with its confidence.

Subscribes ``/joint_sensor/joint_states`` (q̂, q̇̂) and ``/ft_sensor/wrench`` (λ̂, frame
``contact_world_aligned``) and pairs them by cycle (:mod:`ffmpc_ros.impact_common`). For each cycle
k, with the unit motion direction d (parameter ``direction``, world frame):

* forward kinematics (pinocchio) gives the contact-frame position p (m, world) and ż = dᵀṗ
  (m/s, the LOCAL_WORLD_ALIGNED linear velocity);
* the pressing force is f = −dᵀλ̂ (N; λ̂ is the force ON the tool, so pressing along d gives
  λ̂ ≈ −f d);
* **surface**: until the force first reaches ``contact_threshold``, p is remembered at every
  sample with f ≤ ``surface_force``; at the threshold the surface point p_s is the last such
  position (the last force-free sample, as in ``sim_bridge.exploration``; the onset position
  itself when there was none). It is kept until the reset service;
* **samples fed**: once p_s is known, a sample with f > ``feed_force`` is in contact; every
  in-contact sample but the first ``skip_onset_samples`` of each contact episode goes to
  :class:`~ffmpc_core.impact.learner.RecursiveContactLearner` as (z, ż, f) with
  z = dᵀ(p − p_s) (eq 19–20);
* after each sample fed, once the estimate exists (3 samples or more), it is published on
  ``/contact_learner/estimate`` (layout ``contact_estimate``): α̂ (N/m), β̂ (N·s/m), their
  standard errors, σ̂ (N), the sample count, the condition number, the sample, d and p_s.

Gated (parameter ``planner_gate``, the impact graph's touch-first strategy; lockstep): the
samples fed are the ones the impact planner's touch-first controller selects. The node reads
``impact_planner/reference`` (its learning gate: the controller's phase and surface point after
each cycle) and feeds cycle k's sample by the one feeding rule
(:func:`~ffmpc_core.impact.touch_first.fed_surface`) from the gate of cycle k−1 (cycle 0: the
controller's state after its reset, the touch approach without a surface), so it waits for
that gate before it processes cycle k; ``surface_force``, ``feed_force`` and
``skip_onset_samples`` are not used then.

Service ``/contact_learner/reset`` (std_srvs/Trigger): forget every sample and the surface.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from ffmpc_core.errors import InputError
from ffmpc_core.impact.deformation import measured_deformation
from ffmpc_core.impact.learner import ContactEstimate, RecursiveContactLearner
from ffmpc_core.impact.touch_first import TOUCH, LearningGate, fed_surface
from ffmpc_core.robots import load_robot
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import run_node
from ffmpc_ros.impact_common import (
    MeasuredCycleNode,
    direction_parameter,
    estimate_message,
    reference_fields,
)

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class ContactLearnerNode(MeasuredCycleNode):
    """RecursiveContactLearner on topics (see the module docstring).

    Attributes:
        learner: the eq 19–21 learner. surface: p_s (m, world) or None before the onset.
        estimate: the newest published estimate (None before). published: estimates published.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("contact_learner", join=False, **kwargs)
        p = self.params
        self.robot = load_robot(self.scenario.robot)
        self.joint_names = list(self.robot.joint_names)
        self.direction = direction_parameter(p["direction"])
        self.contact_threshold = float(p["contact_threshold"])
        self.surface_force = float(p["surface_force"])
        self.feed_force = float(p["feed_force"])
        self.skip_onset_samples = int(p["skip_onset_samples"])
        if self.surface_force >= self.contact_threshold:
            self.refuse("surface_force must be below contact_threshold (N)")
        self.learner = RecursiveContactLearner(float(p["regularization"]))
        self._data = self.robot.create_data()
        self.published = 0
        self.publisher = self.create_publisher(
            Float64MultiArray,
            topics.CONTACT_ESTIMATE,
            topics.publisher_qos(topics.CONTACT_ESTIMATE),
        )
        self.planner_gate = bool(p["planner_gate"])
        self._gates: dict[int, LearningGate] = {}
        self._waiting: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.subscribe_measurements(True)
        if self.planner_gate:
            self.create_subscription(
                Float64MultiArray,
                topics.IMPACT_REFERENCE,
                self.on_reference,
                topics.subscriber_qos(True, topics.IMPACT_REFERENCE),
            )
        self.create_service(Trigger, topics.CONTACT_LEARNER_RESET_SERVICE, self.on_reset)
        self.forget()
        self.join_graph()

    def forget(self) -> None:
        """Back to the start: no sample, no surface."""
        self.learner.reset()
        self.surface: np.ndarray | None = None
        self._last_free: np.ndarray | None = None
        self._contact_run = 0  # consecutive samples with f > feed_force
        self._gates = {}
        self._waiting = {}
        self.estimate: ContactEstimate | None = None

    def contact_kinematics(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, float]:
        """Contact-frame position p (m, world) and ż = dᵀṗ (m/s) by forward kinematics."""
        model, data, fid = self.robot.model, self._data, self.robot.contact_frame_id
        pin.forwardKinematics(model, data, q, v)
        position = pin.updateFramePlacement(model, data, fid).translation.copy()
        rate = float(self.direction @ pin.getFrameVelocity(model, data, fid, _LWA).linear)
        return position, rate

    def on_reference(self, msg: Float64MultiArray) -> None:
        """The planner's learning gate of a cycle (gated mode)."""
        topic = self.name_of(topics.IMPACT_REFERENCE)
        try:
            fields, k = reference_fields(self, msg)
            gate = LearningGate(
                layouts.impact_phase(fields["gate_phase"]),
                np.asarray(fields["gate_surface"], dtype=float)
                if fields["gate_surface_valid"] > 0
                else None,
                fields["gate_learn"] > 0,
            )
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            return
        if not self.gate.check_cycle(topic, k):
            return
        self.gate.accept(topic, k)
        self._gates[k] = gate
        self._run_gated()

    def _run_gated(self) -> None:
        """Process the waiting cycles whose previous gate is in, in order."""
        while self._waiting:
            k = min(self._waiting)
            if k > 0 and k - 1 not in self._gates:
                return
            q, v, wrench = self._waiting.pop(k)
            gate = self._gates.pop(k - 1) if k > 0 else LearningGate(TOUCH, None)
            for old in [c for c in self._gates if c < k - 1]:
                del self._gates[old]
            d = self.direction
            p, zd = self.contact_kinematics(q, v)
            f = float(-d @ wrench[:3])
            surface = fed_surface(gate, p, f, self.contact_threshold)
            if surface is not None:
                self.surface = surface
                self._feed(k, p, zd, f)

    def process_cycle(self, k: int, q: np.ndarray, v: np.ndarray, wrench: np.ndarray) -> None:
        if self.planner_gate:
            self._waiting[k] = (q, v, wrench)
            self._run_gated()
            return
        d = self.direction
        p, zd = self.contact_kinematics(q, v)
        f = float(-d @ wrench[:3])
        if self.surface is None:
            if f <= self.surface_force:
                self._last_free = p
            if f >= self.contact_threshold:
                if self._last_free is None:
                    self.gate.inform("surface", "in contact from the first sample: surface = onset")
                self.surface = p if self._last_free is None else self._last_free
        self._contact_run = self._contact_run + 1 if f > self.feed_force else 0
        if self.surface is None or self._contact_run <= self.skip_onset_samples:
            return
        self._feed(k, p, zd, f)

    def _feed(self, k: int, p: np.ndarray, zd: float, f: float) -> None:
        """Eq 19–20 with cycle k's sample against :attr:`surface`, then publish the estimate."""
        d = self.direction
        assert self.surface is not None
        z = measured_deformation(p, self.surface, d)
        self.learner.update(z, zd, f)
        if self.learner.samples < 3:
            return
        try:
            estimate = self.learner.estimate()
        except InputError as exc:  # (S Sᵀ) singular: no excitation yet
            self.reject("estimate", str(exc))
            return
        values = (estimate.stiffness, estimate.damping, estimate.stiffness_std)
        if not (np.all(np.isfinite(values)) and np.isfinite(estimate.condition)):
            self.reject("estimate", f"not finite yet: {estimate}")
            return
        self.estimate = estimate
        self.publisher.publish(
            estimate_message(estimate, self.grid.t_of(k), (z, zd, f), d, self.surface)
        )
        self.published += 1

    def on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        samples = self.learner.samples
        self.forget()
        response.success = True
        response.message = f"forgot {samples} samples and the surface"
        self.get_logger().info(f"reset: {response.message}")
        return response


def main(argv: list[str] | None = None) -> int:
    return run_node(ContactLearnerNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
