"""A configuration parameter declared with its dataclass field: unit, range or choices, meaning.

A field of a configuration dataclass (``ContactConfig``, ``PlannerConfig``, the scenario
sections) is a parameter when it is made by :func:`param`::

    stiffness: float = param(1e3, "N/m", (0.0, 1e9), "K of the visco-elastic contact (eq 16)")

:func:`ffmpc_core.scenario.dataclass_schema` reads the declaration from the field (its kind
and list length come from the annotation) and builds the :class:`~ffmpc_core.scenario.ParamSpec`
that ``--set``, the scenario files, the node parameters and the launch arguments check values
with. This module is below every configuration class (it imports nothing of ffmpc).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import MISSING, Field, field
from typing import Any

#: One parameter's declaration: (unit, (low, high) closed range or [choices] or None,
#: description). The kind and the list length come from the field's annotation.
FieldDecl = tuple[str, Any, str]
#: The key of a dataclass field's ``metadata`` that holds its :data:`FieldDecl`.
PARAM_KEY = "ffmpc.param"


def param(
    default: Any = MISSING,
    unit: str = "",
    limits: tuple[float, float] | list[Any] | None = None,
    description: str = "",
    *,
    default_factory: Callable[[], Any] | Any = MISSING,
) -> Any:
    """A dataclass field with its parameter declaration: ``default`` (or ``default_factory``),
    ``unit`` ("" if none), ``limits`` (a closed ``(low, high)`` range, each entry of a list
    in it; a list of the allowed values; or None) and a one-line ``description``."""
    if not description:
        raise ValueError("param: a parameter needs a description")
    metadata = {PARAM_KEY: (unit, limits, description)}
    if default_factory is not MISSING:
        return field(default_factory=default_factory, metadata=metadata)
    return field(default=default, metadata=metadata)


def declaration(f: Field[Any]) -> FieldDecl | None:
    """The :data:`FieldDecl` of a dataclass field made by :func:`param`, or None."""
    decl = f.metadata.get(PARAM_KEY)
    return None if decl is None else (decl[0], decl[1], decl[2])
