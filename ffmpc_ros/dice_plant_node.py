"""The dice plant node: the Panda and the soft dice of the impact experiment (Dehio & Kheddar
2020, Sec. VI) in the plant's simulator (``plant.engine``: PyBullet or MuJoCo), and the
simulated clock of the impact graph.

The plant is the ROS-free impact study's own (``sim_bridge.scenes.impact_plant_config``: no table,
the fixed soft dice, the spherical tool), started at ``ffmpc_core.impact.scenario.start_pose``
(the tool ``approach_height`` above the dice), both built from the impact study's values the
node declares (``plant.*``, ``approach_height``, ``duration``:
``ffmpc_ros.params.DICE_PLANT_SCHEMA``, generated from ``IMPACT_SCHEMA``, the configuration
rebuilt by :func:`ffmpc_ros.params.impact_config_from_parameters`). For every cycle k it
publishes, stamped t_k = k·time_step:

* ``/clock`` — t_k;
* ``plant/joint_states`` — the TRUE q (rad) and q̇ (rad/s) at t_k, and as effort the joint
  torque applied over the step that ended at t_k (N·m; 0 at t_0);
* ``plant/wrench`` — the true wrench the dice exerts on the tool, frame
  ``contact_world_aligned`` (N, N·m);
* ``plant/status`` (layout ``plant_status``) every 100 cycles, when a reflex stops the robot,
  and at the end.

Subscribes ``impact_controller/torque`` (sensor_msgs/JointState, effort N·m): the torque of
cycle k is applied for one step (the plant saturates it to the torque limits, as the ROS-free
run's plant does; a non-finite or absurd torque is rejected), through the robot's reflexes
(``plant.reflex``, on by default: :mod:`ffmpc_core.reflex`, the ROS-free run's model: a
crossing of a data-sheet limit the Panda stops on — q, q̇, τ̇ — brakes it to rest and holds it,
later torques are ignored, the run is aborted; one log line). With ``exit_when_done`` the
process exits 1 s (wall) after the last state (the launch file's ``on_exit: shutdown``).
Lockstep only: the plant steps
once the torque of its current cycle has arrived, so a run does not depend on the CPU speed.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.clock import Clock, ClockType
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ffmpc_core.errors import InputError
from ffmpc_core.reflex import reflex_plant
from ffmpc_core.robots import load_robot
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import GraphNode, run_node
from ffmpc_ros.message_parsing import joint_arrays
from ffmpc_ros.params import impact_config_from_parameters
from ffmpc_ros.plant_node import STATUS_EVERY, joint_state_message, wrench_message


class DicePlantNode(GraphNode):
    """The impact experiment's plant on topics (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("dice_plant", join=False, **kwargs)
        from ffmpc_core.impact.scenario import start_pose
        from sim_bridge.scenes import impact_plant_config, make_plant

        if not self.params["lockstep"]:
            self.refuse("the dice plant runs in lockstep only (lockstep: true)")
        self.config = impact_config_from_parameters(self.spec, self.params)
        robot = self.robot = load_robot(self.scenario.robot)
        self.joint_names = list(robot.joint_names)
        self.plant = make_plant(robot, impact_plant_config(self.config), self.config.engine)
        self.plant.reset(start_pose(self.config, robot))
        self.reflex_plant = reflex_plant(self.plant, robot, enabled=self.config.reflex)
        self._reflex_reported = False
        self.steps = int(round(self.config.duration / self.time_step))
        self.k = 0
        self.applied = np.zeros(robot.nv)
        self.latencies: list[float] = []
        self._published_at: float | None = None
        self._wall_start: float | None = None
        self._done_at: float | None = None
        self.state = self.plant.state()
        self.pub_clock = self.create_publisher(ClockMsg, topics.CLOCK, topics.clock_qos())
        self.pub_joints = self.graph_publisher(JointState, topics.PLANT_JOINT_STATES)
        self.pub_wrench = self.graph_publisher(WrenchStamped, topics.PLANT_WRENCH)
        self.pub_status = self.graph_publisher(Float64MultiArray, topics.PLANT_STATUS)
        self.create_subscription(
            JointState,
            topics.IMPACT_TORQUE,
            self.on_torque,
            topics.subscriber_qos(True, topics.IMPACT_TORQUE),
        )
        self.started = False
        self._start_timer = self.create_timer(
            0.01, self._try_start, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self.join_graph()

    def _try_start(self) -> None:
        """Publish cycle 0 once the start handshake holds
        (:meth:`ffmpc_ros.start_barrier.StartBarrier.handshake`)."""
        if not self.barrier.handshake(self.active, self.pub_joints, self.pub_clock):
            return
        self._start_timer.cancel()
        self.started = True
        self._wall_start = time.perf_counter()
        self.publish_state()

    @property
    def done(self) -> bool:
        return self.k >= self.steps

    def publish_state(self) -> None:
        """Publish the state of cycle self.k (clock first)."""
        k, s = self.k, self.state
        stamp = self.grid.stamp_of(k)
        self.pub_clock.publish(ClockMsg(clock=stamp))
        self._published_at = time.perf_counter()
        self.pub_joints.publish(
            joint_state_message(stamp, self.joint_names, s.q, s.v, self.applied)
        )
        self.pub_wrench.publish(wrench_message(stamp, s.wrench_world))
        if k % STATUS_EVERY == 0 or self.done:
            self.publish_status()

    def publish_status(self) -> None:
        """``plant/status`` of the present cycle (the reflex's event included)."""
        k = self.k
        lat = np.array(self.latencies) if self.latencies else np.zeros(1)
        self.pub_status.publish(
            layouts.PLANT_STATUS.pack(
                {
                    "t": self.grid.t_of(k),
                    "steps": k,
                    "done": float(self.done),
                    "lockstep": 1.0,
                    "deadline_misses": 0.0,
                    "latency_count": len(self.latencies),
                    "latency_mean": float(lat.mean()),
                    "latency_p50": float(np.percentile(lat, 50)),
                    "latency_p99": float(np.percentile(lat, 99)),
                    "latency_max": float(lat.max()),
                    "wall_time": time.perf_counter() - (self._wall_start or time.perf_counter()),
                    **layouts.reflex_status(self.reflex_plant.reflex),
                }
            )
        )

    def on_torque(self, msg: JointState) -> None:
        """The torque of the current cycle: one physics step, then the next state."""
        topic = self.name_of(topics.IMPACT_TORQUE)
        k = self.gate.check_stamp(topic, msg.header.stamp)
        if k is None:
            return
        if k != self.k:
            self.reject(f"{topic}:cycle", f"torque of cycle {k} while at cycle {self.k}")
            return
        try:
            (tau,) = joint_arrays(msg, self.joint_names, ("effort",))
            self.robot.clip_torque(tau)  # an absurd torque is refused (the plant saturates)
        except InputError as exc:
            self.reject(f"{topic}:value", str(exc))
            return
        self.gate.accept(topic, k)
        if self.done:
            return
        if self._published_at is not None:
            self.latencies.append(time.perf_counter() - self._published_at)
        self.reflex_plant.step(tau)
        self.k += 1
        self.state = self.reflex_plant.state()
        self.applied = self.state.tau
        event = self.reflex_plant.reflex.event
        if event is not None and not self._reflex_reported:
            self._reflex_reported = True
            self.get_logger().warning(event.describe())
            self.publish_status()
        self.publish_state()
        if self.done:
            self.get_logger().info(
                f"done: {self.k} cycles, {self.grid.t_of(self.k):.3f} s simulated"
            )

    def diagnostic_values(self, period: float) -> dict[str, str]:
        """The plant's cycle and simulated time (s)."""
        return {"cycle": str(self.k), "sim_time_s": f"{self.grid.t_of(self.k):.3f}"}

    def finished(self) -> bool:
        """With ``exit_when_done``: 1 s (wall) after the last state; otherwise never (the
        plant's reliable writers keep resending to readers that lag until it is shut down)."""
        if not (self.done and self.params["exit_when_done"]):
            return False
        if self._done_at is None:
            self._done_at = time.monotonic()
        return time.monotonic() - self._done_at > 1.0

    def destroy_node(self) -> None:
        self.plant.close()
        super().destroy_node()


def main(argv: Sequence[str] | None = None) -> int:
    return run_node(DicePlantNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
