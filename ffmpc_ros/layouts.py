"""The layouts of every ``std_msgs/Float64MultiArray`` payload of the graph (the one code copy).

``mpc/command`` is no longer one of them: it is the typed ``ffmpc_msgs/msg/MpcCommand``
(``ffmpc_ros.command_msg``; its array layout ``ffmpc/mpc_command/1`` is retired).

``msgs_notes/`` documents the same layouts for humans; ``tests/test_ros_layouts.py`` checks that
the notes and this module agree field by field.

Convention (all layouts): the array is 1-D; ``layout.dim`` has exactly one entry whose ``label``
is the layout's name and version (e.g. ``"ffmpc/plant_truth/1"``), ``size`` and ``stride`` the
number of elements, ``data_offset`` 0. Receivers check the label, the total length and that
every element is finite. Sizes may depend on the robot's number of joints ``nv`` and on the
MPC's state dimension ``nx`` (2·nv classical, 3·nv torque-feedback, 2·nv + nc force-feedback);
``nv`` and ``nx`` are then carried in the array itself, so a receiver can check them.
Matrices are row-major.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from std_msgs.msg import Float64MultiArray, MultiArrayDimension

from ffmpc_core.errors import InputError

if TYPE_CHECKING:  # (the reflex model imports pinocchio: loaded where a status is built)
    from ffmpc_core.reflex import ReflexEvent, RobotReflex


@dataclass(frozen=True)
class Field:
    """One field of a layout: its name, its size (an int, or an expression of nv, nx and the
    number of horizon nodes ``nodes`` such as ``"nv*nx"``), its unit and its meaning."""

    name: str
    size: int | str
    unit: str
    meaning: str

    def length(self, nv: int = 0, nx: int = 0, nodes: int = 0) -> int:
        if isinstance(self.size, int):
            return self.size
        symbols = {"nv": nv, "nx": nx, "nodes": nodes}
        n = 1
        for factor in self.size.split("*"):  # a product of integers and symbols
            n *= symbols[factor] if factor in symbols else int(factor)
        return n


@dataclass(frozen=True)
class ArrayLayout:
    """A named, versioned sequence of fields packed into a Float64MultiArray."""

    name: str
    version: int
    fields: tuple[Field, ...]

    @property
    def label(self) -> str:
        return f"ffmpc/{self.name}/{self.version}"

    def length(self, nv: int = 0, nx: int = 0, nodes: int = 0) -> int:
        return sum(f.length(nv, nx, nodes) for f in self.fields)

    def slices(self, nv: int = 0, nx: int = 0, nodes: int = 0) -> dict[str, slice]:
        out, start = {}, 0
        for f in self.fields:
            n = f.length(nv, nx, nodes)
            out[f.name] = slice(start, start + n)
            start += n
        return out

    def pack(self, values: dict, nv: int = 0, nx: int = 0, nodes: int = 0) -> Float64MultiArray:
        """A message from {field: value} with every field (scalars or arrays, row-major)."""
        missing = {f.name for f in self.fields} - set(values)
        extra = set(values) - {f.name for f in self.fields}
        if missing or extra:
            raise InputError(f"{self.label}: missing {sorted(missing)}, unknown {sorted(extra)}")
        data = np.empty(self.length(nv, nx, nodes))
        for name, sl in self.slices(nv, nx, nodes).items():
            value = np.asarray(values[name], dtype=float).reshape(-1)
            if value.size != sl.stop - sl.start:
                raise InputError(f"{self.label}.{name}: {value.size} values, expected a slice")
            data[sl] = value
        msg = Float64MultiArray()
        msg.layout.dim = [MultiArrayDimension(label=self.label, size=data.size, stride=data.size)]
        msg.layout.data_offset = 0
        msg.data = data.tolist()
        return msg

    def unpack(self, msg: Float64MultiArray, nv: int = 0, nx: int | None = None) -> dict:
        """The fields of a message (scalars as float, others as arrays); InputError when the
        label, the length or a value is wrong. With ``nx=None`` nx is read from the ``nx``
        field (layouts that carry it; 0 for the others); ``nodes`` is always read from the
        ``nodes`` field of the layouts that carry one."""
        dims = msg.layout.dim
        if len(dims) != 1 or dims[0].label != self.label or msg.layout.data_offset != 0:
            got = [d.label for d in dims]
            raise InputError(f"expected a {self.label} array, got layout {got}")
        data = np.asarray(msg.data, dtype=float)
        names = [f.name for f in self.fields]
        if nx is None and "nx" not in names:
            nx = 0
        elif nx is None:
            index = names.index("nx")
            if data.size <= index or not math.isfinite(data[index]):
                raise InputError(f"{self.label}: no valid nx field")
            nx = int(data[index])
        nodes = 0
        if "nodes" in names:
            index = names.index("nodes")
            if data.size <= index or not math.isfinite(data[index]) or data[index] < 0:
                raise InputError(f"{self.label}: no valid nodes field")
            nodes = int(data[index])
        expected = self.length(nv, nx, nodes)
        if data.size != expected:
            raise InputError(f"{self.label}: {data.size} elements, expected {expected}")
        if dims[0].size != data.size:
            raise InputError(
                f"{self.label}: the layout says {dims[0].size} elements, the data has {data.size}"
            )
        if not np.all(np.isfinite(data)):
            raise InputError(f"{self.label}: non-finite element(s)")
        out = {}
        for f, (name, sl) in zip(self.fields, self.slices(nv, nx, nodes).items(), strict=True):
            out[name] = float(data[sl][0]) if f.size == 1 else data[sl].copy()
        return out


#: /plant/truth — ground truth of the simulator that no controller reads (metrics only).
PLANT_TRUTH = ArrayLayout(
    "plant_truth",
    1,
    (
        Field("t", 1, "s", "simulated time of the state"),
        Field("normal_force", 1, "N", "table force on the tool along the TRUE table normal"),
        Field("in_contact", 1, "-", "1 if a tool contact point carries a positive normal force"),
        Field("robot_collision", 1, "-", "1 if a robot link other than the tool touches anything"),
        Field("table_normal", 3, "-", "unit normal of the table top, world frame"),
        Field("contact_position", 3, "m", "origin of the contact frame, world frame (PyBullet)"),
    ),
)

#: /plant/status — progress and timing of the plant node.
PLANT_STATUS = ArrayLayout(
    "plant_status",
    2,
    (
        Field("t", 1, "s", "simulated time"),
        Field("steps", 1, "-", "plant steps done"),
        Field("done", 1, "-", "1 once the run's last step is done"),
        Field("lockstep", 1, "-", "1 lockstep, 0 real time"),
        Field(
            "deadline_misses",
            1,
            "-",
            "real time: steps that missed their deadline (composed loop: ffmpc_ros/realtime.py)",
        ),
        Field(
            "latency_count",
            1,
            "-",
            "latencies measured (sensor-to-torque; composed real-time loop: cycle latency)",
        ),
        Field("latency_mean", 1, "s", "mean wall time from publishing a state to its command"),
        Field("latency_p50", 1, "s", "median of that latency"),
        Field("latency_p99", 1, "s", "99th percentile of that latency"),
        Field("latency_max", 1, "s", "maximum of that latency"),
        Field("wall_time", 1, "s", "wall time since the first step"),
        Field(
            "reflex_enabled",
            1,
            "-",
            "1 when the robot's reflexes stop it (plant.reflex), 0 when they only record",
        ),
        Field(
            "reflex_stopped",
            1,
            "-",
            "1 once a reflex has stopped the robot: the run is aborted",
        ),
        Field(
            "reflex_kind",
            1,
            "-",
            "the first crossing's kind: index in ffmpc_core.reflex.REFLEX_KINDS, -1 none",
        ),
        Field(
            "reflex_joint",
            1,
            "-",
            "its joint, 0-based (-1: none, or communication)",
        ),
        Field(
            "reflex_value",
            1,
            "SI",
            "its measured value (rad, rad/s, rad/s², N·m, N·m/s; s without a command; 0 none)",
        ),
        Field(
            "reflex_limit",
            1,
            "SI",
            "the data-sheet limit it crossed, same unit (0 none)",
        ),
        Field(
            "reflex_ratio",
            1,
            "-",
            "value/limit (position: distance of q from mid-range / half range; 0 none)",
        ),
        Field(
            "reflex_t",
            1,
            "s",
            "simulated time of the crossing (0 none)",
        ),
    ),
)

#: /pid/status — the low-level loop's state each cycle.
LOWLEVEL_STATUS = ArrayLayout(
    "lowlevel_status",
    1,
    (
        Field("t", 1, "s", "simulated time of the cycle"),
        Field("mode", 1, "-", "0 hold, 1 blend, 2 track, 3 fallback (LowLevelMode)"),
        Field("command_age", 1, "s", "age of the newest MPC command (1e9 when there is none)"),
        Field("blend", 1, "-", "weight of the MPC torque in [0, 1]"),
        Field("rejected", 1, "-", "inputs rejected by the node so far"),
    ),
)

#: /contact_learner/estimate — the recursive least-squares estimate of eq 21 with its confidence
#: (ffmpc_core.impact.learner.ContactEstimate) and the sample it last took in.
CONTACT_ESTIMATE = ArrayLayout(
    "contact_estimate",
    1,
    (
        Field("t", 1, "s", "simulated time of the newest sample fed"),
        Field("stiffness", 1, "N/m", "α̂ along d (eq 21)"),
        Field("damping", 1, "N·s/m", "β̂ along d (eq 21)"),
        Field("stiffness_std", 1, "N/m", "standard error of α̂"),
        Field("damping_std", 1, "N·s/m", "standard error of β̂"),
        Field("noise_std", 1, "N", "σ̂, residual standard deviation of eq 3"),
        Field("samples", 1, "-", "K, samples fed since the last reset"),
        Field("condition", 1, "-", "condition number of (S Sᵀ + λI) (large: poorly excited)"),
        Field("deformation", 1, "m", "z of the newest sample, dᵀ(p − surface)"),
        Field("deformation_rate", 1, "m/s", "ż of the newest sample, dᵀṗ"),
        Field("force", 1, "N", "f of the newest sample, −dᵀλ̂ (pressing force)"),
        Field("direction", 3, "-", "unit motion direction d, world frame"),
        Field("surface", 3, "m", "surface point p_s (contact frame at the onset), world frame"),
    ),
)

#: /impact_planner/status — the impact controller's state each cycle (Sec. IV-C, Fig. 2).
#: The impact experiment's phase codes (``phase`` of impact_status, impact_reference and
#: impact_control): the paper's scheme (approach, contact), the force-feedback MPC alone, the
#: touch-first strategy's phases (ffmpc_core.impact.touch_first), none (baseline: −1).
IMPACT_PHASES: dict[str, float] = {
    "": -1.0,
    "approach": 0.0,
    "contact": 1.0,
    "ff_mpc": 2.0,
    "touch": 3.0,
    "touch_contact": 4.0,
    "retract": 5.0,
    "strike": 6.0,
    "refused": 7.0,
}
_PHASES = (
    "-1 none, 0 approach, 1 contact, 2 ff_mpc, 3 touch, 4 touch_contact, 5 retract, "
    "6 strike, 7 refused"
)


def impact_phase(code: float) -> str:
    """The phase name of a code of :data:`IMPACT_PHASES` (InputError for another)."""
    for name, value in IMPACT_PHASES.items():
        if value == code:
            return name
    raise InputError(f"unknown impact phase code {code}")


IMPACT_STATUS = ArrayLayout(
    "impact_status",
    3,
    (
        Field("t", 1, "s", "simulated time of the measurement the command is computed from"),
        Field("phase", 1, "-", "the planner's phase after the cycle: " + _PHASES),
        Field("safe_stop", 1, "-", "1: zero-velocity stop after bad, stale or missing input"),
        Field(
            "pre_impact_velocity",
            1,
            "m/s",
            "eq 14 bound of this cycle along d; 0 in contact, on a stop or without a bound",
        ),
        Field("velocity", 1, "m/s", "commanded contact-frame velocity along d"),
        Field("acceleration", 1, "m/s²", "feed-forward acceleration along d"),
        Field("force", 1, "N", "measured pressing force along d, −dᵀλ̂"),
        Field("target_force", 1, "N", "force regulated in contact"),
        Field("contact_time", 1, "s", "time the contact was detected (−1 before)"),
        Field("contact_velocity", 1, "m/s", "speed along d at the contact detection (0 before)"),
        Field("stiffness", 1, "N/m", "α of the material the planner uses"),
        Field("damping", 1, "N·s/m", "β of the material the planner uses"),
        Field("learned", 1, "-", "1 if that material is the learner's estimate, 0 the prior"),
        Field("solver_failures", 1, "-", "cycles without a certified eq 14 bound (rest commanded)"),
        Field("rejected", 1, "-", "inputs rejected by the node so far"),
        Field("direction", 3, "-", "unit motion direction d, world frame"),
        Field("position", 3, "m", "reference position of the contact frame, world frame"),
        Field("touch_time", 1, "s", "touch-first: time the exploratory touch began (−1 before)"),
        Field("touch_velocity", 1, "m/s", "touch-first: speed along d at the touch (0 before)"),
        Field(
            "decision_time",
            1,
            "s",
            "touch-first: the strike decided; strike-first: the target decided in contact (−1)",
        ),
        Field("admitted", 1, "-", "strike-first: 1 once the target is admitted in contact"),
    ),
)

#: /impact_planner/reference — the whole Cartesian command of the impact planner each cycle
#: (what the task-space controller node tracks; the twist of /impact_planner/command is its
#: velocity part).
IMPACT_REFERENCE = ArrayLayout(
    "impact_reference",
    3,
    (
        Field("t", 1, "s", "simulated time of the measurement the command is computed from"),
        Field("safe_stop", 1, "-", "1: zero-velocity stop after bad, stale or missing input"),
        Field("phase", 1, "-", "the planner's phase after the cycle: " + _PHASES),
        Field("bound_valid", 1, "-", "1 when pre_impact_velocity is this cycle's eq 14 bound"),
        Field("pre_impact_velocity", 1, "m/s", "eq 14 bound of this cycle along d (0 if none)"),
        Field("position", 3, "m", "reference position of the contact frame, world frame"),
        Field("velocity", 3, "m/s", "reference velocity of the contact frame, world frame"),
        Field("acceleration", 3, "m/s²", "feed-forward acceleration, world frame"),
        Field("rotation", 9, "-", "held orientation of the contact frame, 3×3 row-major"),
        Field("force", 1, "N", "measured pressing force along d, −dᵀλ̂"),
        Field("target_force", 1, "N", "force regulated in contact"),
        Field("strike", 1, "-", "1 unless touch-first before its strike (the touch is no contact)"),
        Field(
            "impact_force",
            1,
            "N",
            "touch-/strike-first: the guard's impact force along d (0 otherwise)",
        ),
        Field(
            "handover_allowed",
            1,
            "-",
            "touch-/strike-first: 1 when the MPC may take over (strike-first: target admitted)",
        ),
        Field(
            "learner_samples", 1, "-", "touch-/strike-first: samples its feeding rule fed so far"
        ),
        Field("gate_phase", 1, "-", "touch-/strike-first: the learning gate's phase (as phase)"),
        Field("gate_learn", 1, "-", "touch-/strike-first: 1 when the planner learns online"),
        Field("gate_surface_valid", 1, "-", "1 when gate_surface is set"),
        Field("gate_surface", 3, "m", "the learning gate's surface point, world frame (or 0)"),
        Field(
            "stopped_short_time",
            1,
            "s",
            "the regulation stopped at its depth bound below the target then (−1: not)",
        ),
        Field("stopped_short_force", 1, "N", "the force measured then (0: not stopped)"),
    ),
)

#: /impact_controller/status — the impact experiment's controller each cycle (Sec. VI).
IMPACT_CONTROL = ArrayLayout(
    "impact_control",
    3,
    (
        Field("t", 1, "s", "simulated time of the measurement the torque is computed from"),
        Field("safe_hold", 1, "-", "1: the torque holds the pose after a rejected reference"),
        Field("in_contact", 1, "-", "1 once the contact is declared (force ≥ contact_threshold)"),
        Field("phase", 1, "-", _PHASES),
        Field("pre_impact_velocity", 1, "m/s", "the maximal approach's eq 14 bound (0 if none)"),
        Field("contact_time", 1, "s", "time the contact was declared (−1 before)"),
        Field("touch_speed", 1, "m/s", "speed along d at the last force-free sample before it"),
        Field("handover_time", 1, "s", "time the force-feedback MPC took over (−1 before)"),
        Field("mpc_weight", 1, "-", "share of the MPC's torque in the blend, [0, 1]"),
        Field("mpc_stiffness", 1, "N/m", "the MPC's contact stiffness (0 before the hand-over)"),
        Field("mpc_damping", 1, "N·s/m", "the MPC's contact damping (0 before the hand-over)"),
        Field("mpc_learned", 1, "-", "1 when that contact model is the learner's estimate"),
        Field("mpc_force", 1, "N", "the MPC's predicted contact force at its next node (0 before)"),
        Field("learner_samples", 1, "-", "samples fed to the contact learner so far"),
        Field(
            "stopped_short_time",
            1,
            "s",
            "the regulation stopped at its depth bound below the target then (−1: not)",
        ),
        Field("stopped_short_force", 1, "N", "the force measured then (0: not stopped)"),
        Field("rejected", 1, "-", "inputs rejected by the node so far"),
        Field("nv", 1, "-", "number of joints (7)"),
        Field("torque", "nv", "N·m", "the joint torque sent (impact_controller/torque)"),
    ),
)

#: /mpc/prediction — the horizon of the MPC's last solve, for display (published only while
#: something subscribes; ModelPredictiveController.prediction).
MPC_PREDICTION = ArrayLayout(
    "mpc_prediction",
    1,
    (
        Field("t", 1, "s", "simulated time of the measurement the solve started from"),
        Field("nodes", 1, "-", "N + 1, the OCP's nodes (the horizon's states x_0..x_N)"),
        Field("dt", 1, "s", "Δt between two nodes; node k predicts t + command_delay + k·Δt"),
        Field("normal_axis", 1, "-", "world axis (0 x, 1 y, 2 z) of the normal forces below"),
        Field("normal_force", "nodes", "N", "predicted contact force along normal_axis, per node"),
        Field("reference_force", "nodes", "N", "reference λ̄ along normal_axis, per node"),
        Field(
            "positions",
            "nodes*3",
            "m",
            "predicted contact-frame origin per node, world frame, nodes×3 row-major",
        ),
    ),
)

LAYOUTS: dict[str, ArrayLayout] = {
    layout.name: layout
    for layout in (
        PLANT_TRUTH,
        PLANT_STATUS,
        LOWLEVEL_STATUS,
        CONTACT_ESTIMATE,
        IMPACT_STATUS,
        IMPACT_REFERENCE,
        IMPACT_CONTROL,
        MPC_PREDICTION,
    )
}


def reflex_status(reflex: RobotReflex) -> dict[str, float]:
    """The ``reflex_*`` fields of ``plant_status`` (layout ``plant_status``): enabled, stopped,
    the event's kind (index in :data:`~ffmpc_core.reflex.REFLEX_KINDS`, −1 none), joint
    (0-based, −1 none or communication), value, limit, ratio and time (0 without an event)."""
    from ffmpc_core.reflex import REFLEX_KINDS

    event = reflex.event
    if event is None:
        kind, joint, value, limit, ratio, t = -1, -1, 0.0, 0.0, 0.0, 0.0
    else:
        kind = REFLEX_KINDS.index(event.kind)
        joint = -1 if event.joint is None else event.joint
        value, limit, ratio, t = event.value, event.limit, event.ratio, event.t
    return {
        "reflex_enabled": float(reflex.config.enabled),
        "reflex_stopped": float(reflex.stopped),
        "reflex_kind": float(kind),
        "reflex_joint": float(joint),
        "reflex_value": value,
        "reflex_limit": limit,
        "reflex_ratio": ratio,
        "reflex_t": t,
    }


def reflex_event_from_status(
    status: dict[str, float], joint_names: tuple[str, ...] | list[str]
) -> ReflexEvent | None:
    """The reflex event a ``plant_status`` carries (:func:`reflex_status`), None without one."""
    from ffmpc_core.reflex import REFLEX_KINDS, ReflexEvent

    kind = int(round(status["reflex_kind"]))
    if kind < 0:
        return None
    joint = int(round(status["reflex_joint"]))
    return ReflexEvent(
        kind=REFLEX_KINDS[kind],
        joint=None if joint < 0 else joint,
        joint_name=None if joint < 0 else joint_names[joint],
        value=float(status["reflex_value"]),
        limit=float(status["reflex_limit"]),
        ratio=float(status["reflex_ratio"]),
        t=float(status["reflex_t"]),
        stopped=bool(status["reflex_stopped"]),
    )
