"""``ros2msg`` schemas from the installed ``.msg`` files, and rosbag2's QoS YAML. No ROS import.

A bag's schema for a type is its *complete message definition* in rosbag2's ``ros2msg``
encoding: the type's own ``.msg`` text, then every type it depends on (recursively, each once, in
sorted order, depth first), each preceded by a line of 80 ``=`` and a line ``MSG: pkg/Type`` —
the same text rosbag2's ``LocalMessageDefinitionSource`` writes, so ``rosbags``,
``mcap-ros2-support``, Foxglove and ``ros2 bag`` decode our bags without our code.

The ``.msg`` files are looked up in ``<prefix>/share/<package>/msg/`` for every prefix of
``AMENT_PREFIX_PATH`` and then ``sys.prefix`` (where the ``ros-jazzy-*`` wheels install them).
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import yaml

from ffmpc_ros.bag.errors import SchemaError

#: Schema encoding of a complete ``.msg`` definition (MCAP well-known value).
SCHEMA_ENCODING = "ros2msg"
#: Message encoding of every channel (MCAP well-known value).
MESSAGE_ENCODING = "cdr"
#: MCAP profile of ROS 2 bags.
PROFILE = "ros2"
#: The line before each dependency's definition.
DELIMITER = "=" * 80 + "\n"

# A field's type at the start of a line: "std_msgs/Header header", "float64[] position".
_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_NAME = r"[a-zA-Z][a-zA-Z0-9_]*"
_TYPE = re.compile(rf"^({_NAME})/(?:({_NAME})/)?({_NAME})$")
PRIMITIVE_TYPES = frozenset(
    {
        "bool",
        "byte",
        "char",
        "float32",
        "float64",
        "int8",
        "uint8",
        "int16",
        "uint16",
        "int32",
        "uint32",
        "int64",
        "uint64",
        "string",
        "wstring",
    }
)


def split_type(name: str) -> tuple[str, str, str]:
    """(package, namespace, type) of ``pkg/msg/Type`` or ``pkg/Type`` (namespace ``msg``)."""
    match = _TYPE.match(name)
    if match is None:
        raise SchemaError(f"not a ROS message type name: {name!r} (expected pkg/msg/Type)")
    package, namespace, type_name = match.groups()
    return package, namespace or "msg", type_name


def normalize_type(name: str) -> str:
    """The full ``pkg/msg/Type`` form of a type name."""
    package, namespace, type_name = split_type(name)
    return f"{package}/{namespace}/{type_name}"


def share_directories() -> list[Path]:
    """``<prefix>/share`` of every ``AMENT_PREFIX_PATH`` entry, then of ``sys.prefix``."""
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    out: list[Path] = []
    for prefix in prefixes:
        share = Path(prefix) / "share"
        if share not in out:
            out.append(share)
    return out


def dependencies(text: str, package: str) -> set[str]:
    """The non-primitive field types of a ``.msg`` text, as written (``pkg/Type``); an
    unqualified type is taken from ``package``."""
    out = set()
    for match in _FIELD_TYPE.finditer(text):
        name = match.group(1)
        if name in PRIMITIVE_TYPES:
            continue
        out.add(name if "/" in name else f"{package}/{name}")
    return out


class MessageDefinitions:
    """Finds ``.msg`` files and builds complete definitions (cached).

    Args:
        search_path: ``share`` directories to look in (default :func:`share_directories`).
        known: ``.msg`` texts of types that are not installed, {``pkg/msg/Type``: text}.
    """

    def __init__(
        self,
        search_path: Sequence[os.PathLike | str] | None = None,
        known: Mapping[str, str] | None = None,
    ) -> None:
        paths = share_directories() if search_path is None else search_path
        self.search_path = [Path(p) for p in paths]
        self._texts: dict[str, str] = {normalize_type(k): v for k, v in (known or {}).items()}

    def msg_file(self, type_name: str) -> Path:
        """The ``.msg`` file of a type (SchemaError when none is installed)."""
        package, namespace, name = split_type(type_name)
        for share in self.search_path:
            path = share / package / namespace / f"{name}.msg"
            if path.is_file():
                return path
        looked = ", ".join(str(p) for p in self.search_path)
        raise SchemaError(f"no .msg definition of {type_name} in {looked}")

    def text(self, type_name: str) -> str:
        """The ``.msg`` text of one type, as installed."""
        key = normalize_type(type_name)
        if key not in self._texts:
            self._texts[key] = self.msg_file(key).read_text(encoding="utf-8")
        return self._texts[key]

    def full_text(self, type_name: str, max_depth: int = 50) -> str:
        """The complete ``ros2msg`` definition of a type (rosbag2's layout, module docstring)."""
        seen: set[str] = set()

        def append(name: str, depth: int) -> str:
            if depth <= 0:
                raise SchemaError(f"definition of {type_name} nests deeper than {max_depth}")
            text = self.text(name)
            result = text
            for dep in sorted(dependencies(text, split_type(name)[0])):
                if dep not in seen:
                    seen.add(dep)
                    result += "\n" + DELIMITER + f"MSG: {dep}\n" + append(dep, depth - 1)
            return result

        return append(type_name, max_depth)


#: The "no limit" duration of rosbag2's QoS YAML (RMW_DURATION_INFINITE).
INFINITE_DURATION = {"sec": 9223372036, "nsec": 854775807}
_QOS_KEYS = (
    "history",
    "depth",
    "reliability",
    "durability",
    "deadline",
    "lifespan",
    "liveliness",
    "liveliness_lease_duration",
    "avoid_ros_namespace_conventions",
)


def qos_profile_dict(
    history: str = "keep_last",
    depth: int = 10,
    reliability: str = "reliable",
    durability: str = "volatile",
    liveliness: str = "automatic",
    deadline: Mapping[str, int] | None = None,
    lifespan: Mapping[str, int] | None = None,
    liveliness_lease_duration: Mapping[str, int] | None = None,
    avoid_ros_namespace_conventions: bool = False,
) -> dict[str, Any]:
    """One offered QoS profile as rosbag2 (metadata version 9) writes it."""
    return {
        "history": history,
        "depth": int(depth),
        "reliability": reliability,
        "durability": durability,
        "deadline": dict(deadline or INFINITE_DURATION),
        "lifespan": dict(lifespan or INFINITE_DURATION),
        "liveliness": liveliness,
        "liveliness_lease_duration": dict(liveliness_lease_duration or INFINITE_DURATION),
        "avoid_ros_namespace_conventions": bool(avoid_ros_namespace_conventions),
    }


def qos_yaml(profiles: Sequence[Mapping[str, Any]]) -> str:
    """The ``offered_qos_profiles`` channel metadata: a YAML list of profiles."""
    ordered = [{k: p[k] for k in _QOS_KEYS if k in p} for p in profiles]
    return yaml.safe_dump(ordered, sort_keys=False, default_flow_style=False) if ordered else ""


def parse_qos_yaml(text: str) -> list[dict[str, Any]]:
    """The profiles of an ``offered_qos_profiles`` value ([] for an empty one)."""
    if not text.strip():
        return []
    value = yaml.safe_load(text)
    if not isinstance(value, list) or not all(isinstance(p, dict) for p in value):
        raise SchemaError(f"offered_qos_profiles is not a list of profiles: {text[:200]!r}")
    return value
