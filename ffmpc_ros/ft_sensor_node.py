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
"""

from __future__ import annotations

from typing import Any

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import WrenchStamped
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from ffmpc_core.errors import ConfigError, InputError
from ffmpc_core.lowpass import lowpass_alpha
from ffmpc_core.polishing import device_generator, force_sensing_model, measured_force
from ffmpc_core.sensing import DelayLine, ForceTare
from ffmpc_ros import topics
from ffmpc_ros.base import GraphNode, force_on_axes, run_node, wrench_stamped


class FtSensorNode(GraphNode):
    """Eq 32 plus tare, filter and contact detection (see the module docstring)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("ft_sensor", **kwargs)
        s = self.scenario
        fs = s.ft_sensor
        if fs.contact_off_force > fs.contact_on_force:
            raise ConfigError("contact_off_force must not exceed contact_on_force")
        self.contact = s.mpc.contact
        self.model = force_sensing_model(s, device_generator(s.seed, "force_sensor"))
        dim = self.contact.dimension
        self.axes = [self.contact.normal_axis] if dim == 1 else [0, 1, 2]
        self.normal_index = 0 if dim == 1 else self.contact.normal_axis
        fc = fs.filter_cutoff_frequency
        # the first-order low-pass of eq 13 (α of eq 13 is the memory: this gain is 1 − α)
        self.alpha = 1.0 - lowpass_alpha(fc, self.time_step) if fc > 0 else 1.0
        self.offset = np.zeros(dim)
        self.filtered: np.ndarray | None = None
        self.in_contact = False
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

    def _message(
        self, stamp: TimeMsg, force: np.ndarray, moment: np.ndarray | None = None
    ) -> WrenchStamped:
        """The wrench of ``force`` (N, on the contact axes) and ``moment`` (N·m, or zero)."""
        return wrench_stamped(stamp, force_on_axes(self.axes, force), moment)

    def on_wrench(self, msg: WrenchStamped) -> None:
        topic = self.name_of(topics.PLANT_WRENCH)
        got = self.receive(topic, msg, self.wrench_array)
        if got is None:
            return
        k, wrench = got
        raw = self.model.step(measured_force(wrench, self.contact))
        self.force_tare.add(raw)  # an implausible reading is not kept for the tare
        measured = raw - self.offset
        if self.filtered is None:
            self.filtered = measured.copy()
        else:
            self.filtered += self.alpha * (measured - self.filtered)
        normal = self.filtered[self.normal_index]
        fs = self.scenario.ft_sensor
        if self.in_contact and normal < fs.contact_off_force:
            self.in_contact = False
        elif not self.in_contact and normal > fs.contact_on_force:
            self.in_contact = True
        moment = None if self.moments is None else self.moments.step(wrench[3:])
        self.pub_wrench.publish(self._message(msg.header.stamp, measured, moment))
        self.pub_filtered.publish(self._message(msg.header.stamp, self.filtered))
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
