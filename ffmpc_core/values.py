"""One reader of parameter values: ROS 2's rules, for the command line, scenario files and nodes.

A node reads its parameters through rcl (``--params-file FILE``, ``-p name:=value``), whose YAML
parser (``rcl_yaml_param_parser``, ``get_value``) types a plain (unquoted) scalar itself:

* ``true``/``false``, ``True``, ``TRUE``, ``yes``/``no``, ``on``/``off``, ``y``/``n`` (each in
  its three spellings): a bool;
* what C's ``strtoll(text, &end, 0)`` reads whole, without overflow: an integer (``42``,
  ``-3``, ``0x1f``; a leading ``0`` is octal, ``010`` is 8);
* ``.inf``, ``-.inf``, ``.nan`` (three spellings each) and what ``strtod`` reads whole without
  overflow: a double (``1e4``, ``1e+09``, ``2.5``, ``.5``, ``5.``, ``inf``, ``nan``, ``0x1p3``);
* anything else, and every quoted scalar or ``!!str``: a string.

PyYAML's ``safe_load`` (YAML 1.1) reads ``1e4`` and ``1e+09`` as strings (its floats need a
dot), ``1_000`` as 1000 and ``1:30`` as 90: the ROS-free runner and the nodes read one file
differently. :func:`load_yaml` reads a document with rcl's rules (:func:`parse_scalar` for every
plain scalar, a list of mixed scalar types refused as rcl refuses it), and :func:`parse_number`
reads one number from the command line by the same rules. Every reader of parameter values
in ffmpc goes through this module: ``ffmpc run --set``, the numeric options of every command,
scenario files (``ffmpc_core.scenario``), ``--set-file``, and the nodes' live parameters given
as text (``ros2 param set /mpc contact.stiffness 1e4``, which the ros2 CLI sends as a string).

``null``, ``~`` and an empty value stay None (YAML's null; rcl would read the text ``null``):
no node-graph parameter takes None, so both refuse it; the studies' optional values use it.
Whether a number is acceptable (finite, in range) is the schema's business
(``ffmpc_core.scenario.ParamSpec``), not the parser's: ``.inf`` is read as inf and refused where
a range says so.
"""

from __future__ import annotations

import math
import re
from typing import IO, Any

import yaml

from ffmpc_core.errors import ConfigError

#: Plain scalars rcl reads as true / false (``rcl_yaml_param_parser/src/parse.c``, get_value).
TRUE_WORDS = frozenset("Y y yes Yes YES true True TRUE on On ON".split())
FALSE_WORDS = frozenset("N n no No NO false False FALSE off Off OFF".split())
#: rcl's YAML infinities and NaNs (read before strtod, which does not know them).
_SPECIAL = {
    f"{sign}.{word}": value
    for word, inf in (("inf", math.inf), ("Inf", math.inf), ("INF", math.inf))
    for sign, value in (("", inf), ("+", inf), ("-", -inf))
} | {".nan": math.nan, ".NaN": math.nan, ".NAN": math.nan}
_INT64 = (-(2**63), 2**63 - 1)
# strtoll(text, &end, 0) read whole: sign, then hex, octal (leading 0) or decimal digits.
_STRTOLL = re.compile(r"[ \t\n\v\f\r]*([+-]?)(0[xX][0-9a-fA-F]+|0[0-7]*|[1-9][0-9]*)")
# strtod read whole: decimal (with exponent), hexadecimal (with binary exponent), inf, nan.
_DECIMAL = re.compile(r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_HEXFLOAT = re.compile(
    r"[+-]?0[xX](?:[0-9a-fA-F]+\.?[0-9a-fA-F]*|\.[0-9a-fA-F]+)(?:[pP][+-]?[0-9]+)?"
)
_INF_NAN = re.compile(r"([+-]?)(inf|infinity|nan(?:\([0-9a-zA-Z_]*\))?)", re.IGNORECASE)


def _strtoll(text: str) -> int | None:
    """The integer ``strtoll(text, &end, 0)`` reads from the whole of ``text``, or None
    (not all of it read, or out of the int64 range: ERANGE)."""
    match = _STRTOLL.fullmatch(text)
    if match is None:
        return None
    sign, digits = match.groups()
    if digits[:2] in ("0x", "0X"):
        value = int(digits[2:], 16)
    elif digits.startswith("0") and len(digits) > 1:
        value = int(digits[1:], 8)
    else:
        value = int(digits, 10)
    value = -value if sign == "-" else value
    return value if _INT64[0] <= value <= _INT64[1] else None


def _strtod(text: str) -> float | None:
    """The double ``strtod`` reads from the whole of ``text`` without ERANGE, or None."""
    body = text.lstrip(" \t\n\v\f\r")
    special = _INF_NAN.fullmatch(body)
    if special is not None:
        sign, word = special.groups()
        value = math.nan if word.lower().startswith("nan") else math.inf
        return -value if sign == "-" else value
    if _DECIMAL.fullmatch(body):
        value = float(body)
    elif _HEXFLOAT.fullmatch(body):
        sign = -1.0 if body.startswith("-") else 1.0
        hexa = body.lstrip("+-")
        value = sign * float.fromhex(hexa if "p" in hexa.lower() else hexa + "p0")
    else:
        return None
    mantissa = re.sub(r"[eEpP].*|[^0-9a-fA-F]|^[+-]?0[xX]", "", body)
    # ERANGE: overflow to inf, or a non-zero number that underflowed below the normal range
    if math.isinf(value) or (value != 0.0 and abs(value) < 2.2250738585072014e-308):
        return None
    if value == 0.0 and mantissa.strip("0"):
        return None
    return value


def parse_scalar(text: str) -> bool | int | float | str:
    """A plain (unquoted) YAML scalar typed as rcl types it (module docstring)."""
    if text in TRUE_WORDS:
        return True
    if text in FALSE_WORDS:
        return False
    integer = _strtoll(text)
    if integer is not None and text != "":
        return integer
    if text in _SPECIAL:
        return _SPECIAL[text]
    number = _strtod(text)
    if number is not None:
        return number
    return text


def parse_number(text: str, what: str = "value") -> float:
    """The number ``text`` spells by ROS 2's rules (``1e4``, ``1e+09``, ``-3``, ``.inf``), as a
    float; ConfigError (``what``: expected a number, got …) for anything else (a bool word, a
    string). Finiteness and ranges are the caller's to check."""
    value = parse_scalar(text.strip())
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{what}: expected a number, got {text!r}")
    return float(value)


def parse_integer(text: str, what: str = "value") -> int:
    """The integer ``text`` spells by ROS 2's rules (``42``, ``-3``, ``0x1f``); ConfigError for
    anything else (``1e3`` and ``2.0`` are doubles to ROS 2, not integers)."""
    value = parse_scalar(text.strip())
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigError(f"{what}: expected an integer, got {text!r}")
    return value


#: The tag :class:`RosYamlLoader` gives a plain scalar that is not null (typed by rcl's rules).
PLAIN_TAG = "tag:ffmpc,2026:ros-plain-scalar"
_STR_TAG = "tag:yaml.org,2002:str"
_NULL_TAG = "tag:yaml.org,2002:null"
_NULLS = frozenset({"", "~", "null", "Null", "NULL"})


class RosYamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader with rcl's typing of plain scalars (module docstring): every plain
    scalar that is not null is typed by :func:`parse_scalar`; quoted and ``!!str`` ones stay
    strings, and mapping keys are always strings (as rcl's parameter names)."""

    def resolve(self, kind: Any, value: Any, implicit: Any) -> str:
        """The tag of a node: a plain scalar without a tag is read by :func:`parse_scalar`
        (rcl's rules), not by YAML 1.1's resolvers."""
        if kind is yaml.ScalarNode and implicit[0]:  # a plain scalar without a tag
            return _NULL_TAG if value in _NULLS else PLAIN_TAG
        return str(super().resolve(kind, value, implicit))

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        """A mapping whose plain keys stay strings (parameter names are never numbers)."""
        for key, _ in node.value:
            if key.tag == PLAIN_TAG:
                key.tag = _STR_TAG
        return super().construct_mapping(node, deep=deep)


def _construct_plain(loader: RosYamlLoader, node: yaml.ScalarNode) -> Any:
    return parse_scalar(str(loader.construct_scalar(node)))


class RosValueLoader(RosYamlLoader):
    """:class:`RosYamlLoader` for one command-line value (``--set NAME=[0, 40.0, 0]``): a list
    may mix integers and doubles, since the value is checked by the schema and handed to the
    nodes as the schema's type, never as the text."""

    mixed_numbers_ok = True


def _construct_sequence(loader: RosYamlLoader, node: yaml.SequenceNode) -> list:
    items = loader.construct_sequence(node, deep=True)
    kinds = {_kind(v) for v in items if not isinstance(v, list | dict)}
    if getattr(loader, "mixed_numbers_ok", False) and kinds <= {"integer", "double"}:
        return items
    if len(kinds) > 1:
        line = node.start_mark.line + 1
        raise ConfigError(
            f"line {line}: a list mixes {', '.join(sorted(kinds))} values (ROS 2 refuses it: "
            "'Sequence should be of same type'; write 1.0, not 1, among doubles)"
        )
    return items


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "double"
    return "string" if isinstance(value, str) else type(value).__name__


RosYamlLoader.add_constructor(PLAIN_TAG, _construct_plain)
RosYamlLoader.add_constructor("tag:yaml.org,2002:seq", _construct_sequence)


def load_yaml(stream: str | IO[str]) -> Any:
    """One YAML document read with rcl's scalar rules (:class:`RosYamlLoader`). yaml.YAMLError
    for malformed YAML, ConfigError for a list of mixed types."""
    return yaml.load(stream, Loader=RosYamlLoader)  # noqa: S506  (a SafeLoader subclass)


def load_value(text: str) -> Any:
    """One command-line value (``--set NAME=VALUE``, ``--node-param NODE:NAME:=VALUE``): a
    scalar by rcl's rules, or a flow list/mapping (``[1.0, 2.0]``; integers and doubles may mix,
    :class:`RosValueLoader`); ConfigError when it is not YAML."""
    try:
        return yaml.load(text, Loader=RosValueLoader)  # noqa: S506  (a SafeLoader subclass)
    except yaml.YAMLError:
        raise ConfigError(f"{text!r} is not a YAML value") from None
