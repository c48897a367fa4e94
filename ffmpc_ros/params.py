"""Node parameters: which scenario values each node declares, with descriptors and ranges.

A scenario file (``ffmpc_core/scenarios/*.yaml``) is a ROS 2 parameter file with one section per
node (``plant``, ``joint_sensor``, ``ft_sensor``, ``mpc``, ``pid``) and ``/**`` for all. Each
node declares:

* its own section's parameters under their plain names (``mpc`` declares ``horizon``);
* the shared ``/**`` values it needs (``robot``, ``seed``, ``task.*``);
* the few values of OTHER sections it needs, under ``<section>.<name>`` (the MPC node declares
  ``pid.delay_cycles`` for its δo and ``plant.time_step``): ``ffmpc run`` fills them from the
  scenario; with ``ros2 run … --params-file`` they keep their defaults unless given with ``-p``;
* the impact study's values it uses (:attr:`NodeSpec.impact`, patterns over
  :data:`~ffmpc_core.impact.scenario.IMPACT_SCHEMA`), under the schema's dotted names
  (``planner.horizon``, ``target_force``, ``touch.touch_force``): the impact planner and the
  contact learner, which have no polishing-scenario section; ``ffmpc run impact`` fills them from
  the loaded impact scenario (:func:`impact_parameter_values`), the node rebuilds
  the study's configuration from them (:func:`impact_config_from_parameters`,
  ``IMPACT_SCHEMA.build``: the checks and messages of ``ffmpc study impact --set``);
* graph parameters that are not part of a scenario (``lockstep``, ``duration``, ``direction``,
  …).

Every parameter has a description and numeric ones a range. Most are read-only (nodes build
their models once); the few a node applies in place while it runs are **live**
(:attr:`NodeSpec.live`: the MPC's contact K and B, its scalar cost weights and phase weights, the
force reference ``task.normal_force`` and ``position_offset``; the PID's gains): writable, with
the same schema range, checked again by the node
(:class:`ffmpc_ros.live_parameters.LiveParameters`), and applied from the node's next solve or
cycle.

The descriptors of scenario parameters are generated from :data:`ffmpc_core.scenario.SCHEMA`
(the impact study's from ``IMPACT_SCHEMA``), the one declaration of each parameter's type, unit
and range; the node builds its :class:`~ffmpc_core.scenario.Scenario` from its slice alone (its
values, the schema's defaults for the rest) with the same validation as the ROS-free runner
(:func:`scenario_from_parameters`), and a value rclpy refuses gives the same ConfigError as the
runner's, so both accept and refuse the same experiments. ``ffmpc run`` gives each node
process the scenario file as it is, then the run's parameter file with the rest of the node's
``{ROS name: value}``, dotted names as dotted keys (``ffmpc_ros.graph_nodes.write_graph_params``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from fnmatch import fnmatchcase
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterException
from rclpy.node import Node
from rclpy.parameter import Parameter

from ffmpc_core.config import FORMULATIONS, LIVE_COST_WEIGHTS, CostWeights
from ffmpc_core.errors import ConfigError
from ffmpc_core.impact.scenario import IMPACT_SCHEMA, ImpactStudyConfig
from ffmpc_core.scenario import (
    DELAY,
    FLOAT,
    FLOAT_OR_FLOATS,
    FLOATS,
    INT,
    PHASE_WEIGHT_NAMES,
    SCENARIO_SCHEMA,
    SCHEMA,
    ParamSpec,
    Scenario,
    config_error,
    scenario_from_flat,
)
from ffmpc_core.tasks import PhaseWeights

INF = 1e300  # "no upper bound" for FloatingPointRange


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
    #: ROS names (``fnmatch`` patterns) of the scenario parameters the node applies in place
    #: while it runs: writable, every other one read-only.
    live: tuple[str, ...] = ()
    #: Names (``fnmatch`` patterns) of :data:`~ffmpc_core.impact.scenario.IMPACT_SCHEMA`, the
    #: impact study's parameters, the node declares under their dotted names (read-only,
    #: descriptors generated from the schema; :func:`impact_config_from_parameters`).
    impact: tuple[str, ...] = ()

    @property
    def graph_parameters(self) -> tuple[GraphParameter, ...]:
        """Every graph parameter the node declares: its own and :data:`COMMON_GRAPH`."""
        return (*self.graph, *COMMON_GRAPH)

    def is_live(self, ros_name: str) -> bool:
        """Whether the node changes ``ros_name`` while it runs (see :attr:`live`)."""
        return any(fnmatchcase(ros_name, pattern) for pattern in self.live)


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
START_CLOCK_SUBSCRIBERS = GraphParameter(
    "start_clock_subscribers",
    0,
    "lockstep start barrier: /clock readers of the whole graph, two per member (every node, "
    "the graph's recorder): a node declares itself ready (a reader of lockstep/ready) once it "
    "has discovered every member's lockstep/member marker and each of its writers has matched "
    "every compatible reader discovered on its topic; the plant also waits for that many /clock "
    "readers before its first state (0: no barrier)",
    (0, 1000),
)
START_NODES = GraphParameter(
    "start_nodes",
    0,
    "lockstep start barrier: nodes of the graph, the plant included, whose lockstep/ready "
    "reader the plant waits for before its first state (each node's writers are then matched "
    "to every reader of the graph: nothing it sends is lost, with no replay)",
    (0, 1000),
)

AUTOSTART = GraphParameter(
    "autostart",
    True,
    "configure and activate the node as soon as it is built (false: it stays unconfigured "
    "until a lifecycle transition, `ros2 lifecycle set NODE configure` then `activate`, or "
    "the bring-up's)",
)
RESULTS_FILE = GraphParameter(
    "results_file",
    "",
    "where the node writes what it hands back as it exits (its rejected-input counts; "
    "ffmpc_ros.node_results; the bring-up sets it; empty: nowhere)",
)
#: Graph parameters every node declares (lifecycle start, ffmpc_ros.base; the results file).
COMMON_GRAPH: tuple[GraphParameter, ...] = (AUTOSTART, START_CLOCK_SUBSCRIBERS, RESULTS_FILE)

WAIT_FOR_METRICS = GraphParameter(
    "wait_for_metrics",
    False,
    "lockstep: start only after the metrics node announced /metrics/ready",
)

INTERFACES = GraphParameter(
    "interfaces",
    "ffmpc",
    "the node's topics: ffmpc (its own: ffmpc_msgs/MpcCommand, pid/motor_torque) or "
    "ros2_control (linear_feedback_controller_msgs Control and Sensor on "
    "linear_feedback_controller/{control,sensor}, efforts on effort_controller/commands, "
    "joint_states; msgs_notes/topics.md)",
)
LOW_LEVEL = GraphParameter(
    "low_level",
    "pid",
    "the graph's low-level node whose torques are recorded: pid (pid/desired_torque, "
    "pid/motor_torque) or lfc (the LFC-law node's lfc/effort)",
)
TRANSITION_DURATION = GraphParameter(
    "pd_to_lf_transition_duration",
    0.1,
    "s, linear transition from the safe hold to the law once controls arrive after hold "
    "torques were sent (upstream's parameter of the same name)",
    (0.0, 10.0),
)
REMOVE_GRAVITY = GraphParameter(
    "remove_gravity_compensation_effort",
    False,
    "subtract g(q) from the effort sent (drives that add gravity compensation themselves: "
    "Panda, KUKA FRI torque mode; upstream's parameter of the same name)",
)

_TIME_STEP = ("plant.time_step",)
_CONTACT = ("mpc.contact.dimension", "mpc.contact.normal_axis", "mpc.contact.frame_type")
#: The tool on the flange (the controllers' load data, the wrist F/T sensor's weighed tool).
_TOOL = ("plant.tool_mass", "plant.tool_center_of_mass")

# -- the impact nodes (Dehio & Kheddar 2020) and the MPC's use of the learned contact ----------
# The impact study's values (target force, planner, prior, admittance, learner, touch-first, …)
# are IMPACT_SCHEMA's, declared by NodeSpec.impact under the schema's dotted names; the graph
# parameters below are the nodes' own settings, not part of the impact study's scenario.
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
REAL_TIME_ITERATIONS = GraphParameter(
    "real_time_iterations",
    1,
    "real time only (lockstep false): SQP iterations of the constrained solver (SolverCSQP) "
    "per solve, at most: 1, one per MPC tick (the real-time iteration scheme), keeps the "
    "constrained solve inside the 2 ms period; 0: mpc.max_iterations, as lockstep",
    (0, 1000),
)
USE_LEARNED_CONTACT = GraphParameter(
    "use_learned_contact",
    False,
    "force-feedback: take K, B live from /contact_learner/estimate when it is confident",
)
#: The impact planner's graph parameters (its impact-study values: :data:`IMPACT_PLANNER_SCHEMA`).
IMPACT_PLANNER_GRAPH: tuple[GraphParameter, ...] = (
    DIRECTION,
    GraphParameter(
        "acceleration_limit",
        Parameter.Type.DOUBLE_ARRAY,
        "q̈_max per joint, rad/s² (unset: the Panda data sheet; required for other robots)",
    ),
    GraphParameter("n_directions", 8, "eq 10 weight directions (vertices)", (3, 64)),
    GraphParameter(
        "max_approach_velocity", 0.0, "cap on the approach speed, m/s (0: none)", (0.0, 100.0)
    ),
    GraphParameter(
        "use_learned_material",
        False,
        "strategy prior: plan with /contact_learner/estimate once it is confident (false: the "
        "prior only, the paper's scheme; touch_first and strike_first need false)",
    ),
)
#: The IMPACT_SCHEMA names the impact planner declares: what its controller
#: (``ffmpc_core.impact.scenario.task_config``'s ``controller``), its limits, its prior and the
#: touch-first and strike-first strategies (and the dice's surface the latter is given) are
#: built from.
IMPACT_PLANNER_SCHEMA: tuple[str, ...] = (
    "plant.time_step",
    "plant.dice_max_penetration",
    "planner.*",
    "target_force",
    "contact_threshold",
    "replan_period",
    "limit_margin",
    "admittance.*",
    "learner.*",
    "strategy",
    "touch.*",
    "strike.*",
    "plant.dice_position_xy",
    "plant.dice_top_height",
)
#: The IMPACT_SCHEMA names the dice plant declares: the scene (the dice, the tool, the plant
#: step), the start pose (``approach_height`` above the dice) and the run's ``duration``.
DICE_PLANT_SCHEMA: tuple[str, ...] = ("plant.*", "approach_height", "duration")
#: The contact learner's graph parameters (and IMPACT_SCHEMA's ``contact_threshold``, the
#: pressing force along d that ends the search for the surface, N).
CONTACT_LEARNER_GRAPH: tuple[GraphParameter, ...] = (
    DIRECTION,
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
    GraphParameter(
        "planner_gate",
        False,
        "feed the samples the impact planner's touch-first phases select (its reference's "
        "learning gate of the previous cycle; lockstep) instead of the surface rule above",
    ),
)

# -- the impact graph (``ffmpc run impact``): the dice plant and the impact controller build
# their configuration from the impact study's scenario (ffmpc_core.impact.scenario's
# IMPACT_SCHEMA), so that the graph and the ROS-free run are built from the one declaration.
APPROACH = GraphParameter("approach", "maximal", "approach before contact: maximal or baseline")
REGULATION = GraphParameter(
    "regulation", "admittance", "regulation after contact: admittance or ff_mpc"
)
EXIT_WHEN_DONE = GraphParameter(
    "exit_when_done",
    False,
    "exit 1 s (wall) after the last state (a launch file's on_exit: shutdown ends the run)",
)
MEASURE_MOMENTS = GraphParameter(
    "measure_moments",
    False,
    "also measure the moments of the wrench (with the force's delay, no noise): the impact "
    "controller compensates the whole wrench",
)

# -- the state publisher (robot_state_publisher's parameters, ffmpc_ros.state_publisher_node) ----
PUBLISH_FREQUENCY = GraphParameter(
    "publish_frequency",
    100.0,
    "/tf rate, Hz of simulated time: the first joint state at or after each k/f s "
    "(robot_state_publisher's parameter; at most the joint-state rate)",
    (1e-3, 1e6),
)
FRAME_PREFIX = GraphParameter(
    "frame_prefix",
    "",
    "prefix of every frame id of /tf and /tf_static (robot_state_publisher's parameter, e.g. "
    "arm1/; a namespaced graph has its own /tf already)",
)
#: The MPC's live parameters: contact K (N/m) and B (N·s/m), the force set-point (N), the
#: position offset (m) and the cost weights it can change in place (of the formulation it runs).
MPC_LIVE: tuple[str, ...] = (
    "contact.stiffness",
    "contact.damping",
    "task.normal_force",
    "position_offset",
    *(f"weights.*.{name}" for name in (*LIVE_COST_WEIGHTS, *PHASE_WEIGHT_NAMES)),
)
#: The PID's live parameters: the gains of eq 33 and the low level's limits (the saturation, a
#: fraction of the data-sheet torque limits, and the command timeout of the safe hold).
PID_LIVE: tuple[str, ...] = ("kp", "ki", "kd", "torque_limit_fraction", "stale_timeout")

NODE_SPECS: dict[str, NodeSpec] = {
    "plant": NodeSpec(
        "plant",
        "plant",
        ("robot", "seed", "task.*"),
        (),
        (
            LOCKSTEP,
            DURATION,
            START_DELAY,
            START_SUBSCRIBERS,
            START_NODES,
            WAIT_FOR_METRICS,
            MAX_AGE,
            INTERFACES,
        ),
    ),
    "joint_sensor": NodeSpec(
        "joint_sensor", "joint_sensor", ("robot", "seed"), _TIME_STEP, (MAX_AGE,)
    ),
    "ft_sensor": NodeSpec(
        "ft_sensor",
        "ft_sensor",
        ("robot", "seed"),
        _TIME_STEP + _CONTACT + _TOOL + ("joint_sensor.position_noise_std",),
        (MAX_AGE, MEASURE_MOMENTS),
    ),
    "mpc": NodeSpec(
        "mpc",
        "mpc",
        ("robot", "task.*"),
        _TIME_STEP + _TOOL + ("pid.delay_cycles",),
        (
            LOCKSTEP,
            MAX_AGE,
            REAL_TIME_ITERATIONS,
            USE_LEARNED_CONTACT,
            LEARNER_MIN_SAMPLES,
            LEARNER_MAX_RELATIVE_STD,
            INTERFACES,
        ),
        MPC_LIVE,
    ),
    "pid": NodeSpec(
        "pid",
        "pid",
        ("robot",),
        _TIME_STEP + _CONTACT + _TOOL + ("mpc.period", "mpc.formulation", "mpc.riccati_feedback"),
        (LOCKSTEP, LOCKSTEP_TIMEOUT, MAX_AGE, INTERFACES, REMOVE_GRAVITY),
        PID_LIVE,
    ),
    # the linear_feedback_controller's law (ffmpc_ros.lfc_node): the PID's place in a graph
    # with ros2_control interfaces; its safe hold is the low level's (pid.hold_*)
    "lfc": NodeSpec(
        "lfc",
        None,
        ("robot",),
        _TIME_STEP + _CONTACT + ("mpc.period", "mpc.formulation", "mpc.riccati_feedback", "pid.*"),
        (
            LOCKSTEP,
            LOCKSTEP_TIMEOUT,
            MAX_AGE,
            TRANSITION_DURATION,
            REMOVE_GRAVITY,
        ),
    ),
    "metrics": NodeSpec(
        "metrics",
        None,
        ("robot", "seed", "task.*"),
        _TIME_STEP + _CONTACT + ("mpc.formulation",),
        (DURATION, LOCKSTEP, LOW_LEVEL),
    ),
    "state_publisher": NodeSpec(
        "state_publisher",
        None,
        ("robot",),
        _TIME_STEP,
        (MAX_AGE, PUBLISH_FREQUENCY, FRAME_PREFIX),
    ),
    "impact_planner": NodeSpec(
        "impact_planner",
        None,
        ("robot",),
        (),
        (LOCKSTEP, LOCKSTEP_TIMEOUT, MAX_AGE, *IMPACT_PLANNER_GRAPH),
        impact=IMPACT_PLANNER_SCHEMA,
    ),
    "contact_learner": NodeSpec(
        "contact_learner",
        None,
        ("robot",),
        (),
        (MAX_AGE, *CONTACT_LEARNER_GRAPH),
        impact=("plant.time_step", "contact_threshold"),
    ),
    "dice_plant": NodeSpec(
        "dice_plant",
        None,
        ("robot",),
        (),
        (
            LOCKSTEP,
            START_DELAY,
            START_SUBSCRIBERS,
            START_NODES,
            MAX_AGE,
            EXIT_WHEN_DONE,
        ),
        impact=DICE_PLANT_SCHEMA,
    ),
    "impact_controller": NodeSpec(
        "impact_controller",
        None,
        ("robot",),
        (),
        (
            LOCKSTEP,
            LOCKSTEP_TIMEOUT,
            MAX_AGE,
            APPROACH,
            REGULATION,
        ),
        impact=("*",),
    ),
}


def _weight_defaults() -> dict[str, Any]:
    """mpc.weights.<formulation>.<name> for every formulation, with the dataclass defaults."""
    out: dict[str, Any] = {}
    for form in FORMULATIONS:
        for f in fields(CostWeights):
            out[f"mpc.weights.{form}.{f.name}"] = getattr(CostWeights(), f.name)
        out[f"mpc.weights.{form}.force_phase"] = PhaseWeights.force
        out[f"mpc.weights.{form}.ee_position_phase"] = PhaseWeights.contact_ee_position
    return out


def scenario_flat(scenario: Scenario) -> dict[str, Any]:
    """The scenario as dotted scenario names (``plant.time_step``, ``robot``, ``task.reach``),
    with every MPC weight present."""
    flat = SCENARIO_SCHEMA.flatten(scenario)
    weights = _weight_defaults()
    weights.update({k: v for k, v in flat.items() if k.startswith("mpc.weights.")})
    for form in FORMULATIONS:  # c4 in free space follows c4 in contact unless set
        weights[f"mpc.weights.{form}.ee_position_free"] = scenario.mpc.phase_weights(
            form
        ).free_ee_position
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


def sharing_nodes(node: str, ros_name: str, nodes: Sequence[str]) -> tuple[str, list[str]]:
    """``(scenario name, other nodes)``: the scenario parameter node ``node``'s ROS parameter
    ``ros_name`` holds and the other nodes among ``nodes`` that declare it too (``("", [])``
    for a name that is no scenario parameter of the node)."""
    flat = scenario_flat(Scenario(name="names"))
    scenario_name = node_scenario_names(NODE_SPECS[node], flat).get(ros_name)
    if scenario_name is None:
        return "", []
    others = [
        other
        for other in nodes
        if other != node
        and other in NODE_SPECS
        and scenario_name in node_scenario_names(NODE_SPECS[other], flat).values()
    ]
    return scenario_name, others


#: Names of both schemas: an impact node declares them from IMPACT_SCHEMA and its
#: :class:`Scenario` (the node's clock grid, ffmpc_ros.base) takes the value too.
_IMPACT_IN_SCENARIO = ("plant.time_step",)


def node_impact_names(spec: NodeSpec) -> list[str]:
    """The :data:`IMPACT_SCHEMA` names a node declares (:attr:`NodeSpec.impact`), in the
    schema's order; ConfigError for a pattern that matches none."""
    names = list(IMPACT_SCHEMA.params)
    for pattern in spec.impact:
        if not any(fnmatchcase(n, pattern) for n in names):
            raise ConfigError(f"no impact-study parameter {pattern!r}")
    return [n for n in names if any(fnmatchcase(n, p) for p in spec.impact)]


def impact_flat(config: ImpactStudyConfig | None = None) -> dict[str, Any]:
    """{IMPACT_SCHEMA name: ROS value} of ``config`` (default: the schema's defaults); tuples
    as lists of floats."""
    flat = IMPACT_SCHEMA.flatten(ImpactStudyConfig() if config is None else config)
    return {name: _ros_value(value) for name, value in flat.items()}


def impact_parameter_values(node: str, config: ImpactStudyConfig) -> dict[str, Any]:
    """{IMPACT_SCHEMA name: value} of ``config`` that node ``node`` declares
    (:attr:`NodeSpec.impact`) and that differ from the schema's defaults (the declared ones),
    and always the clock grid (``plant.time_step``, also the node's :class:`Scenario`'s): what
    ``ffmpc run impact`` passes from the loaded scenario, and what a launch file lists."""
    study, defaults = impact_flat(config), impact_flat()
    names = node_impact_names(NODE_SPECS[node])
    return {
        name: study[name]
        for name in names
        if study[name] != defaults[name] or name in _IMPACT_IN_SCENARIO
    }


def node_parameter_values(node: str, scenario: Scenario, **graph: Any) -> dict[str, Any]:
    """{ROS name: value} that makes node ``node`` run ``scenario`` (what ``ffmpc run`` passes),
    plus graph parameters (``lockstep=False``…) and impact-study values given by their
    IMPACT_SCHEMA names (``**{"planner.horizon": 10}``; :func:`impact_parameter_values`)."""
    spec = NODE_SPECS[node]
    flat = scenario_flat(scenario)
    values = {ros: _ros_value(flat[name]) for ros, name in node_scenario_names(spec, flat).items()}
    impact_names = node_impact_names(spec)
    known = {g.name for g in spec.graph_parameters} | set(impact_names)
    for key, value in graph.items():
        if key in known:
            values[key] = value
    return values


def _ros_value(value: Any) -> Any:
    return [float(v) for v in value] if isinstance(value, tuple) else value


def descriptor(
    name: str,
    value: Any,
    description: str = "",
    limits: tuple[float, float] | None = None,
) -> ParameterDescriptor:
    """A read-only ParameterDescriptor of a graph parameter: description and, for numbers,
    a range."""
    desc = ParameterDescriptor(read_only=True, description=description)
    if isinstance(value, bool) or limits is None:
        return desc
    if isinstance(value, int):
        desc.integer_range = [IntegerRange(from_value=int(limits[0]), to_value=int(limits[1]))]
    elif isinstance(value, float):
        desc.floating_point_range = [_float_range(limits)]
    return desc


def _float_range(limits: tuple[float, float]) -> FloatingPointRange:
    lo, hi = (max(min(float(x), INF), -INF) for x in limits)
    return FloatingPointRange(from_value=lo, to_value=hi)


def scenario_descriptor(spec: ParamSpec, live: bool = False) -> ParameterDescriptor:
    """The ROS descriptor of a scenario parameter, generated from its :data:`SCHEMA` entry;
    read-only unless ``live`` (the node applies it while it runs).

    bool, int and str parameters have their ROS type (ints an integer range); numbers are
    dynamically typed (an integer is a number, as in a scenario file: ``normal_force:=60``)
    with a floating-point range, and lists (per axis, per joint) are dynamically typed with the
    range of each entry (rclpy applies it to a single number; the node checks lists). The
    node checks every value against the schema when it starts (:func:`scenario_from_parameters`),
    so rclpy and the ROS-free runner accept and refuse the same values."""
    unit = f", {spec.unit}" if spec.unit else ""
    desc = ParameterDescriptor(read_only=not live, description=spec.description + unit)
    desc.additional_constraints = f"{spec.expected()}"
    if spec.kind == INT:
        values = spec.range or (min(spec.choices), max(spec.choices))
        desc.integer_range = [IntegerRange(from_value=int(values[0]), to_value=int(values[1]))]
    elif spec.kind in (FLOAT, FLOATS, FLOAT_OR_FLOATS):
        desc.dynamic_typing = True
        if spec.range is not None:
            desc.floating_point_range = [_float_range(spec.range)]
    elif spec.kind == DELAY:
        desc.dynamic_typing = True
    return desc


def _raw_override(node: Node, ros: str) -> Any:
    """The value given for ``ros`` (``-p``, ``--params-file`` or ``parameter_overrides``)."""
    given = getattr(node, "_parameter_overrides", {}).get(ros)
    return None if given is None else plain_value(given.value)


def plain_value(value: Any) -> Any:
    """A ROS parameter value as plain Python (array.array → list)."""
    return list(value) if type(value).__name__ == "array" else value


def declare_node_parameters(node: Node, spec: NodeSpec) -> dict[str, Any]:
    """Declare every parameter of ``spec`` on an rclpy node; returns {ROS name: value}.

    A value rclpy refuses (wrong type, out of range) raises the schema's ConfigError
    (``name = value: expected …``), the message the ROS-free runner gives for it. A ``base``
    (a scenario file's ``/**: {base: polishing}``) makes that scenario's values the defaults,
    as the runner merges such a file over its base
    (:func:`ffmpc_core.scenario.read_parameter_file`)."""
    flat = scenario_flat(_base_scenario(node, spec))
    values: dict[str, Any] = {}
    for ros, name in node_scenario_names(spec, flat).items():
        default = _ros_value(flat[name])
        try:
            node.declare_parameter(
                ros, default, scenario_descriptor(SCHEMA[name], spec.is_live(ros))
            )
        except ParameterException:
            raw = _raw_override(node, ros)
            SCHEMA[name].check(raw)  # raises the schema's error
            raise SCHEMA[name].error(raw) from None
        values[ros] = plain_value(node.get_parameter(ros).value)
    impact_defaults = impact_flat() if spec.impact else {}
    for name in node_impact_names(spec):
        param = IMPACT_SCHEMA.params[name]
        try:
            node.declare_parameter(name, impact_defaults[name], scenario_descriptor(param))
        except ParameterException:
            raw = _raw_override(node, name)
            param.check(raw)  # raises the schema's error
            raise param.error(raw) from None
        values[name] = plain_value(node.get_parameter(name).value)
    for g in spec.graph_parameters:
        # (the declared Parameter: get_parameter raises for one declared by type and not set)
        try:
            declared = node.declare_parameter(
                g.name, g.default, descriptor(g.name, g.default, g.description, g.range)
            )
        except ParameterException:
            raise config_error(g.name, _raw_override(node, g.name), _graph_expected(g)) from None
        values[g.name] = declared.value
    return values


def _base_scenario(node: Node, spec: NodeSpec) -> Scenario:
    """The scenario whose values the node's scenario parameters default to: the one its
    ``base`` parameter names (the scenario file's ``/**: {base: ...}``), else the schema's
    defaults. ConfigError for a base the runner would not load the same way."""
    from ffmpc_core.scenario import BASE_KEY, base_scenario_path, load_scenario

    declared = node.declare_parameter(
        BASE_KEY,
        "",
        ParameterDescriptor(
            read_only=True,
            description="the scenario this node's scenario file changes (a shipped name or an "
            "absolute path; empty: none): its values are the defaults",
        ),
    )
    base = declared.value
    if not isinstance(base, str):
        raise config_error(BASE_KEY, base, "a scenario name or an absolute path")
    if not base.strip():
        return Scenario(name="defaults")
    if spec.impact:
        raise config_error(BASE_KEY, base, "nothing: the impact nodes take no base scenario")

    return load_scenario(base_scenario_path(base))


def check_node_parameter(node: str, name: str, value: Any) -> None:
    """ConfigError (one line, the schema's ``name = value: expected …``) unless node ``node``
    declares parameter ``name`` and would take ``value`` (ROS typed, as rcl reads ``-p
    name:=value``: :func:`ffmpc_core.values.load_value`): the check ``ffmpc run --node-param``
    and ``ffmpc launch`` make before any node starts, with the node's own rules (scenario
    names by :data:`SCHEMA`, the impact study's by ``IMPACT_SCHEMA``, graph parameters by
    their type and range). QoS override parameters are left to rclpy (it refuses them at
    start, one line)."""
    from ffmpc_core.scenario import BASE_KEY

    spec = NODE_SPECS.get(node)
    if spec is None:
        raise ConfigError(f"no node {node!r} (nodes: {', '.join(NODE_SPECS)})")
    if name.startswith("qos_overrides.") or name == BASE_KEY:
        return
    if name == "use_sim_time":
        if value is not True:
            raise config_error(name, value, "true (every ffmpc node runs on simulated time)")
        return
    scenario_names = node_scenario_names(spec, scenario_flat(Scenario(name="defaults")))
    graph = {g.name: g for g in spec.graph_parameters}
    if name in scenario_names:
        param = SCHEMA[scenario_names[name]]
    elif name in node_impact_names(spec):
        param = IMPACT_SCHEMA.params[name]
    elif name in graph:
        _check_graph_value(graph[name], value)
        return
    else:
        raise ConfigError(f"{name} = {value!r}: node {node} has no such parameter")
    try:
        param.check(value)
    except ConfigError as exc:
        raise ConfigError(str(exc).replace(param.name, name, 1)) from None


def declares(node: str, name: str) -> bool:
    """Whether node ``node`` declares parameter ``name`` (a value for another name in a
    parameter file that reaches it is ignored by rclpy, as by ROS)."""
    from ffmpc_core.scenario import BASE_KEY

    spec = NODE_SPECS[node]
    scenario_names = node_scenario_names(spec, scenario_flat(Scenario(name="defaults")))
    return (
        name in scenario_names
        or name in node_impact_names(spec)
        or name in {g.name for g in spec.graph_parameters}
        or name in (BASE_KEY, "use_sim_time")
    )


def _check_graph_value(g: GraphParameter, value: Any) -> None:
    """A graph parameter's value as rclpy would take it: the default's type, within the range."""
    default = g.default
    if isinstance(default, bool):
        ok = isinstance(value, bool)
    elif isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif isinstance(default, float):
        ok = isinstance(value, float)
    elif isinstance(default, str):
        ok = isinstance(value, str)
    else:
        ok = isinstance(value, list) and all(
            isinstance(v, float) and not isinstance(v, bool) for v in value
        )
    if ok and g.range is not None and isinstance(value, int | float):
        ok = g.range[0] <= value <= g.range[1]
    if not ok:
        raise config_error(g.name, value, _graph_expected(g))


def _graph_expected(g: GraphParameter) -> str:
    """What a graph parameter must be, in words."""
    if isinstance(g.default, bool):
        return "true or false"
    if isinstance(g.default, str):
        return "a string"
    if isinstance(g.default, list) or not isinstance(g.default, int | float):
        return "a list of numbers"
    kind = "an integer" if isinstance(g.default, int) else "a number (with a decimal point)"
    span = f" in [{g.range[0]:g}, {g.range[1]:g}]" if g.range else ""
    return kind + span


def scenario_from_parameters(spec: NodeSpec, values: dict[str, Any], name: str) -> Scenario:
    """The Scenario a node runs: its slice of the scenario (its parameter values under their
    scenario names) built by :func:`ffmpc_core.scenario.scenario_from_flat` over the schema's
    defaults, with the checks and cross-section rules of a scenario file; what the node does
    not declare keeps its default (nothing of it is read)."""
    mapping = node_scenario_names(spec, scenario_flat(Scenario(name="names")))
    flat = {scenario_name: plain_value(values[ros]) for ros, scenario_name in mapping.items()}
    for shared in _IMPACT_IN_SCENARIO:
        if shared in node_impact_names(spec):
            flat[shared] = plain_value(values[shared])
    return scenario_from_flat(name, flat)


def impact_config_from_parameters(
    spec: NodeSpec, values: dict[str, Any], base: ImpactStudyConfig | None = None
) -> ImpactStudyConfig:
    """The impact study's configuration of a node: ``base`` (default: the schema's defaults)
    with the node's :data:`IMPACT_SCHEMA` parameter values (those in ``values``: a node has all
    it declares, :func:`impact_parameter_values` the changed ones), built by ``IMPACT_SCHEMA.build``
    (the validation of ``ffmpc study impact --set``: same ConfigError, ``name = value: …``,
    same cross-field checks)."""
    names = node_impact_names(spec)
    return IMPACT_SCHEMA.build({n: plain_value(values[n]) for n in names if n in values}, base)


def parameter_overrides(values: dict[str, Any]) -> list[Parameter]:
    """rclpy Parameter objects for ``Node(parameter_overrides=…)``."""
    return [Parameter(k, value=v) for k, v in values.items()]
