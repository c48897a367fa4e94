"""The impact controller node: the task-space controller of the impact experiment (Dehio &
Kheddar 2020, Sec. VI) — the joint-limit guard (a QP on the joint accelerations, eq 1b–1e) that
turns the planner's Cartesian command into joint torques, the admittance task or the baseline
approach, and the hand-over to the force-feedback MPC.

It runs :class:`~ffmpc_core.impact.controllers.ImpactTaskController`, the object of the ROS-free
study (``studies.impact_study.run_impact``), built from the same configuration (the impact
study's parameters, all of ``IMPACT_SCHEMA`` declared under its dotted names, and
``approach``, ``regulation``), except
for two parts that run in other nodes and reach it as messages of the same cycle:

* the maximal approach (eq 9–14): the impact planner node's ``impact_planner/reference``
  (layout ``impact_reference``: position, velocity, feed-forward acceleration, orientation),
  computed from the same measurement; with the touch-first strategy it also carries what the
  task controller takes from the touch-first approach before its step (whether the approach
  is in its strike, the guard's impact force) and the samples its feeding rule fed;
* the learner (eq 19–21) the hand-over reads: the contact learner node's
  ``contact_learner/estimate`` (regulation ``ff_mpc``); :class:`ReceivedEstimates` stands in
  for the learner object and applies the one confidence rule to the node's estimate. With the
  touch-first strategy the ROS-free controller feeds the learner in the approach's step,
  after the hand-over has read it: here the estimate of cycle k (and the planner's sample
  count) is taken after the step of cycle k, so the hand-over of cycle k reads cycle k−1's,
  as there.

Cycle k (t_k = k·time_step) is computed once its inputs are in: ``joint_sensor/joint_states``
and ``ft_sensor/wrench`` (paired by :class:`~ffmpc_ros.impact_common.MeasuredCycleNode`), the
planner's reference of cycle k (maximal approach) and, with ``ff_mpc``, the learner's estimate
of cycle k whenever the learner is fed in that cycle (the controller applies the same contact
and feeding rule to the same measurement, so it knows). A cycle whose inputs do not come within
``lockstep_timeout`` wall s goes on without them (a missing estimate: the previous one). Outputs,
stamped t_k: ``impact_controller/torque`` (sensor_msgs/JointState, effort N·m, what the plant
applies) and ``impact_controller/status`` (layout ``impact_control``).

The MPC runs inside this node (:class:`~ffmpc_core.impact.controllers.ForceFeedbackHandover`),
not in the polishing graph's MPC node: it is built at the hand-over instant from that cycle's
measurement (posture reference = q, press where the tool is), its contact model changes with
the learner's estimate, and its torque goes through this node's guard and is blended with the
admittance torque in the same cycle — a separate node would add a cycle of latency (or a
second handshake per cycle) and lose the equality with the ROS-free run.

Bad input: a reference that is malformed (wrong layout, NaN/Inf, a rotation that is not one)
or missing, or a controller step that fails, is rejected with one throttled log line and the
cycle gets a safe command: hold the measured pose (zero velocity and acceleration, the held
orientation) through the same joint-limit guard (``safe_hold`` = 1 in the status).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import FfmpcError, InputError
from ffmpc_core.impact.control import APPROACH, CartesianCommand
from ffmpc_core.impact.controllers import (
    ContactMeasurement,
    ExternalApproach,
    ImpactTaskCommand,
    ImpactTaskController,
)
from ffmpc_core.impact.learner import ContactEstimate
from ffmpc_core.impact.limits import joint_limits
from ffmpc_core.impact.scenario import LEARNING_STRATEGIES, ImpactStudyConfig
from ffmpc_core.robots import load_robot
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import run_node
from ffmpc_ros.impact_common import (
    MeasuredCycleNode,
    ReceivedEstimates,
    receive_estimate,
    reference_fields,
)
from ffmpc_ros.params import impact_config_from_parameters

#: Wall-time period of the lockstep-timeout check, s.
WATCHDOG_PERIOD = 0.05
#: Largest |RᵀR − I| entry of a reference rotation.
ROTATION_TOLERANCE = 1e-6
#: The phase codes of the status (layout ``impact_control``).
PHASE_CODES = layouts.IMPACT_PHASES


def reference_approach(
    fields: dict, learning: bool, config: ImpactStudyConfig | None = None
) -> ExternalApproach:
    """The ExternalApproach of an ``impact_reference`` message (InputError when its rotation is
    not a rotation or its phase no phase); ``learning``: a learning strategy's inputs are in it;
    ``config``: the study's, for the regulation's stop short of the target (its target, depth
    and z̄; None: not reported)."""
    from ffmpc_core.impact.control import StoppedShort
    from ffmpc_core.impact.touch_first import TouchCycleInputs

    touch = (
        TouchCycleInputs(
            strike=fields["strike"] > 0,
            impact_force=fields["impact_force"],
            handover_allowed=fields["handover_allowed"] > 0,
        )
        if learning
        else None
    )
    stopped = None
    if config is not None and fields["stopped_short_time"] >= 0.0:
        zbar = config.dice.max_penetration
        stopped = StoppedShort(
            fields["stopped_short_time"],
            fields["stopped_short_force"],
            config.target_force,
            config.admittance.max_depth(zbar),
            zbar,
        )
    return ExternalApproach(
        reference_command(fields), layouts.impact_phase(fields["phase"]), touch, stopped
    )


def reference_command(fields: dict) -> CartesianCommand:
    """The CartesianCommand of an ``impact_reference`` message (InputError when its rotation
    is not a rotation)."""
    rotation = np.asarray(fields["rotation"], dtype=float).reshape(3, 3)
    if np.max(np.abs(rotation.T @ rotation - np.eye(3))) > ROTATION_TOLERANCE:
        raise InputError("rotation is not orthonormal")
    bound = fields["pre_impact_velocity"] if fields["bound_valid"] > 0 else math.nan
    return CartesianCommand(
        phase=layouts.impact_phase(fields["phase"]),
        position=np.asarray(fields["position"], dtype=float),
        velocity=np.asarray(fields["velocity"], dtype=float),
        acceleration=np.asarray(fields["acceleration"], dtype=float),
        rotation=rotation,
        pre_impact_velocity=bound,
        force=fields["force"],
        target_force=fields["target_force"],
    )


class ImpactControllerNode(MeasuredCycleNode):
    """ImpactTaskController on topics (see the module docstring).

    Attributes:
        controller: the core controller. learner: its :class:`ReceivedEstimates`.
        safe_holds: cycles commanded with the safe hold. published: torques published.
        last_command: the newest ImpactTaskCommand.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("impact_controller", join=False, **kwargs)
        from ffmpc_core.impact.scenario import task_config

        p = self.params
        if not p["lockstep"]:
            self.refuse("the impact controller runs in lockstep only (lockstep: true)")
        self.config = impact_config_from_parameters(self.spec, p)
        self.approach, self.regulation = str(p["approach"]), str(p["regulation"])
        self.learning_strategy = (
            self.approach == "maximal" and self.config.strategy in LEARNING_STRATEGIES
        )
        self.robot = load_robot(self.scenario.robot)
        self.joint_names = list(self.robot.joint_names)
        self._data = self.robot.create_data()
        limits = self.config.control_limits(joint_limits(self.robot))
        self.learner = ReceivedEstimates()
        self.external = self.approach == "maximal"
        self.controller = ImpactTaskController(
            self.robot,
            limits,
            task_config(self.approach, self.regulation, self.config),
            learner=self.learner,
            external_approach=self.external,
        )
        self.uses_learner = self.regulation == "ff_mpc"
        self.lockstep_timeout = float(p["lockstep_timeout"])
        self._pending: dict[int, tuple[ContactMeasurement, float]] = {}
        # cycle → (the approach's part, None: the planner's safe stop; its sample count)
        self._references: dict[int, tuple[ExternalApproach | None, int]] = {}
        self._bad_references = 0
        self._estimates: dict[int, ContactEstimate] = {}
        self._last_run: int | None = None
        self.safe_holds = 0
        self.published = 0
        self.last_command: ImpactTaskCommand | None = None
        self.pub_torque = self.graph_publisher(JointState, topics.IMPACT_TORQUE)
        self.pub_status = self.graph_publisher(Float64MultiArray, topics.IMPACT_CONTROL_STATUS)
        self.subscribe_measurements(True)
        if self.external:
            self.create_subscription(
                Float64MultiArray,
                topics.IMPACT_REFERENCE,
                self.on_reference,
                topics.subscriber_qos(True, topics.IMPACT_REFERENCE),
            )
        if self.uses_learner:
            self.create_subscription(
                Float64MultiArray,
                topics.CONTACT_ESTIMATE,
                self.on_estimate,
                topics.subscriber_qos(True, topics.CONTACT_ESTIMATE),
            )
        self.create_timer(
            WATCHDOG_PERIOD, self._watchdog, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self.join_graph()

    # -- inputs ------------------------------------------------------------------------------
    def process_cycle(self, k: int, q: np.ndarray, v: np.ndarray, wrench: np.ndarray) -> None:
        from ffmpc_core.impact.scenario import dice_measurement

        m = dice_measurement(self.robot, self._data, q, v, wrench)
        self._pending[k] = (m, time.monotonic())
        self._run_ready()

    def on_reference(self, msg: Float64MultiArray) -> None:
        topic = self.name_of(topics.IMPACT_REFERENCE)
        try:
            fields, k = reference_fields(self, msg)
            command = reference_approach(fields, self.learning_strategy, self.config)
        except InputError as exc:
            # the planner sends one reference per cycle, in order: this one was the next's
            self.reject(f"{topic}:value", f"{exc}; that cycle holds its pose")
            self._bad_references += 1
            self._run_ready()
            return
        if not self.gate.check_cycle(topic, k):
            return
        self.gate.accept(topic, k)
        self._references[k] = (
            None if fields["safe_stop"] > 0 else command,
            int(fields["learner_samples"]),
        )
        self._run_ready()

    def on_estimate(self, msg: Float64MultiArray) -> None:
        got = receive_estimate(self, msg)
        if got is None:
            return
        k, estimate, _ = got
        self.gate.accept(topics.CONTACT_ESTIMATE, k)
        self._estimates[k] = estimate
        self._run_ready()

    def _learner_fed(self, m: ContactMeasurement) -> bool:
        """Whether the learner is fed this cycle (ImpactTaskController's rule: in contact — the
        contact declared now or before — and pressing)."""
        threshold = self.config.contact_threshold
        in_contact = self.controller.contact_time is not None or m.force >= threshold
        return in_contact and m.force > 0.0

    def _ready(self, k: int, m: ContactMeasurement) -> bool:
        if self.external and k not in self._references and self._bad_references == 0:
            return False
        if self.learning_strategy:  # the planner's count says whether the learner fed cycle k
            if not self.uses_learner or k not in self._references:
                return True
            fed = self._references[k][1]
            return fed <= self.learner.samples or fed < 3 or k in self._estimates
        if self.uses_learner and self._learner_fed(m) and self.learner.samples + 1 >= 3:
            return k in self._estimates  # the learner node publishes once it has 3 samples
        return True

    def _run_ready(self, timed_out: bool = False) -> None:
        while self._pending:
            k = min(self._pending)
            m, since = self._pending[k]
            if not self._ready(k, m):
                if not (timed_out and time.monotonic() - since > self.lockstep_timeout):
                    return
                self.reject("inputs:missing", f"cycle {k}: inputs missing after the timeout")
            del self._pending[k]
            self._run_cycle(k, m)

    def _watchdog(self) -> None:
        self._run_ready(timed_out=True)

    # -- the control cycle -------------------------------------------------------------------
    def _run_cycle(self, k: int, m: ContactMeasurement) -> None:
        reference: ExternalApproach | None = None
        fed: int | None = None
        hold = False
        if self.external:
            if k in self._references:
                reference, fed = self._references.pop(k)
                hold = reference is None  # the planner's own safe stop
            elif self._bad_references > 0:
                self._bad_references -= 1
                hold = True
            else:
                hold = True  # missing after the timeout
        for old in [c for c in self._references if c < k]:
            del self._references[old]
        estimate = self._estimates.pop(k, None)
        for old in [c for c in self._estimates if c < k]:
            self._estimates.pop(old)
        if estimate is not None and not self.learning_strategy:
            self.learner.receive(estimate)
        t = self.grid.t_of(k)
        command = None
        if not hold:
            try:
                command = self.controller.step(m, t, reference)
            except FfmpcError as exc:
                self.reject("step", f"cycle {k}: {exc}; the cycle holds its pose")
        if self.learning_strategy:  # after the step: the hand-over of cycle k read cycle k−1's
            if fed is not None:
                self.learner.samples = fed
            if estimate is not None:
                self.learner.receive(estimate)
        if command is None:
            torque = self._hold_torque(m)
            self.safe_holds += 1
        else:
            torque = command.torque
            self.last_command = command
        self._publish(k, m, torque, command)

    def _hold_torque(self, m: ContactMeasurement) -> np.ndarray:
        """Hold the measured pose (zero velocity and acceleration, the held orientation) through
        the joint-limit guard, the measured wrench compensated."""
        c = self.controller
        rotation = c._hold_rotation if c._hold_rotation is not None else m.rotation
        zero = np.zeros(3)
        hold = CartesianCommand(
            phase=APPROACH,
            position=m.position,
            velocity=zero,
            acceleration=zero,
            rotation=rotation,
            pre_impact_velocity=math.nan,
            force=m.force,
            target_force=0.0,
        )
        return c.law.torque(hold, m.q, m.v, m.wrench)

    def _publish(
        self,
        k: int,
        m: ContactMeasurement,
        torque: np.ndarray,
        command: ImpactTaskCommand | None,
    ) -> None:
        from ffmpc_ros.plant_node import joint_state_message

        stamp = self.grid.stamp_of(k)
        zeros = np.zeros(self.robot.nv)
        self.pub_torque.publish(joint_state_message(stamp, self.joint_names, zeros, zeros, torque))
        c = self.controller

        def finite(value: float | None, default: float) -> float:
            return default if value is None or not math.isfinite(value) else float(value)

        stopped = c.stopped_short
        status = {
            "t": self.grid.t_of(k),
            "safe_hold": float(command is None),
            "in_contact": float(c.contact_time is not None),
            "phase": PHASE_CODES.get("" if command is None else command.phase, -1.0),
            "pre_impact_velocity": finite(
                None if command is None else command.pre_impact_velocity, 0.0
            ),
            "contact_time": finite(c.contact_time, -1.0),
            "touch_speed": finite(c.touch_speed, 0.0),
            "handover_time": finite(c.handover_time, -1.0),
            "mpc_weight": 0.0 if command is None else command.mpc_weight,
            "mpc_stiffness": finite(None if command is None else command.mpc_stiffness, 0.0),
            "mpc_damping": finite(None if command is None else command.mpc_damping, 0.0),
            "mpc_learned": float(command is not None and command.mpc_learned),
            "mpc_force": finite(None if command is None else command.mpc_force, 0.0),
            "learner_samples": float(self.learner.samples),
            "stopped_short_time": -1.0 if stopped is None else stopped.time,
            "stopped_short_force": 0.0 if stopped is None else stopped.force,
            "rejected": float(sum(self.rejected.values())),
            "nv": float(self.robot.nv),
            "torque": torque,
        }
        self.pub_status.publish(layouts.IMPACT_CONTROL.pack(status, nv=self.robot.nv))
        self.published += 1
        self._last_run = k


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(ImpactControllerNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
