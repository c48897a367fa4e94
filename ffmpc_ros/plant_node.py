"""The plant node: the PyBullet robot stand-in, the motor side (eq 31) and the simulated clock.

Publishes, for every cycle k, stamped t_k = k·time_step:

* ``/clock`` — t_k (every node runs on this simulated time);
* ``/plant/joint_states`` — the TRUE q (rad) and q̇ (rad/s) at t_k, and as effort the joint
  torque τ̂ (N·m) applied over the step that ended at t_k (eq 31: what the joint torque sensors
  measure; the simulator applies it saturated to the torque limits). At t_0 it is the gravity
  torque the motors hold the robot with;
* ``/plant/wrench`` — the true contact wrench the environment exerts on the tool, frame
  ``contact_world_aligned`` (N, N·m);
* ``/plant/truth`` (layout ``plant_truth``) and ``/plant/status`` (layout ``plant_status``,
  every 100 cycles, when a reflex stops the robot, and at the end; it carries the reflex's
  event).

Subscribes ``/pid/motor_torque``: τ^m of cycle k (saturated to the torque limits here too) goes
through the actuation model (eq 31, the ``actuation`` generator: τ̂ = a·τ^m(t − δs) + b −
friction + ν_τ) and the plant steps to t_{k+1}.

ros2_control's terms (``interfaces: ros2_control``): the plant is driven like a robot behind a
forward_command_controller instead, through ``effort_controller/commands``
(``std_msgs/Float64MultiArray``: one effort per joint, N·m, in the robot's joint order — the
controller's configured ``joints`` —, no stamp: in lockstep each message is the command of the
current cycle, in real time the newest), and also publishes ``joint_states`` (the same
JointState as ``plant/joint_states``, joint_state_broadcaster's topic). A command of another
size, non-finite or implausible is rejected with one throttled log line (the plant keeps waiting
in lockstep, keeps its last torque in real time), as forward_command_controller refuses a
command whose size is not its number of joints.

The robot's reflexes (``plant.reflex``, on by default; :mod:`ffmpc_core.reflex`, the same model
as the ROS-free runner and the real-time loop): the plant steps through the scenario's
:class:`~ffmpc_core.reflex.ReflexPlant`. A measured value over a data-sheet limit the robot stops
on, or motor torques missing for longer than the data sheet's command timeout (real time: the
drives' own safe stop, which replaced the node's former hold after ``max_input_age``), stops the
robot: the drives brake it to rest and hold it, every later motor torque is ignored, the run is
aborted (one log line, ``/plant/status`` at once).

Lockstep (default): the plant steps only once the motor torque of the current cycle has arrived,
so a run does not depend on the CPU speed. Real time (``lockstep: false``, this node on its
own): the plant steps on a wall-clock timer of period time_step with the newest motor torque; a
step taken without the torque of its own cycle is a deadline miss (and a step without a new
command for the communication reflex). ``ffmpc run --real-time``
does not use this path: it composes the plant with the sensor and PID nodes in one wall-clock
loop (``ffmpc_ros.realtime``), since separate processes cannot hold 1 kHz in Python. The
sensor-to-torque latency (wall time from publishing the state of cycle k to receiving its motor
torque) is measured in both modes.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import WrenchStamped
from rclpy.clock import Clock, ClockType
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray

from ffmpc_core.errors import InputError
from ffmpc_core.polishing import device_generator, scenario_robot
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import (
    GraphNode,
    interfaces_of,
    joint_state_message,
    run_node,
    wrench_stamped,
)
from ffmpc_ros.message_parsing import joint_arrays, vector
from sim_bridge.scenes import simulated_robot

STATUS_EVERY = 100  # cycles between two /plant/status messages


def wrench_message(stamp: TimeMsg, wrench_world: np.ndarray) -> WrenchStamped:
    """``plant/wrench`` of one cycle: [f; m] on the tool (N, N·m), ``contact_world_aligned``."""
    return wrench_stamped(stamp, wrench_world[:3], wrench_world[3:])


class PlantNode(GraphNode):
    """The simulated robot on topics (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("plant", join=False, **kwargs)
        s = self.scenario
        robot = self.robot = scenario_robot(s)  # carrying the tool (the cell's load data)
        self.joint_names = list(robot.joint_names)
        self.sim = simulated_robot(
            s, robot, device_generator(s.seed, "draws"), device_generator(s.seed, "actuation")
        )
        self.draws, self.task, self.actuation = self.sim.draws, self.sim.task, self.sim.actuation
        self.plant = self.sim.plant
        self.reflex_plant = self.sim.reflex_plant  # the robot's reflexes (module docstring)
        self._reflex_reported = False
        duration = float(self.params["duration"]) or self.task.duration
        self.steps = int(round(duration / self.time_step))
        self.lockstep = bool(self.params["lockstep"])
        self.k = 0
        self.tau_hat = robot.gravity(robot.q_nominal)  # the motors hold the robot at start
        self.motor_torque = self.tau_hat.copy()  # real time: used until a command arrives
        self._motor_cycle = -1  # cycle of self.motor_torque
        self.deadline_misses = 0
        self.latencies: list[float] = []
        self._published_at: dict[int, float] = {}
        self._wall_start: float | None = None
        self.state = self.plant.state()

        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.pub_clock = self.create_publisher(ClockMsg, topics.CLOCK, topics.clock_qos())
        self.pub_joints = self.graph_publisher(JointState, topics.PLANT_JOINT_STATES)
        self.pub_wrench = self.graph_publisher(WrenchStamped, topics.PLANT_WRENCH)
        self.pub_truth = self.graph_publisher(Float64MultiArray, topics.PLANT_TRUTH)
        self.pub_status = self.graph_publisher(Float64MultiArray, topics.PLANT_STATUS)
        self.ros2_control = interfaces_of(self) == topics.ROS2_CONTROL_INTERFACES
        self.pub_joint_states = (
            self.graph_publisher(JointState, topics.JOINT_STATES) if self.ros2_control else None
        )
        if self.ros2_control:
            self.create_subscription(
                Float64MultiArray,
                topics.EFFORT_COMMANDS,
                self.on_effort,
                topics.subscriber_qos(self.lockstep, topics.EFFORT_COMMANDS),
            )
        else:
            self.create_subscription(
                JointState,
                topics.MOTOR_TORQUE,
                self.on_motor,
                topics.subscriber_qos(self.lockstep, topics.MOTOR_TORQUE),
            )
        self.metrics_ready = False
        if self.params["wait_for_metrics"]:
            self.create_subscription(
                Bool,
                topics.METRICS_READY,
                self._on_metrics_ready,
                topics.subscriber_qos(True, topics.METRICS_READY),
            )
        self.started = False
        self._start_timer = self.create_timer(0.01, self._try_start, clock=self._steady)
        self.join_graph()

    def _try_start(self) -> None:
        """Start once the start handshake holds
        (:meth:`ffmpc_ros.start_barrier.StartBarrier.handshake`) and the
        metrics node is ready (``wait_for_metrics``: it has matched every topic it records):
        lockstep publishes the state of cycle 0, real time starts the wall-clock timer."""
        metrics = self.metrics_ready or not self.params["wait_for_metrics"]
        if not self.barrier.handshake(self.active, self.pub_joints, self.pub_clock, metrics):
            return
        self._start_timer.cancel()
        self.started = True
        if self.lockstep:
            self.publish_state()
        else:
            self._timer = self.create_timer(self.time_step, self.on_tick, clock=self._steady)

    def _on_metrics_ready(self, msg: Bool) -> None:
        self.metrics_ready = self.metrics_ready or bool(msg.data)

    # -- publishing -----------------------------------------------------------------------------
    def publish_state(self) -> None:
        """Publish the state of cycle self.k (clock first)."""
        k, s = self.k, self.state
        stamp = self.grid.stamp_of(k)
        self.pub_clock.publish(ClockMsg(clock=stamp))
        joints = joint_state_message(stamp, self.joint_names, s.q, s.v, self.tau_hat)
        wrench = wrench_message(stamp, s.wrench_world)
        truth = layouts.PLANT_TRUTH.pack(
            {
                "t": self.grid.t_of(k),
                "normal_force": s.normal_force,
                "in_contact": float(s.in_contact),
                "robot_collision": float(s.robot_collision),
                "table_normal": self.plant.table_normal,
                "contact_position": s.contact_frame_position,
            }
        )
        self._published_at[k] = time.perf_counter()
        self.pub_joints.publish(joints)
        if self.pub_joint_states is not None:
            self.pub_joint_states.publish(joints)
        self.pub_wrench.publish(wrench)
        self.pub_truth.publish(truth)
        if k % STATUS_EVERY == 0 or self.done:
            self.publish_status()

    def publish_status(self) -> None:
        lat = np.array(self.latencies) if self.latencies else np.zeros(1)
        count = len(self.latencies)
        self.pub_status.publish(
            layouts.PLANT_STATUS.pack(
                {
                    "t": self.grid.t_of(self.k),
                    "steps": self.k,
                    "done": float(self.done),
                    "lockstep": float(self.lockstep),
                    "deadline_misses": self.deadline_misses,
                    "latency_count": count,
                    "latency_mean": float(lat.mean()),
                    "latency_p50": float(np.percentile(lat, 50)),
                    "latency_p99": float(np.percentile(lat, 99)),
                    "latency_max": float(lat.max()),
                    "wall_time": time.perf_counter() - (self._wall_start or time.perf_counter()),
                    **layouts.reflex_status(self.reflex_plant.reflex),
                }
            )
        )

    @property
    def done(self) -> bool:
        return self.k >= self.steps

    def finished(self) -> bool:
        return False  # its reliable writers resend to readers that lag until it is shut down

    def diagnostic_values(self, period: float) -> dict[str, str]:
        """The plant's cycle and simulated time (s)."""
        return {"cycle": str(self.k), "sim_time_s": f"{self.grid.t_of(self.k):.3f}"}

    # -- stepping -------------------------------------------------------------------------------
    def on_motor(self, msg: JointState) -> None:
        topic = self.name_of(topics.MOTOR_TORQUE)
        k = self.gate.check_stamp(topic, msg.header.stamp)
        if k is None:
            return
        if self.lockstep and k != self.k:
            self.reject(f"{topic}:cycle", f"motor torque of cycle {k} while at cycle {self.k}")
            return
        try:
            (tau,) = joint_arrays(msg, self.joint_names, ("effort",))
            tau = self.robot.clip_torque(tau)  # an absurd torque is refused, not saturated
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            return
        self.gate.accept(topic, k)
        self._take_motor(k, tau)

    def on_effort(self, msg: Float64MultiArray) -> None:
        """A forward_command_controller command (module docstring): the current cycle's."""
        topic = self.name_of(topics.EFFORT_COMMANDS)
        if not self.active:
            self.reject(f"{topic}:inactive", f"{topic} ignored: the node is {self.lifecycle_state}")
            return
        try:
            tau = vector(msg.data, self.robot.nv, "effort command")
            tau = self.robot.clip_torque(tau)  # an absurd torque is refused, not saturated
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            return
        self.accepted[topic] += 1
        self._take_motor(self.k, tau)

    def _take_motor(self, k: int, tau: np.ndarray) -> None:
        """τ^m of cycle k (accepted): the latency, then a step in lockstep."""
        sent = self._published_at.pop(k, None)
        if sent is not None:
            self.latencies.append(time.perf_counter() - sent)
        self.motor_torque = tau
        self._motor_cycle = k
        if self.lockstep and not self.done:
            self.step_plant()

    def on_tick(self) -> None:
        """Real time: one step per wall-clock period, with the newest motor torque."""
        if self.done:
            self._timer.cancel()
            return
        if self._wall_start is None:
            self.publish_state()  # the first state; its command is due at the next tick
            self._wall_start = time.perf_counter()
            return
        fresh = self._motor_cycle == self.k
        if not fresh:
            self.deadline_misses += 1
        self.step_plant(fresh)

    def step_plant(self, fresh: bool = True) -> None:
        """Cycle k: actuation (eq 31) of τ^m, one physics step through the reflexes (``fresh``:
        τ^m is this cycle's; otherwise the drives hold the newest one), publish cycle k + 1."""
        if self._wall_start is None:
            self._wall_start = time.perf_counter()
        self.sim.push_if_due(self.k)
        self.tau_hat = self.actuation.step(self.motor_torque, self.state.v)
        self.reflex_plant.step(self.tau_hat, fresh=fresh)
        for old in [c for c in self._published_at if c < self.k - 1000]:
            del self._published_at[old]
        self.k += 1
        self.state = self.reflex_plant.state()
        reflex = self.reflex_plant.reflex
        if reflex.event is not None and not self._reflex_reported:
            self._reflex_reported = True
            self.get_logger().warning(reflex.event.describe())
            self.publish_status()
        self.publish_state()

    def destroy_node(self) -> None:
        self.plant.close()
        super().destroy_node()


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(PlantNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
