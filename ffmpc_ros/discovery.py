"""ROS 2 discovery stays on this machine unless the user widens it on purpose.

ROS 2 Jazzy's default (``ROS_AUTOMATIC_DISCOVERY_RANGE`` unset = SUBNET) lets every node of a
controller stack find, and be found by, every ROS 2 process on the local network: a robot cell
next door could publish torques to this one. Every ffmpc entry point (the ``ffmpc`` command line
and each node executable) calls :func:`ensure_local_discovery` before ``rclpy.init``: it sets
``LOCALHOST`` when the variable is unset or empty, and keeps any range the user set (``SUBNET``
for a real robot network, ``OFF``, ``SYSTEM_DEFAULT``). Child processes inherit it.
"""

from __future__ import annotations

import os

#: The environment variable rcl reads at ``rclpy.init``.
DISCOVERY_RANGE_VARIABLE = "ROS_AUTOMATIC_DISCOVERY_RANGE"
#: What ffmpc uses when the user said nothing.
DEFAULT_DISCOVERY_RANGE = "LOCALHOST"


def ensure_local_discovery() -> str:
    """Set LOCALHOST discovery unless the user chose a range; returns the range in force."""
    chosen = os.environ.get(DISCOVERY_RANGE_VARIABLE, "").strip()
    if not chosen:
        os.environ[DISCOVERY_RANGE_VARIABLE] = DEFAULT_DISCOVERY_RANGE
        return DEFAULT_DISCOVERY_RANGE
    return chosen
