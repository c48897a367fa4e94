"""A node's real-time wait loop, instead of an executor: block on a wait set over its readers,
take the newest sample of each (older ones are worthless), hand it to the reader's handler; until
the node's context shuts down (SIGINT). The garbage collector is frozen and disabled meanwhile
(no collection pause inside a cycle). Used by the MPC node in real time
(:meth:`ffmpc_ros.mpc_node.MpcNode.spin_realtime`)."""

from __future__ import annotations

import contextlib
import gc
from collections.abc import Callable, Sequence
from typing import Any

from rclpy.node import Node
from rclpy.subscription import Subscription

#: A reader of the loop: (subscription, handler of its newest sample, whether that sample is
#: taken only when its stamp passes the loop's ``wanted`` test).
Reader = tuple[Subscription, Callable[[Any], None], bool]


def spin_newest(node: Node, readers: Sequence[Reader], wanted: Callable[[Any], bool]) -> None:
    """Run ``node``'s wait loop over ``readers`` (module docstring); ``wanted(stamp)`` says
    whether the newest sample of a filtered reader is handled (e.g. only MPC ticks)."""
    from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

    context_handle = node.context.handle
    if context_handle is None:  # the context is already destroyed: nothing to wait for
        return
    gc.collect()
    gc.freeze()
    gc.disable()
    with contextlib.ExitStack() as stack:
        for sub, _, _ in readers:
            stack.enter_context(sub.handle)
        stack.enter_context(context_handle)
        wait_set = _rclpy.WaitSet(len(readers), 0, 0, 0, 0, 0, context_handle)
        while node.context.ok():
            wait_set.clear_entities()
            for sub, _, _ in readers:
                wait_set.add_subscription(sub.handle)
            try:
                wait_set.wait(100_000_000)  # ns
            except Exception:  # noqa: BLE001  (the context shut down while waiting)
                break
            for sub, handler, filtered in readers:
                newest = None
                while (taken := sub.handle.take_message(sub.msg_type, sub.raw)) is not None:
                    newest = taken[0]
                if newest is None or (filtered and not wanted(newest.header.stamp)):
                    continue
                handler(newest)
    gc.enable()
