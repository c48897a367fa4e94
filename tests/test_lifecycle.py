"""Every node is a ROS 2 managed node (ffmpc_ros.base, "Lifecycle"): with ``autostart`` false it
waits unconfigured and ignores its inputs; the ``change_state`` service (what ``ros2 lifecycle
set`` and the bring-up call) configures and activates it; deactivated, it ignores them again;
shut down, its executable's loop ends; destroyed, it leaves the ROS graph."""

from __future__ import annotations

import numpy as np
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
from ros_helpers import joint_state, overrides, recorder
from sensor_msgs.msg import JointState

from ffmpc_ros import topics
from ffmpc_ros.joint_sensor_node import JointSensorNode
from ffmpc_ros.plant_node import PlantNode


def _call(ros, probe, service_type, name: str, request):
    client = probe.create_client(service_type, name)
    assert ros.spin_until(client.service_is_ready)
    future = client.call_async(request)
    assert ros.spin_until(future.done)
    probe.destroy_client(client)
    return future.result()


def _transition(ros, probe, node: str, label: str) -> bool:
    request = ChangeState.Request(transition=Transition(label=label))
    return _call(ros, probe, ChangeState, f"/{node}/change_state", request).success


def _state(ros, probe, node: str) -> str:
    return _call(ros, probe, GetState, f"/{node}/get_state", GetState.Request()).current_state.label


def test_a_node_without_autostart_processes_inputs_only_while_active(ros):
    node = ros.add(
        JointSensorNode(
            context=ros.context, parameter_overrides=overrides("joint_sensor", autostart=False)
        )
    )
    probe = ros.probe()
    out = recorder(probe, JointState, topics.SENSED_JOINT_STATES)
    pub = probe.create_publisher(JointState, topics.PLANT_JOINT_STATES, topics.publisher_qos())
    zero = np.zeros(7)
    topic = topics.resolve(topics.PLANT_JOINT_STATES)
    assert _state(ros, probe, "joint_sensor") == "unconfigured"
    pub.publish(joint_state(node, 0, zero, zero, zero))
    assert ros.spin_until(lambda: node.rejected[f"{topic}:inactive"] == 1)
    assert out == []  # nothing computed from an input of an unconfigured node

    assert _transition(ros, probe, "joint_sensor", "configure")
    assert _state(ros, probe, "joint_sensor") == "inactive"
    pub.publish(joint_state(node, 1, zero, zero, zero))
    assert ros.spin_until(lambda: node.rejected[f"{topic}:inactive"] == 2)
    assert not _transition(ros, probe, "joint_sensor", "configure")  # not from inactive

    assert _transition(ros, probe, "joint_sensor", "activate")
    assert _state(ros, probe, "joint_sensor") == "active"
    pub.publish(joint_state(node, 2, zero, zero, zero))
    assert ros.spin_until(lambda: len(out) == 1)
    assert node.cycle_of(out[0].header.stamp) == 2

    assert _transition(ros, probe, "joint_sensor", "deactivate")
    pub.publish(joint_state(node, 3, zero, zero, zero))
    assert ros.spin_until(lambda: node.rejected[f"{topic}:inactive"] == 3)
    ros.spin_for(0.2)
    assert len(out) == 1
    # one log line for the three rejections of that kind (throttled)
    assert node.log_lines[f"{topic}:inactive"] == 1

    assert _transition(ros, probe, "joint_sensor", "shutdown")
    assert node.lifecycle_state == "finalized"  # run_node's loop ends on it


def test_autostart_makes_a_node_active_once_built(ros):
    node = ros.add(
        JointSensorNode(context=ros.context, parameter_overrides=overrides("joint_sensor"))
    )
    assert node.active
    assert _state(ros, ros.probe(), "joint_sensor") == "active"


def test_the_plant_starts_its_first_cycle_only_once_activated(ros):
    plant = ros.add(
        PlantNode(context=ros.context, parameter_overrides=overrides("plant", autostart=False))
    )
    probe = ros.probe()
    out = recorder(probe, JointState, topics.PLANT_JOINT_STATES)
    ros.spin_for(0.3)
    assert not plant.started and out == []
    assert _transition(ros, probe, "plant", "configure")
    ros.spin_for(0.2)
    assert not plant.started and out == []
    assert _transition(ros, probe, "plant", "activate")
    assert ros.spin_until(lambda: len(out) == 1)
    assert plant.cycle_of(out[0].header.stamp) == 0


def test_a_destroyed_node_leaves_the_ros_graph(ros):
    node = ros.add(
        JointSensorNode(
            context=ros.context,
            parameter_overrides=overrides("joint_sensor"),
            node_name="short_lived",
        )
    )
    probe = ros.probe()
    assert ros.spin_until(lambda: "short_lived" in probe.get_node_names())
    ros.nodes.remove(node)
    ros.executor.remove_node(node)
    node.destroy_node()
    assert ros.spin_until(lambda: "short_lived" not in probe.get_node_names())
