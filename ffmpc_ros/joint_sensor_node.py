"""The joint-sensor node: eq 30's delay and noise on the plant's true joint state.

Subscribes ``/plant/joint_states`` (true q, q̇ and the applied torque τ̂), publishes
``/joint_sensor/joint_states`` with the same stamp: q̂ = q(t − δs) + ν_q, q̇̂ = q̇(t − δs) + ν_q̇
(ffmpc_core.sensing.JointSensingModel, the generator of the ``joint_sensor`` device), and the effort
τ̂ passed through undelayed (the joint torque sensor is part of the actuation model, eq 31).
"""

from __future__ import annotations

from typing import Any

from sensor_msgs.msg import JointState

from ffmpc_core.polishing import device_generator, joint_sensing_model
from ffmpc_core.robots import load_robot
from ffmpc_ros import topics
from ffmpc_ros.base import GraphNode, run_node
from ffmpc_ros.message_parsing import joint_fields


class JointSensorNode(GraphNode):
    """Eq 30 on every plant joint state (one cycle per message)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("joint_sensor", join=False, **kwargs)
        s = self.scenario
        self.robot = load_robot(s.robot)
        self.joint_names = list(self.robot.joint_names)
        self.model = joint_sensing_model(s, self.robot.nv, device_generator(s.seed, "joint_sensor"))
        lockstep = True  # the sensor processes every sample it gets
        self.publisher = self.create_publisher(
            JointState, topics.SENSED_JOINT_STATES, topics.publisher_qos(topics.SENSED_JOINT_STATES)
        )
        self.create_subscription(
            JointState,
            topics.PLANT_JOINT_STATES,
            self.on_joint_state,
            topics.subscriber_qos(lockstep, topics.PLANT_JOINT_STATES),
        )
        self.published = 0
        self.join_graph()

    def on_joint_state(self, msg: JointState) -> None:
        topic = self.name_of(topics.PLANT_JOINT_STATES)
        got = self.gate.receive(
            topic, msg, joint_fields(self.joint_names, "position", "velocity", "effort")
        )
        if got is None:
            return
        _, (q, v, effort) = got
        q_hat, v_hat = self.model.step(q, v)
        out = JointState()
        out.header.stamp = msg.header.stamp
        out.name = self.joint_names
        out.position = q_hat.tolist()
        out.velocity = v_hat.tolist()
        out.effort = effort.tolist()
        self.publisher.publish(out)
        self.published += 1


def main(argv: list[str] | None = None) -> int:
    return run_node(JointSensorNode, __doc__.splitlines()[0], argv)


if __name__ == "__main__":
    raise SystemExit(main())
