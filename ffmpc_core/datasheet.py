"""The robots' data-sheet limits, in one place, with their sources (``RobotModel`` reads them).

One :class:`DataSheet` per supported robot: joint positions q, velocities q̇, accelerations q̈,
jerks q⃛, torques τ and torque rates τ̇ where the manufacturer states them, the time without a
command after which the robot's controller stops the motion, and which limits that controller
stops the robot on in torque control (:mod:`ffmpc_core.reflex` does what it does).

**KUKA LBR iiwa 14 R820** (:data:`IIWA14_R820`, robot ``"iiwa"``: the paper's hardware robot,
"Kuka iiwa LBR 1480" in Kleff et al. VII-A). KUKA's LBR iiwa brochure, axis data table of the
LBR iiwa 14 R820 (as quoted in drake's ``manipulation/models/iiwa_description/README.md``,
RobotLocomotion/drake): range of motion ±170, ±120, ±170, ±120, ±170, ±120, ±175°; maximum
speed 85, 85, 100, 75, 130, 135, 135 °/s; maximum torque 320, 320, 176, 176, 110, 40, 40 N·m.
No joint acceleration, jerk or torque-rate limit is published. The simulated URDF is
``pybullet_data``'s ``kuka_iiwa/model.urdf``: its joint ranges are the ones above, but its link
masses (4, 4, 3, 2.7, 1.7, 1.8, 0.3 kg: 17.5 kg) are lighter than the iiwa 14's (≈ 6.4, 7.9,
2.5, 4.8, 1.8, 2.5, 0.4 kg in the explicit-robotics iiwa 14 model), so its gravity torques use
less of the 14's torque limits than the real arm would.

**Franka Emika Panda** (:data:`PANDA`, robot ``"panda"``: the impact paper's robot).
Franka's "Robot and interface specifications" (frankaemika.github.io/docs/control_parameters.html,
"Limits for Panda", the page the impact paper cites for its hardware limits) and libfranka's
``include/franka/rate_limiting.h`` (kMaxJointAcceleration, kMaxJointJerk, kMaxTorqueRate):
q ∈ [−2.8973, 2.8973], [−1.7628, 1.7628], [−2.8973, 2.8973], [−3.0718, −0.0698],
[−2.8973, 2.8973], [−0.0175, 3.7525], [−2.8973, 2.8973] rad; q̇ 2.1750 (joints 1–4), 2.6100
(5–7) rad/s; q̈ 15, 7.5, 10, 12.5, 15, 20, 20 rad/s²; q⃛ 7500, 3750, 5000, 6250, 7500, 10000,
10000 rad/s³; τ 87 (1–4), 12 (5–7) N·m; τ̇ 1000 N·m/s. example-robot-data's URDF carries the
same q, q̇ and τ (checked in ``tests/test_reflex.py``).

**What the robot checks in torque control** (:attr:`DataSheet.stops`). Franka's specification
lists, for the torque interface, ONE necessary condition (violated: the motion is aborted):
|τ̇_d| < τ̇_max of the commanded torque; |τ_d| < τ_max is only a *recommended* condition (the
robot processes the command, the drives saturate); the q̈ and q⃛ conditions are the motion
generators' (on the commanded q_c), not checked on the measured state in torque control. The
robot's own safety stops on the measured joint positions and velocities in every mode
(libfranka errors ``joint_position_limits_violation``: "the robot moved past the joint limits",
``joint_velocity_violation``: "the robot exceeded joint velocity limits"). The τ̇ condition is
never reached through the Panda's own client library with its defaults: libfranka up to 0.9.2
(the last release for the Panda; 0.10.0 requires the FR3) rate-limits the commanded torque to
kMaxTorqueRate by default (``limit_rate = true``; its CHANGELOG, 0.10.0: "Disable rate-limiter by
default") and low-pass filters it at 100 Hz (``kDefaultCutoffFrequency``). Our controllers talk
to the simulated robot without libfranka, so τ̇ is **reported** (largest ratio, first crossing),
not a stop: stopping on it aborts every impact run at t = 2 ms (the impact controllers' torque
steps reach 21× τ̇_max, measured), while modelling libfranka's limiter instead breaks the
impact guard's q̈ guarantee (30–137 steps over q̈_max per run, measured with the rate limiter
alone) — a τ̇ constraint in the impact controllers is the fix, not a choice of this table.
So the Panda stops on q and q̇. The iiwa (Sunrise safety configuration: axis range and axis
velocity monitoring) stops on q and q̇; its drives saturate τ at the maximum torque.

**Commands missing.** Franka: the robot expects a command every 1 ms; "if the robot fails to
receive a command packet in time for 20 steps in a row" it aborts with
``communication_constraints_violation`` (facebookresearch/fairo Polymetis troubleshooting
page; libfranka's own error list names the error without the count): 20 ms. iiwa FRI: the
Sunrise controller grades the connection (``EConnectionQuality`` of KUKA's FRI Client SDK,
``friClientIf.h``: FAIR is "connection quality insufficient for command mode") and leaves
COMMANDING_ACTIVE when it drops; the time it takes is not published in what we found, so the
Panda's 20 ms is used for the iiwa too (an assumption, stated here).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from ffmpc_core.errors import ConfigError

__all__ = [
    "DATASHEETS",
    "IIWA14_R820",
    "LIMIT_KINDS",
    "PANDA",
    "DataSheet",
    "datasheet",
]

#: The limit kinds of a data sheet, in table order (units: rad, rad/s, rad/s², rad/s³, N·m,
#: N·m/s).
LIMIT_KINDS = ("position", "velocity", "acceleration", "jerk", "torque", "torque_rate")
#: The kinds a robot's controller may stop on (``DataSheet.stops``); jerk is never measured.
STOP_KINDS = ("position", "velocity", "acceleration", "torque", "torque_rate")


def _vector(value: object, name: str, n: int = 7) -> np.ndarray:
    arr = np.array(value, dtype=float)
    if arr.shape != (n,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"data sheet {name}: expected {n} finite numbers, got {value!r}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class DataSheet:
    """One robot's joint limits as its manufacturer states them (one entry per joint).

    Attributes:
        model: the robot's commercial name.
        position_lower, position_upper: q̲, q̄ (rad).
        velocity: |q̇| limit (rad/s).
        torque: |τ| limit (N·m).
        acceleration: |q̈| limit (rad/s²), None when not published.
        jerk: |q⃛| limit (rad/s³), None when not published.
        torque_rate: |τ̇| limit (N·m/s), None when not published.
        command_timeout: s without a command after which the robot stops (module docstring).
        stops: the kinds (of :data:`STOP_KINDS`) the robot's controller stops on in torque
            control; the others are reported, not acted on (torque: the drives saturate).
        sources: per kind (and ``command_timeout``), where the value comes from.
    """

    model: str
    position_lower: np.ndarray
    position_upper: np.ndarray
    velocity: np.ndarray
    torque: np.ndarray
    command_timeout: float
    stops: frozenset[str]
    sources: Mapping[str, str] = field(repr=False)
    acceleration: np.ndarray | None = None
    jerk: np.ndarray | None = None
    torque_rate: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in LIMIT_KINDS[1:] + ("position_lower", "position_upper"):
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, _vector(value, name))
        for name in ("velocity", "acceleration", "jerk", "torque", "torque_rate"):
            value = getattr(self, name)
            if value is not None and np.any(value <= 0.0):
                raise ConfigError(f"data sheet {name}: limits must be > 0, got {value}")
        if np.any(self.position_lower >= self.position_upper):
            raise ConfigError("data sheet: position_lower must be below position_upper")
        if not (np.isfinite(self.command_timeout) and self.command_timeout > 0.0):
            raise ConfigError(
                f"data sheet command_timeout must be > 0 s, got {self.command_timeout}"
            )
        unknown = set(self.stops) - set(STOP_KINDS)
        if unknown:
            raise ConfigError(f"data sheet stops: unknown kinds {sorted(unknown)}")
        for kind in self.stops:
            if kind != "position" and getattr(self, kind) is None:
                raise ConfigError(f"data sheet stops on {kind} but states no {kind} limit")
        object.__setattr__(self, "stops", frozenset(self.stops))
        object.__setattr__(self, "sources", MappingProxyType(dict(self.sources)))

    def limit(self, kind: str) -> np.ndarray | None:
        """The per-joint limit of ``kind`` (a :data:`LIMIT_KINDS` entry but ``position``: use
        the bounds), None when not published."""
        if kind not in LIMIT_KINDS or kind == "position":
            raise ConfigError(f"no single limit vector for {kind!r}; kinds: {LIMIT_KINDS[1:]}")
        value: np.ndarray | None = getattr(self, kind)
        return value

    def table(self) -> list[tuple[str, str, str, str]]:
        """Rows (kind, per-joint values, stops in torque control, source) for reports."""
        rows = []
        lo, hi = np.rad2deg(self.position_lower), np.rad2deg(self.position_upper)
        rows.append(
            (
                "position (deg)",
                ", ".join(f"[{a:.1f}, {b:.1f}]" for a, b in zip(lo, hi, strict=True)),
                "stop" if "position" in self.stops else "-",
                self.sources["position"],
            )
        )
        units = {
            "velocity": ("deg/s", np.rad2deg),
            "acceleration": ("rad/s²", None),
            "jerk": ("rad/s³", None),
            "torque": ("N·m", None),
            "torque_rate": ("N·m/s", None),
        }
        for kind, (unit, convert) in units.items():
            value = getattr(self, kind)
            if value is None:
                continue
            shown = convert(value) if convert is not None else value
            action = "stop" if kind in self.stops else ("saturate" if kind == "torque" else "-")
            rows.append(
                (
                    f"{kind} ({unit})",
                    ", ".join(f"{x:g}" for x in shown),
                    action,
                    self.sources[kind],
                )
            )
        rows.append(
            (
                "commands missing (s)",
                f"{self.command_timeout:g}",
                "stop",
                self.sources["command_timeout"],
            )
        )
        return rows


_KUKA = (
    "KUKA LBR iiwa brochure, axis data of the LBR iiwa 14 R820 (quoted in RobotLocomotion/"
    "drake manipulation/models/iiwa_description/README.md)"
)
_FRANKA = (
    "Franka 'Robot and interface specifications', Limits for Panda "
    "(frankaemika.github.io/docs/control_parameters.html)"
)
_LIBFRANKA = "libfranka include/franka/rate_limiting.h"

#: KUKA LBR iiwa 14 R820 (module docstring).
IIWA14_R820 = DataSheet(
    model="KUKA LBR iiwa 14 R820",
    position_lower=-np.deg2rad([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0]),
    position_upper=np.deg2rad([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 175.0]),
    velocity=np.deg2rad([85.0, 85.0, 100.0, 75.0, 130.0, 135.0, 135.0]),
    torque=np.array([320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0]),
    command_timeout=0.02,
    stops=frozenset({"position", "velocity"}),
    sources={
        "position": _KUKA,
        "velocity": _KUKA,
        "torque": _KUKA + "; the drives saturate at it",
        "command_timeout": (
            "assumed as the Panda's: the FRI's threshold time is not published (KUKA FRI "
            "Client SDK friClientIf.h: connection quality FAIR is insufficient for command mode)"
        ),
    },
)

#: Franka Emika Panda (module docstring).
PANDA = DataSheet(
    model="Franka Emika Panda",
    position_lower=np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]),
    position_upper=np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]),
    velocity=np.array([2.1750, 2.1750, 2.1750, 2.1750, 2.6100, 2.6100, 2.6100]),
    acceleration=np.array([15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0]),
    jerk=np.array([7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0]),
    torque=np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0]),
    torque_rate=np.full(7, 1000.0),
    command_timeout=0.02,
    stops=frozenset({"position", "velocity"}),
    sources={
        "position": _FRANKA,
        "velocity": _FRANKA,
        "acceleration": _FRANKA + "; " + _LIBFRANKA + " (motion generators only)",
        "jerk": _FRANKA + "; " + _LIBFRANKA + " (motion generators only)",
        "torque": _FRANKA + " (recommended condition: saturated)",
        "torque_rate": _FRANKA
        + "; "
        + _LIBFRANKA
        + " (torque control: necessary condition; libfranka <= 0.9 rate-limits to it by default)",
        "command_timeout": (
            "communication_constraints_violation after 20 missed 1 ms packets "
            "(facebookresearch/fairo Polymetis troubleshooting)"
        ),
    },
)

#: Data sheet per robot name of :func:`ffmpc_core.robots.load_robot`.
DATASHEETS: Mapping[str, DataSheet] = MappingProxyType({"iiwa": IIWA14_R820, "panda": PANDA})


def datasheet(robot: str) -> DataSheet:
    """The data sheet of robot ``robot`` (``"iiwa"`` or ``"panda"``); ConfigError otherwise."""
    try:
        return DATASHEETS[robot]
    except KeyError:
        raise ConfigError(
            f"no data sheet for robot {robot!r}; robots: {sorted(DATASHEETS)}"
        ) from None
