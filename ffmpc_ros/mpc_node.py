"""The MPC node: one of the three OCP formulations (parameter ``formulation``) in receding horizon.

Subscribes ``/joint_sensor/joint_states`` (q̂, q̇̂, τ̂) and, for force-feedback,
``/ft_sensor/wrench`` (λ̂); publishes ``/mpc/command`` (``ffmpc_msgs/MpcCommand``:
``ffmpc_ros.command_msg``) and, after the command and only while something subscribes,
``/mpc/prediction`` (layout ``mpc_prediction``: the horizon's contact positions and normal
forces, for the live view).

It solves at the ticks k = j·``period / time_step`` (as the ROS-free runner does), once it has
the measurements OF cycle k (joint state, and the wrench with the same stamp for force-
feedback). In real time (``lockstep: false``) it solves the newest complete tick (a tick that
arrives while a solve runs is skipped): the node warms up (``WARM_UP_SOLVES`` solves, then
``reset``) before it subscribes, and runs without an executor (``spin_realtime``: a wait set
over its inputs, newest sample taken). The command carries the measurement's time t_k; the
solver's wall time is reported but never used for control.

Learned contact (force-feedback only; parameter ``use_learned_contact``, default off, so the
polishing graph is unchanged): the node also subscribes ``/contact_learner/estimate`` (layout
``contact_estimate``) and, for every estimate that is confident (``learner_min_samples``,
``learner_max_relative_std``: both standard errors at most that fraction of the value), sets the
OCP's contact stiffness K (N/m) and damping B (N·s/m) live (``set_contact_parameters``) for the
next solve. The estimate is along the learner's motion direction: it replaces the normal-axis
entry of K and B (``contact.normal_axis``; the only one of a 1-D contact), and with a
LOCAL_WORLD_ALIGNED contact an estimate whose direction is not ±that axis is rejected. Each
accepted update is logged (at most one line per 2 s). Estimates are not synchronised with the
lockstep cycle: one applies from the first solve after its arrival.

Live parameters (``ffmpc_ros.params.MPC_LIVE``; checked, logged and queued by
:class:`~ffmpc_ros.live_parameters.LiveParameters`), applied in place at the next solve (no
rebuild of the OCP):

* ``contact.stiffness``, ``contact.damping``: K (N/m), B (N·s/m) of the force-feedback OCP
  (``ModelPredictiveController.set_contact_parameters``; refused for the other formulations);
  with ``use_learned_contact`` the learner's next confident estimate overrides the normal entry;
* ``weights.<formulation>.{posture,joint_velocity,torque,ee_velocity,force_rate}``: the cost
  weights c (``set_cost_weight``), of the formulation the node runs only;
  ``weights.<formulation>.{force_phase,ee_position_phase}``: the task's phase weights c6, c4;
* ``task.normal_force`` (N) and ``position_offset`` (m, world): the force set-point and the offset
  of the position reference (:class:`ffmpc_core.tasks.LiveTask`), blended in with a minimum jerk
  over ``RETARGET_BLEND`` s from the time of the solve that applies them.

Reference topics (relative names, ``msgs_notes/topics.md``): ``mpc/reference``
(``geometry_msgs/PoseStamped``: the target of the contact frame, world frame, m: the polishing
circle's centre, the contact point of the other tasks; the orientation is not used) and
``mpc/force_setpoint`` (``std_msgs/Float64``, N). Each valid message sets ``position_offset`` =
target − the scenario's target (or ``task.normal_force``) through the node's own parameters, so
it is applied, logged and read back (``get_parameter``) like a live parameter. A message with a
non-finite value, a frame_id other than ``world``, a stamp from the future, a target farther
than the schema's bound on ``mpc.position_offset`` (0.1 m per axis) from the scenario's, or a
force outside ``task.normal_force``'s range is rejected and counted
(:meth:`ffmpc_ros.input_gate.InputGate.reject`).
In real time the node serves the reference topics from its wait set, but not the parameter
services (it has no executor).

ros2_control's terms (graph parameter ``interfaces: ros2_control``; docs/explanation/ros.md "MPC on
a ros2_control
robot"): the node reads ``linear_feedback_controller/sensor`` (``linear_feedback_controller_msgs/
Sensor``: q̂, q̇̂, τ̂ stamped t_k, as the agimus linear_feedback_controller publishes them) instead
of the joint states, and publishes ``linear_feedback_controller/control``
(``linear_feedback_controller_msgs/Control``: τ* as the feed-forward, the first Riccati gain
K = −G on the (q, v) columns, x0 as the initial state; ``ffmpc_ros.lfc_msgs``) instead of
``mpc/command``, so that a real linear_feedback_controller (or ffmpc's PID or LFC-law node)
executes it. The wrench input is the same.
"""

from __future__ import annotations

import contextlib
import gc
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from ffmpc_msgs.msg import MpcCommand as MpcCommandMsg
from geometry_msgs.msg import PoseStamped, WrenchStamped
from linear_feedback_controller_msgs.msg import Control, Sensor
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_core.impact.learner import confident
from ffmpc_core.mpc import ModelPredictiveController, MpcMeasurement
from ffmpc_core.polishing import (
    build_task,
    measured_force,
    mpc_config,
    mpc_schedule,
    scenario_robot,
    steps_per_mpc_period,
)
from ffmpc_core.scenario import SCHEMA
from ffmpc_core.tasks import PhaseWeights
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import GraphNode, interfaces_of, run_node
from ffmpc_ros.command_msg import command_message
from ffmpc_ros.impact_common import DIRECTION_TOLERANCE, receive_estimate
from ffmpc_ros.input_gate import MAX_FUTURE_STAMP
from ffmpc_ros.lfc_msgs import control_message, sensor_fields
from ffmpc_ros.message_parsing import joint_fields, wrench_array
from ffmpc_ros.time_grid import drop_stale_cycles

_KEEP = 20  # cycles of unmatched measurements kept
WARM_UP_SOLVES = 20  # real time: solves before the node subscribes to its inputs


class MpcNode(GraphNode):
    """ModelPredictiveController on topics (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("mpc", join=False, **kwargs)
        s = self.scenario
        self.robot = scenario_robot(s)  # carrying the tool (the cell's load data)
        self.joint_names = list(self.robot.joint_names)
        self.lockstep = bool(self.params["lockstep"])
        # a wall-clock cap on the solve (mpc.constraints.max_solve_time) in real time only
        self.config = mpc_config(s, real_time=not self.lockstep)
        self.task = build_task(s, self.robot)
        self.schedule = mpc_schedule(self.task, s)
        self.mpc = ModelPredictiveController(self.robot, self.config, self.schedule)
        # The reference topics' target without an offset: the circle's centre, else the contact
        # point (m, world); position_offset = target − this.
        centre = getattr(self.task, "circle_center", None)
        self.nominal_target = (
            centre() if centre is not None else np.asarray(self.task.contact_position, float)
        )
        self.every = steps_per_mpc_period(s)
        self.needs_force = self.config.formulation == "force_feedback"
        self._joints: dict[int, tuple] = {}
        self._forces: dict[int, np.ndarray] = {}
        self._last_solve: int | None = None
        self.sequence = 0
        self.solve_times: list[float] = []
        self._diagnosed_solves = (0, 0)  # (solves, failed solves) at the last report
        if not self.lockstep:
            self.warm_up()
        self.ros2_control = interfaces_of(self) == topics.ROS2_CONTROL_INTERFACES
        contact = self.config.contact
        self.force_axes = [contact.normal_axis] if contact.dimension == 1 else [0, 1, 2]
        command_type, command_topic = (
            (Control, topics.LFC_CONTROL)
            if self.ros2_control
            else (MpcCommandMsg, topics.MPC_COMMAND)
        )
        self.publisher = self.create_publisher(
            command_type, command_topic, topics.publisher_qos(command_topic)
        )
        self.prediction_publisher = self.create_publisher(
            Float64MultiArray, topics.MPC_PREDICTION, topics.publisher_qos(topics.MPC_PREDICTION)
        )
        qos = topics.subscriber_qos(self.lockstep, topics.SENSED_JOINT_STATES)  # SENSOR, all
        self._on_state = self.on_sensor if self.ros2_control else self.on_joints
        self.inputs = [
            self.create_subscription(Sensor, topics.LFC_SENSOR, self.on_sensor, qos)
            if self.ros2_control
            else self.create_subscription(
                JointState, topics.SENSED_JOINT_STATES, self.on_joints, qos
            )
        ]
        if self.needs_force:
            self.inputs.append(
                self.create_subscription(WrenchStamped, topics.SENSED_WRENCH, self.on_wrench, qos)
            )
        ref_qos = topics.reference_qos()
        self.references = [
            self.create_subscription(PoseStamped, topics.MPC_REFERENCE, self.on_reference, ref_qos),
            self.create_subscription(
                Float64, topics.MPC_FORCE_SETPOINT, self.on_force_setpoint, ref_qos
            ),
        ]
        self.use_learned_contact = bool(self.params["use_learned_contact"])
        self.learner_min_samples = int(self.params["learner_min_samples"])
        self.learner_max_relative_std = float(self.params["learner_max_relative_std"])
        self.contact_updates = 0
        if self.use_learned_contact:
            if not self.needs_force:
                raise ConfigError("use_learned_contact needs the force_feedback formulation")
            contact = self.config.contact
            self.contact_stiffness = contact.stiffness_vector().copy()  # N/m, per force entry
            self.contact_damping = contact.damping_vector().copy()  # N·s/m
            self._learned_entry = 0 if contact.dimension == 1 else contact.normal_axis
            self.estimates = self.create_subscription(
                Float64MultiArray,
                topics.CONTACT_ESTIMATE,
                self.on_estimate,
                topics.subscriber_qos(False, topics.CONTACT_ESTIMATE),
            )
        self.join_graph()

    def on_sensor(self, msg: Sensor) -> None:
        """ros2_control's terms: the measured state of a ``Sensor`` (its joint_state)."""
        self.on_joints(sensor_fields(msg), topics.LFC_SENSOR)

    def on_joints(self, msg: JointState, topic_name: str = topics.SENSED_JOINT_STATES) -> None:
        topic = self.name_of(topic_name)
        got = self.gate.receive(
            topic, msg, joint_fields(self.joint_names, "position", "velocity", "effort")
        )
        if got is None:
            return
        k, arrays = got
        self._joints[k] = tuple(arrays)
        self._try_solve(k)

    def on_wrench(self, msg: WrenchStamped) -> None:
        topic = self.name_of(topics.SENSED_WRENCH)
        got = self.gate.receive(
            topic, msg, lambda m: measured_force(wrench_array(m), self.config.contact)
        )
        if got is None:
            return
        k, force = got
        self._forces[k] = force
        self._try_solve(k)

    def on_estimate(self, msg: Float64MultiArray) -> None:
        """A learner estimate: applied to the OCP's contact model when confident."""
        topic = self.name_of(topics.CONTACT_ESTIMATE)
        got = receive_estimate(self, msg)
        if got is None:
            return
        k, estimate, direction = got
        contact = self.config.contact
        if contact.frame_type == "LOCAL_WORLD_ALIGNED":
            along = abs(float(direction[contact.normal_axis]))
            if along < 1.0 - DIRECTION_TOLERANCE:
                self.reject(
                    f"{topic}:direction",
                    f"estimate along {direction}, the contact model's axis is "
                    f"{contact.normal_axis}",
                )
                return
        self.gate.accept(topic, k)
        if not confident(estimate, self.learner_min_samples, self.learner_max_relative_std):
            return
        stiffness, damping = self.contact_stiffness.copy(), self.contact_damping.copy()
        stiffness[self._learned_entry] = estimate.stiffness
        damping[self._learned_entry] = estimate.damping
        try:
            self.mpc.set_contact_parameters(stiffness, damping)
        except FfmpcError as exc:
            self.reject(f"{topic}:value", str(exc))
            return
        self.contact_stiffness, self.contact_damping = stiffness, damping
        self.contact_updates += 1
        self.gate.inform(
            "contact_update",
            f"contact model from the learner: stiffness {estimate.stiffness:.1f} N/m, damping "
            f"{estimate.damping:.2f} N·s/m ({estimate.samples} samples, update "
            f"{self.contact_updates})",
        )

    # -- live parameters and reference topics ------------------------------------------------
    applies_at = "next solve"

    def check_live(self, name: str, value: Any) -> str | None:
        """The MPC's own rules (module docstring): which formulation and task can take it."""
        formulation = self.config.formulation
        if name.startswith("contact.") and formulation != "force_feedback":
            return f"the {formulation} formulation has no visco-elastic contact (K, B unused)"
        if name.startswith("weights."):
            form, _, term = name[len("weights.") :].partition(".")
            if form != formulation:
                return f"this node runs the {formulation} formulation, not {form}"
            if term == "force_rate" and formulation != "force_feedback":
                return "only the force-feedback formulation has the force-rate cost"
        if name == "task.normal_force" and not self.schedule.nominal_force:
            return (
                f"the {self.scenario.task.name} task has no single positive force set-point "
                f"(task.normal_force is {self.scenario.task.normal_force} N at start)"
            )
        return None

    def apply_live(self, changes: dict, k: int) -> None:
        """Apply accepted live parameters before the solve of tick k (module docstring)."""
        t_task = self.mpc.task_time(self.grid.t_of(k))
        contact = self.mpc.config.contact
        stiffness = changes.get("contact.stiffness", contact.stiffness)
        damping = changes.get("contact.damping", contact.damping)
        phase = False
        try:
            if "contact.stiffness" in changes or "contact.damping" in changes:
                self.mpc.set_contact_parameters(stiffness, damping)
                if self.use_learned_contact:
                    self.contact_stiffness = self.mpc.config.contact.stiffness_vector().copy()
                    self.contact_damping = self.mpc.config.contact.damping_vector().copy()
            for name, value in changes.items():
                if name.startswith("weights."):
                    term = name.rpartition(".")[2]
                    if term in ("force_phase", "ee_position_phase"):
                        phase = True
                    else:
                        self.mpc.set_cost_weight(term, value)
            if phase:
                form = self.config.formulation
                force = self.get_parameter(f"weights.{form}.force_phase").value
                ee = self.get_parameter(f"weights.{form}.ee_position_phase").value
                self.schedule.set_phase_weights(
                    PhaseWeights(free_ee_position=ee, contact_ee_position=ee, force=force)
                )
            if "task.normal_force" in changes:
                self.schedule.set_force(changes["task.normal_force"], t_task)
            if "position_offset" in changes:
                self.schedule.set_position_offset(changes["position_offset"], t_task)
        except FfmpcError as exc:  # (checked when accepted: not expected)
            self.reject("parameter", f"cycle {k}: {exc}")

    def on_reference(self, msg: PoseStamped) -> None:
        """A target position of the contact frame (module docstring)."""
        topic = topics.MPC_REFERENCE
        if msg.header.frame_id != topics.WORLD_FRAME:
            self.reject(
                f"{topic}:frame",
                f"frame_id {msg.header.frame_id!r}, expected {topics.WORLD_FRAME!r}",
            )
            return
        stamp_ns = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        ahead = (stamp_ns - self.get_clock().now().nanoseconds) * 1e-9
        if ahead > MAX_FUTURE_STAMP:
            self.reject(f"{topic}:future", f"stamp {stamp_ns * 1e-9:.6f} s is {ahead:.4f} s ahead")
            return
        p = msg.pose.position
        target = np.array([p.x, p.y, p.z], dtype=float)
        if not np.all(np.isfinite(target)):
            self.reject(f"{topic}:value", f"target position is not finite: {target}")
            return
        offset = target - self.nominal_target
        bound = SCHEMA["mpc.position_offset"].range
        assert bound is not None  # the schema bounds it
        if np.any(offset < bound[0]) or np.any(offset > bound[1]):
            self.reject(
                f"{topic}:workspace",
                f"target {np.round(target, 4).tolist()} m is {np.round(offset, 4).tolist()} m "
                f"from the task's {np.round(self.nominal_target, 4).tolist()} m (bound "
                f"[{bound[0]:g}, {bound[1]:g}] m per axis)",
            )
            return
        self._set_from_topic(topic, Parameter("position_offset", value=offset.tolist()))

    def on_force_setpoint(self, msg: Float64) -> None:
        """A force set-point, N (module docstring)."""
        self._set_from_topic(
            topics.MPC_FORCE_SETPOINT, Parameter("task.normal_force", value=float(msg.data))
        )

    def _set_from_topic(self, topic: str, param: Parameter) -> None:
        """Set a live parameter from a reference topic: checked first (a refusal is a rejected
        message, counted, one throttled line), then set like any parameter request."""
        reason = self.live.refusal([param])
        if reason is not None:
            self.reject(f"{topic}:value", reason)
            return
        result = self.set_parameters([param])[0]
        if not result.successful:
            self.reject(f"{topic}:value", result.reason)
            return
        self.accepted[topic] += 1

    def _due(self, k: int) -> bool:
        """Whether cycle k is an MPC tick to solve: k = j·every (the runner's grid, and the
        cycles the PID waits on in lockstep), after the last solve. Never off the grid: after
        an outage (a process frozen and resumed) a solve on the first cycle that completes
        would shift every later command by a cycle from the ticks the PID waits for (measured:
        each PID tick then timed out, the commands acted a cycle late, and the wrist went to
        8× its velocity limit)."""
        return k % self.every == 0 and (self._last_solve is None or k > self._last_solve)

    def _behind_clock(self, k: int) -> bool:
        """Lockstep: whether tick k is already more than one MPC period behind this node's
        clock (the plant's newest cycle), and is skipped (counted as ``solve:late``).

        In a lockstep run the plant never passes a tick before the PID has its command, so an
        on-time tick is never behind; a tick that is behind comes from a backlog (a process
        frozen and resumed finds the sensor messages queued meanwhile). Its command would reach
        the PID after the PID went on without it, and solving it would hide the outage from the
        controller: the task's clock pauses for the time between two solves
        (``ModelPredictiveController.step``), so the next solve must be the first live tick."""
        if not self.lockstep:
            return False
        behind = self.get_clock().now().nanoseconds - k * self.step_ns
        if behind > self.every * self.step_ns:
            self.reject("solve:late", f"tick {k} is {behind * 1e-9:.4f} s behind the clock")
            return True
        return False

    # -- real time ----------------------------------------------------------------------------
    def warm_up(self, solves: int = WARM_UP_SOLVES) -> None:
        """Real time: solve a few times from the start posture (t = 0), then forget it all
        (``reset``): the first real solve then runs warm code, not a cold start."""
        nv = self.robot.nv
        q = self.robot.q_nominal
        meas = MpcMeasurement(
            q=q.copy(),
            v=np.zeros(nv),
            force=np.zeros(self.config.contact.dimension) if self.needs_force else None,
            torque=self.robot.gravity(q),
        )
        for _ in range(solves):
            self.mpc.reset()
            self.mpc.step(meas, 0.0)
        self.mpc.reset()

    def _is_tick(self, stamp: TimeMsg) -> bool:
        """Real time: whether a stamp is an MPC tick (other cycles are not parsed at all)."""
        k = self.cycle_of(stamp)
        return k is None or k % self.every == 0  # (a stamp that is no time: rejected there)

    def spin_realtime(self) -> None:
        """Real time, instead of an executor: block on a wait set over the inputs, take the
        newest sample of each topic (older ones are worthless) and solve when it completes a
        tick; until the context shuts down (SIGINT). The collector is frozen and disabled.
        /clock is taken first at every wake-up (the newest sample): the node judges its inputs'
        stamps against it like every node (stale, or from the future and never adopted)."""
        from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

        context_handle = self.context.handle
        if context_handle is None:  # the context is already destroyed: nothing to wait for
            return
        gc.collect()
        gc.freeze()
        gc.disable()
        # (subscription, handler, only on MPC ticks): measurements, then the learner's estimate
        clock_topic = self.resolve_topic_name(topics.CLOCK)  # remapped: /arm1/clock
        clock = [s for s in self.subscriptions if s.topic_name == clock_topic]
        inputs = [(sub, sub.callback, False) for sub in clock]
        inputs += [
            (sub, handler, True)
            for sub, handler in zip(self.inputs, (self._on_state, self.on_wrench), strict=False)
        ]
        if self.use_learned_contact:
            inputs.append((self.estimates, self.on_estimate, False))
        inputs += [(sub, sub.callback, False) for sub in self.references]
        with contextlib.ExitStack() as stack:
            for sub, _, _ in inputs:
                stack.enter_context(sub.handle)
            stack.enter_context(context_handle)
            wait_set = _rclpy.WaitSet(len(inputs), 0, 0, 0, 0, 0, context_handle)
            while self.context.ok():
                wait_set.clear_entities()
                for sub, _, _ in inputs:
                    wait_set.add_subscription(sub.handle)
                try:
                    wait_set.wait(100_000_000)  # ns
                except Exception:  # noqa: BLE001  (the context shut down while waiting)
                    break
                for sub, handler, ticks_only in inputs:
                    newest = None
                    while (taken := sub.handle.take_message(sub.msg_type, sub.raw)) is not None:
                        newest = taken[0]
                    if newest is None or (ticks_only and not self._is_tick(newest.header.stamp)):
                        continue
                    handler(newest)
        gc.enable()

    def _try_solve(self, k: int) -> None:
        drop_stale_cycles((self._joints, self._forces), k, _KEEP)
        if not self._due(k) or k not in self._joints:
            return
        if self.needs_force and k not in self._forces:
            return
        q, v, tau = self._joints.pop(k)
        force = self._forces.pop(k, None)
        if self._behind_clock(k):
            return
        t = self.grid.t_of(k)
        self.live.apply_pending(k)
        try:
            command = self.mpc.step(MpcMeasurement(q=q, v=v, force=force, torque=tau), t)
        except FfmpcError as exc:
            self.reject("solve", f"cycle {k}: {exc}")
            return
        self._last_solve = k
        self.solve_times.append(command.solve_time)
        stamp, formulation = self.grid.stamp_of(k), self.config.formulation
        self.publisher.publish(
            control_message(stamp, formulation, self.joint_names, command, self.force_axes)
            if self.ros2_control
            else command_message(stamp, formulation, self.joint_names, self.sequence, command)
        )
        self.sequence += 1
        if self.prediction_publisher.get_subscription_count() > 0:
            self.publish_prediction(t)

    def publish_prediction(self, t: float) -> None:
        """``/mpc/prediction`` of the last solve (t: its time, s), after the command."""
        positions, forces, references = self.mpc.prediction()
        contact = self.config.contact
        column = 0 if contact.dimension == 1 else contact.normal_axis
        self.prediction_publisher.publish(
            layouts.MPC_PREDICTION.pack(
                {
                    "t": t,
                    "nodes": positions.shape[0],
                    "dt": self.config.dt,
                    "normal_axis": contact.normal_axis,
                    "normal_force": forces[:, column],
                    "reference_force": references[:, column],
                    "positions": positions,
                },
                nodes=positions.shape[0],
            )
        )

    def diagnostic_values(self, period: float) -> dict[str, str]:
        """Solves over the period: rate (Hz, wall), median and max solve time (ms, wall)."""
        new = self.solve_times[self._diagnosed_solves[0] :]
        values = {"solves": str(len(self.solve_times)), "solve_rate_hz": f"{len(new) / period:.1f}"}
        if new:
            values["solve_time_p50_ms"] = f"{1e3 * float(np.median(new)):.3f}"
            values["solve_time_max_ms"] = f"{1e3 * max(new):.3f}"
        return values

    def diagnostic_problems(self) -> list[str]:
        """Solves that failed since the previous report (their ticks got no command)."""
        failed = self.rejected["solve"] - self._diagnosed_solves[1]
        self._diagnosed_solves = (len(self.solve_times), self.rejected["solve"])
        return [f"{failed} solves failed"] if failed else []


def main(argv: list[str] | None = None) -> int:
    return run_node(MpcNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
