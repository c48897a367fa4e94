"""What a run learned about an object, kept for the next run on the same object: the
strike-first strategy's knowledge before contact (Dehio & Kheddar 2020, eq 21's estimate and
its confidence, as the interval of
:meth:`~ffmpc_core.impact.robust.MaterialInterval.from_estimate`).

An object memory is a plain mapping ``{object name: RememberedMaterial.to_dict()}`` (JSON on
disk, written and read by the study, :mod:`studies.impact_study`); nothing here does I/O. The
object's name is the only link between the runs: a memory recalled for the wrong object gives
the strike a wrong interval (the strike-first strategy then trusts it as it trusts the prior's
plausible range).

Units: N/m (stiffness), N·s/m (damping), m (z̄).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ffmpc_core.errors import ConfigError
from ffmpc_core.impact.learner import ContactEstimate
from ffmpc_core.impact.robust import MaterialInterval

__all__ = ["RememberedMaterial", "recall", "remember"]


@dataclass(frozen=True)
class RememberedMaterial:
    """The interval a run learned on an object.

    Attributes:
        stiffness: ``(α̲, ᾱ)``, N/m. damping: ``(β̲, β̄)``, N·s/m.
        estimate: ``(α̂, β̂)`` at the end of the run (N/m, N·s/m). samples: K of that estimate.
    """

    stiffness: tuple[float, float]
    damping: tuple[float, float]
    estimate: tuple[float, float]
    samples: int

    def __post_init__(self) -> None:
        for name in ("stiffness", "damping", "estimate"):
            value = getattr(self, name)
            if len(value) != 2 or not all(np.isfinite(float(x)) for x in value):
                raise ConfigError(f"RememberedMaterial.{name} must be two finite numbers")
        (a0, a1), (b0, b1) = self.stiffness, self.damping
        if not (0.0 < a0 <= a1 and 0.0 <= b0 <= b1):
            raise ConfigError(
                f"RememberedMaterial: needs 0 < α̲ ≤ ᾱ and 0 ≤ β̲ ≤ β̄, got {self.stiffness}, "
                f"{self.damping}"
            )
        if int(self.samples) != self.samples or self.samples < 0:
            raise ConfigError("RememberedMaterial.samples must be a whole number ≥ 0")

    @classmethod
    def from_estimate(
        cls,
        estimate: ContactEstimate,
        sigmas: float = 3.0,
        stiffness_floor: float = 0.1,
        damping_floor: float = 0.25,
    ) -> RememberedMaterial:
        """The learner's confidence interval of ``estimate`` (the widths of
        :meth:`MaterialInterval.from_estimate`); InputError for an unusable estimate."""
        box = MaterialInterval.from_estimate(estimate, 1.0, sigmas, stiffness_floor, damping_floor)
        return cls(
            stiffness=(box.stiffness_lower, box.stiffness_upper),
            damping=(box.damping_lower, box.damping_upper),
            estimate=(float(estimate.stiffness), float(estimate.damping)),
            samples=int(estimate.samples),
        )

    def describe(self) -> str:
        """One line with the units."""
        (a0, a1), (b0, b1) = self.stiffness, self.damping
        return (
            f"stiffness [{a0:.0f}, {a1:.0f}] N/m, damping [{b0:.1f}, {b1:.1f}] N·s/m "
            f"(estimate {self.estimate[0]:.0f} N/m, {self.estimate[1]:.2f} N·s/m from "
            f"{self.samples} samples)"
        )

    def overrides(self) -> dict[str, list[float]]:
        """The impact study's ``--set`` values that hand it to the strike-first strategy."""
        return {
            "strike.remembered_stiffness": [float(x) for x in self.stiffness],
            "strike.remembered_damping": [float(x) for x in self.damping],
        }

    def to_dict(self) -> dict[str, Any]:
        """JSON types."""
        return {
            "stiffness": [float(x) for x in self.stiffness],
            "damping": [float(x) for x in self.damping],
            "estimate": [float(x) for x in self.estimate],
            "samples": int(self.samples),
        }

    @classmethod
    def from_dict(cls, value: Mapping[str, Any]) -> RememberedMaterial:
        """From :meth:`to_dict`'s form; ConfigError for anything else."""
        try:
            return cls(
                stiffness=(float(value["stiffness"][0]), float(value["stiffness"][1])),
                damping=(float(value["damping"][0]), float(value["damping"][1])),
                estimate=(float(value["estimate"][0]), float(value["estimate"][1])),
                samples=int(value["samples"]),
            )
        except (KeyError, IndexError, TypeError, ValueError) as exc:
            raise ConfigError(f"not a remembered material: {value!r} ({exc})") from None


def recall(memory: Mapping[str, Any], name: str) -> RememberedMaterial | None:
    """The material remembered for object ``name`` (None: never seen)."""
    entry = memory.get(name)
    return None if entry is None else RememberedMaterial.from_dict(entry)


def remember(memory: Mapping[str, Any], name: str, material: RememberedMaterial) -> dict[str, Any]:
    """A new memory with ``name``'s entry replaced by ``material`` (the others kept)."""
    if not name:
        raise ConfigError("an object needs a name to be remembered")
    return {**memory, name: material.to_dict()}
