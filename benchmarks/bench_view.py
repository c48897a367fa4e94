"""The cost of ``/mpc/prediction`` on the MPC node's solve path (the live view's subscription).

The MPC node (polishing scenario, lockstep parameters) in this process, driven directly: each
tick puts a measurement in and calls the node's solve path (``_try_solve``: solve, command
publish, and the prediction publish when ``/mpc/prediction`` has a subscriber). Blocks of ticks
alternate without and with a subscriber (a raw subscription in another node of the same
context), so drift hits both alike; per formulation the medians of each, their ratio, and the
median of ``publish_prediction`` alone (timed once more after each subscribed solve).

    python benchmarks/bench_view.py [--ticks 400] [--blocks 6]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def bench(formulation: str, ticks: int, blocks: int) -> tuple[float, float, float]:
    import numpy as np
    import rclpy
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from std_msgs.msg import Float64MultiArray

    from ffmpc_core.scenario import load_scenario
    from ffmpc_ros import topics
    from ffmpc_ros.graph_nodes import graph_parameters
    from ffmpc_ros.mpc_node import MpcNode
    from ffmpc_ros.params import parameter_overrides

    scenario = load_scenario("polishing", {"mpc.formulation": formulation})
    params = graph_parameters(scenario, True, 10.0)["mpc"]
    context = Context()
    rclpy.init(context=context, domain_id=int(os.environ.get("ROS_DOMAIN_ID", "0")))
    executor = EventsExecutor(context=context)
    node = MpcNode(context=context, parameter_overrides=parameter_overrides(params))
    probe = Node("bench_probe", context=context)
    executor.add_node(node)
    executor.add_node(probe)
    robot = node.robot
    q, v = robot.q_nominal.copy(), np.zeros(robot.nv)
    tau = robot.gravity(q)
    force = np.zeros(node.config.contact.dimension)
    k = 0
    times: dict[bool, list[float]] = {False: [], True: []}
    alone: list[float] = []
    received = [0]
    try:
        for block in range(2 * blocks):
            subscribed = block % 2 == 1
            sub = None
            if subscribed:
                sub = probe.create_subscription(
                    Float64MultiArray,
                    topics.MPC_PREDICTION,
                    lambda _m: received.__setitem__(0, received[0] + 1),
                    topics.publisher_qos(),
                    raw=True,
                )
            end = time.monotonic() + 5.0
            while (node.prediction_publisher.get_subscription_count() > 0) != subscribed:
                executor.spin_once(timeout_sec=0.01)
                if time.monotonic() > end:
                    raise RuntimeError("the subscription did not match within 5 s")
            for _ in range(ticks):
                node._joints[k] = (q, v, tau)
                node._forces[k] = force
                start = time.perf_counter()
                node._try_solve(k)
                if block >= 2:  # the first pair of blocks warms up
                    times[subscribed].append(time.perf_counter() - start)
                    if subscribed:  # the prediction's share alone, once more
                        start = time.perf_counter()
                        node.publish_prediction(node.grid.t_of(k))
                        alone.append(time.perf_counter() - start)
                k += node.every
            executor.spin_once(timeout_sec=0.0)
            if sub is not None:
                probe.destroy_subscription(sub)
    finally:
        executor.shutdown()
        node.destroy_node()
        probe.destroy_node()
        rclpy.shutdown(context=context)
    return (
        statistics.median(times[False]),
        statistics.median(times[True]),
        statistics.median(alone),
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ticks", type=int, default=400, help="solves per block")
    parser.add_argument("--blocks", type=int, default=6, help="blocks of each kind")
    args = parser.parse_args()
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs")
    print(f"{args.blocks - 1} measured blocks of {args.ticks} solves each way (1 pair warms up)")
    print("formulation      without ms  with ms  ratio  prediction alone ms")
    for formulation in ("classical", "torque_feedback", "force_feedback"):
        without, with_, alone = bench(formulation, args.ticks, args.blocks)
        print(
            f"{formulation:<16} {without * 1e3:10.3f} {with_ * 1e3:8.3f} {with_ / without:6.2f}"
            f" {alone * 1e3:20.3f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
