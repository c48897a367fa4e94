"""The CPU cost of the state publisher (ffmpc_ros.state_publisher_node) per joint state.

The node (polishing scenario's robot, autostarted) in this process, driven directly: its
joint-state callback is called with JointState messages of consecutive 1 ms cycles, as the
graph's ``joint_sensor/joint_states`` arrives. At the default ``publish_frequency`` (100 Hz of
simulated time) one message in ten is on the grid (forward kinematics, one TFMessage of the
moving edges, publish); the others only have their stamp read. Reported: the median wall time
of both kinds of call, and the process CPU time per simulated second (1000 joint states) with
the default frequency and with ``publish_frequency`` = 1000 Hz (robot_state_publisher's way:
every joint state). The DDS receive path of rclpy (deserialising each JointState before the
callback) is not in these numbers: see the README for the node's whole process in a graph run.

    python benchmarks/bench_state_publisher.py [--seconds 5]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def bench(frequency: float, seconds: float) -> tuple[float, float, float, int]:
    """(median µs of a grid call, median µs of an off-grid call, CPU ms per simulated s,
    messages published) for ``seconds`` of simulated 1 kHz joint states."""
    import numpy as np
    import rclpy
    from rclpy.context import Context
    from sensor_msgs.msg import JointState

    from ffmpc_core.scenario import load_scenario
    from ffmpc_ros.params import node_parameter_values, parameter_overrides
    from ffmpc_ros.state_publisher_node import StatePublisherNode

    scenario = load_scenario("polishing")
    values = node_parameter_values("state_publisher", scenario, publish_frequency=frequency)
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    node = StatePublisherNode(context=context, parameter_overrides=parameter_overrides(values))
    try:
        rng = np.random.default_rng(0)
        names = list(node.joint_names)
        n = int(seconds * 1000)
        msgs = []
        for k in range(n):
            msg = JointState(
                name=names, position=(node.robot.q_nominal + 0.1 * rng.normal(size=7)).tolist()
            )
            msg.header.stamp = node.grid.stamp_of(k)
            msgs.append(msg)
        grid, off = [], []
        cpu0 = time.process_time()
        for msg in msgs:
            before = node.published
            t0 = time.perf_counter()
            node.on_joint_state(msg)
            dt = time.perf_counter() - t0
            (grid if node.published > before else off).append(dt)
        cpu = time.process_time() - cpu0
        return (
            statistics.median(grid) * 1e6,
            statistics.median(off) * 1e6 if off else float("nan"),
            cpu / seconds * 1e3,
            node.published,
        )
    finally:
        node.destroy_node()
        rclpy.shutdown(context=context)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="simulated s of joint states")
    args = parser.parse_args()
    print(f"{platform.processor() or platform.machine()}, python {platform.python_version()}")
    for frequency in (100.0, 1000.0):
        grid, off, cpu, published = bench(frequency, args.seconds)
        print(
            f"publish_frequency {frequency:g} Hz: {published} /tf messages; grid call median "
            f"{grid:.1f} µs, off-grid call {off:.1f} µs; CPU {cpu:.1f} ms per simulated s "
            f"({cpu / 10:.2f} % of a core at real-time speed)"
        )


if __name__ == "__main__":
    main()
