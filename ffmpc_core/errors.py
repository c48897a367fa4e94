"""The one exception hierarchy of ffmpc: catch :class:`FfmpcError` to catch them all."""

from __future__ import annotations


class FfmpcError(Exception):
    """Base class of every error raised by ffmpc."""


class ConfigError(FfmpcError, ValueError):
    """A configuration value is missing, out of range or inconsistent."""


class CalibrationError(ConfigError):
    """A sensor calibration is refused: stale, for another cell or tool, or implausible (the
    message says which and the numbers)."""


class ModelError(FfmpcError):
    """A robot or contact model is wrong (bad frame, wrong size, failed self-check)."""


class SelfCheckError(ModelError):
    """A dynamics library disagrees with the reference (e.g. crocoddyl vs ``pin.aba``)."""


class SolverError(FfmpcError):
    """An optimal-control or QP solve failed in a way the caller must handle."""


class InputError(FfmpcError, ValueError):
    """A measurement or message is malformed (NaN/Inf, wrong size, wrong names, stale)."""


class InfeasibleTargetError(FfmpcError):
    """A task cannot be done safely with what is known (e.g. a force target whose steady
    penetration, target / worst-case stiffness, exceeds the material's bound z̄). Raised
    before the motion that would need it; the message carries the numbers."""
