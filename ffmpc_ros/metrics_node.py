"""The metrics node: records the run from the topics and computes the study's metrics with the
same code as the ROS-free runner (``ffmpc_core.polishing.PolishingLog`` and
``polishing_run_metrics``).

Row k of the log takes: the TRUE q of ``/plant/joint_states`` at t_k (end-effector position by
pinocchio), the normal force of ``/plant/truth`` at t_k, the last measured force entry of
``/ft_sensor/wrench`` at t_k, τ^d and τ^m of ``/pid/desired_torque`` and ``/pid/motor_torque``
at t_k (with ``low_level: lfc``, both from the LFC-law node's ``/lfc/effort``), and τ̂ of
cycle k — the effort of ``/plant/joint_states`` at t_{k+1}. Once every cycle of the run is in,
it publishes the metrics as JSON on ``/metrics/summary`` (transient local).

Real time (``lockstep: false``): the PID may skip cycles, so once the plant's last state is in
and ``FINISH_GRACE`` (wall s) has passed, a missing value of a cycle is the previous cycle's
(the motors hold their last command; before the first command, the start torque and no
measured force); the summary counts these ``filled`` values.
"""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.clock import Clock, ClockType
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray, String

from ffmpc_core.errors import InputError
from ffmpc_core.metrics import PolishingMetrics
from ffmpc_core.polishing import (
    PolishingLog,
    build_task,
    polishing_run_metrics,
    steps_per_mpc_period,
)
from ffmpc_core.robots import load_robot
from ffmpc_core.tasks import GuardedTask
from ffmpc_ros import layouts, topics
from ffmpc_ros.base import GraphNode, run_node
from ffmpc_ros.message_parsing import joint_arrays, wrench_array

#: The graph's low-level nodes whose torques the log records (graph parameter ``low_level``).
LOW_LEVELS = ("pid", "lfc")
_LOGGED = ("force_true", "force_measured", "tau_desired", "tau_measured", "tau_motor")
FINISH_GRACE = 0.5  # real time: wall s after the last state before finishing, s
_PARTS = ("q", "force_true", "force_measured", "tau_desired", "tau_measured", "tau_motor")


class MetricsNode(GraphNode):
    """Recorder + metrics (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("metrics", join=False, **kwargs)
        s = self.scenario
        self.robot = load_robot(s.robot)
        self.joint_names = list(self.robot.joint_names)
        self.task = build_task(s, self.robot)
        duration = float(self.params["duration"]) or self.task.duration
        self.steps = int(round(duration / self.time_step))
        self.log = PolishingLog(self.steps, self.robot, self.task)
        contact = s.mpc.contact
        self.axes = [contact.normal_axis] if contact.dimension == 1 else [0, 1, 2]
        self._rows: dict[int, dict] = {}
        self.recorded = 0
        self.table_normal: np.ndarray | None = None
        self.metrics: tuple[PolishingMetrics, PolishingMetrics] | None = None
        self.contact_time: float | None = None  # the guarded approach's detection, s (_finish)
        self.lockstep = bool(self.params["lockstep"])
        self.filled = 0
        self._recorded = np.zeros(self.steps, dtype=bool)
        self._q = np.zeros((self.steps, self.robot.nv))
        self._last_state_at: float | None = None
        self.pub_summary = self.create_publisher(
            String, topics.METRICS_SUMMARY, topics.publisher_qos(topics.METRICS_SUMMARY)
        )
        self.pub_ready = self.create_publisher(
            Bool, topics.METRICS_READY, topics.publisher_qos(topics.METRICS_READY)
        )
        low_level = str(self.params["low_level"])
        if low_level not in LOW_LEVELS:
            self.refuse(f"low_level must be one of {list(LOW_LEVELS)}, got {low_level!r}")
        desired, motor, _ = topics.low_level_topics(low_level)
        self._subs = [
            self.create_subscription(msg_type, topic, callback, topics.subscriber_qos(True, topic))
            for msg_type, topic, callback in (
                (JointState, topics.PLANT_JOINT_STATES, self.on_plant_joints),
                (Float64MultiArray, topics.PLANT_TRUTH, self.on_truth),
                (WrenchStamped, topics.SENSED_WRENCH, self.on_wrench),
                (JointState, desired, self.on_desired),
                (JointState, motor, self.on_motor),
            )
        ]
        self.ready = False
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._ready_timer = self.create_timer(0.02, self._check_ready, clock=steady)
        if not self.lockstep:
            self.create_timer(0.1, self._check_finish, clock=steady)
        self.join_graph()

    @property
    def has_states(self) -> bool:
        """Whether a plant state came in since the last (attempted) finish."""
        return self._last_state_at is not None

    def finish_now(self) -> None:
        """Finish with the cycles that are in now, as real time does once the last state is
        :data:`FINISH_GRACE` old (a missing measurement takes the previous value, counted in
        ``filled``): the bring-up's, once the plant is done and a stopped sensor's
        measurements will not come; the bag's metrics of a real-time run."""
        self._last_state_at = time.monotonic() - FINISH_GRACE
        self._check_finish()

    def _check_finish(self) -> None:
        """Real time: finish with the cycles that are in, once the last state is old enough."""
        if self.metrics is not None or self._last_state_at is None or self.table_normal is None:
            return
        if time.monotonic() - self._last_state_at < FINISH_GRACE:
            return
        # Before the first controller output the motors hold the start torque (the plant's
        # initial τ^m) and no force has been measured.
        start = self.robot.gravity(self.robot.q_nominal)
        previous: dict = {"force_measured": 0.0, "tau_desired": start, "tau_motor": start}
        for k in range(self.steps):
            if self._recorded[k]:
                previous = {name: self.log.arrays[name][k] for name in _LOGGED}
                previous["q"] = self._q[k]
                continue
            row = self._rows.pop(k, {})
            for part in _PARTS:
                if part not in row:
                    if part not in previous:  # the plant's own data is never skipped
                        self.reject("incomplete", f"cycle {k} has no {part}; no metrics")
                        self._last_state_at = None
                        return
                    row[part] = previous[part]
                    self.filled += 1
            self._record(k, row)
            previous = row
        self._finish(self.table_normal)

    def _check_ready(self) -> None:
        """Announce on /metrics/ready once every recorded topic has a matched publisher (the
        plant waits for it when ``wait_for_metrics`` is set, so no cycle is missed)."""
        if all(sub.get_publisher_count() > 0 for sub in self._subs):
            self._ready_timer.cancel()
            self.ready = True
            self.pub_ready.publish(Bool(data=True))

    def _put(self, k: int | None, part: str, value: float | np.ndarray) -> None:
        if k is None or not 0 <= k < self.steps or self.metrics is not None:
            return
        row = self._rows.setdefault(k, {})
        row[part] = value
        if len(row) == len(_PARTS):
            del self._rows[k]
            self._record(k, row)
            if self.recorded == self.steps and self.table_normal is not None:
                self._finish(self.table_normal)

    def _record(self, k: int, row: dict) -> None:
        self._q[k] = row["q"]
        self.log.record(
            k,
            self.grid.t_of(k),
            row["q"],
            row["force_true"],
            row["force_measured"],
            row["tau_desired"],
            row["tau_measured"],
            row["tau_motor"],
        )
        self._recorded[k] = True
        self.recorded += 1

    def _joints(self, msg: JointState, fields: tuple[str, ...]) -> list[np.ndarray] | None:
        try:
            return joint_arrays(msg, self.joint_names, fields)
        except InputError as exc:
            self.reject("joint_state", str(exc))
            return None

    def on_plant_joints(self, msg: JointState) -> None:
        k = self.cycle_of(msg.header.stamp)
        arrays = self._joints(msg, ("position", "effort"))
        if k is None or arrays is None:
            return
        q, effort = arrays
        if k == self.steps and not self.lockstep:
            self._last_state_at = time.monotonic()
        self._put(k, "q", q)
        if k >= 1:
            self._put(k - 1, "tau_measured", effort)

    def on_truth(self, msg: Float64MultiArray) -> None:
        try:
            truth = layouts.PLANT_TRUTH.unpack(msg)
        except InputError as exc:
            self.reject("truth", str(exc))
            return
        self.table_normal = truth["table_normal"]
        self._put(self.grid.cycle_of_time(truth["t"]), "force_true", truth["normal_force"])

    def on_wrench(self, msg: WrenchStamped) -> None:
        try:
            wrench = wrench_array(msg)
        except InputError as exc:
            self.reject("wrench", str(exc))
            return
        self._put(self.cycle_of(msg.header.stamp), "force_measured", wrench[self.axes[-1]])

    def on_desired(self, msg: JointState) -> None:
        arrays = self._joints(msg, ("effort",))
        if arrays is not None:
            self._put(self.cycle_of(msg.header.stamp), "tau_desired", arrays[0])

    def on_motor(self, msg: JointState) -> None:
        arrays = self._joints(msg, ("effort",))
        if arrays is not None:
            self._put(self.cycle_of(msg.header.stamp), "tau_motor", arrays[0])

    def _finish(self, table_normal: np.ndarray) -> None:
        """The metrics (``table_normal``: the table's unit normal, world) and the summary. A
        guarded approach's phases are read from the logged measured force at the MPC's ticks
        (:meth:`~ffmpc_core.polishing.PolishingLog.replay_contact`: the MPC node detected the
        contact from the same λ̂)."""
        self.contact_time = self.log.replay_contact(steps_per_mpc_period(self.scenario))
        self.metrics = polishing_run_metrics(self.log.arrays, self.task, table_normal)
        true, measured = self.metrics
        summary = {
            "formulation": self.scenario.mpc.ocp.formulation,
            "seed": self.scenario.seed,
            "cycles": self.steps,
            "filled": self.filled,
            "metrics_true": true.to_dict(),
            "metrics_measured": measured.to_dict(),
            "contact_time_s": self.contact_time,
            "contact_missed": self.contact_missed,
        }
        self.pub_summary.publish(String(data=json.dumps(summary)))
        self.get_logger().info(f"metrics: {json.dumps(summary)}")

    @property
    def contact_missed(self) -> bool:
        """A guarded approach whose descent reached its bound by the log's end, no contact."""
        task = self.task
        end = float(self.log.arrays["t"][-1])
        return isinstance(task, GuardedTask) and task.contact_missed(end)

    def finished(self) -> bool:
        return self.metrics is not None


def main(argv: list[str] | None = None) -> int:
    return run_node(MetricsNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
