"""The MPC node: one of the three OCP formulations (parameter ``formulation``) in receding horizon.

Subscribes ``/joint_sensor/joint_states`` (q̂, q̇̂, τ̂) and, for force-feedback or a guarded
approach (``task.approach_speed`` > 0: its contact detection), ``/ft_sensor/wrench`` (λ̂);
publishes ``/mpc/command`` (``ffmpc_msgs/MpcCommand``:
``ffmpc_ros.command_msg``) and, after the command and only while something subscribes,
``/mpc/prediction`` (layout ``mpc_prediction``: the horizon's contact positions and normal
forces, for the live view).

It solves at the ticks k = j·``period / time_step`` (as the ROS-free runner does), once it has
the measurements OF cycle k (joint state, and the wrench with the same stamp for force-
feedback). In real time (``lockstep: false``) it solves the newest complete tick (a tick that
arrives while a solve runs is skipped): the node warms up (``WARM_UP_SOLVES`` solves, then
``reset``) before it subscribes, and runs without an executor (``spin_realtime``: a wait set
over its inputs, newest sample taken). The command carries the measurement's time t_k; the
solver's wall time is reported but never used for control. Its constrained solve
(``SolverCSQP``) makes at most ``real_time_iterations`` SQP iterations (graph parameter, 1 by
default; 0: ``mpc.max_iterations``, as lockstep): the full solve (two SQP iterations, each
a QP of 25 or more ADMM iterations) took 1.2 ms median and 2.7 ms at p99 in the MPC
process, so that with the rest of a step most commands missed the 2 ms period; one iteration
per tick (the real-time iteration scheme: the warm start carries the iterations on from tick
to tick) takes about what the unconstrained solve takes. Its plan is checked against every
bound as in lockstep and refused beyond ``violation_tolerance`` (the low level's safe hold).
Lockstep nodes never use it: their numbers are the ROS-free runner's.

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
  ``weights.<formulation>.{force_phase,ee_position_phase,ee_position_free}``: the task's phase
  weights c6, c4 in contact, c4 in free space;
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

from dataclasses import replace
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from ffmpc_msgs.msg import MpcCommand as MpcCommandMsg
from geometry_msgs.msg import PoseStamped, WrenchStamped
from linear_feedback_controller_msgs.msg import Control, Sensor
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from ffmpc_core.errors import FfmpcError
from ffmpc_core.mpc import ModelPredictiveController, MpcMeasurement
from ffmpc_core.polishing import (
    build_task,
    measured_force,
    mpc_config,
    mpc_schedule,
    scenario_robot,
    steps_per_mpc_period,
)
from ffmpc_core.tasks import PhaseWeights
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import GraphNode, interfaces_of, run_node
from ffmpc_ros.command_msg import command_message
from ffmpc_ros.impact_common import receive_estimate
from ffmpc_ros.lfc_msgs import control_message, sensor_fields
from ffmpc_ros.message_parsing import joint_fields, wrench_array
from ffmpc_ros.mpc_live import (
    LearnedContact,
    Refusal,
    apply_live_changes,
    live_refusal,
    reference_offset,
)
from ffmpc_ros.time_grid import drop_stale_cycles
from ffmpc_ros.wait_loop import Reader, spin_newest

_KEEP = 20  # cycles of unmatched measurements kept
WARM_UP_SOLVES = 20  # real time: solves before the node subscribes to its inputs


class MpcNode(GraphNode):
    """ModelPredictiveController on topics (see the module docstring)."""

    #: When an accepted live parameter takes effect (for the log line).
    applies_at = "next solve"

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("mpc", join=False, **kwargs)
        s = self.scenario
        self.robot = scenario_robot(s)  # carrying the tool (the cell's load data)
        self.joint_names = list(self.robot.joint_names)
        self.lockstep = bool(self.params["lockstep"])
        # a wall-clock cap on the solve (mpc.constraints.max_solve_time) in real time only
        self.config = mpc_config(s, real_time=not self.lockstep)
        if not self.lockstep:  # the constrained solve's SQP iterations (module docstring)
            iterations = int(self.params["real_time_iterations"])
            self.config = replace(self.config, constrained_iterations=iterations)
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
        # λ̂: the force-feedback state, and every formulation's guarded approach (its contact
        # detection, ffmpc_core.tasks.GuardedTask)
        self.needs_force = self.config.ocp.formulation == "force_feedback" or hasattr(
            self.task, "observe_force"
        )
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
        self.use_learned_contact = bool(self.params["use_learned_contact"])
        if self.use_learned_contact and self.config.ocp.formulation != "force_feedback":
            self.refuse("use_learned_contact needs the force_feedback formulation")
        self.learned = LearnedContact(
            self.config,
            int(self.params["learner_min_samples"]),
            float(self.params["learner_max_relative_std"]),
        )
        self._create_endpoints()
        self.join_graph()

    def _create_endpoints(self) -> None:
        """The command and prediction writers, the measurement, reference and (learned
        contact) estimate readers (module docstring)."""
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
        if self.use_learned_contact:
            self.estimates = self.create_subscription(
                Float64MultiArray,
                topics.CONTACT_ESTIMATE,
                self.on_estimate,
                topics.subscriber_qos(False, topics.CONTACT_ESTIMATE),
            )

    # -- measurements ---------------------------------------------------------------------------
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
        refusal = self.learned.direction_refusal(direction)
        if refusal is not None:
            self.reject(f"{topic}:{refusal.kind}", refusal.reason)
            return
        self.gate.accept(topic, k)
        try:
            applied = self.learned.apply(self.mpc, estimate)
        except FfmpcError as exc:
            self.reject(f"{topic}:value", str(exc))
            return
        if applied:
            self.gate.inform(
                "contact_update",
                f"contact model from the learner: stiffness {estimate.stiffness:.1f} N/m, "
                f"damping {estimate.damping:.2f} N·s/m ({estimate.samples} samples, update "
                f"{self.learned.updates})",
            )

    # -- live parameters and reference topics (ffmpc_ros.mpc_live) ------------------------------
    def check_live(self, name: str, value: Any) -> str | None:
        """The MPC's own rules (:func:`ffmpc_ros.mpc_live.live_refusal`)."""
        task = self.scenario.task
        nominal = bool(self.schedule.nominal_force)
        return live_refusal(
            name, value, self.config.ocp.formulation, task.name, nominal, task.normal_force
        )

    def apply_live(self, changes: dict, k: int) -> None:
        """Apply accepted live parameters before the solve of tick k
        (:func:`ffmpc_ros.mpc_live.apply_live_changes`)."""
        form = self.config.ocp.formulation

        def phase_weights() -> PhaseWeights:
            def value(name: str) -> float:
                return float(self.get_parameter(f"weights.{form}.{name}").value)

            return PhaseWeights(
                free_ee_position=value("ee_position_free"),
                contact_ee_position=value("ee_position_phase"),
                force=value("force_phase"),
            )

        t_task = self.mpc.task_time(self.grid.t_of(k))
        try:
            apply_live_changes(self.mpc, self.schedule, changes, t_task, phase_weights)
        except FfmpcError as exc:  # (checked when accepted: not expected)
            self.reject("parameter", f"cycle {k}: {exc}")
        if self.use_learned_contact and any(n.startswith("contact.") for n in changes):
            self.learned.follow(self.mpc)

    def on_reference(self, msg: PoseStamped) -> None:
        """A target position of the contact frame (module docstring)."""
        topic = topics.MPC_REFERENCE
        offset = reference_offset(msg, self.nominal_target, self.get_clock().now().nanoseconds)
        if isinstance(offset, Refusal):
            self.reject(f"{topic}:{offset.kind}", offset.reason)
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

    # -- the solve ------------------------------------------------------------------------------
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
        stamp, formulation = self.grid.stamp_of(k), self.config.ocp.formulation
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
                    "dt": self.config.ocp.dt,
                    "normal_axis": contact.normal_axis,
                    "normal_force": forces[:, column],
                    "reference_force": references[:, column],
                    "positions": positions,
                },
                nodes=positions.shape[0],
            )
        )

    # -- real time ------------------------------------------------------------------------------
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
        """Real time, instead of an executor (:func:`ffmpc_ros.wait_loop.spin_newest`): /clock
        first at every wake-up (the node judges its inputs' stamps against it like every
        node), the measurements on MPC ticks only, then the learner's estimate and the
        references."""
        clock_topic = self.resolve_topic_name(topics.CLOCK)  # remapped: /arm1/clock
        clock = [s for s in self.subscriptions if s.topic_name == clock_topic]
        readers: list[Reader] = [(sub, sub.callback, False) for sub in clock]
        readers += [
            (sub, handler, True)
            for sub, handler in zip(self.inputs, (self._on_state, self.on_wrench), strict=False)
        ]
        if self.use_learned_contact:
            readers.append((self.estimates, self.on_estimate, False))
        readers += [(sub, sub.callback, False) for sub in self.references]
        spin_newest(self, readers, self._is_tick)

    # -- diagnostics ----------------------------------------------------------------------------
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
