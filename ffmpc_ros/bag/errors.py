"""Errors of the bag tools (all are :class:`ffmpc_core.errors.FfmpcError`)."""

from __future__ import annotations

from ffmpc_core.errors import FfmpcError


class BagError(FfmpcError):
    """A bag cannot be written, read or used as asked."""


class BagExistsError(BagError, FileExistsError):
    """The target of a writer already exists (bags are never overwritten)."""


class SchemaError(BagError):
    """A message type or its ``.msg`` definition cannot be found or understood."""
