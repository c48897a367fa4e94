"""Node parameters: which scenario values each node declares, with descriptors and ranges.

A scenario file (``ffmpc_core/scenarios/*.yaml``) is a ROS 2 parameter file with one section per
node (``plant``, ``joint_sensor``, ``ft_sensor``, ``mpc``, ``pid``) and ``/**`` for all. Each
node declares:

* its own section's parameters under their plain names (``mpc`` declares ``horizon``);
* the shared ``/**`` values it needs (``robot``, ``seed``, ``task.*``);
* the few values of OTHER sections it needs, under ``<section>.<name>`` (the MPC node declares
  ``pid.delay_cycles`` for its δo and ``plant.time_step``): ``ffmpc run`` fills them from the
  scenario; with ``ros2 run … --params-file`` they keep their defaults unless given with ``-p``;
* graph parameters that are not part of a scenario (``lockstep``, ``duration``, …). The impact
  nodes (``impact_planner``, ``contact_learner``) have no scenario section: apart from ``robot``
  and ``plant.time_step`` all their parameters are graph parameters.

Every parameter is read-only (nodes build their models once), has a description, and numeric
ones a range. The node rebuilds a :class:`~ffmpc_core.scenario.Scenario` from its values with the
same validation as the ROS-free runner (:func:`scenario_from_parameters`), so both run the same
experiment.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.parameter import Parameter

from ffmpc_core.config import FORMULATIONS, CostWeights
from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import WILDCARD, Scenario, scenario_parameters
from ffmpc_core.tasks import PhaseWeights

INF = 1e300  # "no upper bound" for FloatingPointRange

#: Ranges of the numeric scenario parameters (dotted scenario names); a value outside is refused
#: by rclpy when the node starts.
RANGES: dict[str, tuple[float, float]] = {
    "seed": (0, 2**31 - 1),
    "task.normal_force": (0.0, 500.0),
    "task.circle_radius": (0.0, 0.5),
    "task.angular_velocity": (0.0, 50.0),
    "task.circles": (0.0, 100.0),
    "task.start_height": (0.0, 0.5),
    "task.still": (0.0, 60.0),
    "task.reach": (0.0, 60.0),
    "task.force_ramp": (0.0, 60.0),
    "task.stop": (0.0, 60.0),
    "task.low_force": (0.0, 500.0),
    "task.high_force": (0.0, 500.0),
    "task.square_period": (0.0, 60.0),
    "task.square_cycles": (0, 1000),
    "plant.time_step": (1e-5, 0.01),
    "plant.table_tilt_deg": (-45.0, 45.0),
    "plant.random_tilt_deg": (0.0, 45.0),
    "plant.table_stiffness": (1.0, 1e9),
    "plant.table_damping": (0.0, 1e6),
    "plant.table_friction": (0.0, 10.0),
    "plant.actuation_delay_cycles": (0, 1000),
    "plant.actuation_noise_fraction": (0.0, 0.99),
    "plant.static_friction": (0.0, 100.0),
    "plant.viscous_friction": (0.0, 100.0),
    "plant.friction_velocity": (1e-6, 100.0),
    "plant.push_time": (0.0, 3600.0),
    "plant.push_duration": (0.0, 60.0),
    "joint_sensor.delay_cycles": (0, 1000),
    "joint_sensor.position_noise_std": (0.0, 1.0),
    "joint_sensor.velocity_noise_std": (0.0, 10.0),
    "ft_sensor.delay_cycles": (0, 1000),
    "ft_sensor.force_noise_std": (0.0, 100.0),
    "ft_sensor.filter_cutoff_frequency": (0.0, 1e4),
    "ft_sensor.contact_on_force": (0.0, 1e4),
    "ft_sensor.contact_off_force": (0.0, 1e4),
    "ft_sensor.tare_samples": (1, 100000),
    "mpc.horizon": (1, 1000),
    "mpc.dt": (1e-5, 1.0),
    "mpc.period": (1e-5, 1.0),
    "mpc.max_iterations": (1, 1000),
    "mpc.kkt_tolerance": (1e-12, 1.0),
    "mpc.cutoff_frequency": (1e-3, 1e4),
    "mpc.contact.dimension": (1, 3),
    "mpc.contact.normal_axis": (0, 2),
    "pid.kp": (0.0, 100.0),
    "pid.ki": (0.0, 1e5),
    "pid.kd": (0.0, 100.0),
    "pid.integral_fraction": (0.0, 1.0),
    "pid.delay_cycles": (0, 1000),
    "pid.stale_timeout": (1e-5, 10.0),
    "pid.blend_duration": (0.0, 10.0),
    "pid.hold_frequency": (0.0, 100.0),
    "pid.hold_damping_ratio": (0.0, 10.0),
}

DESCRIPTIONS: dict[str, str] = {
    "robot": "robot model: iiwa | panda",
    "seed": "seed of every random draw of the run (numpy Generator spawn)",
    "task.name": "polishing | force_square",
    "task.normal_force": "polishing normal force reference, N",
    "task.circle_radius": "circle radius, m",
    "task.angular_velocity": "angular velocity along the circle, rad/s",
    "task.circles": "number of turns",
    "task.start_height": "start height above the believed table, m",
    "task.still": "phase duration: stand still, s",
    "task.reach": "phase duration: reach the table, s",
    "task.force_ramp": "phase duration: ramp the force, s",
    "task.stop": "phase duration after the circle, s",
    "task.low_force": "force_square low level, N",
    "task.high_force": "force_square high level, N",
    "task.square_period": "force_square period, s",
    "task.square_cycles": "force_square number of periods",
    "plant.time_step": "physics step = control cycle, s; every stamp is a multiple of it",
    "plant.table_tilt_deg": "table tilt θ when random_tilt_deg is 0, deg",
    "plant.table_tilt_axis": "horizontal tilt axis, world frame",
    "plant.random_tilt_deg": "θ ~ U(−this, +this) per seed when > 0, deg",
    "plant.table_stiffness": "table contact stiffness, N/m",
    "plant.table_damping": "table contact damping, N·s/m",
    "plant.table_friction": "table Coulomb friction coefficient",
    "plant.actuation_random_bias": "draw the actuation bias (a, b) per seed (eq 31)",
    "plant.actuation_delay_cycles": "actuation delay δs, cycles (eq 31)",
    "plant.actuation_noise_fraction": "σ_τ as a fraction of the torque limits (eq 31)",
    "plant.static_friction": "μs, N·m (eq 31)",
    "plant.viscous_friction": "μv, N·m·s/rad (eq 31)",
    "plant.friction_velocity": "v_s of the tanh friction, rad/s",
    "plant.push_enabled": "apply an external push on the tool",
    "plant.push_time": "push start, s",
    "plant.push_force": "push force, N, world frame",
    "plant.push_duration": "push duration, s",
    "joint_sensor.delay_cycles": "sensing delay δs, cycles (eq 30)",
    "joint_sensor.position_noise_std": "σ_q, rad (eq 30)",
    "joint_sensor.velocity_noise_std": "σ_q̇, rad/s (eq 30)",
    "ft_sensor.delay_cycles": "sensing delay δs, cycles (eq 32)",
    "ft_sensor.force_noise_std": "σ_λ, N (eq 32)",
    "ft_sensor.filter_cutoff_frequency": "cut-off of the filtered wrench, Hz (0: no filter)",
    "ft_sensor.contact_on_force": "filtered normal force above which contact starts, N",
    "ft_sensor.contact_off_force": "filtered normal force below which contact ends, N",
    "ft_sensor.tare_samples": "measurements averaged by the tare service",
    "mpc.formulation": "classical | torque_feedback | force_feedback",
    "mpc.horizon": "OCP nodes N",
    "mpc.dt": "OCP node duration, s",
    "mpc.period": "re-planning period, s (a multiple of plant.time_step)",
    "mpc.max_iterations": "SQP iterations per solve",
    "mpc.kkt_tolerance": "SQP KKT tolerance",
    "mpc.cutoff_frequency": "low-pass actuation cut-off f_c, Hz (torque-feedback)",
    "mpc.riccati_feedback": "low level applies τ* + G·Δx between solves",
    "mpc.delay_compensation": "plan for t + δo (δo = pid.delay_cycles cycles)",
    "mpc.command_delay": "δo: pid (pid.delay_cycles), seconds (sets pid.delay_cycles) or measured",
    "mpc.backend": "action models: native (C++, default) | python (the reference)",
    "mpc.contact.dimension": "contact force entries: 1 (normal) or 3",
    "mpc.contact.frame_type": "LOCAL_WORLD_ALIGNED (the study feeds world-aligned forces)",
    "mpc.contact.normal_axis": "axis of the 1-D force: 0 x, 1 y, 2 z",
    "mpc.contact.stiffness": "K of the visco-elastic contact, N/m (force-feedback)",
    "mpc.contact.damping": "B of the visco-elastic contact, N·s/m (force-feedback)",
    "pid.enabled": "torque PID on (off: τ^m = τ^d(t − δo))",
    "pid.kp": "K_P (eq 33)",
    "pid.ki": "K_I, 1/s (eq 33)",
    "pid.kd": "K_D, s (eq 33)",
    "pid.integral_fraction": "anti-windup bound on K_I·∫e, fraction of the torque limit",
    "pid.delay_cycles": "δo, cycles (eq 33)",
    "pid.stale_timeout": "MPC command age that triggers the safe hold, s",
    "pid.blend_duration": "hold → MPC blend, s",
    "pid.hold_frequency": "natural frequency of the hold PD, Hz",
    "pid.hold_damping_ratio": "damping ratio of the hold PD",
}

_DYNAMIC = ("_diag", "contact.stiffness", "contact.damping")  # scalar or per-axis array


@dataclass(frozen=True)
class GraphParameter:
    """A parameter of the graph that is not part of a scenario."""

    name: str
    default: Any
    description: str
    range: tuple[float, float] | None = None


@dataclass(frozen=True)
class NodeSpec:
    """What a node declares: its section, shared (``/**``) names, other sections' names, and
    graph parameters. Names ending in ``.*`` take every name with that prefix."""

    name: str
    section: str | None
    shared: tuple[str, ...]
    foreign: tuple[str, ...]
    graph: tuple[GraphParameter, ...] = ()


LOCKSTEP = GraphParameter(
    "lockstep", True, "lockstep: wait for every step's inputs (false: real time, wall clock)"
)
DURATION = GraphParameter(
    "duration", 0.0, "simulated time of the run, s (0: the task's duration)", (0.0, 1e6)
)
LOCKSTEP_TIMEOUT = GraphParameter(
    "lockstep_timeout",
    5.0,
    "lockstep: wall time to wait for an MPC command before going on without it, s",
    (0.01, 3600.0),
)
MAX_AGE = GraphParameter(
    "max_input_age",
    0.05,
    "inputs older than this (simulated time, s) are rejected as stale",
    (1e-4, 3600.0),
)
START_DELAY = GraphParameter(
    "start_delay",
    0.0,
    "wall time between start-up and the first published state, s (lets discovery settle)",
    (0.0, 3600.0),
)
START_SUBSCRIBERS = GraphParameter(
    "start_subscribers",
    0,
    "subscribers of /plant/joint_states to wait for before the first state",
    (0, 1000),
)

WAIT_FOR_METRICS = GraphParameter(
    "wait_for_metrics",
    False,
    "lockstep: start only after the metrics node announced /metrics/ready",
)

_TIME_STEP = ("plant.time_step",)
_CONTACT = ("mpc.contact.dimension", "mpc.contact.normal_axis", "mpc.contact.frame_type")

# -- the impact nodes (Dehio & Kheddar 2020) and the MPC's use of the learned contact ----------
# Defaults: the paper's experiment (Sec. VI) as in sim_bridge.impact_study (Panda, prior
# 2400 N/m and 15 N·s/m, z̄ = 3 cm, 90 % of the data-sheet limits).
DIRECTION = GraphParameter(
    "direction", [0.0, 0.0, -1.0], "unit motion direction d, world frame (eq 2; z, ż, f along d)"
)
LEARNER_MIN_SAMPLES = GraphParameter(
    "learner_min_samples",
    20,
    "samples the learner's estimate needs before it is used",
    (3, 2**31 - 1),
)
LEARNER_MAX_RELATIVE_STD = GraphParameter(
    "learner_max_relative_std",
    0.05,
    "an estimate is used only when both standard errors are at most this fraction of the value",
    (0.0, 1e3),
)
USE_LEARNED_CONTACT = GraphParameter(
    "use_learned_contact",
    False,
    "force-feedback: take K, B live from /contact_learner/estimate when it is confident",
)
IMPACT_PLANNER_GRAPH: tuple[GraphParameter, ...] = (
    DIRECTION,
    GraphParameter("target_force", 60.0, "force regulated after contact, N", (1e-3, 1e4)),
    GraphParameter(
        "contact_threshold", 2.0, "pressing force along d that declares the contact, N", (1e-6, 1e4)
    ),
    GraphParameter("preview_horizon", 20, "h, preview steps of eq 12–14", (2, 1000)),
    GraphParameter("preview_dt", 0.025, "Δt of the penetration preview (eq 6), s", (1e-4, 1.0)),
    GraphParameter(
        "prior_stiffness", 2400.0, "α of the planning material until learned, N/m", (1e-3, 1e9)
    ),
    GraphParameter(
        "prior_damping", 15.0, "β of the planning material until learned, N·s/m", (0.0, 1e6)
    ),
    GraphParameter("max_penetration", 0.03, "z̄, end of the elastic domain, m", (1e-6, 1.0)),
    GraphParameter(
        "limit_margin",
        0.9,
        "fraction of the joint velocity and acceleration limits the planner may use",
        (1e-3, 1.0),
    ),
    GraphParameter(
        "acceleration_limit",
        Parameter.Type.DOUBLE_ARRAY,
        "q̈_max per joint, rad/s² (unset: the Panda data sheet; required for other robots)",
    ),
    GraphParameter("n_directions", 8, "eq 10 weight directions (vertices)", (3, 64)),
    GraphParameter(
        "solver",
        "daqp",
        "eq 10 and eq 14 solver: daqp (warm-started active set; eq 9 and 11 in closed form) "
        "or osqp (the previous pipeline, kept as a reference)",
    ),
    GraphParameter(
        "max_approach_velocity", 0.0, "cap on the approach speed, m/s (0: none)", (0.0, 100.0)
    ),
    GraphParameter(
        "replan_period",
        0.0,
        "re-solve eq 9–14 this often during the approach, s (0: every cycle, as the paper)",
        (0.0, 10.0),
    ),
    GraphParameter("admittance", 2e-3, "admittance G after contact, m/(N·s)", (1e-9, 1.0)),
    GraphParameter("admittance_max_velocity", 0.1, "admittance velocity bound, m/s", (1e-6, 10.0)),
    GraphParameter(
        "admittance_velocity_filter", 0.8, "admittance velocity filter γ per ms", (0.0, 0.999)
    ),
    GraphParameter(
        "use_learned_material",
        True,
        "plan with /contact_learner/estimate once it is confident (else the prior only)",
    ),
    LEARNER_MIN_SAMPLES,
    LEARNER_MAX_RELATIVE_STD,
)
CONTACT_LEARNER_GRAPH: tuple[GraphParameter, ...] = (
    DIRECTION,
    GraphParameter(
        "contact_threshold",
        2.0,
        "pressing force along d that ends the search for the surface, N",
        (1e-6, 1e4),
    ),
    GraphParameter(
        "surface_force",
        0.0,
        "surface = contact-frame position at the last sample with force ≤ this before the "
        "threshold, N",
        (-1e4, 1e4),
    ),
    GraphParameter(
        "feed_force", 0.0, "samples with force above this are in contact (and fed), N", (-1e4, 1e4)
    ),
    GraphParameter(
        "skip_onset_samples",
        1,
        "first in-contact samples of each contact episode not fed to the learner",
        (0, 100000),
    ),
    GraphParameter("regularization", 1e-9, "λ of (S Sᵀ)_0 = λI (eq 19), m² and m²/s²", (0.0, 1.0)),
)

NODE_SPECS: dict[str, NodeSpec] = {
    "plant": NodeSpec(
        "plant",
        "plant",
        ("robot", "seed", "task.*"),
        (),
        (LOCKSTEP, DURATION, START_DELAY, START_SUBSCRIBERS, WAIT_FOR_METRICS, MAX_AGE),
    ),
    "joint_sensor": NodeSpec(
        "joint_sensor", "joint_sensor", ("robot", "seed"), _TIME_STEP, (MAX_AGE,)
    ),
    "ft_sensor": NodeSpec("ft_sensor", "ft_sensor", ("seed",), _TIME_STEP + _CONTACT, (MAX_AGE,)),
    "mpc": NodeSpec(
        "mpc",
        "mpc",
        ("robot", "task.*"),
        _TIME_STEP + ("pid.delay_cycles",),
        (LOCKSTEP, MAX_AGE, USE_LEARNED_CONTACT, LEARNER_MIN_SAMPLES, LEARNER_MAX_RELATIVE_STD),
    ),
    "pid": NodeSpec(
        "pid",
        "pid",
        ("robot",),
        _TIME_STEP + _CONTACT + ("mpc.period", "mpc.formulation", "mpc.riccati_feedback"),
        (LOCKSTEP, LOCKSTEP_TIMEOUT, MAX_AGE),
    ),
    "metrics": NodeSpec(
        "metrics",
        None,
        ("robot", "seed", "task.*"),
        _TIME_STEP + _CONTACT + ("mpc.formulation",),
        (DURATION, LOCKSTEP),
    ),
    "impact_planner": NodeSpec(
        "impact_planner", None, ("robot",), _TIME_STEP, (LOCKSTEP, MAX_AGE, *IMPACT_PLANNER_GRAPH)
    ),
    "contact_learner": NodeSpec(
        "contact_learner", None, ("robot",), _TIME_STEP, (MAX_AGE, *CONTACT_LEARNER_GRAPH)
    ),
}


def _weight_defaults() -> dict[str, Any]:
    """mpc.weights.<formulation>.<name> for every formulation, with the dataclass defaults."""
    out: dict[str, Any] = {}
    for form in FORMULATIONS:
        for f in fields(CostWeights):
            out[f"mpc.weights.{form}.{f.name}"] = getattr(CostWeights(), f.name)
        out[f"mpc.weights.{form}.force_phase"] = PhaseWeights.force
        out[f"mpc.weights.{form}.ee_position_phase"] = PhaseWeights.free_ee_position
    return out


def scenario_flat(scenario: Scenario) -> dict[str, Any]:
    """The scenario as dotted scenario names (``plant.time_step``, ``robot``, ``task.reach``),
    with every MPC weight present."""
    flat: dict[str, Any] = {}
    for section, values in scenario_parameters(scenario).items():
        prefix = "" if section == WILDCARD else section + "."
        flat.update({prefix + k: v for k, v in values.items()})
    weights = _weight_defaults()
    weights.update({k: v for k, v in flat.items() if k.startswith("mpc.weights.")})
    flat.update(weights)
    return flat


def _select(flat: dict[str, Any], patterns: tuple[str, ...]) -> list[str]:
    names = []
    for pattern in patterns:
        if pattern.endswith(".*"):
            names += sorted(k for k in flat if k.startswith(pattern[:-1]))
        elif pattern in flat:
            names.append(pattern)
        else:
            raise ConfigError(f"no scenario parameter {pattern!r}")
    return names


def node_scenario_names(spec: NodeSpec, flat: dict[str, Any]) -> dict[str, str]:
    """{ROS parameter name: scenario name} of a node (own section names lose their prefix)."""
    out: dict[str, str] = {}
    if spec.section is not None:
        prefix = spec.section + "."
        for key in flat:
            if key.startswith(prefix):
                out[key[len(prefix) :]] = key
    for key in _select(flat, spec.shared) + _select(flat, spec.foreign):
        out[key] = key
    return out


def node_parameter_values(node: str, scenario: Scenario, **graph: Any) -> dict[str, Any]:
    """{ROS name: value} that makes node ``node`` run ``scenario`` (what ``ffmpc run`` passes),
    plus graph parameters (``lockstep=False``…)."""
    spec = NODE_SPECS[node]
    flat = scenario_flat(scenario)
    values = {ros: _ros_value(flat[name]) for ros, name in node_scenario_names(spec, flat).items()}
    known = {g.name for g in spec.graph}
    for key, value in graph.items():
        if key in known:
            values[key] = value
    return values


def _ros_value(value: Any) -> Any:
    return [float(v) for v in value] if isinstance(value, tuple) else value


def descriptor(
    scenario_name: str,
    value: Any,
    description: str | None = None,
    limits: tuple[float, float] | None = None,
) -> ParameterDescriptor:
    """A read-only ParameterDescriptor with description and, for numbers, a range."""
    desc = ParameterDescriptor(read_only=True)
    desc.description = description or DESCRIPTIONS.get(scenario_name, "")
    if not desc.description and ".weights." in scenario_name:
        desc.description = "cost weight (ffmpc_core.config.CostWeights, tasks.PhaseWeights)"
    if any(scenario_name.endswith(s) for s in _DYNAMIC):
        desc.dynamic_typing = True
        desc.description += " (a number or one per axis/entry)"
        return desc
    limits = limits or RANGES.get(scenario_name)
    if limits is None and ".weights." in scenario_name:
        limits = (0.0, INF)
    if isinstance(value, bool) or limits is None:
        return desc
    if isinstance(value, int):
        desc.integer_range = [IntegerRange(from_value=int(limits[0]), to_value=int(limits[1]))]
    elif isinstance(value, float):
        desc.floating_point_range = [
            FloatingPointRange(from_value=float(limits[0]), to_value=float(limits[1]))
        ]
    return desc


def declare_node_parameters(node, spec: NodeSpec) -> dict[str, Any]:
    """Declare every parameter of ``spec`` on an rclpy node; returns {ROS name: value}."""
    flat = scenario_flat(Scenario(name="defaults"))
    values: dict[str, Any] = {}
    for ros, name in node_scenario_names(spec, flat).items():
        default = _ros_value(flat[name])
        node.declare_parameter(ros, default, descriptor(name, default))
        values[ros] = node.get_parameter(ros).value
    for g in spec.graph:
        # (the declared Parameter: get_parameter raises for one declared by type and not set)
        declared = node.declare_parameter(
            g.name, g.default, descriptor(g.name, g.default, g.description, g.range)
        )
        values[g.name] = declared.value
    return values


def scenario_from_parameters(spec: NodeSpec, values: dict[str, Any], name: str) -> Scenario:
    """The Scenario a node runs, from its parameter values (validated like a scenario file)."""
    flat = scenario_flat(Scenario(name="defaults"))
    mapping = node_scenario_names(spec, flat)
    overrides = {}
    for ros, scenario_name in mapping.items():
        value = values[ros]
        if isinstance(value, list | tuple) or type(value).__name__ == "array":
            value = tuple(float(v) for v in value)
        overrides[scenario_name] = value
    return Scenario(name=name).with_overrides(overrides)


def parameter_overrides(values: dict[str, Any]) -> list[Parameter]:
    """rclpy Parameter objects for ``Node(parameter_overrides=…)``."""
    return [Parameter(k, value=v) for k, v in values.items()]
