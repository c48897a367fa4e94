"""Argument types and ``--set`` parsing shared by ``ffmpc`` (``ffmpc_ros.cli``), its ``bag``
sub-commands (``ffmpc_ros.bag.cli``) and the studies' commands (``studies.cli``, one layer up);
imports none of them, so none imports another for these.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ffmpc_core.errors import ConfigError

#: ffmpc_core.config.FORMULATIONS, spelled out so that building a parser imports nothing heavy
#: (``ffmpc run --formulation``, ``ffmpc study ... --formulations``, ``ffmpc tune``).
STUDY_FORMULATIONS = ("classical", "torque_feedback", "force_feedback")
#: ffmpc_core.scenario.PLANT_ENGINES, spelled out likewise (``--plant``).
PLANT_ENGINES = ("pybullet", "mujoco")
#: The scenario parameter ``--plant`` sets (every scenario and study names it so).
PLANT_ENGINE_PARAMETER = "plant.engine"


def add_plant_argument(parser: argparse.ArgumentParser) -> None:
    """``--plant pybullet|mujoco``: the simulator of the plant (= ``--set plant.engine=…``)."""
    parser.add_argument(
        "--plant",
        choices=PLANT_ENGINES,
        default=None,
        help="simulator of the plant: pybullet or mujoco (the same robot, scene and contact "
        "parameters; = --set plant.engine=ENGINE; default: the scenario's, pybullet)",
    )


def with_plant_engine(overrides: dict, plant: str | None) -> dict:
    """``overrides`` with ``--plant``'s ``plant.engine`` (ConfigError if ``--set`` gave another
    engine)."""
    if plant is None:
        return overrides
    given = overrides.get(PLANT_ENGINE_PARAMETER, plant)
    if given != plant:
        raise ConfigError(f"--plant {plant} and --set {PLANT_ENGINE_PARAMETER}={given}: give one")
    return {**overrides, PLANT_ENGINE_PARAMETER: plant}


# -- argument types: each refuses a malformed value with argparse's one-line error -------------
# Numbers are read by ROS 2's rules (ffmpc_core.values: 1e4, 1e+09, 0x10, .inf), as the nodes and
# scenario files read them.
def _number(text: str) -> float:
    from ffmpc_core.values import parse_number

    try:
        value = parse_number(text)
    except ConfigError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return value


def finite_float(text: str) -> float:
    """A finite number (ROS 2's spelling: ``1e4``, ``-0.5``)."""
    return _number(text)


def positive_float(text: str) -> float:
    """A finite number > 0."""
    value = _number(text)
    if value <= 0.0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}")
    return value


def nonnegative_float(text: str) -> float:
    """A finite number >= 0."""
    value = _number(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}")
    return value


def _integer(text: str, low: int) -> int:
    from ffmpc_core.values import parse_integer

    try:
        value = parse_integer(text)
    except ConfigError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"expected an integer >= {low}, got {text!r}")
    return value


def port_int(text: str) -> int:
    """A TCP port: an integer in [1, 65535]."""
    value = _integer(text, 1)
    if value > 65535:
        raise argparse.ArgumentTypeError(f"expected a port in [1, 65535], got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1."""
    return _integer(text, 1)


def nonnegative_int(text: str) -> int:
    """An integer >= 0."""
    return _integer(text, 0)


def seed_int(text: str) -> int:
    """A seed: an integer in [0, 2**31 - 1] (the range of the scenario's ``seed``)."""
    value = _integer(text, 0)
    if value > 2**31 - 1:
        raise argparse.ArgumentTypeError(f"expected an integer in [0, 2147483647], got {text!r}")
    return value


def new_path(text: str) -> str:
    """An output path in an existing directory; whether it may exist (``--force``) and whether
    the directory is writable is checked before anything starts
    (:func:`ffmpc_ros.preflight.check_output`)."""
    path = Path(text)
    if not text:
        raise argparse.ArgumentTypeError("expected a path, got ''")
    if not path.parent.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: no directory {str(path.parent)!r}")
    return text


def output_file(text: str) -> str:
    """A file to write: not a directory, in an existing directory (existence and writability:
    :func:`ffmpc_ros.preflight.check_output`)."""
    path = Path(text)
    if not text or path.is_dir():
        raise argparse.ArgumentTypeError(f"expected a file path, got {text!r}")
    return new_path(text)


def existing_file(text: str) -> str:
    """An input file that exists."""
    if not Path(text).is_file():
        what = "a directory, not a file" if Path(text).is_dir() else "no such file"
        raise argparse.ArgumentTypeError(f"{text}: {what}")
    return text


def parse_overrides(
    items: list[str] | None, node_names: bool = False, schema: dict | None = None
) -> dict:
    """``--set name=value`` pairs; values are read as ROS 2 reads them (``3``, ``true``, ``1e4``,
    ``[1.0, 2.0]``: :func:`ffmpc_core.values.load_value`)
    and checked against ``schema`` (default: the node-graph scenarios' ``SCHEMA``; a study's
    ``ConfigSchema.params``) (ConfigError ``name = value: expected …``).
    ``node_names``: names that are not scenario names are left to the caller (``bag rerun``
    takes a node's own parameter names)."""
    from ffmpc_core.scenario import SCHEMA as GRAPH_SCHEMA
    from ffmpc_core.scenario import unknown_parameter
    from ffmpc_core.values import load_value

    SCHEMA = GRAPH_SCHEMA if schema is None else schema

    out = {}
    for item in items or []:
        name, sep, text = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise ConfigError(f"--set {item!r}: expected NAME=VALUE")
        try:
            value = load_value(text)  # ROS 2's rules: 1e4 is a number (ffmpc_core.values)
        except ConfigError as exc:
            raise ConfigError(f"--set {item!r}: the value is not a YAML value ({exc})") from None
        if isinstance(value, dict):
            raise ConfigError(f"--set {item!r}: expected one value, not a mapping")
        if name in SCHEMA:
            SCHEMA[name].check(value)  # the length of per-contact-axis lists is checked later
        elif not node_names:
            raise unknown_parameter(name, value, SCHEMA)
        out[name] = value
    return out
