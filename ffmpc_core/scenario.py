"""Scenario files: one YAML per experiment, in the ROS 2 parameter-file format.

A scenario file has one section per node (``plant``, ``joint_sensor``, ``ft_sensor``, ``mpc``,
``pid``) plus the wildcard section ``/**`` shared by all nodes (robot, seed, task). The same file
is given to the ROS nodes (``--params-file``) and read here by the ROS-free runner, so both run
the same experiment. Nested maps are flattened to dotted names exactly as ROS does
(``task: {normal_force: 50}`` → parameter ``task.normal_force``).

:func:`load_scenario` returns a :class:`Scenario` of typed, validated, frozen dataclasses; unknown
keys are an error (an option that silently does nothing is a bug). Overrides use dotted names:
``load_scenario(path, {"mpc.formulation": "classical", "pid.enabled": False})``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ffmpc_core.config import BACKENDS, FORMULATIONS, ContactConfig, CostWeights
from ffmpc_core.errors import ConfigError

SECTIONS = ("plant", "joint_sensor", "ft_sensor", "mpc", "pid")
WILDCARD = "/**"

#: Where the scenario files shipped with ffmpc live.
SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"


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


@dataclass(frozen=True)
class TaskSection:
    """The task of the run (shared by every node). Durations in s, forces in N."""

    name: str = "polishing"  # "polishing" | "force_square"
    normal_force: float = 50.0
    circle_radius: float = 0.07
    angular_velocity: float = 3.0
    circles: float = 2.0
    start_height: float = 0.05  # m above the believed table at the circle start
    still: float = 0.1
    reach: float = 0.4
    force_ramp: float = 0.5
    stop: float = 0.3
    low_force: float = 20.0  # force_square
    high_force: float = 50.0
    square_period: float = 2.0
    square_cycles: int = 2


@dataclass(frozen=True)
class PlantSection:
    time_step: float = 1e-3
    table_tilt_deg: float = 0.0
    table_tilt_axis: tuple[float, float, float] = (0.0, 1.0, 0.0)
    random_tilt_deg: float = 0.0  # θ ~ U(−this, +this) per seed when > 0
    table_stiffness: float = 1e4
    table_damping: float = 1e2
    table_friction: float = 0.5
    actuation_random_bias: bool = True
    actuation_delay_cycles: int = 1
    actuation_noise_fraction: float = 0.01
    static_friction: float = 1.0
    viscous_friction: float = 0.5
    friction_velocity: float = 1.0
    push_enabled: bool = False
    push_time: float = 0.0
    push_force: tuple[float, float, float] = (0.0, 0.0, 0.0)
    push_duration: float = 0.0


@dataclass(frozen=True)
class JointSensorSection:
    delay_cycles: int = 1
    position_noise_std: float = 1e-3
    velocity_noise_std: float = 1e-3


@dataclass(frozen=True)
class ForceSensorSection:
    delay_cycles: int = 1
    force_noise_std: float = 0.5
    # Outputs of the F/T sensor node beside the eq-32 measurement (the runner does not use them):
    filter_cutoff_frequency: float = 20.0  # Hz, first-order low-pass of the filtered wrench
    contact_on_force: float = 5.0  # N, filtered normal force that starts a contact
    contact_off_force: float = 2.0  # N, filtered normal force that ends it (hysteresis)
    tare_samples: int = 50  # measurements averaged by the tare service


@dataclass(frozen=True)
class MpcSection:
    formulation: str = "force_feedback"
    horizon: int = 5
    dt: float = 0.003
    period: float = 0.002
    max_iterations: int = 8
    kkt_tolerance: float = 1e-4
    cutoff_frequency: float = 50.0
    riccati_feedback: bool = False
    delay_compensation: bool = True  # send the plan for t + δo (δo = pid.delay_cycles)
    backend: str = "native"  # action models: native (C++) | python (reference), MpcConfig.backend
    contact: ContactConfig = field(default_factory=ContactConfig)
    #: per formulation: CostWeights fields plus ``force_phase`` (c6) and ``ee_position_phase``
    weights: dict[str, dict[str, Any]] = field(default_factory=dict)

    def cost_weights(self, formulation: str | None = None) -> CostWeights:
        values = dict(self.weights.get(formulation or self.formulation, {}))
        values.pop("force_phase", None)
        values.pop("ee_position_phase", None)
        try:
            return CostWeights(**values)
        except TypeError as exc:
            raise ConfigError(f"mpc weights: {exc}") from None

    def phase_weight(self, name: str, default: float, formulation: str | None = None) -> float:
        return float(self.weights.get(formulation or self.formulation, {}).get(name, default))


@dataclass(frozen=True)
class PidSection:
    enabled: bool = True
    kp: float = 0.1
    ki: float = 20.0  # 1/s; see ffmpc_core/pid.py for why these gains
    kd: float = 0.0
    integral_fraction: float = 0.3
    delay_cycles: int = 5  # δo = 5 ms at 1 kHz
    # Low-level loop around the PID (ffmpc_core.lowlevel); inactive while the MPC is on time.
    stale_timeout: float = 0.004  # s without a new MPC command → safe hold (2 MPC periods)
    blend_duration: float = 0.1  # s, hold → MPC torque blend (minimum jerk)
    hold_frequency: float = 4.0  # Hz, natural frequency of the inertia-scaled hold PD
    hold_damping_ratio: float = 1.0


@dataclass(frozen=True)
class Scenario:
    """A whole experiment: what every node runs with."""

    name: str
    robot: str = "iiwa"
    seed: int = 0
    task: TaskSection = field(default_factory=TaskSection)
    plant: PlantSection = field(default_factory=PlantSection)
    joint_sensor: JointSensorSection = field(default_factory=JointSensorSection)
    ft_sensor: ForceSensorSection = field(default_factory=ForceSensorSection)
    mpc: MpcSection = field(default_factory=MpcSection)
    pid: PidSection = field(default_factory=PidSection)

    def with_overrides(self, overrides: dict[str, Any]) -> Scenario:
        """A copy with dotted-name overrides applied (``"mpc.formulation"``, ``"seed"``)."""
        flat = _scenario_to_flat(self)
        for key, value in overrides.items():
            if key not in flat and not key.startswith("mpc.weights."):
                raise ConfigError(f"unknown scenario parameter {key!r}")
            flat[key] = value
        return _scenario_from_flat(self.name, flat)


def _coerce(cls, values: dict[str, Any], where: str):
    names = {f.name: f for f in fields(cls)}
    kwargs = {}
    for key, value in values.items():
        if key not in names:
            raise ConfigError(f"{where}: unknown parameter {key!r}")
        default = getattr(cls(), key) if key in names else None
        if isinstance(default, tuple):
            value = tuple(float(v) for v in value)
        elif isinstance(default, bool):
            if not isinstance(value, bool):
                raise ConfigError(f"{where}.{key} must be true or false, got {value!r}")
        elif isinstance(default, int):
            if int(value) != value:
                raise ConfigError(f"{where}.{key} must be an integer, got {value!r}")
            value = int(value)
        elif isinstance(default, float):
            value = float(value)
            if not np.isfinite(value):
                raise ConfigError(f"{where}.{key} must be finite")
        kwargs[key] = value
    return cls(**kwargs)


def _split(flat: dict[str, Any], prefix: str) -> dict[str, Any]:
    n = len(prefix) + 1
    return {k[n:]: v for k, v in flat.items() if k.startswith(prefix + ".")}


def _scenario_from_flat(name: str, flat: dict[str, Any]) -> Scenario:
    known_top = {"robot", "seed"}
    for key in flat:
        head = key.split(".", 1)[0]
        if head not in known_top and head not in ("task", *SECTIONS):
            raise ConfigError(f"scenario {name}: unknown parameter {key!r}")
    mpc_flat = _split(flat, "mpc")
    contact = _coerce(
        ContactConfig, {k[8:]: v for k, v in mpc_flat.items() if k.startswith("contact.")}, "mpc"
    )
    weights: dict[str, dict[str, Any]] = {}
    for key, value in mpc_flat.items():
        if key.startswith("weights."):
            form, _, wname = key[8:].partition(".")
            if form not in FORMULATIONS:
                raise ConfigError(f"mpc.weights: unknown formulation {form!r}")
            weights.setdefault(form, {})[wname] = value
    plain = {k: v for k, v in mpc_flat.items() if not k.startswith(("contact.", "weights."))}
    mpc = replace(_coerce(MpcSection, plain, "mpc"), contact=contact, weights=weights)
    if mpc.formulation not in FORMULATIONS:
        raise ConfigError(f"mpc.formulation must be one of {FORMULATIONS}")
    if mpc.backend not in BACKENDS:
        raise ConfigError(f"mpc.backend must be one of {BACKENDS}, got {mpc.backend!r}")
    for form in weights:
        mpc.cost_weights(form)  # validate now, not mid-run
    scenario = Scenario(
        name=name,
        robot=str(flat.get("robot", "iiwa")),
        seed=int(flat.get("seed", 0)),
        task=_coerce(TaskSection, _split(flat, "task"), "task"),
        plant=_coerce(PlantSection, _split(flat, "plant"), "plant"),
        joint_sensor=_coerce(JointSensorSection, _split(flat, "joint_sensor"), "joint_sensor"),
        ft_sensor=_coerce(ForceSensorSection, _split(flat, "ft_sensor"), "ft_sensor"),
        mpc=mpc,
        pid=_coerce(PidSection, _split(flat, "pid"), "pid"),
    )
    if scenario.task.name not in ("polishing", "force_square"):
        raise ConfigError(f"task.name must be polishing or force_square, got {scenario.task.name}")
    return scenario


def _scenario_to_flat(s: Scenario) -> dict[str, Any]:
    flat: dict[str, Any] = {"robot": s.robot, "seed": s.seed}
    for section in ("task", "plant", "joint_sensor", "ft_sensor", "pid"):
        obj = getattr(s, section)
        for f in fields(obj):
            flat[f"{section}.{f.name}"] = getattr(obj, f.name)
    for f in fields(s.mpc):
        if f.name not in ("contact", "weights"):
            flat[f"mpc.{f.name}"] = getattr(s.mpc, f.name)
    for f in fields(s.mpc.contact):
        flat[f"mpc.contact.{f.name}"] = getattr(s.mpc.contact, f.name)
    for form, values in s.mpc.weights.items():
        for k, v in values.items():
            flat[f"mpc.weights.{form}.{k}"] = v
    return flat


def scenario_parameters(s: Scenario) -> dict[str, dict[str, Any]]:
    """The scenario as ROS parameters: ``{section: {dotted_name: value}}`` (``/**`` included)."""
    flat = _scenario_to_flat(s)
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


def load_scenario(name_or_path: str | os.PathLike, overrides: dict | None = None) -> Scenario:
    """Read a scenario file (ROS 2 parameter-file format) into a validated :class:`Scenario`."""
    path = resolve_scenario_path(name_or_path)
    with open(path, encoding="utf-8") as fh:
        doc = yaml.safe_load(fh) or {}
    if not isinstance(doc, dict):
        raise ConfigError(f"{path}: expected a mapping of node sections")
    flat: dict[str, Any] = {}
    for section, body in doc.items():
        if not isinstance(body, dict) or set(body) != {"ros__parameters"}:
            raise ConfigError(f"{path}: section {section!r} must hold only 'ros__parameters'")
        params = flatten(body["ros__parameters"] or {})
        if section == WILDCARD:
            flat.update(params)
        elif section in SECTIONS:
            flat.update({f"{section}.{k}": v for k, v in params.items()})
        else:
            raise ConfigError(f"{path}: unknown node section {section!r}; expected {SECTIONS}")
    scenario = _scenario_from_flat(path.stem, flat)
    return scenario.with_overrides(overrides) if overrides else scenario
