"""The low-level torque node: hold / blend / track / fallback and the torque PID of eq 33.

Subscribes ``/joint_sensor/joint_states`` (q̂, q̇̂, τ̂), ``/mpc/command`` and, when the Riccati
feedback of force-feedback needs λ̂, ``/ft_sensor/wrench``. For every measured cycle k it runs
``ffmpc_core.lowlevel.LowLevelController`` (the same class as the ROS-free runner) and
publishes, stamped t_k:

* ``/pid/motor_torque`` — τ^m (JointState effort, N·m, saturated to the torque limits);
* ``/pid/desired_torque`` — τ^d, the torque the PID tracks (N·m, saturated);
* ``/pid/status`` — layout ``lowlevel_status`` (mode, command age, blend weight, rejections).

Lockstep: on the cycles where the MPC solves (k a multiple of ``mpc.period / time_step``) the
node waits for the command of that cycle before stepping, as the runner does; if none comes
within ``lockstep_timeout`` (wall time, s) it goes on without it (the stale-command fallback then
takes over). Real time: every cycle is stepped at once with the newest command.

Missing force (Riccati feedback of force-feedback). Cycle k waits for the wrench of cycle k only
while it may still come: once that wrench was rejected, a later one was accepted, the lockstep
timeout passed, or in real time, the cycle goes on without it; the low level then holds the newest
accepted λ̂ for ``force_hold_time`` and sends τ* without feedback after that
(``LowLevelController``, the runner's rule too). One bad wrench never stalls the loop.

Commands from outside the graph. Any node of the domain may publish on ``/mpc/command``. A
message is checked whole before it may claim the command of its cycle: its fields and sizes
(``command_msg.command_fields``), a torque within the plausibility bound
(``LowLevelController.check_command``), a cycle that is an MPC tick, not taken yet and not
stamped from the future. A rejected message is counted and logged (one throttled line per
kind) and changes nothing: no cycle is consumed, no safe hold is engaged, so the graph's own
MPC command for that tick is still taken and a lockstep run goes on (before, a finite but absurd
command stamped from ``/clock`` made the genuine one "out of order" and stalled the loop for
``lockstep_timeout``, and any malformed message engaged the safe hold). The MPC node never
publishes an implausible torque (``ModelPredictiveController.step`` raises instead; the tick then
gets no command and the stale-command rule holds the robot). A well-formed, plausible command
on a tick before the MPC's own cannot be told from it: rclpy 7.1.6 gives no publisher identity
per message and the wheels' Fast DDS has no security; the bring-up refuses to start beside
foreign publishers (``--allow-foreign-publishers`` to override).

Live parameters (``ffmpc_ros.params.PID_LIVE``), applied from the next cycle the node steps:
the gains ``kp``, ``ki`` (1/s), ``kd`` (s) of eq 33 (``TorquePid.set_gains``: the integral state
is kept, clamped to the new anti-windup bound), and the limits of the low level
(``LowLevelController.set_limits``): ``torque_limit_fraction``, the fraction of the robot's
data-sheet torque limits τ^d and τ^m are saturated to, in [0.01, 1] (a value above 1 is refused
with the schema's reason: never above the data sheet), and ``stale_timeout``, the command age
(s) that engages the safe hold, refused unless it exceeds the MPC period.

ros2_control's terms (graph parameter ``interfaces: ros2_control``): the node plays the agimus
linear_feedback_controller's part on its topics — it reads the MPC's
``linear_feedback_controller/control`` (``linear_feedback_controller_msgs/Control``:
``ffmpc_ros.lfc_msgs.low_level_command``; Control has no augmented gain columns, so the Riccati
feedback of torque- or force-feedback acts on (q, q̇) only) instead of ``mpc/command``, publishes
each measured state as ``linear_feedback_controller/sensor`` (what the MPC then reads) and sends
τ^m on ``effort_controller/commands`` too (``std_msgs/Float64MultiArray``, the robot's joint
order), the effort command topic of a forward_command_controller; with
``remove_gravity_compensation_effort`` minus g(q̂), for drives that add gravity compensation
themselves (Panda, KUKA FRI torque mode), as the agimus controller's parameter of that name.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np
from ffmpc_msgs.msg import MpcCommand as MpcCommandMsg
from geometry_msgs.msg import WrenchStamped
from linear_feedback_controller_msgs.msg import Control, Sensor
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import InputError
from ffmpc_core.lowlevel import LowLevelCommand, LowLevelMeasurement
from ffmpc_core.polishing import (
    lowlevel_controller,
    measured_force,
    scenario_robot,
    steps_per_mpc_period,
)
from ffmpc_ros import topics
from ffmpc_ros.base import GraphNode, interfaces_of, run_node
from ffmpc_ros.command_msg import command_fields
from ffmpc_ros.lfc_msgs import (
    control_fields,
    effort_message,
    low_level_command,
    sensor_message,
)
from ffmpc_ros.low_level_report import LowLevelReport
from ffmpc_ros.message_parsing import joint_fields, wrench_array
from ffmpc_ros.time_grid import drop_stale_cycles

_KEEP = 50  # cycles of pending inputs kept


class PidNode(GraphNode):
    """LowLevelController on topics (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("pid", join=False, **kwargs)
        s = self.scenario
        self.robot = scenario_robot(s)  # carrying the tool (the cell's load data)
        self.joint_names = list(self.robot.joint_names)
        self.lowlevel = lowlevel_controller(s, self.robot)
        self.every = steps_per_mpc_period(s)
        self.lockstep = bool(self.params["lockstep"])
        self.lockstep_timeout = float(self.params["lockstep_timeout"])
        self.needs_force = s.mpc.riccati_feedback and s.mpc.ocp.formulation == "force_feedback"
        self._joints: dict[int, tuple] = {}
        self._forces: dict[int, np.ndarray] = {}
        self._commands: dict[int, LowLevelCommand] = {}
        self._used_command: int | None = None  # cycle of the newest command handed to the loop
        self._force_rejected: set[int] = set()  # cycles whose wrench was rejected
        self._newest_force: int | None = None  # cycle of the newest accepted wrench
        self._last_step: int | None = None
        self._waiting_since: float | None = None
        self._skip_wait: set[int] = set()
        self.pub_motor = self.graph_publisher(JointState, topics.MOTOR_TORQUE)
        self.pub_desired = self.graph_publisher(JointState, topics.DESIRED_TORQUE)
        self.report = LowLevelReport(
            self.graph_publisher(Float64MultiArray, topics.LOWLEVEL_STATUS),
            self.rejected,
            "MPC command",
            "command_age_s",
        )
        sub_qos = topics.subscriber_qos(self.lockstep, topics.SENSED_JOINT_STATES)  # SENSOR
        self.create_subscription(JointState, topics.SENSED_JOINT_STATES, self.on_joints, sub_qos)
        self.ros2_control = interfaces_of(self) == topics.ROS2_CONTROL_INTERFACES
        contact = s.mpc.contact
        self.force_axes = [contact.normal_axis] if contact.dimension == 1 else [0, 1, 2]
        self.pub_sensor = self.pub_effort = None
        self.remove_gravity = bool(self.params["remove_gravity_compensation_effort"])
        self._gravity_data = self.robot.create_data()
        if self.ros2_control:
            self.pub_sensor = self.graph_publisher(Sensor, topics.LFC_SENSOR)
            self.pub_effort = self.graph_publisher(Float64MultiArray, topics.EFFORT_COMMANDS)
            self.create_subscription(
                Control,
                topics.LFC_CONTROL,
                self.on_control,
                topics.subscriber_qos(self.lockstep, topics.LFC_CONTROL),
            )
        else:
            self.create_subscription(
                MpcCommandMsg,
                topics.MPC_COMMAND,
                self.on_command,
                topics.subscriber_qos(self.lockstep, topics.MPC_COMMAND),
            )
        if self.needs_force:
            self.create_subscription(WrenchStamped, topics.SENSED_WRENCH, self.on_wrench, sub_qos)
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
        k, arrays = got
        self._joints[k] = tuple(arrays)
        if self.pub_sensor is not None:  # the state the MPC solves from (ros2_control's terms)
            self.pub_sensor.publish(
                sensor_message(self.grid.stamp_of(k), self.joint_names, *arrays)
            )
        self._advance()

    def on_wrench(self, msg: WrenchStamped) -> None:
        topic = self.name_of(topics.SENSED_WRENCH)
        got = self.gate.receive(
            topic, msg, lambda m: measured_force(wrench_array(m), self.scenario.mpc.contact)
        )
        if got is None:
            k = self.cycle_of(msg.header.stamp)
            if k is not None:
                self._force_rejected.add(k)
                self._advance()
            return
        k, force = got
        self._forces[k] = force
        self._newest_force = k
        self._advance()

    def on_command(self, msg: MpcCommandMsg) -> None:
        """An MPC command (module docstring, "Commands from outside the graph"): checked whole
        before it may claim its cycle; a rejected one changes nothing."""
        topic = self.name_of(topics.MPC_COMMAND)
        try:
            fields = command_fields(msg, self.robot.nv, self.robot.joint_names)
            if fields["nx"] != self.lowlevel.nx:
                raise InputError(
                    f"command for nx={fields['nx']}; this loop has nx={self.lowlevel.nx}"
                )
            command = self._checked_command(fields)
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            return
        self._take_command(topic, fields, command)

    def on_control(self, msg: Control) -> None:
        """ros2_control's terms: the MPC's ``Control`` (module docstring)."""
        topic = self.name_of(topics.LFC_CONTROL)
        try:
            fields = control_fields(msg, self.joint_names, self.robot.model.nq, self.force_axes)
            fields.update(
                low_level_command(fields, self.scenario.mpc.ocp.formulation, self.lowlevel.nx)
            )
            command = self._checked_command(fields)
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))  # changes nothing, as for on_command
            return
        self._take_command(topic, fields, command)

    def _checked_command(self, fields: dict) -> LowLevelCommand:
        """The low level's command of parsed ``fields``, checked whole (InputError) before it
        may claim a cycle."""
        return self.lowlevel.check_command(
            LowLevelCommand(fields["torque"], fields["state"], fields["feedback_gain"])
        )

    def _take_command(self, topic: str, fields: dict, command: LowLevelCommand) -> None:
        """A checked command (``fields``: its stamp and time) for the cycle of its stamp."""
        k = self.cycle_of(fields["stamp"])
        if k is None:
            self.reject(f"{topic}:stamp", f"command time {fields['t']} s off the grid")
            return
        if k % self.every != 0:
            self.reject(f"{topic}:tick", f"cycle {k} is no MPC tick (every {self.every} cycles)")
            return
        if k in self._commands or (self._used_command is not None and k <= self._used_command):
            self.reject(f"{topic}:order", f"a command for cycle {k} was already taken")
            return
        if not self.gate.check_cycle(topic, k, ordered=False):
            return
        self.gate.accept(topic, k)
        self._commands[k] = command
        self._advance()

    # -- the loop ----------------------------------------------------------------------------
    def _next_cycle(self) -> int | None:
        pending = sorted(self._joints)
        return pending[0] if pending else None

    def _force_settled(self, k: int) -> bool:
        """Whether cycle k need not wait any longer for its wrench (see the module docstring)."""
        return (
            k in self._forces
            or k in self._force_rejected
            or not self.lockstep
            or k in self._skip_wait
            or (self._newest_force is not None and self._newest_force > k)
        )

    def _ready(self, k: int) -> bool:
        if self.needs_force and not self._force_settled(k):
            if self._waiting_since is None:
                self._waiting_since = time.monotonic()
            return False
        if not self.lockstep or k % self.every != 0 or k in self._commands:
            return True
        if k in self._skip_wait:
            return True
        if self._waiting_since is None and self.lowlevel.command_time > -math.inf:
            # the timeout counts only once the MPC has been heard from (it may start slowly)
            self._waiting_since = time.monotonic()
        return False

    def _check_wait(self) -> None:
        """Lockstep: stop waiting for a command that does not come (wall-time timeout)."""
        if self._waiting_since is None:
            return
        if time.monotonic() - self._waiting_since > self.lockstep_timeout:
            k = self._next_cycle()
            if k is not None:
                self.reject("lockstep", f"no MPC command for cycle {k}; going on without it")
                self._skip_wait.add(k)
            self._waiting_since = None
            self._advance()

    def _advance(self) -> None:
        """Step every pending cycle whose inputs are complete, in order."""
        while True:
            k = self._next_cycle()
            if k is None or not self._ready(k):
                return
            self._waiting_since = None
            self._skip_wait.discard(k)
            q, v, tau = self._joints.pop(k)
            force = self._forces.pop(k, None)  # None: missing (the low level's hold rule)
            self._force_rejected.discard(k)
            for kc in sorted(c for c in self._commands if c <= k):
                self._used_command = kc
                try:
                    self.lowlevel.set_command(self._commands.pop(kc), self.grid.t_of(kc))
                except InputError as exc:
                    self.reject(f"{self.name_of(topics.MPC_COMMAND)}:value", str(exc))
            self._step(k, LowLevelMeasurement(q, v, tau, force))
            drop_stale_cycles((self._joints, self._forces, self._commands), k, _KEEP)
            if self._force_rejected:  # (empty on every cycle without a rejection)
                self._force_rejected = {c for c in self._force_rejected if c >= k - _KEEP}

    applies_at = "next cycle"

    def check_live(self, name: str, value: Any) -> str | None:
        """A command timeout must exceed the MPC period (an on-time MPC would look stale)."""
        if name == "stale_timeout" and float(value) <= self.lowlevel.config.mpc_period:
            return (
                f"stale_timeout {value} s must exceed the MPC period "
                f"{self.lowlevel.config.mpc_period} s (an on-time MPC would look stale)"
            )
        return None

    def apply_live(self, changes: dict, k: int) -> None:
        """New PID gains and limits from cycle k on (module docstring)."""
        self.lowlevel.set_gains(kp=changes.get("kp"), ki=changes.get("ki"), kd=changes.get("kd"))
        self.lowlevel.set_limits(
            torque_limit_fraction=changes.get("torque_limit_fraction"),
            stale_timeout=changes.get("stale_timeout"),
        )

    def _step(self, k: int, meas: LowLevelMeasurement) -> None:
        self.live.apply_pending(k)
        try:
            out = self.lowlevel.step(meas, self.grid.t_of(k))
        except InputError as exc:
            self.reject("step", f"cycle {k}: {exc}")
            return
        self._last_step = k
        stamp = self.grid.stamp_of(k)
        for pub, value in (
            (self.pub_motor, out.motor_torque),
            (self.pub_desired, out.desired_torque),
        ):
            msg = JointState()
            msg.header.stamp = stamp
            msg.name = self.joint_names
            msg.effort = value.tolist()
            pub.publish(msg)
        if self.pub_effort is not None:  # ros2_control's effort command topic
            effort = out.motor_torque
            if self.remove_gravity:  # drives that add gravity compensation themselves
                effort = effort - self.robot.gravity(meas.q, self._gravity_data)
            self.pub_effort.publish(effort_message(effort))
        self.report.publish(self.grid.t_of(k), out)

    def diagnostic_values(self, period: float) -> dict[str, str]:
        """The loop's mode (hold, blend, track, fallback) and command age (s, simulated)."""
        return self.report.values()

    def diagnostic_problems(self) -> list[str]:
        """The safe hold after the commands went stale or were refused (FALLBACK)."""
        return self.report.problems()


def main(argv: list[str] | None = None) -> int:
    return run_node(PidNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
