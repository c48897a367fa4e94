"""The study's metrics and plots from a bag, with the metrics node's own code.

:func:`bag_study` builds a :class:`~ffmpc_ros.metrics_node.MetricsNode` with the parameters it
ran with (recorded in the bag) and hands its callbacks the recorded messages of the topics it
subscribes to, in recorded order — the node never spins and publishes nothing outside a private
hidden namespace. Its log (:class:`~ffmpc_core.polishing.PolishingLog`) and metrics
(:func:`~ffmpc_core.polishing.polishing_run_metrics`) are therefore those of the live metrics
node: for a lockstep run they equal the ``/metrics/summary`` recorded in the same bag.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass

import numpy as np
import rclpy
from rclpy.context import Context
from rclpy.logging import LoggingSeverity
from rclpy.serialization import deserialize_message

from ffmpc_core.metrics import PolishingMetrics
from ffmpc_ros import topics
from ffmpc_ros.bag.errors import BagError
from ffmpc_ros.bag.reader import BagReader
from ffmpc_ros.bag.rerun import bag_namespace, node_parameters
from ffmpc_ros.discovery import domain_id as _env_domain_id


@dataclass
class BagStudy:
    """A run rebuilt from a bag."""

    bag: str
    formulation: str
    seed: int
    cycles: int  # cycles of the run
    recorded_cycles: int  # cycles complete in the bag
    filled: int  # real time: values carried over from the previous cycle
    log: dict[str, np.ndarray]
    table_normal: np.ndarray
    metrics_true: PolishingMetrics | None
    metrics_measured: PolishingMetrics | None
    recorded_summary: dict | None  # the /metrics/summary recorded in the bag, if any
    #: the guarded approach (ffmpc_core.tasks.GuardedTask): the detection time read from the
    #: bag's measured force, s (None: none), and whether the descent reached its bound
    contact_time: float | None = None
    contact_missed: bool = False

    def summary(self) -> dict:
        """The metrics node's summary, computed from the bag."""
        return {
            "formulation": self.formulation,
            "seed": self.seed,
            "cycles": self.cycles,
            "filled": self.filled,
            "metrics_true": None if self.metrics_true is None else self.metrics_true.to_dict(),
            "metrics_measured": None
            if self.metrics_measured is None
            else self.metrics_measured.to_dict(),
            "contact_time_s": self.contact_time,
            "contact_missed": self.contact_missed,
        }

    @property
    def matches_recorded(self) -> bool | None:
        """The metrics equal the recorded summary (None when the bag has none), compared on
        the keys the recorded summary has: a bag recorded before a key was added (the
        guarded approach's ``contact_time_s``) still matches on everything it holds."""
        if self.recorded_summary is None:
            return None
        computed = json.loads(json.dumps(self.summary()))
        return {k: computed.get(k) for k in self.recorded_summary} == self.recorded_summary

    def position_error(self) -> np.ndarray:
        """Tangential position error ‖(I − n nᵀ)(p − p̄)‖ per cycle, m (E_P's integrand)."""
        error = self.log["ee_position"] - self.log["ee_reference"]
        n = self.table_normal
        return np.linalg.norm(error - np.outer(error @ n, n), axis=1)


def bag_study(path: str | os.PathLike) -> BagStudy:
    """Rebuild the run's log and metrics from a bag (module docstring)."""
    from ffmpc_ros.metrics_node import MetricsNode
    from ffmpc_ros.params import parameter_overrides

    with BagReader(path) as bag:
        values = node_parameters(bag, "metrics")
        values.pop("use_sim_time", None)
        namespace = bag_namespace(bag)  # the node's names resolve to the recorded ones
        summary_topic = topics.resolve(topics.METRICS_SUMMARY, namespace)
        recorded = None
        if summary_topic in bag.topics and bag.topics[summary_topic].count:
            from std_msgs.msg import String

            last = list(bag.messages([summary_topic]))[-1]
            recorded = json.loads(deserialize_message(last.data, String).data)
        context = Context()
        rclpy.init(args=[], context=context, domain_id=_env_domain_id())
        prefix = f"/_ffmpc_bag_{os.getpid()}"
        remaps = [
            a
            for t in (topics.METRICS_SUMMARY, topics.METRICS_READY)
            for a in ("-r", f"{topics.resolve(t, namespace)}:={prefix}{t}")
        ]
        remaps += topics.graph_ros_args(namespace)  # its namespace and clock, as recorded
        values.pop("start_clock_subscribers", None)  # the recorded graph's start barrier
        node = None
        try:
            node = MetricsNode(
                context=context,
                parameter_overrides=parameter_overrides(values),
                node_name="_bag_metrics",
                cli_args=["--ros-args", *remaps],
            )
            node.get_logger().set_level(LoggingSeverity.WARN)  # no "metrics: …" line
            subs = {s.topic_name: s for s in node.subscriptions if s.topic_name in bag.topics}
            missing = sorted(
                s.topic_name for s in node.subscriptions if s.topic_name not in bag.topics
            )
            if missing:
                raise BagError(f"the bag lacks topics the metrics need: {missing}")
            for m in bag.messages(list(subs)):
                sub = subs[m.topic]
                sub.callback(deserialize_message(m.data, sub.msg_type))
            if node.metrics is None and not node.lockstep and node.has_states:
                node.finish_now()  # real time: finish with what the bag holds
            true, measured = node.metrics if node.metrics is not None else (None, None)
            return BagStudy(
                bag=str(path),
                formulation=node.scenario.mpc.ocp.formulation,
                seed=node.scenario.seed,
                cycles=node.steps,
                recorded_cycles=node.recorded,
                filled=node.filled,
                log={k: v.copy() for k, v in node.log.arrays.items()},
                table_normal=np.array(
                    node.table_normal if node.table_normal is not None else [0.0, 0.0, 1.0]
                ),
                metrics_true=true,
                metrics_measured=measured,
                recorded_summary=recorded,
                contact_time=node.contact_time,
                contact_missed=node.metrics is not None and node.contact_missed,
            )
        finally:
            if node is not None:
                node.destroy_node()
            rclpy.shutdown(context=context)


def plot_study(study: BagStudy, out: str | os.PathLike) -> str:
    """PNG of the normal force (true, measured, reference) and the tangential position error
    over time; returns the path written (refuses to overwrite)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = os.fspath(out)
    if os.path.exists(out):
        raise BagError(f"{out} exists; not overwritten")
    n = study.recorded_cycles if study.metrics_true is None else study.cycles
    log = {k: v[:n] for k, v in study.log.items()}
    t = log["t"]
    fig, (ax_f, ax_p) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    ax_f.plot(t, log["force_reference"], "k--", lw=1.2, label="reference λ̄")
    ax_f.plot(t, log["force_true"], lw=1.0, label="true (plant)")
    ax_f.plot(t, log["force_measured"], lw=0.6, alpha=0.7, label="measured (F/T sensor)")
    ax_f.set_ylabel("normal force [N]")
    ax_f.legend(loc="best", fontsize=8)
    ax_f.grid(alpha=0.3)
    ax_p.plot(t, 1e3 * study.position_error()[:n], lw=1.0, color="tab:red")
    ax_p.set_ylabel("tangential position error [mm]")
    ax_p.set_xlabel("simulated time [s]")
    ax_p.grid(alpha=0.3)
    title = f"{os.path.basename(study.bag)}: {study.formulation}, seed {study.seed}"
    if study.metrics_true is not None:
        m = study.metrics_true
        title += f" — E_P {m.position_mae_mm:.2f} mm, E_λ {m.force_mae:.2f} N"
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
