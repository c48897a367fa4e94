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


#: The environment variable of the ROS domain (rcl reads it at ``rclpy.init``).
DOMAIN_ID_VARIABLE = "ROS_DOMAIN_ID"
#: Largest domain id Fast DDS can open (its UDP ports are 7400 + 250·id + …, below 65536):
#: ROS 2's documented range is 0–232; 233 and above fail to create a participant.
MAX_DOMAIN_ID = 232
#: The values rcl knows for ROS_AUTOMATIC_DISCOVERY_RANGE (rcl/src/rcl/discovery_options.c).
DISCOVERY_RANGES = ("OFF", "LOCALHOST", "SUBNET", "SYSTEM_DEFAULT")


def domain_id() -> int:
    """The ROS domain of this process: ``ROS_DOMAIN_ID`` (unset or empty: 0), an integer in
    0..:data:`MAX_DOMAIN_ID`; ConfigError (one line) otherwise, before rcl or Fast DDS would
    fail with their own (``ROS_DOMAIN_ID=abc``: rcl's "not an integral number" as a Python
    traceback; ``ROS_DOMAIN_ID=999``: Fast DDS's error on stdout only)."""
    from ffmpc_core.errors import ConfigError
    from ffmpc_core.values import parse_integer

    text = os.environ.get(DOMAIN_ID_VARIABLE, "").strip()
    if not text:
        return 0
    try:
        value = parse_integer(text, DOMAIN_ID_VARIABLE)
    except ConfigError:
        value = -1
    if not 0 <= value <= MAX_DOMAIN_ID:
        raise ConfigError(
            f"{DOMAIN_ID_VARIABLE}={text!r}: expected an integer in [0, {MAX_DOMAIN_ID}] "
            "(ROS 2's domain range; Fast DDS opens no port beyond it)"
        )
    return value


def check_ros_environment() -> int:
    """Every environment variable a ROS entry point depends on, checked before anything
    starts (ConfigError, one line): ``ROS_DOMAIN_ID`` (:func:`domain_id`) and
    ``ROS_AUTOMATIC_DISCOVERY_RANGE`` (one of :data:`DISCOVERY_RANGES`; rcl reads any other
    value as LOCALHOST with a warning); sets LOCALHOST discovery when unset
    (:func:`ensure_local_discovery`). Returns the domain id."""
    from ffmpc_core.errors import ConfigError

    chosen = os.environ.get(DISCOVERY_RANGE_VARIABLE, "").strip()
    if chosen and chosen not in DISCOVERY_RANGES:
        raise ConfigError(
            f"{DISCOVERY_RANGE_VARIABLE}={chosen!r}: expected one of {', '.join(DISCOVERY_RANGES)}"
        )
    ensure_local_discovery()
    return domain_id()
