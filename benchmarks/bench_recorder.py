"""Recorder throughput and its overhead on the node graph.

1. BagWriter alone (no ROS): messages/s and MB/s writing recorded CDR into a zstd MCAP file.
2. The recorder node in one process: a publisher sends JointState messages in bursts of 100 and
   the recorder (raw subscription → BagWriter) takes them; messages/s end to end, against the
   same loop with a plain (non-recording) raw subscriber.
3. The lockstep graph with and without ``--record`` (single- and multi-process): real-time
   factor, its change, bag size, and — single-process, where every publisher lives in this
   process and is counted — messages published vs recorded per topic.

    python benchmarks/bench_recorder.py [--duration 1.0] [--formulation force_feedback]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from collections import Counter
from pathlib import Path

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def _joint_state_bytes() -> bytes:
    """A 7-joint JointState as the middleware carries it (CDR from a raw subscription)."""
    from mcap_ros2._dynamic import serialize_dynamic

    from ffmpc_ros.bag.schema import MessageDefinitions

    encoder = serialize_dynamic(
        "sensor_msgs/msg/JointState",
        MessageDefinitions().full_text("sensor_msgs/msg/JointState"),
    )["sensor_msgs/msg/JointState"]
    names = [f"lbr_iiwa_joint_{i}" for i in range(1, 8)]
    return encoder(
        {
            "header": {"stamp": {"sec": 1, "nanosec": 2000000}, "frame_id": ""},
            "name": names,
            "position": [0.1 * i for i in range(7)],
            "velocity": [0.2 * i for i in range(7)],
            "effort": [0.3 * i for i in range(7)],
        }
    )


def bench_writer(messages: int) -> None:
    from ffmpc_ros.bag.writer import BagWriter

    data = _joint_state_bytes()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "w.mcap"
        start = time.perf_counter()
        with BagWriter(path) as writer:
            writer.add_topic("/js", "sensor_msgs/msg/JointState")
            for i in range(messages):
                writer.write("/js", data, i * 1_000_000)
        wall = time.perf_counter() - start
        size = path.stat().st_size
    print(
        f"BagWriter alone          : {messages} JointState ({len(data)} B) in {wall:.2f} s -> "
        f"{messages / wall:,.0f} msgs/s, {messages * len(data) / wall / 1e6:.1f} MB/s raw "
        f"({size / 1e6:.2f} MB zstd file)"
    )


def bench_node(messages: int) -> None:
    import rclpy
    from rclpy.context import Context
    from rclpy.experimental import EventsExecutor
    from rclpy.node import Node
    from sensor_msgs.msg import JointState

    from ffmpc_ros import topics
    from ffmpc_ros.bag.recorder import BagRecorder

    data = _joint_state_bytes()
    rates = {}
    for mode in ("plain raw subscriber", "recorder"):
        context = Context()
        rclpy.init(args=[], context=context, domain_id=int(os.environ.get("ROS_DOMAIN_ID", "0")))
        executor = EventsExecutor(context=context)
        pub_node = Node("bench_pub", context=context)
        pub = pub_node.create_publisher(JointState, "/bench/js", topics.publisher_qos())
        received = Counter()
        tmp = tempfile.TemporaryDirectory()
        if mode == "recorder":
            sink = BagRecorder(
                Path(tmp.name) / "r.mcap",
                context=context,
                topics=["/bench/js"],
                use_sim_time=False,
            )

            def count(sink=sink) -> int:
                return sink.received.get("/bench/js", 0)
        else:
            sink = Node("bench_sub", context=context)
            sink.create_subscription(
                JointState,
                "/bench/js",
                lambda _d, received=received: received.update(["x"]),
                topics.subscriber_qos(True),
                raw=True,
            )

            def count(received=received) -> int:
                return received["x"]

        for n in (pub_node, sink):
            executor.add_node(n)
        end = time.monotonic() + 10
        while pub.get_subscription_count() == 0 and time.monotonic() < end:
            executor.spin_once(timeout_sec=0.01)
        start = time.perf_counter()
        sent = 0
        while sent < messages:
            for _ in range(100):
                pub.publish(data)
            sent += 100
            while count() < sent and time.monotonic() < end + 60:
                executor.spin_once(timeout_sec=0.01)
        wall = time.perf_counter() - start
        rates[mode] = (sent / wall, count(), sent)
        if mode == "recorder":
            sink.close()
        for n in (pub_node, sink):
            executor.remove_node(n)
            n.destroy_node()
        executor.shutdown()
        rclpy.shutdown(context=context)
        tmp.cleanup()
    for mode, (rate, got, sent) in rates.items():
        print(f"in-process {mode:20s}: {rate:,.0f} msgs/s published and taken ({got} of {sent})")
    plain, rec = rates["plain raw subscriber"][0], rates["recorder"][0]
    print(f"    recorder cost per message: {1e6 * (1 / rec - 1 / plain):.1f} µs")


def bench_graph(duration: float, formulation: str, repeats: int) -> None:
    import statistics

    from rclpy.publisher import Publisher

    from ffmpc_core.scenario import load_scenario
    from ffmpc_ros.bag.reader import BagReader
    from ffmpc_ros.bringup import GraphOptions, run_graph

    published: Counter[str] = Counter()
    original = Publisher.publish

    def counting(self, msg):
        published[self.topic_name] += 1
        return original(self, msg)

    scenario = load_scenario("polishing", {"mpc.formulation": formulation})
    with tempfile.TemporaryDirectory() as tmp:
        for single in (True, False):
            label = "single-process" if single else "multi-process "
            without, with_record = [], []
            for i in range(repeats):  # alternate, so a change of machine load hits both
                without.append(
                    run_graph(
                        scenario, GraphOptions(duration=duration, single_process=single)
                    ).real_time_factor
                )
                published.clear()
                Publisher.publish = counting
                try:
                    bag = Path(tmp) / f"run_{single}_{i}.mcap"
                    rec = run_graph(
                        scenario, GraphOptions(duration=duration, single_process=single, record=bag)
                    )
                finally:
                    Publisher.publish = original
                with_record.append(rec.real_time_factor)
            base, recorded = statistics.median(without), statistics.median(with_record)
            with BagReader(bag) as reader:
                size, messages = reader.file_size, reader.message_count
            print(
                f"graph lockstep {label}: real-time factor (median of {repeats}) {base:.3f} "
                f"without, {recorded:.3f} with --record ({100 * (base / recorded - 1):+.1f} % "
                f"wall time); runs without {_fmt(without)}, with {_fmt(with_record)}; bag "
                f"{messages} msgs, {size / 1e6:.2f} MB ({size / 1e6 / duration:.2f} MB per "
                "simulated s)"
            )
            received = rec.bag["received"]
            if single:
                rows = [(t, published[t], received.get(t, 0)) for t in sorted(published)]
                rows = [r for r in rows if r[0] in received]
                dropped = sum(p - r for _, p, r in rows)
                print(f"    published vs recorded per topic (dropped in total: {dropped}):")
                for topic, p, r in rows:
                    print(f"      {topic:28s} {p:6d} {r:6d}")
            else:
                print(f"    recorded per topic: {dict(sorted(received.items()))}")


def _fmt(values: list[float]) -> str:
    return "[" + ", ".join(f"{v:.3f}" for v in values) + "]"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=1.0, help="simulated s per graph run")
    parser.add_argument("--formulation", default="force_feedback")
    parser.add_argument("--writer-messages", type=int, default=200_000)
    parser.add_argument("--node-messages", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=3, help="graph runs per configuration")
    args = parser.parse_args(argv)
    print(f"bench_recorder: {platform.processor() or platform.machine()}, {os.cpu_count()} cores")
    bench_writer(args.writer_messages)
    bench_node(args.node_messages)
    bench_graph(args.duration, args.formulation, args.repeats)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
