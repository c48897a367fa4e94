"""The LFC-law node: the agimus linear_feedback_controller's law on topics, in ros2_control's
terms (``ffmpc_core.linear_feedback``: τ = τ_ff + K·(x₀ ⊖ x) at the plant's rate).

It stands in for the real controller (a ros2_control chainable controller, C++) in ffmpc's graph
with ``interfaces: ros2_control`` (``ffmpc run --interfaces ros2_control --low-level lfc``), in
the PID node's place:

* subscribes ``joint_sensor/joint_states`` (q̂ rad, q̇̂ rad/s, τ̂ N·m; on a robot: remap it to
  ``/joint_states``) and ``linear_feedback_controller/control``
  (``linear_feedback_controller_msgs/Control``, ``ffmpc_ros.lfc_msgs``);
* publishes, for every measured cycle k: ``linear_feedback_controller/sensor``
  (``linear_feedback_controller_msgs/Sensor``, the measured state stamped t_k — what the MPC
  solves from, as upstream's controller publishes it every update), then the effort on
  ``effort_controller/commands`` (``std_msgs/Float64MultiArray``, N·m, the robot's joint order:
  a forward_command_controller's input; saturated to the torque limits), its stamped record
  ``lfc/effort`` (JointState effort, N·m) and ``lfc/status`` (layout ``lowlevel_status``: mode,
  control age, blend weight, rejections).

Lockstep: on the MPC's ticks (k a multiple of ``mpc.period / time_step``) the node waits for the
Control of that cycle before stepping, as the PID waits for its command, and goes on without it
after ``lockstep_timeout`` wall s. Real time: every cycle is stepped at once with the newest
control. Before the first control, and once the newest is older than ``pid.stale_timeout``
(simulated s), the node sends ffmpc's safe hold (upstream: its joint PD, then the last control
for ever); a control it cannot use (other joints, wrong sizes or layout, non-finite, implausible
feed-forward) is rejected with one throttled log line and drops the current one (safe hold from
the next cycle).

Not in this node (upstream's controller has them): the free-flyer base, the joint-velocity
exponential filter (``joint_velocity_filter_coefficient``: ffmpc's joint sensor model already
filters nothing, and the MPC reads the same velocities), continuous joints.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from linear_feedback_controller_msgs.msg import Control, Sensor
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import InputError
from ffmpc_core.linear_feedback import LinearFeedbackCommand, LinearFeedbackLoop
from ffmpc_core.polishing import lowlevel_controller, steps_per_mpc_period
from ffmpc_core.robots import load_robot
from ffmpc_ros import topics
from ffmpc_ros.base import GraphNode, joint_state_message, run_node
from ffmpc_ros.lfc_msgs import control_fields, effort_message, sensor_message
from ffmpc_ros.low_level_report import LowLevelReport
from ffmpc_ros.message_parsing import joint_fields
from ffmpc_ros.time_grid import drop_stale_cycles

_KEEP = 50  # cycles of pending inputs kept


class LfcNode(GraphNode):
    """LinearFeedbackLoop on topics (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("lfc", join=False, **kwargs)
        s = self.scenario
        self.robot = load_robot(s.robot)
        self.joint_names = list(self.robot.joint_names)
        self.loop = LinearFeedbackLoop(
            self.robot,
            lowlevel_controller(s, self.robot),
            stale_timeout=s.pid.stale_timeout,
            transition_duration=float(self.params["pd_to_lf_transition_duration"]),
            remove_gravity=bool(self.params["remove_gravity_compensation_effort"]),
        )
        self.every = steps_per_mpc_period(s)
        self.lockstep = bool(self.params["lockstep"])
        self.lockstep_timeout = float(self.params["lockstep_timeout"])
        self._joints: dict[int, tuple] = {}
        self._controls: dict[int, LinearFeedbackCommand] = {}
        self._waiting_since: float | None = None
        self._skip_wait: set[int] = set()
        self.pub_sensor = self.graph_publisher(Sensor, topics.LFC_SENSOR)
        self.pub_effort = self.graph_publisher(Float64MultiArray, topics.EFFORT_COMMANDS)
        self.pub_record = self.graph_publisher(JointState, topics.LFC_EFFORT)
        self.report = LowLevelReport(
            self.graph_publisher(Float64MultiArray, topics.LFC_STATUS),
            self.rejected,
            "Control",
            "control_age_s",
        )
        self.create_subscription(
            JointState,
            topics.SENSED_JOINT_STATES,
            self.on_joints,
            topics.subscriber_qos(self.lockstep, topics.SENSED_JOINT_STATES),
        )
        self.create_subscription(
            Control,
            topics.LFC_CONTROL,
            self.on_control,
            topics.subscriber_qos(self.lockstep, topics.LFC_CONTROL),
        )
        if self.lockstep:
            self.create_timer(0.05, self._check_wait, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.join_graph()

    # -- inputs ------------------------------------------------------------------------------
    def on_joints(self, msg: JointState) -> None:
        topic = self.name_of(topics.SENSED_JOINT_STATES)
        got = self.gate.receive(
            topic, msg, joint_fields(self.joint_names, "position", "velocity", "effort")
        )
        if got is None:
            return
        k, (q, v, tau) = got
        self._joints[k] = (q, v)
        # the state the MPC solves from, before this cycle waits for its control
        self.pub_sensor.publish(sensor_message(self.grid.stamp_of(k), self.joint_names, q, v, tau))
        self._advance()

    def on_control(self, msg: Control) -> None:
        topic = self.name_of(topics.LFC_CONTROL)
        try:
            fields = control_fields(msg, self.joint_names, self.robot.model.nq)
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            self.loop.engage_hold()  # an unusable control: safe hold from the next cycle
            return
        k = self.cycle_of(fields["stamp"])
        if k is None:
            self.reject(f"{topic}:stamp", f"control time {fields['t']} s is no time")
            return
        if not self.gate.check_cycle(topic, k):
            return
        self.gate.accept(topic, k)
        self._controls[k] = LinearFeedbackCommand(
            fields["feedforward"], fields["feedback_gain"], fields["q0"], fields["v0"]
        )
        self._advance()

    # -- the loop ----------------------------------------------------------------------------
    def _ready(self, k: int) -> bool:
        if not self.lockstep or k % self.every != 0 or k in self._controls or k in self._skip_wait:
            return True
        if self._waiting_since is None:
            self._waiting_since = time.monotonic()
        return False

    def _check_wait(self) -> None:
        """Lockstep: stop waiting for a control that does not come (wall-time timeout)."""
        if self._waiting_since is None or not self._joints:
            return
        if time.monotonic() - self._waiting_since > self.lockstep_timeout:
            k = min(self._joints)
            self.reject("lockstep", f"no Control for cycle {k}; going on without it")
            self._skip_wait.add(k)
            self._waiting_since = None
            self._advance()

    def _advance(self) -> None:
        """Step every pending cycle whose inputs are complete, in order."""
        while self._joints:
            k = min(self._joints)
            if not self._ready(k):
                return
            self._waiting_since = None
            self._skip_wait.discard(k)
            q, v = self._joints.pop(k)
            for kc in sorted(c for c in self._controls if c <= k):
                try:
                    self.loop.set_command(self._controls.pop(kc), self.grid.t_of(kc))
                except InputError as exc:
                    self.reject(f"{self.name_of(topics.LFC_CONTROL)}:value", str(exc))
            self._step(k, q, v)
            drop_stale_cycles((self._joints, self._controls), k, _KEEP)

    def _step(self, k: int, q: np.ndarray, v: np.ndarray) -> None:
        try:
            out = self.loop.step(q, v, self.grid.t_of(k))
        except InputError as exc:
            self.reject("step", f"cycle {k}: {exc}")
            return
        stamp = self.grid.stamp_of(k)
        self.pub_effort.publish(effort_message(out.motor_torque))
        self.pub_record.publish(
            joint_state_message(stamp, self.joint_names, None, None, out.motor_torque)
        )
        self.report.publish(self.grid.t_of(k), out)

    def diagnostic_values(self, period: float) -> dict[str, str]:
        """The loop's mode (hold, blend, track, fallback) and command age (s, simulated)."""
        return self.report.values()

    def diagnostic_problems(self) -> list[str]:
        """The safe hold after the commands went stale or were refused (FALLBACK)."""
        return self.report.problems()


def main(argv: list[str] | None = None) -> int:
    return run_node(LfcNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
