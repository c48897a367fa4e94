"""What every child process of the bring-up (the recorder, the view) does around its node: read
its JSON configuration, turn SIGINT/SIGTERM into a stop request (the bring-up's stop, and the
signal PR_SET_PDEATHSIG sends when the bring-up dies), and own an rclpy context and executor on
the run's ROS domain, shut down on the way out."""

from __future__ import annotations

import contextlib
import json
import signal
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions


@dataclass
class ChildProcess:
    """A child's configuration (``config["domain"]`` is its ROS domain, ``config["ros_args"]``
    the ROS arguments of its context, e.g. ``-r __ns:=/arm1``), rclpy context and
    executor, and the signals received so far (non-empty: stop)."""

    config: dict[str, Any]
    context: Context
    executor: Executor  # an rclpy EventsExecutor
    stopping: list[int] = field(default_factory=list)


@contextlib.contextmanager
def child_ros_process(config_path: str) -> Iterator[ChildProcess]:
    """The child's :class:`ChildProcess`; the executor and the context are shut down at exit."""
    with open(config_path, encoding="utf-8") as fh:
        config = json.load(fh)
    stopping: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _frame: stopping.append(signum))
    context = Context()
    rclpy.init(
        # ROS arguments of every node of the child (the graph's namespace and clock remap)
        args=["ffmpc-child", "--ros-args", *config.get("ros_args", [])],
        context=context,
        domain_id=int(config["domain"]),
        signal_handler_options=SignalHandlerOptions.NO,
    )
    executor = EventsExecutor(context=context)
    try:
        yield ChildProcess(config, context, executor, stopping)
    finally:
        executor.shutdown()
        rclpy.shutdown(context=context)
