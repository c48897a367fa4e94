"""The lockstep start barrier (``ffmpc_ros.start_barrier.StartBarrier.writers_matched``,
ffmpc_ros.topics ``START_READY``): a node declares itself ready (a ``lockstep/ready`` reader)
only once it knows every /clock reader of the graph and each of its writers has matched every
compatible reader;
the plant publishes cycle 0 only once every node is ready. With reliable, VOLATILE topics (no
replay), the first sample then reaches a reader that was created after the writer."""

from __future__ import annotations

import numpy as np
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_helpers import joint_state
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Empty

from ffmpc_core.scenario import load_scenario
from ffmpc_ros import topics
from ffmpc_ros.joint_sensor_node import JointSensorNode
from ffmpc_ros.params import node_parameter_values, parameter_overrides
from ffmpc_ros.plant_node import PlantNode


def _graph_overrides(node: str, **graph):
    """What the bring-up gives ``node``: the scenario, ``graph`` and the graph's QoS overrides
    (reliable sensor topics, nothing transient local); an ideal joint sensor (no noise, no
    delay: its output is its input)."""
    values = node_parameter_values(node, load_scenario("polishing"), **graph)
    if node == "joint_sensor":
        values.update(delay_cycles=0, position_noise_std=0.0, velocity_noise_std=0.0)
    return parameter_overrides({**values, **topics.graph_qos_overrides()})


def _ready_readers(probe) -> int:
    return probe.count_subscribers(topics.resolve(topics.START_READY))


def test_a_node_is_ready_only_once_its_writer_matched_a_late_reader_and_loses_nothing(ros):
    clock_readers = 2 * topics.CLOCK_READERS_PER_NODE  # two members: the node and a late one
    node = ros.add(
        JointSensorNode(
            context=ros.context,
            parameter_overrides=_graph_overrides(
                "joint_sensor", start_clock_subscribers=clock_readers
            ),
        )
    )
    watcher = ros.probe("watcher")
    ros.spin_for(1.0)
    # alone on the graph: it does not know every member yet
    assert not node.barrier.ready and _ready_readers(watcher) == 0

    # /clock readers of a non-member (a live view, a ros2 topic echo) do not count
    outsider = ros.probe("outsider")
    for _ in range(topics.CLOCK_READERS_PER_NODE):
        outsider.create_subscription(Clock, topics.CLOCK, lambda m: None, topics.clock_reader_qos())
    ros.spin_for(1.0)
    assert not node.barrier.ready
    # a late member of the graph: first its data reader and an incompatible reader (transient
    # local on a volatile writer, which the barrier must not wait for), then its membership
    # marker (last, as a GraphNode's)
    late = ros.probe("late_member")
    got: list[JointState] = []
    reliable = topics.graph_qos(topics.SENSED_JOINT_STATES, "subscription")
    late.create_subscription(JointState, topics.SENSED_JOINT_STATES, got.append, reliable)
    incompatible = QoSProfile(
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    late.create_subscription(JointState, topics.SENSED_JOINT_STATES, lambda m: None, incompatible)
    late.create_subscription(Empty, topics.START_MEMBER, lambda m: None, topics.start_ready_qos())
    assert ros.spin_until(lambda: node.barrier.ready, timeout=20.0)
    writer = node.publisher
    # the token came only after the writer had matched the compatible late reader
    assert writer.get_subscription_count() >= 1
    assert ros.spin_until(lambda: _ready_readers(watcher) == 1)

    # the first sample reaches the late reader: reliable, volatile, no replay needed
    assert writer.qos_profile.durability == DurabilityPolicy.VOLATILE
    ros.set_clock(node, 0)
    source = watcher.create_publisher(
        JointState,
        topics.PLANT_JOINT_STATES,
        topics.graph_qos(topics.PLANT_JOINT_STATES, "publisher"),
    )
    assert ros.spin_until(lambda: source.get_subscription_count() >= 1)
    q = np.linspace(0.1, 0.7, 7)
    source.publish(joint_state(node, 0, q, np.zeros(7), np.zeros(7)))
    assert ros.spin_until(lambda: len(got) == 1)
    assert np.array_equal(np.array(got[0].position), q)  # cycle 0's state, through


def test_the_plant_publishes_cycle_0_only_once_every_node_passed_the_barrier(ros):
    clock_readers = 2 * topics.CLOCK_READERS_PER_NODE  # the plant and the joint sensor
    plant = ros.add(
        PlantNode(
            context=ros.context,
            parameter_overrides=_graph_overrides(
                "plant",
                start_clock_subscribers=clock_readers,
                start_nodes=3,  # the plant, the joint sensor and a third node
                start_subscribers=1,
                start_delay=0.0,
                duration=0.01,
            ),
        )
    )
    ros.spin_for(1.0)
    assert not plant.barrier.ready  # it knows only its own /clock readers
    sensor = ros.add(
        JointSensorNode(
            context=ros.context,
            parameter_overrides=_graph_overrides(
                "joint_sensor", start_clock_subscribers=clock_readers
            ),
        )
    )
    assert ros.spin_until(lambda: plant.barrier.ready and sensor.barrier.ready, timeout=20.0)
    # every /clock reader matched, two tokens of three: the plant waits for the third node
    ros.spin_for(1.0)
    assert not plant.started
    third = ros.probe("third_node")
    third.create_subscription(Empty, topics.START_READY, lambda m: None, topics.start_ready_qos())
    assert ros.spin_until(lambda: plant.started, timeout=20.0)
    # cycle 0 went out to a reader that was matched: the sensor took it
    topic = topics.resolve(topics.PLANT_JOINT_STATES)
    assert ros.spin_until(lambda: sensor.accepted[topic] >= 1)


def test_without_a_graph_to_wait_for_a_node_is_ready_at_once(ros):
    """``ros2 run`` of one node (start_clock_subscribers 0): no barrier, no token."""
    node = ros.add(
        JointSensorNode(context=ros.context, parameter_overrides=_graph_overrides("joint_sensor"))
    )
    assert node.barrier.ready
    assert topics.resolve(topics.START_READY) not in {s.topic_name for s in node.subscriptions}
