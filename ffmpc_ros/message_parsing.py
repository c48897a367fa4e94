"""Parsers of the graph's input messages into arrays: each returns the values or raises
:class:`~ffmpc_core.errors.InputError` naming what is wrong (the node then rejects the message:
:meth:`ffmpc_ros.input_gate.InputGate.receive`). No rclpy here but the message types."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from geometry_msgs.msg import WrenchStamped
from numpy.typing import ArrayLike
from sensor_msgs.msg import JointState

from ffmpc_core.errors import InputError
from ffmpc_ros.topics import WRENCH_FRAME


def vector(values: ArrayLike, n: int, name: str) -> np.ndarray:
    """A float array of n finite values (InputError otherwise)."""
    arr = np.asarray(values, dtype=float)
    if arr.shape != (n,):
        raise InputError(f"{name} has {arr.size} values, expected {n}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} is not finite: {arr}")
    return arr


def joint_arrays(
    msg: JointState, joint_names: Sequence[str], fields: Sequence[str]
) -> list[np.ndarray]:
    """The requested JointState fields in the robot's joint order (any order of names is
    accepted); InputError on unknown, missing or repeated names and bad values."""
    names = list(msg.name)
    if len(names) != len(set(names)) or set(names) != set(joint_names):
        unknown = sorted(set(names) - set(joint_names))
        missing = sorted(set(joint_names) - set(names))
        raise InputError(f"joint names: unknown {unknown}, missing {missing}")
    order = [names.index(n) for n in joint_names]
    out = []
    for f in fields:
        raw = np.asarray(getattr(msg, f), dtype=float)
        if raw.shape != (len(names),):
            raise InputError(f"{f} has {raw.size} values for {len(names)} joints")
        out.append(vector(raw[order], len(joint_names), f))
    return out


def joint_fields(joint_names: Sequence[str], *fields: str) -> Callable[[Any], list[np.ndarray]]:
    """A parser of JointState messages into ``fields`` in the order of ``joint_names``."""
    return lambda msg: joint_arrays(msg, joint_names, fields)


def wrench_array(msg: WrenchStamped) -> np.ndarray:
    """[f; m] of a WrenchStamped in :data:`~ffmpc_ros.topics.WRENCH_FRAME` (N, N·m; InputError
    otherwise)."""
    if msg.header.frame_id != WRENCH_FRAME:
        raise InputError(f"frame_id {msg.header.frame_id!r}, expected {WRENCH_FRAME!r}")
    f, m = msg.wrench.force, msg.wrench.torque
    return vector([f.x, f.y, f.z, m.x, m.y, m.z], 6, "wrench")
