"""The force/torque-sensor node: eq 32's delay and noise, a tare, a low-pass filter and contact
detection with hysteresis.

Subscribes ``/plant/wrench`` (the true wrench on the tool, frame ``contact_world_aligned``) and
publishes, with the same stamp:

* ``/ft_sensor/wrench`` — λ̂ = λ(t − δs) + ν_λ − tare offset (eq 32; ffmpc_core.sensing, the
  generator of the ``force_sensor`` device). The sensor measures the axes of the MPC's contact
  model: 1-D → the ``normal_axis`` component (a one-axis load cell), 3-D → the three forces;
  the components it does not measure are published as 0. This is what the MPC reads.
  With ``measure_moments`` (the impact graph) its moments are the plant's, delayed like the
  force and without noise (eq 32 models forces only); otherwise they are 0.
* ``/ft_sensor/wrench_filtered`` — the same through a first-order low-pass filter of cut-off
  ``filter_cutoff_frequency`` (y ← y + α(λ̂ − y), α = 1 − exp(−2π·f_c·Δt); 0 Hz: no filter).
* ``/ft_sensor/in_contact`` — std_msgs/Bool: true once the filtered normal force exceeds
  ``contact_on_force``, false again once it falls below ``contact_off_force`` (hysteresis).

Service ``/ft_sensor/tare`` (std_srvs/Trigger): the offset becomes the mean of the last
``tare_samples`` plausible measurements; refused while in contact, before any measurement, or
when that mean is implausible (``ffmpc_core.sensing.ForceTare``, ``ffmpc_core.plausibility``).

The wrist sensor (``model: wrist``, ``ffmpc_core.wrist_ft``): the node is then the sensor on
the flange and its driver. It also subscribes ``/plant/joint_states`` (the true q, q̇: the
sensor reads the tool's weight at the wrist's true orientation, and with ``inertial_wrench``
its inertial wrench) and ``/joint_sensor/joint_states`` (q̂, q̇̂: the compensation, as a cell's
F/T node reads the robot's measured joint states), and processes a cycle once it has all three
inputs of that cycle. At configure it calibrates (``calibration: startup``, the simulated
poses of ``ffmpc_core.ft_calibration``) or loads ``calibration_file``, and refuses to
configure, with the reason, a calibration that is stale, for another cell or tool, or
implausible (``calibration: none``: no calibration, no compensation). ``/ft_sensor/wrench``
then carries the compensated wrench: the three forces (the tare offset subtracted on the MPC's
axes) and the moments, about the contact frame origin in world axes; the filter, contact
detection and tare act on the MPC's axes as above.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import WrenchStamped
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.lowpass import lowpass_alpha
from ffmpc_core.polishing import (
    device_generator,
    force_sensing_model,
    measured_force,
    tool_calibration,
    wrist_compensator,
    wrist_sensor_model,
)
from ffmpc_core.robots import load_robot
from ffmpc_core.sensing import ContactHysteresis, DelayLine, ForceTare
from ffmpc_core.wrist_ft import WristForceSensing
from ffmpc_ros import topics
from ffmpc_ros.base import GraphNode, force_on_axes, run_node, wrench_stamped
from ffmpc_ros.message_parsing import joint_fields, wrench_array
from ffmpc_ros.time_grid import drop_stale_cycles

_KEEP = 50  # cycles of unmatched wrist-sensor inputs kept


class FtSensorNode(GraphNode):
    """Eq 32 plus tare, filter and contact detection (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("ft_sensor", join=False, **kwargs)
        s = self.scenario
        fs = s.ft_sensor
        self.detector = ContactHysteresis(fs.contact_on_force, fs.contact_off_force)
        self.contact = s.mpc.contact
        self.wrist = fs.model == "wrist"
        self.model = force_sensing_model(s, device_generator(s.seed, "force_sensor"))
        self.pipeline: WristForceSensing | None = None  # the wrist sensor, built at configure
        self.calibration_line = ""
        dim = self.contact.dimension
        self.axes = [self.contact.normal_axis] if dim == 1 else [0, 1, 2]
        self.normal_index = 0 if dim == 1 else self.contact.normal_axis
        fc = fs.filter_cutoff_frequency
        # the first-order low-pass of eq 13 (α of eq 13 is the memory: this gain is 1 − α)
        self.alpha = 1.0 - lowpass_alpha(fc, self.time_step) if fc > 0 else 1.0
        self.offset = np.zeros(dim)
        self.filtered: np.ndarray | None = None
        self.force_tare = ForceTare(fs.tare_samples, dim)
        self.moments = DelayLine(fs.delay_cycles, 3) if self.params["measure_moments"] else None
        self.pub_wrench = self.graph_publisher(WrenchStamped, topics.SENSED_WRENCH)
        self.pub_filtered = self.graph_publisher(WrenchStamped, topics.FILTERED_WRENCH)
        self.pub_contact = self.graph_publisher(Bool, topics.IN_CONTACT)
        self.create_subscription(
            WrenchStamped,
            topics.PLANT_WRENCH,
            self.on_wrench,
            topics.subscriber_qos(True, topics.PLANT_WRENCH),
        )
        self.create_service(Trigger, topics.TARE_SERVICE, self.on_tare)
        self.published = 0
        if self.wrist:
            self.robot = load_robot(s.robot)
            self.joint_names = list(self.robot.joint_names)
            self.sensor = wrist_sensor_model(
                s, self.robot, device_generator(s.seed, "force_sensor")
            )
            self._wrenches: dict[int, np.ndarray] = {}
            self._truth: dict[int, tuple[np.ndarray, np.ndarray]] = {}
            self._sensed: dict[int, tuple[np.ndarray, np.ndarray]] = {}
            self._last_cycle_done = -1
            for topic, callback in (
                (topics.PLANT_JOINT_STATES, self._on_true_joints),
                (topics.SENSED_JOINT_STATES, self._on_sensed_joints),
            ):
                qos = topics.subscriber_qos(True, topic)
                self.create_subscription(JointState, topic, callback, qos)
        self.join_graph()

    @property
    def in_contact(self) -> bool:
        """The contact flag (hysteresis on the filtered normal force)."""
        return self.detector.in_contact

    def configure(self) -> str | None:
        """The wrist sensor's calibration (module docstring): the reason it is refused, or None."""
        if not self.wrist:
            return None
        s = self.scenario
        rng = device_generator(s.seed, "ft_calibration")  # the same draws at every configure
        self.sensor.reset()
        try:
            calibration = tool_calibration(s, self.sensor, rng, time.time())
        except ConfigError as exc:
            return str(exc)
        compensator = wrist_compensator(s, self.robot, calibration)
        self.pipeline = WristForceSensing(self.sensor, compensator, self.contact)
        self.calibration_line = (
            "no calibration: the raw reading is not compensated"
            if calibration is None
            else f"F/T calibration ({s.ft_sensor.calibration}): {calibration.describe()}"
        )
        self.get_logger().info(self.calibration_line)
        return None

    def _message(
        self, stamp: TimeMsg, force: np.ndarray, moment: np.ndarray | None = None
    ) -> WrenchStamped:
        """The wrench of ``force`` (N, on the contact axes) and ``moment`` (N·m, or zero)."""
        return wrench_stamped(stamp, force_on_axes(self.axes, force), moment)

    def on_wrench(self, msg: WrenchStamped) -> None:
        topic = self.name_of(topics.PLANT_WRENCH)
        got = self.gate.receive(topic, msg, wrench_array)
        if got is None:
            return
        k, wrench = got
        if self.wrist:
            self._wrenches[k] = wrench
            self._try_wrist(k)
            return
        raw = self.model.step(measured_force(wrench, self.contact))
        moment = None if self.moments is None else self.moments.step(wrench[3:])
        self._publish(msg.header.stamp, raw, moment)

    def _on_true_joints(self, msg: JointState) -> None:
        self._on_joints(msg, topics.PLANT_JOINT_STATES, self._truth)

    def _on_sensed_joints(self, msg: JointState) -> None:
        self._on_joints(msg, topics.SENSED_JOINT_STATES, self._sensed)

    def _on_joints(
        self, msg: JointState, topic: str, store: dict[int, tuple[np.ndarray, np.ndarray]]
    ) -> None:
        fields = joint_fields(self.joint_names, "position", "velocity")
        got = self.gate.receive(self.name_of(topic), msg, fields)
        if got is None:
            return
        k, (q, v) = got
        store[k] = (q, v)
        self._try_wrist(k)

    def _try_wrist(self, k: int) -> None:
        """Cycle k of the wrist sensor once its three inputs are in (and it is the newest)."""
        if k <= self._last_cycle_done or not (
            k in self._wrenches and k in self._truth and k in self._sensed
        ):
            return
        if self.pipeline is None:  # not configured (the lifecycle drops inputs before that)
            return
        (q, v), (q_hat, v_hat) = self._truth.pop(k), self._sensed.pop(k)
        wrench = self.pipeline.wrench(q, v, self._wrenches.pop(k), q_hat, v_hat)
        self._last_cycle_done = k
        drop_stale_cycles((self._wrenches, self._truth, self._sensed), k, _KEEP)
        full = wrench.copy()
        raw = measured_force(wrench, self.contact)
        self._publish(self.grid.stamp_of(k), raw, full[3:], full[:3])

    def _publish(
        self,
        stamp: TimeMsg,
        raw: np.ndarray,
        moment: np.ndarray | None,
        force: np.ndarray | None = None,
    ) -> None:
        """Tare, filter, contact detection and the three topics of one cycle: ``raw`` the
        measurement on the MPC's axes (N), ``force`` the three forces the wrist sensor measured
        (their MPC axes replaced by raw − offset), ``moment`` N·m or None."""
        self.force_tare.add(raw)  # an implausible reading is not kept for the tare
        measured = raw - self.offset
        if self.filtered is None:
            self.filtered = measured.copy()
        else:
            self.filtered += self.alpha * (measured - self.filtered)
        self.detector.update(float(self.filtered[self.normal_index]))
        if force is None:
            message = self._message(stamp, measured, moment)
        else:
            force[self.axes] = measured
            message = wrench_stamped(stamp, force, moment)
        self.pub_wrench.publish(message)
        self.pub_filtered.publish(self._message(stamp, self.filtered))
        self.pub_contact.publish(Bool(data=self.in_contact))
        self.published += 1

    def on_tare(self, request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        previous = self.offset
        try:
            self.offset = self.force_tare.tare(self.in_contact)
        except InputError as exc:
            response.success = False
            response.message = str(exc)
        else:
            if self.filtered is not None:
                self.filtered += previous - self.offset
            response.success = True
            response.message = (
                f"offset {np.array2string(self.offset, precision=4)} N "
                f"from {self.force_tare.samples} samples"
            )
        self.get_logger().info(f"tare: {response.message}")
        return response


def main(argv: list[str] | None = None) -> int:
    return run_node(FtSensorNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
