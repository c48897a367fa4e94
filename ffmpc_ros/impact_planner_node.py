"""The impact planner node: approach a soft object at the maximal safe pre-impact velocity, then
regulate the force (Dehio & Kheddar 2020, Sec. IV-C, Fig. 2; eq 9–14).

Subscribes ``/joint_sensor/joint_states`` (q̂, q̇̂) and ``/ft_sensor/wrench`` (λ̂, frame
``contact_world_aligned``), paired by cycle (:mod:`ffmpc_ros.impact_common`), and
``/contact_learner/estimate``. For each complete cycle k it runs
:class:`~ffmpc_core.impact.control.ImpactController` (the same object as the ROS-free
``studies.impact_study.run_impact``'s) at t_k = k·``plant.time_step`` and publishes, stamped
t_k:

* ``/impact_planner/command`` — geometry_msgs/TwistStamped, frame ``contact_world_aligned``:
  linear = the desired contact-frame velocity v_ref·d (m/s), angular = 0 (hold the orientation).
  In the approach v_ref tracks the eq 14 bound, ramped at the contact-space acceleration bound;
  once the pressing force −dᵀλ̂ reaches ``contact_threshold`` (2 N) the admittance controller
  regulates it to ``target_force`` (60 N);
* ``impact_planner/reference`` — layout ``impact_reference``: the whole Cartesian command
  (position, velocity, feed-forward acceleration, held orientation; world frame), what the
  impact controller node tracks (on a safe stop: zero velocity and acceleration at the last
  reference position);
* ``/impact_planner/status`` — layout ``impact_status``: phase, the maximal safe pre-impact
  velocity of the cycle, the commanded velocity/acceleration along d, the reference position,
  the force, the material used, the contact time and speed, failures and rejections.

Parameters. The impact study's values are declared under their
:data:`~ffmpc_core.impact.scenario.IMPACT_SCHEMA` names (``target_force``,
``contact_threshold``, ``planner.*``, ``planner.prior_stiffness``, ``plant.dice_max_penetration``,
``limit_margin``, ``replan_period``, ``admittance.*``, ``learner.*``, ``strategy``, ``touch.*``;
:data:`ffmpc_ros.params.IMPACT_PLANNER_SCHEMA`) with descriptors generated from the schema;
the node rebuilds the study's configuration with ``IMPACT_SCHEMA.build`` (the checks of
``ffmpc study impact --set``) and its controller with the ROS-free run's
``ffmpc_core.impact.scenario.task_config``. Its own graph parameters: ``direction``,
``acceleration_limit``, ``n_directions``, ``max_approach_velocity``, ``use_learned_material``.

Material. The planner plans with the prior (``planner.prior_stiffness``,
``planner.prior_damping``, ``plant.dice_max_penetration``); with ``strategy`` = prior and
``use_learned_material`` it switches to an estimate of ``/contact_learner/estimate`` for the
same direction once it is confident (``learner.min_samples``, ``learner.max_relative_std``),
from then on the newest confident estimate (z̄ stays the prior's).

Limits: the robot's position/torque limits, and ``limit_margin`` × its velocity and acceleration
limits (``acceleration_limit``, rad/s²; unset: the Panda data sheet, any other robot needs it).

Safe output. A rejected measurement (NaN/Inf, wrong names or frame, a stamp that is no time,
stale — not a duplicate or out-of-order one) makes the node publish a zero twist with
``safe_stop`` = 1, stamped with the newest of: the rejected message's cycle, the node's clock,
the last output. So does a watchdog (every 50 ms of wall time) when no complete cycle came for
``max_input_age`` of simulated time. Nothing is published before the first complete cycle. The
controller keeps its state: the next complete cycle resumes its command (a consumer ramps as its
own limits require).

Touch-first (parameter ``strategy`` = touch_first, ``touch.*`` = its
:class:`~ffmpc_core.impact.touch_first.TouchFirstConfig`): the node runs
:class:`~ffmpc_core.impact.touch_first.TouchFirstImpactController` with the contact learner
node's estimates as its learner (:class:`~ffmpc_ros.impact_common.ReceivedEstimates`). Each
reference carries the controller's learning gate (its phase and surface point after the cycle):
the learner node feeds cycle k's sample by the one feeding rule
(:func:`~ffmpc_core.impact.touch_first.fed_surface`) from the gate of cycle k−1, and this node
computes cycle k once the estimate of cycle k is in whenever that rule feeds it (3 samples and
more; after ``lockstep_timeout`` wall s without it, the cycle goes on with the previous one and
one log line). The reference also carries what the impact controller node takes from the
touch-first approach before its step (``strike``, ``impact_force``) and the samples fed.

Service ``/impact_planner/reset`` (std_srvs/Trigger): back to the approach phase; the next
cycle's pose becomes the hold pose (the learned material, if any, is kept).
"""

from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any

import numpy as np
from geometry_msgs.msg import TwistStamped
from rclpy.clock import Clock, ClockType
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from ffmpc_core.errors import FfmpcError
from ffmpc_core.impact.control import (
    CartesianCommand,
    ImpactController,
    ImpactControllerConfig,
    ImpactMeasurement,
)
from ffmpc_core.impact.controllers import contact_measurement, maximal_approach
from ffmpc_core.impact.deformation import SoftMaterial
from ffmpc_core.impact.learner import confident
from ffmpc_core.impact.limits import joint_limits
from ffmpc_core.impact.scenario import LEARNING_STRATEGIES, ImpactStudyConfig, task_config
from ffmpc_core.impact.strike_first import StrikeFirstImpactController
from ffmpc_core.impact.touch_first import (
    TouchCycleInputs,
    TouchFirstImpactController,
    fed_surface,
)
from ffmpc_core.robots import load_robot
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import run_node
from ffmpc_ros.impact_common import (
    DIRECTION_TOLERANCE,
    MeasuredCycleNode,
    ReceivedEstimates,
    direction_parameter,
    receive_estimate,
)
from ffmpc_ros.params import impact_config_from_parameters

#: Wall-time period of the missing-input watchdog, s.
WATCHDOG_PERIOD = 0.05


def controller_config(study: ImpactStudyConfig, params: dict) -> ImpactControllerConfig:
    """The node's ImpactControllerConfig: the ROS-free run's
    (``ffmpc_core.impact.scenario.task_config``'s ``controller``, from the impact study's
    configuration ``study``) with the node's own ``direction``, ``n_directions`` and
    ``max_approach_velocity`` (0: none) graph parameters (ConfigError when inconsistent)."""
    cap = float(params["max_approach_velocity"])
    return replace(
        task_config("maximal", "admittance", study).controller,
        direction=direction_parameter(params["direction"]),
        n_directions=int(params["n_directions"]),
        max_approach_velocity=cap if cap > 0 else math.inf,
    )


class ImpactPlannerNode(MeasuredCycleNode):
    """ImpactController on topics (see the module docstring).

    Attributes:
        controller: the core controller. learned_material: the confident estimate in use (None:
        the prior). safe_stops: safe stops published. last_command: the newest command.
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("impact_planner", join=False, **kwargs)
        p = self.params
        self.robot = load_robot(self.scenario.robot)
        self.joint_names = list(self.robot.joint_names)
        # the impact study's values (IMPACT_SCHEMA, validated as `ffmpc study impact --set`)
        self.study = impact_config_from_parameters(self.spec, p)
        acc = p["acceleration_limit"]
        limits = joint_limits(self.robot, None if acc is None else np.asarray(acc, dtype=float))
        self.limits = self.study.control_limits(limits)
        self.prior = self.study.prior
        self.config = controller_config(self.study, p)
        self.direction = self.config.direction
        self.strategy = self.study.strategy
        #: a learning strategy (touch-first, strike-first): the learner node feeds by its gate
        self.learning_strategy = self.strategy in LEARNING_STRATEGIES
        task = replace(task_config("maximal", "admittance", self.study), controller=self.config)
        self.controller: ImpactController
        if self.learning_strategy:
            if bool(p["use_learned_material"]) or not bool(p["lockstep"]):
                self.refuse(
                    f"strategy {self.strategy}: use_learned_material false (the strategy plans "
                    "from the learned interval itself) and lockstep true"
                )
            self.learner = ReceivedEstimates()
            self.controller = maximal_approach(self.robot, self.limits, task, self.learner)
        else:
            self.controller = maximal_approach(self.robot, self.limits, task)
        self._data = self.robot.create_data()
        self.lockstep_timeout = float(p["lockstep_timeout"])
        self._pending: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, float]] = {}
        self._estimates: dict = {}
        self._touch_inputs: TouchCycleInputs | None = None
        self.use_learned_material = bool(p["use_learned_material"])
        self.learner_min_samples = self.study.learner_min_samples
        self.learner_max_relative_std = self.study.learner_max_relative_std
        self.learned_material: SoftMaterial | None = None
        self.last_command: CartesianCommand | None = None
        self._last_output: int | None = None
        self._last_good: int | None = None
        self._stopped = False
        self.safe_stops = 0
        self.estimates_used = 0
        self.pub_command = self.graph_publisher(TwistStamped, topics.IMPACT_COMMAND)
        self.pub_status = self.graph_publisher(Float64MultiArray, topics.IMPACT_STATUS)
        self.pub_reference = self.graph_publisher(Float64MultiArray, topics.IMPACT_REFERENCE)
        self.subscribe_measurements(bool(p["lockstep"]))
        self.create_subscription(
            Float64MultiArray,
            topics.CONTACT_ESTIMATE,
            self.on_estimate,
            topics.subscriber_qos(self.learning_strategy, topics.CONTACT_ESTIMATE),
        )
        self.create_service(Trigger, topics.IMPACT_RESET_SERVICE, self.on_reset)
        self.create_timer(
            WATCHDOG_PERIOD, self._watchdog, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self.join_graph()

    # -- the control cycle -------------------------------------------------------------------
    def process_cycle(self, k: int, q: np.ndarray, v: np.ndarray, wrench: np.ndarray) -> None:
        if not self.learning_strategy:
            self._step(k, q, v, wrench)
            return
        self._pending[k] = (q, v, wrench, time.monotonic())
        self._run_ready()

    def _needs_estimate(self, q: np.ndarray, v: np.ndarray, wrench: np.ndarray) -> bool:
        """Touch-first: whether the next step feeds the learner (the one feeding rule) with an
        estimate to come (the learner node publishes from its third sample on)."""
        assert isinstance(self.controller, TouchFirstImpactController)
        m = contact_measurement(self.robot, self._data, q, v, wrench, self.direction)
        gate = self.controller.learning_gate()
        fed = fed_surface(gate, m.position, m.force, self.config.contact_threshold)
        return fed is not None and self.learner.samples + 1 >= 3

    def _run_ready(self, timed_out: bool = False) -> None:
        while self._pending:
            k = min(self._pending)
            q, v, wrench, since = self._pending[k]
            if self._needs_estimate(q, v, wrench) and k not in self._estimates:
                if not (timed_out and time.monotonic() - since > self.lockstep_timeout):
                    return
                self.reject("inputs:missing", f"cycle {k}: no estimate after the timeout")
            del self._pending[k]
            estimate = self._estimates.pop(k, None)
            for old in [c for c in self._estimates if c < k]:
                del self._estimates[old]
            if estimate is not None:
                self.learner.receive(estimate)
            self._step(k, q, v, wrench)

    def _step(self, k: int, q: np.ndarray, v: np.ndarray, wrench: np.ndarray) -> None:
        t = self.grid.t_of(k)
        material = self.controller.material
        try:
            if isinstance(self.controller, TouchFirstImpactController):
                m = contact_measurement(self.robot, self._data, q, v, wrench, self.direction)
                self._touch_inputs = self.controller.cycle_inputs(
                    m.speed, self.time_step, m.force, m.position
                )
            command = self.controller.step(ImpactMeasurement(q=q, v=v, force=wrench[:3]), t)
        except FfmpcError as exc:
            self.reject("step", f"cycle {k}: {exc}")
            self.input_failed(k)
            return
        self.last_command = command
        self._last_good = k
        self._stopped = False
        bound = command.pre_impact_velocity
        self._publish(
            k,
            command,
            command.velocity,
            {
                "safe_stop": 0.0,
                "pre_impact_velocity": bound if math.isfinite(bound) else 0.0,
                "velocity": float(self.direction @ command.velocity),
                "acceleration": float(self.direction @ command.acceleration),
                "stiffness": material.stiffness,
                "damping": material.damping,
                "learned": float(material is self.learned_material),
            },
        )

    def _publish(
        self, k: int, command: CartesianCommand, velocity: np.ndarray, fields: dict[str, float]
    ) -> None:
        """The twist ``velocity`` (m/s, world) of cycle k, the status and the reference of
        ``command`` (the newest command) with ``fields``."""
        c = self.controller
        msg = TwistStamped()
        msg.header.stamp = self.grid.stamp_of(k)
        msg.header.frame_id = topics.COMMAND_FRAME
        msg.twist.linear.x, msg.twist.linear.y, msg.twist.linear.z = (float(x) for x in velocity)
        self.pub_command.publish(msg)
        tf = c if isinstance(c, TouchFirstImpactController) else None

        def time_or(value: float | None, default: float) -> float:
            return default if value is None else float(value)

        status = {
            "t": self.grid.t_of(k),
            "phase": layouts.IMPACT_PHASES[c.phase],
            "touch_time": time_or(None if tf is None else tf.touch_time, -1.0),
            "touch_velocity": time_or(None if tf is None else tf.touch_velocity, 0.0),
            "decision_time": time_or(None if tf is None else tf.decision_time, -1.0),
            "admitted": float(isinstance(c, StrikeFirstImpactController) and c.admitted),
            "force": command.force,
            "target_force": command.target_force,
            "contact_time": -1.0 if c.contact_time is None else c.contact_time,
            "contact_velocity": 0.0 if c.contact_velocity is None else c.contact_velocity,
            "solver_failures": float(c.solver_failures),
            "rejected": float(sum(self.rejected.values())),
            "direction": self.direction,
            "position": command.position,
            **fields,
        }
        self.pub_status.publish(layouts.IMPACT_STATUS.pack(status))
        stop = fields["safe_stop"] > 0
        bound = command.pre_impact_velocity
        touch = self._touch_inputs
        gate = None if tf is None else tf.learning_gate()
        surface = None if gate is None else gate.surface
        stopped = c.stopped_short
        reference = {
            "t": self.grid.t_of(k),
            "safe_stop": fields["safe_stop"],
            "phase": layouts.IMPACT_PHASES[c.phase],
            "strike": 1.0 if touch is None else float(touch.strike),
            "impact_force": 0.0 if touch is None else touch.impact_force,
            "handover_allowed": 1.0 if touch is None else float(touch.handover_allowed),
            "learner_samples": float(c.learner.samples),
            "gate_phase": -1.0 if gate is None else layouts.IMPACT_PHASES[gate.phase],
            "gate_learn": float(gate is not None and gate.learn),
            "gate_surface_valid": float(surface is not None),
            "gate_surface": np.zeros(3) if surface is None else surface,
            "stopped_short_time": -1.0 if stopped is None else stopped.time,
            "stopped_short_force": 0.0 if stopped is None else stopped.force,
            "bound_valid": float(math.isfinite(bound) and not stop),
            "pre_impact_velocity": bound if math.isfinite(bound) and not stop else 0.0,
            "position": command.position,
            "velocity": velocity,
            "acceleration": np.zeros(3) if stop else command.acceleration,
            "rotation": command.rotation,
            "force": command.force,
            "target_force": command.target_force,
        }
        self.pub_reference.publish(layouts.IMPACT_REFERENCE.pack(reference))
        self._last_output = k

    # -- safe output -------------------------------------------------------------------------
    def _clock_cycle(self) -> int | None:
        ns = self.get_clock().now().nanoseconds
        return ns // self.step_ns if ns > 0 else None

    def input_failed(self, k: int | None) -> None:
        self.safe_stop(k)

    def safe_stop(self, k: int | None = None) -> None:
        """Publish a zero twist (``safe_stop`` = 1); see the module docstring for its stamp."""
        command = self.last_command
        if command is None:
            return  # nothing commanded yet: nothing to stop
        candidates = [c for c in (k, self._clock_cycle(), self._last_output) if c is not None]
        material = self.controller.material
        self._publish(
            max(candidates),
            command,
            np.zeros(3),
            {
                "safe_stop": 1.0,
                "pre_impact_velocity": 0.0,
                "velocity": 0.0,
                "acceleration": 0.0,
                "stiffness": material.stiffness,
                "damping": material.damping,
                "learned": float(material is self.learned_material),
            },
        )
        self._stopped = True
        self.safe_stops += 1

    def _watchdog(self) -> None:
        """Stop once when no complete cycle came for ``max_input_age`` (simulated time)."""
        if self.learning_strategy:
            self._run_ready(timed_out=True)
        if self._stopped or self._last_good is None:
            return
        now = self._clock_cycle()
        if now is None:
            return
        age = (now - self._last_good) * self.time_step
        if age > self.gate.max_input_age:
            self.reject("inputs:missing", f"no complete cycle for {age:.4f} s")
            self.safe_stop(now)

    # -- the learner's estimate --------------------------------------------------------------
    def on_estimate(self, msg: Float64MultiArray) -> None:
        topic = self.name_of(topics.CONTACT_ESTIMATE)
        got = receive_estimate(self, msg)
        if got is None:
            return
        k, estimate, direction = got
        if np.max(np.abs(direction - self.direction)) > DIRECTION_TOLERANCE:
            self.reject(f"{topic}:direction", f"estimate along {direction}, planning along d")
            return
        self.gate.accept(topic, k)
        if self.learning_strategy:
            self._estimates[k] = estimate
            self._run_ready()
            return
        if not self.use_learned_material or not confident(
            estimate, self.learner_min_samples, self.learner_max_relative_std
        ):
            return
        self.learned_material = SoftMaterial(
            estimate.stiffness, estimate.damping, self.prior.max_penetration
        )
        self.controller.material = self.learned_material
        self.estimates_used += 1
        self.gate.inform(
            "learned_material",
            f"planning with the learned material: stiffness {estimate.stiffness:.1f} N/m, "
            f"damping {estimate.damping:.2f} N·s/m ({estimate.samples} samples)",
        )

    def on_reset(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        self.controller.reset()
        if self.learned_material is not None:
            self.controller.material = self.learned_material
        self.last_command = None
        self._last_good = None
        self._stopped = False
        response.success = True
        response.message = "back to the approach phase"
        self.get_logger().info(f"reset: {response.message}")
        return response


def main(argv: list[str] | None = None) -> int:
    return run_node(ImpactPlannerNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
