"""rclpy glue shared by the recorder, the player and the rerun: message classes from type
names, QoS profiles to and from rosbag2's dictionaries."""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from enum import Enum
from typing import Any, TypeVar

from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)

from ffmpc_ros.bag.errors import SchemaError
from ffmpc_ros.bag.schema import INFINITE_DURATION, qos_profile_dict, split_type

PolicyT = TypeVar("PolicyT", bound=Enum)

_INFINITE_NS = INFINITE_DURATION["sec"] * 1_000_000_000 + INFINITE_DURATION["nsec"]
#: History depth of a publisher whose offered depth is unknown (DDS does not carry it).
DEFAULT_DEPTH = 100


def message_class(type_name: str) -> type[Any]:
    """The rclpy message class of ``pkg/msg/Type`` (SchemaError if it is not installed)."""
    package, namespace, name = split_type(type_name)
    try:
        return getattr(importlib.import_module(f"{package}.{namespace}"), name)
    except (ImportError, AttributeError):
        raise SchemaError(f"message type {type_name} is not installed") from None


def is_installed(type_name: str) -> bool:
    """Whether rclpy has the message class of ``pkg/msg/Type`` here."""
    try:
        message_class(type_name)
    except SchemaError:
        return False
    return True


def _duration(d: Duration) -> dict[str, int]:
    ns = min(int(d.nanoseconds), _INFINITE_NS)
    if ns <= 0:
        ns = _INFINITE_NS  # 0 = "default", which is infinite for deadline/lifespan/lease
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def qos_to_dict(qos: QoSProfile) -> dict[str, Any]:
    """rosbag2's dictionary of an rclpy profile (history ``unknown``, depth 0 as DDS reports
    for remote publishers)."""
    return qos_profile_dict(
        history=qos.history.name.lower(),
        depth=qos.depth,
        reliability=qos.reliability.name.lower(),
        durability=qos.durability.name.lower(),
        liveliness=qos.liveliness.name.lower(),
        deadline=_duration(qos.deadline),
        lifespan=_duration(qos.lifespan),
        liveliness_lease_duration=_duration(qos.liveliness_lease_duration),
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions,
    )


def _policy(enum: type[PolicyT], value: object, default: PolicyT | None) -> PolicyT | None:
    """The member of ``enum`` named ``value`` (any case), or ``default``."""
    try:
        return enum[str(value).upper()]
    except KeyError:
        return default


def qos_from_dicts(profiles: Sequence[Mapping[str, Any]], depth: int | None = None) -> QoSProfile:
    """A profile compatible with every offered one: reliable and transient-local only if all
    of them are (as rosbag2 does); KEEP_LAST with ``depth`` (default: the largest offered depth,
    or :data:`DEFAULT_DEPTH` when unknown)."""
    if not profiles:
        return QoSProfile(depth=depth or DEFAULT_DEPTH)
    reliable = all(
        _policy(ReliabilityPolicy, p.get("reliability"), None) == ReliabilityPolicy.RELIABLE
        for p in profiles
    )
    transient = all(
        _policy(DurabilityPolicy, p.get("durability"), None) == DurabilityPolicy.TRANSIENT_LOCAL
        for p in profiles
    )
    offered = max(int(p.get("depth", 0) or 0) for p in profiles)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth or offered or DEFAULT_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient else DurabilityPolicy.VOLATILE,
        liveliness=LivelinessPolicy.AUTOMATIC,
    )


def offered_profiles(publishers: Sequence[Any]) -> list[dict[str, Any]]:
    """rosbag2's dictionaries of the QoS offered by each publisher (``TopicEndpointInfo``)."""
    return [qos_to_dict(p.qos_profile) for p in publishers]


def subscribe_raw(
    node: Any,
    topic: str,
    type_name: str,
    profiles: Sequence[Mapping[str, Any]],
    callback: Any,
    depth: int,
) -> Any:
    """A raw subscription (the callback gets the CDR bytes, nothing deserialised) whose QoS is
    compatible with every offered profile (:func:`qos_from_dicts`, history ``depth``): the
    recorder's and the live view's way to take any topic as it is."""
    return node.create_subscription(
        message_class(type_name), topic, callback, qos_from_dicts(profiles, depth=depth), raw=True
    )
