"""Scenario files: one YAML per experiment, in the ROS 2 parameter-file format.

A scenario file has one section per node (``plant``, ``joint_sensor``, ``ft_sensor``, ``mpc``,
``pid``) plus the wildcard section ``/**`` shared by all nodes (robot, seed, task). The same file
is given to the ROS nodes (``--params-file``) and read here by the ROS-free runner, so both run
the same experiment. Nested maps are flattened to dotted names exactly as ROS does
(``task: {normal_force: 50}`` → parameter ``task.normal_force``).

:func:`load_scenario` returns a :class:`Scenario` of typed, validated, frozen dataclasses; unknown
keys are an error (an option that silently does nothing is a bug). Overrides use dotted names:
``load_scenario(path, {"mpc.formulation": "classical", "pid.enabled": False})``.

Values are read by ROS 2's rules (:mod:`ffmpc_core.values`: ``stiffness: 1e4`` is 10000.0 here
as in a node given the file), so the runner and the nodes never read a file differently.

Complete or based. An empty file (no parameter) is refused: it is not the default scenario. A
file either sets every node's section (``/**`` and each node's; a name a section leaves out
takes the schema's default, the dataclass field's, in the runner and in the nodes alike) or names
the scenario it changes in its ``/**`` section, ``base: polishing`` (a shipped name, or an
absolute path): its values are then merged over that scenario's, by the runner and by a
node given the file (``ros2 run ... --params-file``: the node loads the base the same way). A
file with neither is a partial scenario and is refused with the sections it lacks.
"""

from __future__ import annotations

import os
from dataclasses import Field, dataclass, field, fields, is_dataclass, replace
from pathlib import Path
from types import UnionType
from typing import Any, Generic, TypeVar, Union, get_args, get_origin, get_type_hints

import numpy as np
import yaml

from ffmpc_core.actuation import ActuationConfig
from ffmpc_core.config import (
    BACKENDS,
    FORMULATIONS,
    TORQUE_STATES,
    ContactConfig,
    CostWeights,
    OcpConfig,
)
from ffmpc_core.constraints import ConstraintConfig
from ffmpc_core.declaration import FieldDecl, declaration, param
from ffmpc_core.errors import ConfigError
from ffmpc_core.pid import PidConfig
from ffmpc_core.sensing import JointSensorConfig
from ffmpc_core.tasks import PhaseWeights

SECTIONS = ("plant", "joint_sensor", "ft_sensor", "mpc", "pid")
#: Simulators of the plant (``plant.engine``): the PyBullet plant (:class:`sim_bridge.plant.Plant`)
#: or the MuJoCo plant (:class:`sim_bridge.mujoco_plant.MujocoPlant`), same model and contact.
PLANT_ENGINES = ("pybullet", "mujoco")
#: ``ft_sensor.model`` and ``ft_sensor.calibration`` settings.
FT_MODELS = ("contact", "wrist")
FT_CALIBRATIONS = ("startup", "file", "none")
#: ``mpc.command_delay`` settings besides a number of seconds.
COMMAND_DELAY_PID = "pid"
COMMAND_DELAY_MEASURED = "measured"
WILDCARD = "/**"
#: Key prefix of a node section that applies in any namespace (``/**/plant``).
ANY_NAMESPACE = "/**/"

#: Where the scenario files shipped with ffmpc live.
SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"
#: Shipped scenario files of the studies configured by their own dataclass tree
#: (:class:`ConfigSchema`: ``ffmpc study impact``, ``ffmpc study explore``); the others are
#: node-graph scenarios (:func:`load_scenario`).
STUDY_SCENARIOS = ("impact", "explore")


def flatten(tree: dict, prefix: str = "") -> dict[str, Any]:
    """Nested maps to dotted names, as ROS 2 parameter files do."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        else:
            out[name] = value
    return out


#: Overrides that give the paper's task schedule (Fig. 2 of the force-feedback paper): the reach
#: ends on the believed table, the OCP switches to contact there and the force ramps from 0 N
#: (no touch phase), and the circle's angular velocity is stepped (no ramp). The polishing
#: scenarios' defaults add the touch phase and the circle ramp (``ffmpc_core.tasks``).
PAPER_SCHEDULE: dict[str, float] = {
    "task.approach_clearance": 0.0,
    "task.touch": 0.0,
    "task.touch_force": 0.0,
    "task.approach_speed": 0.0,
    "task.circle_ramp": 0.0,
}


@dataclass(frozen=True)
class TaskSection:
    """The task of the run (shared by every node). Durations in s, forces in N."""

    # "polishing" | "force_square"
    name: str = param("polishing", "", ["polishing", "force_square"], "task")
    normal_force: float = param(50.0, "N", (0.0, 500.0), "polishing normal force reference")
    circle_radius: float = param(0.07, "m", (0.0, 0.5), "circle radius")
    angular_velocity: float = param(3.0, "rad/s", (0.0, 50.0), "angular velocity along the circle")
    circles: float = param(2.0, "", (0.0, 100.0), "number of turns")
    # s, minimum-jerk ramp of the angular velocity at the circle's start and end (0: the
    # paper's step; ffmpc_core.tasks.PolishingTask.circle_angle). 0.2 s by default: with the
    # step, the tangential velocity jumps at the circle's start and the elbow (joint 3) runs
    # over its speed limit on some seeds (measured: issue 23 report)
    circle_ramp: float = param(
        0.2,
        "s",
        (0.0, 10.0),
        "minimum-jerk ramp of the angular velocity at the circle's start and end (0: a step)",
    )
    # m above the believed table at the circle start
    start_height: float = param(0.05, "m", (0.0, 0.5), "start height above the believed table")
    still: float = param(0.1, "s", (0.0, 60.0), "phase duration: stand still")
    reach: float = param(0.4, "s", (0.0, 60.0), "phase duration: reach the table")
    #: the touch phase (ffmpc_core.tasks): the reach ends approach_clearance (m) above the
    #: believed table, then the nodes are in contact with the force reference touch_force (N)
    #: for touch (s) before the force ramp; 0, 0, 0: the paper's schedule. The defaults: 1 cm
    #: clears the table's height at the circle start under the study's ±6° tilt (7.3 mm at
    #: 7 cm), 1 N keeps the force-feedback MPC's descent slow (its 15 ms horizon asks for the
    #: speed that makes the reference force within it: ~0.07 m/s at 1 N, ~0.3 m/s at 5 N, which
    #: bounces the tool off the 10 kN/m table), 0.3 s lets the tool settle in contact
    approach_clearance: float = param(
        0.01, "m", (0.0, 0.5), "the reach ends this far above the table"
    )
    touch: float = param(0.3, "s", (0.0, 60.0), "phase duration: touch the table under touch_force")
    touch_force: float = param(1.0, "N", (0.0, 500.0), "force reference of the touch phase")
    #: The guarded approach (ffmpc_core.tasks.GuardedTask): after the reach the reference
    #: descends at approach_speed (m/s) in free space, at most approach_depth (m) below the
    #: believed table, until the MPC's measured normal force exceeds contact_force (N); the
    #: touch, force ramp and circle then start from that time. approach_speed 0: the
    #: time-based switch (the contact phases at fixed times). The defaults: 0.03 m/s meets the
    #: 10 kN/m, 100 N·s/m table with a 3 N damping step (the time-based touch met it at
    #: ~0.2 m/s: 25 N in 2 ms) and costs at most (clearance + depth) / speed = 0.67 s;
    #: 1 cm below the belief clears the table's height at the circle start under the study's
    #: ±6° tilt (7.3 mm); 2 N is 200 σ_λ above the sensor's noise and above the 1 N touch force
    approach_speed: float = param(
        0.03,
        "m/s",
        (0.0, 1.0),
        "guarded approach: descent speed until the contact is measured (0: time-based switch)",
    )
    approach_depth: float = param(
        0.01, "m", (0.0, 0.5), "guarded approach: the descent stops this far below the table"
    )
    contact_force: float = param(
        2.0, "N", (1e-3, 500.0), "guarded approach: measured normal force detecting the contact"
    )
    force_ramp: float = param(0.5, "s", (0.0, 60.0), "phase duration: ramp the force")
    stop: float = param(0.3, "s", (0.0, 60.0), "phase duration after the circle")
    low_force: float = param(20.0, "N", (0.0, 500.0), "force_square low level")  # force_square
    high_force: float = param(50.0, "N", (0.0, 500.0), "force_square high level")
    square_period: float = param(2.0, "s", (0.0, 60.0), "force_square period")
    square_cycles: int = param(2, "", (0, 1000), "force_square number of periods")
    #: z entry of the in-contact activation Q4 of the position cost (polishing): 0 gives the
    #: paper's Q4 = diag(1, 1, 0) (eq 25.4, the normal direction belongs to the force task).
    ee_z_weight_in_contact: float = param(
        0.0,
        "",
        (0.0, 1e6),
        "z entry of the in-contact Q4 of the position cost (0: the paper's diag(1, 1, 0))",
    )


@dataclass(frozen=True)
class PlantSection:
    """The simulated plant: engine, step, table, actuation model (eq 31), pushes, tool and
    reflexes."""

    # PLANT_ENGINES
    engine: str = param(
        "pybullet", "", list(PLANT_ENGINES), "simulator of the plant: pybullet | mujoco"
    )
    time_step: float = param(
        1e-3, "s", (1e-5, 0.01), "physics step = control cycle; stamps are multiples"
    )
    table_tilt_deg: float = param(
        0.0, "deg", (-45.0, 45.0), "table tilt θ when random_tilt_deg is 0"
    )
    table_tilt_axis: tuple[float, float, float] = param(
        (0.0, 1.0, 0.0), "", (-1.0, 1.0), "horizontal tilt axis, world frame"
    )
    # θ ~ U(−this, +this) per seed when > 0
    random_tilt_deg: float = param(0.0, "deg", (0.0, 45.0), "θ ~ U(−this, +this) per seed when > 0")
    table_stiffness: float = param(1e4, "N/m", (1.0, 1e9), "table contact stiffness")
    table_damping: float = param(1e2, "N·s/m", (0.0, 1e6), "table contact damping")
    table_friction: float = param(0.5, "", (0.0, 10.0), "table Coulomb friction coefficient")
    #: eq 31 (ffmpc_core.actuation.ActuationConfig); its parameters are named
    #: plant.actuation_random_bias, plant.actuation_delay_cycles, plant.actuation_noise_fraction,
    #: plant.static_friction, plant.viscous_friction, plant.friction_velocity (SECTION_NAMES)
    actuation: ActuationConfig = field(default_factory=ActuationConfig)
    push_enabled: bool = param(False, "", None, "apply an external push on the tool")
    push_time: float = param(0.0, "s", (0.0, 3600.0), "push start")
    push_force: tuple[float, float, float] = param(
        (0.0, 0.0, 0.0), "N", (-1e4, 1e4), "push force, world frame"
    )
    push_duration: float = param(0.0, "s", (0.0, 60.0), "push duration")
    #: A hand's push builds up and lets go over tens of ms, not within one 1 ms physics step:
    #: the force rises from 0 to ``push_force`` along a raised cosine over this time and falls
    #: back the same way before the push ends (0: a step on and off; ``push_envelope``).
    push_rise_time: float = param(
        0.0, "s", (0.0, 30.0), "raised-cosine rise and fall of the push force (0: a step)"
    )
    #: The tool on the flange (behind the wrist F/T sensor): the plant simulates it and the
    #: controllers' robot model carries it (the cell's load data); kg, and m in the flange frame.
    tool_mass: float = param(
        0.0,
        "kg",
        (0.0, 20.0),
        "mass of the tool on the flange (simulated; the controllers' load data)",
    )
    tool_center_of_mass: tuple[float, float, float] = param(
        (0.0, 0.0, 0.0), "m", (-0.5, 0.5), "the tool's centre of mass, flange frame"
    )
    #: The robot's own reflexes (ffmpc_core.reflex): stop on a data-sheet limit or missing
    #: commands and abort the run; off: the crossings are reported, nothing is stopped.
    reflex: bool = param(
        True,
        "",
        None,
        "the robot's own reflexes: stop on a data-sheet limit or missing commands, run aborted "
        "(false: crossings reported only)",
    )


@dataclass(frozen=True)
class ForceSensorSection:
    """The force measurement model (eq 32) and the F/T sensor node's filter, contact detection
    and tare."""

    delay_cycles: int = param(1, "cycles", (0, 1000), "sensing delay δs (eq 32)")
    force_noise_std: float = param(0.01, "N", (0.0, 100.0), "σ_λ (eq 32)")  # N, the authors' σ_λ
    # Outputs of the F/T sensor node beside the eq-32 measurement (the runner does not use them):
    # Hz, first-order low-pass of the filtered wrench
    filter_cutoff_frequency: float = param(
        20.0, "Hz", (0.0, 1e4), "filtered wrench cut-off (0: none)"
    )
    # N, filtered normal force that starts a contact
    contact_on_force: float = param(
        5.0, "N", (0.0, 1e4), "filtered normal force starting a contact"
    )
    # N, filtered normal force that ends it (hysteresis)
    contact_off_force: float = param(2.0, "N", (0.0, 1e4), "filtered normal force ending it")
    # measurements averaged by the tare service
    tare_samples: int = param(50, "", (1, 100000), "measurements averaged by the tare service")
    #: "contact": the paper's sensor (eq 32: the contact force + noise on the MPC's axes);
    #: "wrist": a 6-axis sensor on the flange that also reads the tool's weight and its bias,
    #: calibrated and compensated (ffmpc_core.wrist_ft, ffmpc_core.ft_calibration). The keys
    #: below apply to the wrist sensor only (a changed one with "contact" is refused).
    model: str = param(
        "contact",
        "",
        list(FT_MODELS),
        "contact: the paper's sensor (eq 32); wrist: 6 axes on the flange, tool weight and bias",
    )
    # N, N·m, sensor frame
    bias: tuple[float, float, float, float, float, float] = param(
        (0.0,) * 6, "N, N·m", (-100.0, 100.0), "wrist sensor bias (fx fy fz mx my mz), its frame"
    )
    # N·m, σ_m of the wrist sensor's moments
    moment_noise_std: float = param(0.0005, "N·m", (0.0, 10.0), "wrist sensor: σ of the moments")
    #: "startup": calibrate at the start of the run; "file": load calibration_file; "none": no
    #: compensation (the raw reading, bias and tool weight included, reaches the MPC)
    calibration: str = param(
        "startup",
        "",
        list(FT_CALIBRATIONS),
        "wrist sensor: calibrate at startup, load calibration_file, or none (no compensation)",
    )
    calibration_file: str = param(
        "", "", None, "wrist sensor: calibration file (calibration: file)"
    )
    # readings averaged per calibration pose
    calibration_samples: int = param(100, "", (1, 100000), "wrist sensor: readings per pose")
    # s: an older calibration file is refused (8 h)
    calibration_max_age: float = param(
        28800.0, "s", (0.0, 1e9), "wrist sensor: oldest calibration taken"
    )
    #: the sensor also reads the tool's inertial wrench (from the plant's motion), and the
    #: compensation removes it with the measured q̂, q̇̂; false: the tool is weighed as at rest
    inertial_wrench: bool = param(
        False,
        "",
        None,
        "wrist sensor: also read the tool's inertial wrench, compensated with q̂ and q̇̂",
    )


#: The task's phase weights a ``mpc.weights.<formulation>`` block may set beside the
#: CostWeights fields (:meth:`MpcSection.phase_weights`), and what each is.
PHASE_WEIGHT_NAMES: dict[str, str] = {
    "force_phase": "c6 of the contact phases (ffmpc_core.tasks)",
    "ee_position_phase": "c4 of the contact phases (and of free space without ee_position_free)",
    "ee_position_free": "c4 in free space: the stand-still, the reach, the guarded descent",
}


@dataclass(frozen=True)
class MpcSection:
    """The MPC: its problem and solver (``ocp``), δo, contact model, constraints and the cost
    weights of every formulation; :func:`ffmpc_core.polishing.mpc_config` makes the
    :class:`~ffmpc_core.mpc.MpcConfig` of the chosen formulation from it."""

    #: the problem and its solver (ffmpc_core.config.OcpConfig, which MpcConfig holds); its
    #: parameters are mpc.formulation, mpc.horizon, mpc.dt, mpc.period, mpc.max_iterations,
    #: mpc.kkt_tolerance, mpc.cutoff_frequency (SECTION_NAMES)
    ocp: OcpConfig = field(default_factory=OcpConfig)
    riccati_feedback: bool = param(False, "", None, "low level applies τ* + G·Δx between solves")
    # send the plan for t + δo (δo = pid.delay_cycles)
    delay_compensation: bool = param(
        True, "", None, "plan for t + δo (δo = pid.delay_cycles cycles)"
    )
    #: δo, the delay between a measurement and the moment its command acts (eq 33's delay line
    #: and the MPC's prediction): "pid" = pid.delay_cycles plant steps (the default), a number of
    #: seconds (a whole number of plant steps; it sets pid.delay_cycles), or "measured" = the
    #: median MPC step time of a short calibration run of this MPC on this machine, rounded up
    #: to the plant step (:func:`ffmpc_core.polishing.resolve_command_delay`; the studies do it).
    command_delay: str = param(
        COMMAND_DELAY_PID, "s", None, "δo: pid (pid.delay_cycles), seconds, or measured"
    )
    #: τ of the torque-feedback state: "measured" τ̂ (eq 10/15) | "commanded" (the last τ̃ sent)
    torque_state: str = param(
        "measured",
        "",
        list(TORQUE_STATES),
        "τ of the torque-feedback state: measured τ̂ (eq 10/15) or the last commanded τ̃",
    )
    #: T of the joint-position observer (ffmpc_core.joint_observer): the solve starts from the
    #: measured q with its noise filtered by the measured q̇; 0: the measured q as it is
    position_observer_time: float = param(
        0.0,
        "s",
        (0.0, 10.0),
        "joint-position observer time constant T (q̂ from q and ∫q̇; 0: the measured q)",
    )
    # action models: native (C++) | python (reference), MpcConfig.backend
    backend: str = param(
        "native", "", list(BACKENDS), "action models: native (C++, default) | python (reference)"
    )
    #: o, m, world frame: the MPC tracks p̄(t) + o (ffmpc_core.tasks.LiveTask); the plant's table
    #: stays where the task puts it. Live on the MPC node (parameter ``position_offset``).
    position_offset: tuple[float, float, float] = param(
        (0.0, 0.0, 0.0),
        "m",
        (-0.1, 0.1),
        "offset o added to the task's position reference (the MPC tracks p̄(t) + o), world frame",
    )
    contact: ContactConfig = field(default_factory=ContactConfig)
    #: the hard constraints and their solver (ffmpc_core.constraints.ConstraintConfig)
    constraints: ConstraintConfig = field(default_factory=ConstraintConfig)
    #: per formulation: CostWeights fields plus the task's phase weights: ``force_phase`` (c6),
    #: ``ee_position_phase`` (c4 in contact, and in free space unless ``ee_position_free`` is
    #: given) and ``ee_position_free`` (c4 while the tool is in the air: the stand-still, the
    #: reach and the guarded descent)
    weights: dict[str, dict[str, Any]] = field(default_factory=dict)

    def cost_weights(self, formulation: str | None = None) -> CostWeights:
        """The :class:`~ffmpc_core.config.CostWeights` of ``formulation`` (default: the
        section's)."""
        values = dict(self.weights.get(formulation or self.ocp.formulation, {}))
        for phase in PHASE_WEIGHT_NAMES:
            values.pop(phase, None)
        try:
            return CostWeights(**values)
        except TypeError as exc:
            raise ConfigError(f"mpc weights: {exc}") from None

    def phase_weight(self, name: str, default: float, formulation: str | None = None) -> float:
        """A task phase weight (``force_phase`` c6, ``ee_position_phase`` c4) of
        ``formulation``, or ``default``."""
        return float(self.weights.get(formulation or self.ocp.formulation, {}).get(name, default))

    def phase_weights(self, formulation: str | None = None) -> PhaseWeights:
        """The task's :class:`~ffmpc_core.tasks.PhaseWeights` of ``formulation``: c4 in free
        space is ``ee_position_free`` when given, else ``ee_position_phase`` (1/m²); c4 in
        contact ``ee_position_phase``; c6 ``force_phase`` (1/N²); the task's defaults for
        what is left out."""
        default = PhaseWeights.contact_ee_position
        contact = self.phase_weight("ee_position_phase", default, formulation)
        return PhaseWeights(
            free_ee_position=self.phase_weight("ee_position_free", contact, formulation),
            contact_ee_position=contact,
            force=self.phase_weight("force_phase", PhaseWeights.force, formulation),
        )


@dataclass(frozen=True)
class Scenario:
    """A whole experiment: what every node runs with."""

    name: str
    robot: str = param("iiwa", "", ["iiwa", "panda"], "robot model")
    seed: int = param(
        0, "", (0, 2**31 - 1), "seed of every random draw of the run (numpy Generator spawn)"
    )
    task: TaskSection = field(default_factory=TaskSection)
    plant: PlantSection = field(default_factory=PlantSection)
    #: the joint sensor of eq 30 (ffmpc_core.sensing.JointSensorConfig)
    joint_sensor: JointSensorConfig = field(default_factory=JointSensorConfig)
    ft_sensor: ForceSensorSection = field(default_factory=ForceSensorSection)
    mpc: MpcSection = field(default_factory=MpcSection)
    #: the torque PID and the low-level loop (ffmpc_core.pid.PidConfig)
    pid: PidConfig = field(default_factory=PidConfig)
    #: The scenario file it was read from (an absolute path; "" for one built in code): the
    #: node graph gives this file to its nodes as it is (``ffmpc_ros.graph_nodes``). Not a
    #: parameter, and not compared: the values are the scenario.
    source: str = field(default="", compare=False)

    def with_overrides(self, overrides: dict[str, Any]) -> Scenario:
        """A copy with dotted-name overrides applied (``"mpc.formulation"``, ``"seed"``)."""
        flat = with_overrides_flat(SCENARIO_SCHEMA.flatten(self), overrides)
        return scenario_from_flat(self.name, flat, self.source)


def with_overrides_flat(flat: dict[str, Any], overrides: dict[str, Any]) -> dict[str, Any]:
    """``flat`` (dotted names) with ``overrides`` put over it: an unknown name is a
    ConfigError; ``pid.delay_cycles`` without ``mpc.command_delay`` makes δo that number of
    cycles (``mpc.command_delay: pid``)."""
    out = dict(flat)
    for key, value in overrides.items():
        if not isinstance(key, str) or key not in SCHEMA:
            raise unknown_parameter(str(key), value)
        out[key] = value
    if "pid.delay_cycles" in overrides and "mpc.command_delay" not in overrides:
        out["mpc.command_delay"] = COMMAND_DELAY_PID  # the explicit δo in cycles wins
    return out


# -- the schema: one declaration of every scenario parameter's type, unit and range ----------
#: Joints of every supported robot (ffmpc_core.robots.load_robot refuses any other arm).
N_JOINTS = 7
#: Kinds of parameter: the Python type of the dataclass default, plus the list kinds.
BOOL, INT, FLOAT, STR = "bool", "int", "float", "str"
FLOATS = "floats"  # a list of exactly ``length`` numbers
FLOAT_OR_FLOATS = "float_or_floats"  # a number, or one per entry (``length`` entries)
DELAY = "command_delay"  # "pid" | "measured" | seconds
#: ``length`` of the per-contact-axis lists: mpc.contact.dimension.
CONTACT_DIMENSION = "mpc.contact.dimension"


@dataclass(frozen=True)
class ParamSpec:
    """One scenario parameter: dotted name, kind, unit, range (closed; each entry of a list)
    and meaning. :data:`SCHEMA` holds one per parameter; the runner (:func:`load_scenario`,
    :meth:`Scenario.with_overrides`) and the ROS parameter descriptors are built from it."""

    name: str
    kind: str
    description: str
    unit: str = ""
    range: tuple[float, float] | None = None
    choices: tuple[Any, ...] = ()
    length: int | str | None = None  # list length, or CONTACT_DIMENSION; None: any length
    optional: bool = False  # null (None) is also accepted

    def expected(self, length: int | None = None) -> str:
        """What a value must be, in words (the end of every error message)."""
        text = self._expected(length)
        return f"{text} or null" if self.optional else text

    def _expected(self, length: int | None = None) -> str:
        unit = f" {self.unit}" if self.unit else ""
        span = ""
        if self.range is not None:
            lo, hi = self.range
            span = f" in [{_num(lo)}, {_num(hi)}]" if np.isfinite(hi) else f" >= {_num(lo)}"
        if self.choices:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        n = length if length is not None else self.length
        n_text = f"{n}" if isinstance(n, int) else CONTACT_DIMENSION if n else ""
        if self.length == CONTACT_DIMENSION and isinstance(n, int):
            n_text = f"{n} ({CONTACT_DIMENSION})"
        if self.kind == BOOL:
            return "true or false"
        if self.kind == INT:
            return f"an integer{span}{unit}"
        if self.kind == FLOAT:
            return f"a number{span}{unit}"
        if self.kind == STR:
            return "a string"
        if self.kind == FLOATS:
            return f"a list of {n_text} numbers{span}{unit}".replace("of  ", "of ")
        if self.kind == FLOAT_OR_FLOATS:
            return f"a number{span}{unit} or a list of {n_text or 'any number'} of them"
        return "'pid', 'measured' or a number of seconds >= 0"  # DELAY

    def error(self, value: Any, length: int | None = None) -> ConfigError:
        """The ConfigError for a bad ``value`` (``name = value: expected …``)."""
        return config_error(self.name, value, self.expected(length))

    def check(self, value: Any, length: int | None = None) -> Any:
        """``value`` in its canonical type (float, int, bool, str, tuple of floats), or
        ConfigError. ``length`` resolves a list length given by another parameter."""
        if self.optional and value is None:
            return None
        if self.kind == BOOL:
            if not isinstance(value, bool | np.bool_):
                raise self.error(value)
            return bool(value)
        if self.kind == INT:
            if not _is_int(value):
                raise self.error(value)
            out: Any = int(value)
        elif self.kind == FLOAT:
            out = self._number(value)
        elif self.kind == STR:
            if not isinstance(value, str):
                raise self.error(value)
            out = value.strip()
        elif self.kind in (FLOATS, FLOAT_OR_FLOATS):
            n = length if length is not None else self.length
            if self.kind == FLOAT_OR_FLOATS and not isinstance(value, list | tuple):
                out = self._number(value, length)
            else:
                if not isinstance(value, list | tuple) or len(value) == 0:
                    raise self.error(value, length)
                if isinstance(n, int) and len(value) != n:
                    raise self.error(value, length)
                out = tuple(self._number(v, length, whole=value) for v in value)
            return out
        else:  # DELAY
            return _command_delay_setting(value, self)
        if self.choices and out not in self.choices:
            raise self.error(value)
        if self.range is not None and not self.range[0] <= out <= self.range[1]:
            raise self.error(value)
        return out

    def _number(self, value: Any, length: int | None = None, whole: Any = None) -> float:
        bad = self.error(value if whole is None else whole, length)
        if isinstance(value, bool | np.bool_) or not isinstance(value, int | float | np.number):
            raise bad
        out = float(value)
        if not np.isfinite(out):
            raise bad
        if self.range is not None and not self.range[0] <= out <= self.range[1]:
            raise bad
        return out


def _num(x: float) -> str:
    return str(x) if isinstance(x, int) else f"{x:g}"


def _is_int(value: Any) -> bool:
    return isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_)


def config_error(name: str, value: Any, expected: str) -> ConfigError:
    """The one format of a bad parameter: ``name = value: expected …`` (one line)."""
    shown = repr(value)
    if len(shown) > 80:
        shown = shown[:77] + "..."
    return ConfigError(f"{name} = {shown}: expected {expected}")


def unknown_parameter(
    name: str, value: Any, schema: dict[str, ParamSpec] | None = None
) -> ConfigError:
    """A name that is not in ``schema`` (default :data:`SCHEMA`) (``name = value: unknown
    scenario parameter; did you mean …?``)."""
    import difflib

    known = SCHEMA if schema is None else schema
    close = difflib.get_close_matches(name, list(known), n=3, cutoff=0.6)
    hint = f"; did you mean {', '.join(close)}?" if close else ""
    shown = repr(value) if len(repr(value)) <= 80 else repr(value)[:77] + "..."
    return ConfigError(f"{name} = {shown}: unknown scenario parameter{hint}")


INF = float("inf")
_NONNEG = (0.0, INF)
#: List lengths of the CostWeights activation diagonals (a number broadcasts).
_DIAG_LENGTH: dict[str, int | str] = {
    "posture": N_JOINTS,
    "joint_velocity": N_JOINTS,
    "torque": N_JOINTS,
    "ee_position": 3,
    "ee_velocity": 3,
    "force": CONTACT_DIMENSION,
}
_WEIGHT_UNITS = {
    "posture": "1/rad²",
    "joint_velocity": "s²/rad²",
    "torque": "1/(N·m)²",
    "ee_position": "1/m²",
    "ee_velocity": "s²/m²",
    "force": "1/N²",
    "lowpass_input": "1/(N·m)²",
    "force_rate": "s²/N²",
    "state_limit": "1/rad², s²/rad²",  # on the position excess, on the velocity excess
    "ee_rotation": "1/rad²",
    "ee_angular_velocity": "s²/rad²",
    "lowpass_terminal_torque": "1/(N·m)²",
}
#: The CostWeights fields that are neither a weight c nor an activation diagonal: the fraction
#: of the joint limits inside which the joint-limit barrier is zero (dimensionless, (0, 1]).
_WEIGHT_FRACTIONS = {
    "state_limit_fraction": "fraction of the joint limits where the state_limit barrier starts",
}


# -- one schema builder for any tree of frozen dataclasses (every scenario and study) ---------
def _leaf_fields(root: type, exclude: tuple[str, ...] = ()) -> dict[str, tuple[Any, Field[Any]]]:
    """``{field path: (type annotation, field)}`` of every non-dataclass field of the
    dataclass tree ``root`` (nested dataclass fields are walked, ``"dice.stiffness"``);
    ``exclude``: paths left out, with everything under them."""
    out: dict[str, tuple[Any, Field[Any]]] = {}

    def walk(cls: type, prefix: str) -> None:
        hints = get_type_hints(cls)
        for f in fields(cls):
            path = prefix + f.name
            if path in exclude:
                continue
            hint = hints[f.name]
            if isinstance(hint, type) and is_dataclass(hint):
                walk(hint, path + ".")
            else:
                out[path] = (hint, f)

    walk(root, "")
    return out


def dataclass_leaves(root: type, exclude: tuple[str, ...] = ()) -> dict[str, Any]:
    """``{field path: type annotation}`` of every non-dataclass field of the dataclass tree
    ``root`` (nested dataclass fields are walked, ``"dice.stiffness"``); ``exclude``: paths
    left out, with everything under them."""
    return {path: hint for path, (hint, _) in _leaf_fields(root, exclude).items()}


def _leaf_kind(hint: Any, path: str) -> tuple[str, int | None, bool]:
    """(kind, list length or None for any, None allowed) of a field annotation."""
    args = get_args(hint)
    if get_origin(hint) in (Union, UnionType):
        rest = tuple(a for a in args if a is not type(None))
        optional = len(rest) < len(args)
        if len(rest) == 1:
            kind, length, _ = _leaf_kind(rest[0], path)
            return kind, length, optional
        if float in rest and any(get_origin(a) is tuple for a in rest):
            return FLOAT_OR_FLOATS, None, optional
    elif hint is bool:
        return BOOL, None, False
    elif hint is int:
        return INT, None, False
    elif hint is float:
        return FLOAT, None, False
    elif hint is str:
        return STR, None, False
    elif get_origin(hint) is tuple and all(a in (float, Ellipsis) for a in args):
        return FLOATS, (None if Ellipsis in args else len(args)), False
    raise AssertionError(f"schema: no parameter kind for {path}: {hint}")


def _spec_from_decl(
    name: str,
    kind: str,
    length: int | str | None,
    decl: FieldDecl,
    optional: bool = False,
) -> ParamSpec:
    unit, limits, description = decl
    choices = tuple(limits) if isinstance(limits, list) else ()
    span = limits if isinstance(limits, tuple) else None
    return ParamSpec(name, kind, description, unit, span, choices, length, optional)


def field_declaration(cls: type, name: str) -> FieldDecl:
    """The declaration (:func:`~ffmpc_core.declaration.param`) of field ``name`` of the
    dataclass ``cls`` (AssertionError if it has none)."""
    decl = declaration(next(f for f in fields(cls) if f.name == name))
    if decl is None:
        raise AssertionError(f"schema: {cls.__name__}.{name} is not declared (param)")
    return decl


def public_name(path: str, names: dict[str, str]) -> str:
    """The dotted parameter name of a field path: the longest prefix of ``path`` in ``names``
    replaced by its value (``{"dice.": "plant.dice_"}``: ``dice.stiffness`` →
    ``plant.dice_stiffness``); without one, the path itself."""
    best = max((k for k in names if path.startswith(k)), key=len, default="")
    return names[best] + path[len(best) :] if best else path


def dataclass_schema(
    root: type,
    names: dict[str, str] | None = None,
    exclude: tuple[str, ...] = (),
    given: dict[str, ParamSpec] | None = None,
) -> dict[str, ParamSpec]:
    """``{dotted name: ParamSpec}`` of the dataclass tree ``root``: one entry per leaf field
    (:func:`dataclass_leaves`), named by :func:`public_name`, its kind from the annotation
    and its unit, range or choices and description from the field's declaration
    (:func:`ffmpc_core.declaration.param`). ``given``: ready specs that replace a leaf's or
    add names (dict-valued fields). Every leaf that ``given`` does not replace must be
    declared (AssertionError otherwise)."""
    given = given or {}
    schema: dict[str, ParamSpec] = {}
    for path, (hint, f) in _leaf_fields(root, exclude).items():
        name = public_name(path, names or {})
        if name in schema:
            raise AssertionError(f"schema: two fields named {name}")
        if name in given:
            schema[name] = given[name]
            continue
        decl = declaration(f)
        if decl is None:
            raise AssertionError(
                f"schema: {name} ({root.__name__}.{path}) is not declared (param in its field)"
            )
        kind, length, optional = _leaf_kind(hint, path)
        schema[name] = _spec_from_decl(name, kind, length, decl, optional)
    schema.update({k: v for k, v in given.items() if k not in schema})
    return schema


def cost_weight_specs(prefix: str, force_length: int | str) -> dict[str, ParamSpec]:
    """The :class:`CostWeights` fields under ``prefix`` (``"mpc.weights.classical."``): weights
    c (units of :data:`_WEIGHT_UNITS`), activation diagonals (a number or one per entry; the
    force diagonal has ``force_length`` entries) and the fractions of :data:`_WEIGHT_FRACTIONS`
    (a number in [0.001, 1])."""
    out: dict[str, ParamSpec] = {}
    for f in fields(CostWeights):
        base = f.name.removesuffix("_diag")
        name = prefix + f.name
        if f.name in _WEIGHT_FRACTIONS:
            out[name] = ParamSpec(name, FLOAT, _WEIGHT_FRACTIONS[f.name], "", (1e-3, 1.0))
        elif f.name.endswith("_diag"):
            length = force_length if base == "force" else _DIAG_LENGTH[base]
            out[name] = ParamSpec(
                name,
                FLOAT_OR_FLOATS,
                f"activation diagonal Q of {base} (eq 25)",
                "",
                _NONNEG,
                length=length,
            )
        else:
            out[name] = ParamSpec(
                name, FLOAT, f"cost weight c of {base}", _WEIGHT_UNITS[base], _NONNEG
            )
    return out


def _scenario_given_specs() -> dict[str, ParamSpec]:
    """The scenario's specs that its dataclass annotations cannot give: ``mpc.command_delay``
    (seconds or a word), K and B (one per contact axis, ``mpc.contact.dimension``) and the
    per-formulation weights of ``mpc.weights`` (a dict field: :class:`CostWeights`' fields
    plus the phase weights c6, c4)."""
    given: dict[str, ParamSpec] = {
        "mpc.command_delay": _spec_from_decl(
            "mpc.command_delay", DELAY, None, field_declaration(MpcSection, "command_delay")
        ),
    }
    for entry in ("stiffness", "damping"):
        decl = field_declaration(ContactConfig, entry)
        name = f"mpc.contact.{entry}"
        given[name] = _spec_from_decl(name, FLOAT_OR_FLOATS, CONTACT_DIMENSION, decl)
    for form in FORMULATIONS:
        prefix = f"mpc.weights.{form}."
        given.update(cost_weight_specs(prefix, CONTACT_DIMENSION))
        for phase, what in PHASE_WEIGHT_NAMES.items():
            given[prefix + phase] = ParamSpec(prefix + phase, FLOAT, what, "", _NONNEG)
    return given


def validate_flat(
    flat: dict[str, Any], schema: dict[str, ParamSpec] | None = None
) -> dict[str, Any]:
    """Every dotted-name value checked against ``schema`` (default :data:`SCHEMA`), in its
    canonical type (ConfigError, ``name = value: expected …``, for the first bad or unknown
    one)."""
    known = SCHEMA if schema is None else schema
    out: dict[str, Any] = {}
    for key, value in flat.items():
        if key not in known:
            raise unknown_parameter(key, value, known)
        if known[key].length != CONTACT_DIMENSION:
            out[key] = known[key].check(value)
    dimension = out.get(CONTACT_DIMENSION, ContactConfig.dimension)
    for key, value in flat.items():
        if known[key].length == CONTACT_DIMENSION:
            out[key] = known[key].check(value, dimension)
    return out


def scenario_from_flat(name: str, flat: dict[str, Any], source: str = "") -> Scenario:
    """The :class:`Scenario` ``name`` of dotted-name values (the schema's defaults for the
    others), checked by :data:`SCENARIO_SCHEMA`, with the cross-section rules applied (the
    wrist-only keys, a fixed δo setting the PID's delay line); ``source``: its file, if any."""
    scenario = SCENARIO_SCHEMA.build(flat, Scenario(name=name, source=source))
    check_force_sensor(scenario.ft_sensor)
    check_push(scenario.plant)
    fixed = command_delay_seconds(scenario.mpc.command_delay)
    if fixed is not None:  # a fixed δo sets the PID's delay line
        cycles = delay_in_plant_steps(fixed, scenario.plant.time_step)
        scenario = replace(scenario, pid=replace(scenario.pid, delay_cycles=cycles))
    return scenario


#: The ``ft_sensor`` keys of the wrist sensor only.
WRIST_ONLY = (
    "bias",
    "moment_noise_std",
    "calibration",
    "calibration_file",
    "calibration_samples",
    "calibration_max_age",
    "inertial_wrench",
)


def check_force_sensor(section: ForceSensorSection) -> None:
    """ConfigError for wrist-sensor keys changed with ``model: contact`` (they would do
    nothing) and for ``calibration: file`` without a ``calibration_file``."""
    default = ForceSensorSection()
    if section.model == "contact":
        changed = [k for k in WRIST_ONLY if getattr(section, k) != getattr(default, k)]
        if changed:
            names = ", ".join(f"ft_sensor.{k}" for k in changed)
            raise ConfigError(f"{names}: only with ft_sensor.model: wrist (the model is contact)")
    if section.calibration == "file" and not section.calibration_file:
        raise ConfigError("ft_sensor.calibration: file needs ft_sensor.calibration_file")


def check_push(section: PlantSection) -> None:
    """ConfigError for a push whose rise and fall (``plant.push_rise_time`` each) do not fit in
    its ``plant.push_duration``."""
    if 2.0 * section.push_rise_time > section.push_duration + 1e-12 and section.push_enabled:
        raise config_error(
            "plant.push_rise_time",
            section.push_rise_time,
            f"at most half of plant.push_duration ({section.push_duration:g} s): the force "
            "rises and falls within the push",
        )


def _command_delay_setting(value: Any, spec: ParamSpec) -> str:
    """``mpc.command_delay`` as its canonical text: "pid", "measured" or seconds (``repr``)."""
    if isinstance(value, str) and value.strip() in (COMMAND_DELAY_PID, COMMAND_DELAY_MEASURED):
        return value.strip()
    if isinstance(value, str):
        try:  # a ROS string parameter holding seconds ("0.005")
            value = float(value)
        except ValueError:
            raise spec.error(value) from None
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | float | np.number):
        raise spec.error(value)
    seconds = float(value)
    if not (np.isfinite(seconds) and seconds >= 0.0):
        raise spec.error(value)
    return repr(seconds)


def command_delay_seconds(setting: str) -> float | None:
    """δo in s of a fixed ``mpc.command_delay`` setting; None for "pid" and "measured"."""
    if setting in (COMMAND_DELAY_PID, COMMAND_DELAY_MEASURED):
        return None
    return float(setting)


def delay_in_plant_steps(delay: float, time_step: float) -> int:
    """A delay (s) as a whole number of plant steps (ConfigError if it is not one)."""
    cycles = delay / time_step
    if abs(cycles - round(cycles)) > 1e-6:
        raise config_error(
            "mpc.command_delay", delay, f"a whole number of plant steps ({time_step:g} s)"
        )
    return int(round(cycles))


def scenario_parameters(s: Scenario) -> dict[str, dict[str, Any]]:
    """The scenario as ROS parameters: ``{section: {dotted_name: value}}`` (``/**`` included)."""
    flat = SCENARIO_SCHEMA.flatten(s)
    out: dict[str, dict[str, Any]] = {WILDCARD: {}}
    for key, value in flat.items():
        head, _, rest = key.partition(".")
        if head in SECTIONS:
            out.setdefault(head, {})[rest] = value
        else:
            out[WILDCARD][key] = value
    return out


def resolve_scenario_path(name_or_path: str | os.PathLike) -> Path:
    """A scenario file path: an existing path, or the name of a shipped scenario."""
    path = Path(name_or_path)
    if path.is_file():
        return path
    shipped = SCENARIO_DIR / f"{name_or_path}.yaml"
    if shipped.is_file():
        return shipped
    available = sorted(p.stem for p in SCENARIO_DIR.glob("*.yaml"))
    raise ConfigError(f"no scenario {str(name_or_path)!r}; shipped scenarios: {available}")


#: The key of a scenario file's ``/**`` section that names the scenario it changes (a shipped
#: name or a path, relative to the file): the file's values are merged over that scenario's.
BASE_KEY = "base"


def read_parameter_file(
    name_or_path: str | os.PathLike,
    sections: tuple[str, ...],
    complete: bool = True,
    _chain: tuple[Path, ...] = (),
) -> tuple[Path, dict[str, Any]]:
    """A parameter file (ROS 2 parameter-file format: ``section: {ros__parameters: {...}}``)
    as ``(path, {dotted name: raw value})``: a section's names get its name as prefix, the
    wildcard section ``/**``'s do not. A section is keyed ``/**/plant`` (the shipped files: rcl
    gives it to a node named ``plant`` in any namespace) or ``plant`` (= ``/plant``: a node at
    the root only), not both. Values are read by ROS 2's rules (:func:`ffmpc_core.values.load_yaml`:
    ``1e4`` is a number, as to the nodes).

    Empty and partial files (module docstring of :mod:`ffmpc_core.scenario`, "Complete or
    based"): a file with no parameter is refused; a file whose ``/**`` names a ``base`` is
    merged over that scenario; otherwise, when ``complete``, every section (``/**`` and each of
    ``sections``) must be there. ConfigError for a file that is not one."""
    path = resolve_scenario_path(name_or_path)
    if path.resolve() in _chain:
        raise ConfigError(f"{path}: base scenarios form a cycle ({' -> '.join(map(str, _chain))})")
    flat, seen = _read_sections(path, sections)
    if not flat:
        raise ConfigError(
            f"{path}: an empty scenario (no parameter); a scenario file sets every section, "
            f"or names the scenario it changes ({BASE_KEY}: NAME under /**, NAME a shipped "
            "scenario or an absolute path)"
        )
    base = flat.pop(BASE_KEY, None)
    if base is not None:
        base_path = base_scenario_path(base)
        try:
            _, base_flat = read_parameter_file(
                base_path, sections, complete, (*_chain, path.resolve())
            )
        except ConfigError as exc:
            raise ConfigError(f"{path}: {BASE_KEY} {base!r}: {exc}") from None
        return path, base_flat | flat
    missing = [s for s in (WILDCARD, *sections) if s not in seen]
    if complete and missing:
        raise ConfigError(
            f"{path}: a partial scenario (no section {', '.join(missing)}); a scenario file "
            f"sets every section, or names the scenario it changes ({BASE_KEY}: NAME under /**, "
            "NAME a shipped scenario or an absolute path: the file is merged over it)"
        )
    return path, flat


def base_scenario_path(base: Any) -> Path:
    """The file a ``base`` names: a shipped scenario's name or an absolute path (resolved the
    same way by the runner and by a node, which does not know where its file was)."""
    expected = "a shipped scenario name or an absolute path to a scenario file"
    if not isinstance(base, str) or not base.strip():
        raise config_error(BASE_KEY, base, expected)
    text = base.strip()
    shipped = SCENARIO_DIR / f"{text}.yaml"
    if Path(text).is_absolute():
        return Path(text)
    if "/" not in text and shipped.is_file():
        return shipped
    raise config_error(BASE_KEY, base, expected)


def read_sections(path: str | os.PathLike) -> dict[str, dict[str, Any]]:
    """``{section key as written (``/**``, ``/**/mpc``, ``mpc``): {dotted name: raw value}}``
    of a parameter file: each section's names as rcl gives them to a node the section reaches
    (nested maps flattened, values read by ROS 2's rules). ConfigError for a file that is not
    a parameter file."""
    from ffmpc_core.values import load_yaml

    try:
        with open(path, encoding="utf-8") as fh:
            doc = load_yaml(fh)
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the scenario ({exc})") from None
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" at line {where.line + 1}" if where is not None else ""
        raise ConfigError(f"{path}: not a YAML file{line}") from None
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    if doc is None:
        doc = {}
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: expected a mapping of node sections")
    out: dict[str, dict[str, Any]] = {}
    for key, body in doc.items():
        if not isinstance(body, dict) or set(body) != {"ros__parameters"}:
            raise ConfigError(f"{path}: section {key!r} must hold only 'ros__parameters'")
        if not isinstance(body["ros__parameters"] or {}, dict):
            raise ConfigError(f"{path}: {key}.ros__parameters must be a mapping")
        out[str(key)] = flatten(body["ros__parameters"] or {})
    return out


def _read_sections(path: Path, sections: tuple[str, ...]) -> tuple[dict[str, Any], dict[str, str]]:
    """``({dotted name: raw value}, {section: key as written})`` of a parameter file."""
    flat: dict[str, Any] = {}
    seen: dict[str, str] = {}
    for key, params in read_sections(path).items():
        section = key.removeprefix(ANY_NAMESPACE)
        if section in seen:
            raise ConfigError(f"{path}: sections {seen[section]!r} and {key!r} are the same node")
        seen[section] = key
        if section == WILDCARD:
            flat.update(params)
        elif section in sections:
            flat.update({f"{section}.{k}": v for k, v in params.items()})
        else:
            raise ConfigError(f"{path}: unknown node section {key!r}; expected {sections}")
    return flat, seen


def load_scenario(name_or_path: str | os.PathLike, overrides: dict | None = None) -> Scenario:
    """Read a scenario file (ROS 2 parameter-file format) into a validated :class:`Scenario`."""
    path = resolve_scenario_path(name_or_path)
    if path.parent == SCENARIO_DIR and path.stem in STUDY_SCENARIOS:
        raise ConfigError(
            f"{path.stem!r} is the scenario of 'ffmpc study {path.stem}', not of the node graph"
        )
    path, flat = read_parameter_file(path, SECTIONS)
    flat = with_overrides_flat(flat, overrides or {})
    return scenario_from_flat(path.stem, flat, str(path.resolve()))


_ConfigT = TypeVar("_ConfigT")


@dataclass(frozen=True)
class ConfigSchema(Generic[_ConfigT]):
    """The schema of a study configured by one tree of frozen dataclasses (``root``, e.g. the
    impact study's ``ImpactStudyConfig``): :func:`dataclass_schema`'s ``params`` and the name
    map. Its scenario files have the scenario files' format; their sections are the first
    parts of the dotted names (``plant: {ros__parameters: {dice_stiffness: 3000.0}}``), the
    other names go in ``/**``. Values are checked by the same :class:`ParamSpec` as the
    polishing scenarios (same messages, same "did you mean")."""

    root: type[_ConfigT]
    params: dict[str, ParamSpec]
    paths: dict[str, str]  # dotted name → field path in the dataclass tree
    #: Field paths of the dict-valued fields ``{key: {name: value}}`` (the polishing
    #: scenario's ``mpc.weights``: ``{formulation: {weight: value}}``), whose parameters are
    #: ``<path>.<key>.<name>`` (their specs are ``given``); an unset entry is absent.
    maps: tuple[str, ...] = ()

    @classmethod
    def of(
        cls,
        root: type[_ConfigT],
        names: dict[str, str] | None = None,
        exclude: tuple[str, ...] = (),
        given: dict[str, ParamSpec] | None = None,
        maps: tuple[str, ...] = (),
    ) -> ConfigSchema[_ConfigT]:
        """The schema of ``root`` (arguments of :func:`dataclass_schema`; ``maps``: the
        dict-valued fields, :attr:`maps`)."""
        params = dataclass_schema(root, names, exclude + maps, given)
        paths = {public_name(p, names or {}): p for p in dataclass_leaves(root, exclude + maps)}
        in_maps = {n for n in params if n.startswith(tuple(m + "." for m in maps))}
        if set(paths) != set(params) - in_maps:
            raise AssertionError(f"schema: names without a field: {set(params) ^ set(paths)}")
        return cls(root, params, paths, maps)

    @property
    def sections(self) -> tuple[str, ...]:
        """The file sections besides ``/**``: the first parts of the dotted names."""
        return tuple(sorted({n.split(".")[0] for n in self.params if "." in n}))

    def build(self, flat: dict[str, Any], base: _ConfigT | None = None) -> _ConfigT:
        """``base`` (default: ``root()``) with the dotted-name values of ``flat``, checked
        (ConfigError ``name = value: …``, the first bad or unknown one; the dataclasses' own
        cross-field checks raise theirs). Entries of a dict field (:attr:`maps`) are merged
        into ``base``'s."""
        config = self.root() if base is None else base
        checked = validate_flat(flat, self.params)
        values: dict[str, Any] = {}
        for name, value in checked.items():
            field_map = self._map_of(name)
            if field_map is None:
                values[self.paths[name]] = value
                continue
            if field_map not in values:
                values[field_map] = {k: dict(v) for k, v in _get_path(config, field_map).items()}
            key, _, entry = name[len(field_map) + 1 :].partition(".")
            values[field_map].setdefault(key, {})[entry] = value
        return _replace_tree(config, values, "")

    def flatten(self, config: _ConfigT) -> dict[str, Any]:
        """``{dotted name: value}`` of every parameter of ``config`` (of a dict field, its
        entries)."""
        out = {name: _get_path(config, path) for name, path in self.paths.items()}
        for field_map in self.maps:
            for key, entries in _get_path(config, field_map).items():
                out.update({f"{field_map}.{key}.{k}": v for k, v in entries.items()})
        return out

    def _map_of(self, name: str) -> str | None:
        """The dict field (:attr:`maps`) ``name`` is an entry of, or None."""
        return next((m for m in self.maps if name.startswith(m + ".")), None)

    def load(self, name_or_path: str | os.PathLike, overrides: dict | None = None) -> _ConfigT:
        """A scenario file (a shipped name or a path) with dotted-name ``overrides`` applied."""
        _, flat = read_parameter_file(name_or_path, self.sections)
        return self.build(flat | dict(overrides or {}))


def _get_path(obj: Any, path: str) -> Any:
    """The value at the dotted field path ``path`` of the dataclass tree ``obj``."""
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def _replace_tree(obj: Any, values: dict[str, Any], prefix: str) -> Any:
    """A copy of the dataclass ``obj`` with ``{field path: value}`` set, nested ones too."""
    changes: dict[str, Any] = {}
    for f in fields(obj):
        path = prefix + f.name
        value = getattr(obj, f.name)
        if is_dataclass(value) and any(k.startswith(path + ".") for k in values):
            changes[f.name] = _replace_tree(value, values, path + ".")
        elif path in values:
            changes[f.name] = values[path]
    return replace(obj, **changes) if changes else obj


#: The parameter names of the fields of the core classes that a section holds besides its own
#: fields (``mpc.ocp``, ``plant.actuation``): the section's flat names (:func:`public_name`).
SECTION_NAMES = {
    "mpc.ocp.": "mpc.",
    "plant.actuation.": "plant.actuation_",
    "plant.actuation.static_friction": "plant.static_friction",
    "plant.actuation.viscous_friction": "plant.viscous_friction",
    "plant.actuation.friction_velocity": "plant.friction_velocity",
}
#: The polishing scenario's schema: its tree is :class:`Scenario` (the sections, with the core's
#: configuration classes as they are: the MPC's :class:`~ffmpc_core.config.OcpConfig`,
#: :class:`~ffmpc_core.config.ContactConfig` and
#: :class:`~ffmpc_core.constraints.ConstraintConfig`, the joint sensor's
#: :class:`~ffmpc_core.sensing.JointSensorConfig`, the PID's :class:`~ffmpc_core.pid.PidConfig`,
#: the plant's :class:`~ffmpc_core.actuation.ActuationConfig`), its names the dotted field
#: paths (those of ``mpc.ocp`` and ``plant.actuation``: :data:`SECTION_NAMES`).
#: :func:`load_scenario`, :meth:`Scenario.with_overrides`, ``--set``/``--set-file`` and the
#: node parameters (``ffmpc_ros.params``) all check values with it.
SCENARIO_SCHEMA: ConfigSchema[Scenario] = ConfigSchema.of(
    Scenario,
    names=SECTION_NAMES,
    exclude=("name", "source"),
    given=_scenario_given_specs(),
    maps=("mpc.weights",),
)
#: Every scenario parameter by dotted name: the one declaration of its kind, unit and range.
SCHEMA: dict[str, ParamSpec] = SCENARIO_SCHEMA.params
