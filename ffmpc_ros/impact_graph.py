"""Bring-up of the impact graph (``ffmpc run impact``): the safe-maximal-impact experiment of
Dehio & Kheddar 2020 (Sec. VI) as separate node processes in lockstep.

Nodes (each its own process, started like the polishing graph's, ``ffmpc_ros.bringup``):

* ``dice_plant`` (:mod:`ffmpc_ros.dice_plant_node`): the Panda and the soft dice in PyBullet,
  ``/clock``;
* ``joint_sensor`` and ``ft_sensor``: the polishing graph's sensor nodes, without noise or delay
  (the ROS-free impact study measures the true state), the F/T sensor measuring the three
  forces and the moments (``measure_moments``);
* ``impact_planner`` (maximal approach only): eq 9–14 every 1 ms cycle, its Cartesian
  command on ``impact_planner/reference``;
* ``contact_learner``: eq 19–21 from the first contact on;
* ``impact_controller`` (:mod:`ffmpc_ros.impact_controller_node`): the joint-limit guard and
  task-space law, the admittance task or the baseline approach, and the hand-over to the
  force-feedback MPC (inside it: see that module); its torque goes to the plant.

Every impact node declares the impact study's values it uses under the schema's names
(``IMPACT_SCHEMA``: ``target_force``, ``planner.horizon``, ``touch.touch_force``, …;
``ffmpc_ros.params.NodeSpec.impact``), which
:func:`impact_node_parameters` fills from the loaded scenario, and rebuild the configuration
with ``IMPACT_SCHEMA.build`` and the controller with ``task_config`` (the ROS-free run's
functions); the sensors get parameters derived from it. Each node calls the same core objects in
the same order as ``studies.impact_study.run_impact`` with the same numbers (ROS carries float64
exactly), so the metrics are the ROS-free run's bit for bit (tests/test_impact_graph.py).

The bring-up's own node reads the plant's true state and wrench, the controller's status and
the learner's estimates, computes the metrics with ``ffmpc_core.impact.metrics.run_metrics`` (the
ROS-free run's code), and publishes them once on ``impact_graph/summary`` (std_msgs/String,
JSON) — the last topic of the bag with ``record``.

The bring-up runs in the polishing graph's steps (``ffmpc_ros.bringup.NodeSession``):
:func:`plan_impact_graph` checks the options and works out every node's parameters before
anything starts, then an :class:`ImpactSession` spawns, brings up, records, runs, summarizes,
stops and collects.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, is_dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from builtin_interfaces.msg import Time as TimeMsg
from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from ffmpc_core.errors import ConfigError
from ffmpc_core.scenario import Scenario
from ffmpc_ros import layouts, topics
from ffmpc_ros.bringup import GraphError, GraphOutputs, NodeSession, ProgressWatch
from ffmpc_ros.discovery import domain_id as _env_domain_id
from ffmpc_ros.params import impact_parameter_values, node_parameter_values

if TYPE_CHECKING:
    from ffmpc_core.impact.scenario import ImpactStudyConfig
    from ffmpc_core.robots import RobotModel

#: The impact graph's nodes: name → "module:class" (the planner only for the maximal approach).
IMPACT_NODES: dict[str, str] = {
    "dice_plant": "ffmpc_ros.dice_plant_node:DicePlantNode",
    "joint_sensor": "ffmpc_ros.joint_sensor_node:JointSensorNode",
    "ft_sensor": "ffmpc_ros.ft_sensor_node:FtSensorNode",
    "impact_planner": "ffmpc_ros.impact_planner_node:ImpactPlannerNode",
    "contact_learner": "ffmpc_ros.contact_learner_node:ContactLearnerNode",
    "impact_controller": "ffmpc_ros.impact_controller_node:ImpactControllerNode",
    "state_publisher": "ffmpc_ros.state_publisher_node:StatePublisherNode",
}
#: The robot of the experiment.
ROBOT = "panda"
#: The approach direction d (``ffmpc_core.impact.scenario.DOWN``), world frame.
DOWN = (0.0, 0.0, -1.0)
#: Metrics compared between the graph and the ROS-free run (``ImpactRun`` fields).
COMPARED = (
    "contact_time",
    "pre_impact_velocity",
    "steady_time",
    "peak_force",
    "peak_penetration",
    "final_force",
    "final_force_error",
    "violations",
    "learned_stiffness",
    "learned_damping",
    "learner_samples",
    "handover_time",
    "stopped_short",
)
#: ... and with a learning strategy (touch-first's exploratory touch; both: the decision).
COMPARED_TOUCH = (
    "touch_time",
    "touch_velocity",
    "touch_peak_force",
    "touch_peak_penetration",
    "decision_time",
)


def graph_nodes(approach: str) -> dict[str, str]:
    """The nodes of a run: every node of :data:`IMPACT_NODES`, the planner only for the
    maximal approach (the baseline plans nothing)."""
    return {n: c for n, c in IMPACT_NODES.items() if n != "impact_planner" or approach == "maximal"}


def _same(a: Any, b: Any) -> bool:
    """Equality of configurations (dataclasses, arrays, floats with NaN)."""
    if is_dataclass(a) and is_dataclass(b) and type(a) is type(b):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in fields(a))
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return bool(np.array_equal(np.asarray(a), np.asarray(b)))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return bool(a == b)


def check_approach(approach: str, regulation: str) -> None:
    """ConfigError for an approach or a regulation the impact study does not know."""
    from ffmpc_core.impact.controllers import APPROACHES, REGULATIONS

    if approach not in APPROACHES or regulation not in REGULATIONS:
        raise ConfigError(
            f"approach must be one of {APPROACHES} and regulation one of {REGULATIONS}, got "
            f"{approach!r}, {regulation!r}"
        )


def load_run_config(scenario: str, overrides: Sequence[str]) -> ImpactStudyConfig:
    """The impact study's configuration of ``scenario`` with NAME=VALUE ``overrides``
    (ConfigError: the schema's message)."""
    from ffmpc_core.impact.scenario import IMPACT_SCHEMA, load_impact_config
    from ffmpc_ros.cli_args import parse_overrides

    items = [str(i) for i in overrides]
    return load_impact_config(scenario, parse_overrides(items, schema=IMPACT_SCHEMA.params))


def is_learning(approach: str, cfg: ImpactStudyConfig) -> bool:
    """The run learns the material before the strike (maximal approach, touch-first or
    strike-first): the planner gates the learner's samples and reports its touch."""
    from ffmpc_core.impact.scenario import LEARNING_STRATEGIES

    return approach == "maximal" and cfg.strategy in LEARNING_STRATEGIES


def sensing_scenario(time_step: float) -> Scenario:
    """The polishing scenario the sensor nodes take their parameters from: the ROS-free study
    measures the true state and the whole world wrench (no delay, no noise, 3-D contact)."""
    return Scenario(name="impact_graph").with_overrides(
        {
            "robot": ROBOT,
            "plant.time_step": time_step,
            "joint_sensor.delay_cycles": 0,
            "joint_sensor.position_noise_std": 0.0,
            "joint_sensor.velocity_noise_std": 0.0,
            "ft_sensor.delay_cycles": 0,
            "ft_sensor.force_noise_std": 0.0,
            "mpc.contact.dimension": 3,
        }
    )


def _plant_and_sensor_values(
    cfg: ImpactStudyConfig, sensing: Scenario, record: bool
) -> dict[str, dict]:
    """The dice plant's, the sensors' and the state publisher's parameters."""
    common = {"robot": ROBOT, "plant.time_step": cfg.time_step}
    return {
        "dice_plant": {
            **common,
            **impact_parameter_values("dice_plant", cfg),
            "lockstep": True,
            "start_delay": 0.0,
            # the joint sensor, the bring-up's probe and the recorder
            "start_subscribers": 2 + int(record),
        },
        "joint_sensor": node_parameter_values("joint_sensor", sensing),
        "state_publisher": dict(common),
        "ft_sensor": {**node_parameter_values("ft_sensor", sensing), "measure_moments": True},
    }


def _learner_values(cfg: ImpactStudyConfig, sensing: Scenario, learning: bool) -> dict:
    """The contact learner's parameters (eq 19-21, fed by the planner's gate when
    ``learning``)."""
    return {
        **node_parameter_values("contact_learner", sensing),
        **impact_parameter_values("contact_learner", cfg),
        "direction": list(DOWN),
        "surface_force": 0.0,  # the last force-free sample (ImpactTaskController's rule)
        "feed_force": 0.0,
        "skip_onset_samples": 0,
        "regularization": 1e-9,  # RecursiveContactLearner's default
        # touch-first, strike-first: the planner's feeding rule selects the samples (its gate)
        "planner_gate": learning,
        # no node waits for the learner before the touch: in lockstep it may fall behind the
        # plant's clock; its inputs stay usable as long as the publishers keep them (measured:
        # 54 ms behind at 0.6 s of a 46 cm approach, then every input of the touch rejected as
        # stale with the 0.05 s default, and the planner waited for estimates that never came)
        "max_input_age": topics.PUBLISHER_DEPTH * cfg.time_step,
    }


def _controller_values(cfg: ImpactStudyConfig, approach: str, regulation: str) -> dict:
    """The impact controller's parameters."""
    return {
        "robot": ROBOT,
        "plant.time_step": cfg.time_step,
        **impact_parameter_values("impact_controller", cfg),
        "lockstep": True,
        "approach": approach,
        "regulation": regulation,
    }


def _planner_values(cfg: ImpactStudyConfig, sensing: Scenario) -> dict:
    """The impact planner's parameters: the impact study's values under their IMPACT_SCHEMA
    names, from the loaded scenario (the node rebuilds the configuration and its controller
    from them with the ROS-free run's IMPACT_SCHEMA.build and task_config)."""
    from ffmpc_core.impact.limits import PANDA_ACCELERATION_LIMIT

    return {
        **node_parameter_values("impact_planner", sensing),
        **impact_parameter_values("impact_planner", cfg),
        "lockstep": True,
        "direction": list(DOWN),
        # the Panda's data-sheet values, given: the bag's parameters then show the limits the
        # run used (unset, the node takes the same values and the bag records null)
        "acceleration_limit": [float(a) for a in PANDA_ACCELERATION_LIMIT],
        "use_learned_material": False,  # the paper's scheme plans with the prior
    }


def add_start_barrier(params: dict[str, dict], record: bool) -> None:
    """The lockstep start barrier (``ffmpc_ros.start_barrier.StartBarrier.writers_matched``):
    every node waits to know every /clock reader, two per node (rclpy's and the node's
    reliable one) and the recorder's two; the plant waits for every node's token."""
    clock_readers = topics.CLOCK_READERS_PER_NODE * (len(params) + int(record))
    for values in params.values():
        values["start_clock_subscribers"] = clock_readers
    params["dice_plant"]["start_nodes"] = len(params)


def impact_node_parameters(
    approach: str,
    regulation: str,
    scenario: str = "impact",
    overrides: Sequence[str] = (),
    record: bool = False,
    namespace: str = topics.ROOT_NAMESPACE,
) -> tuple[Any, dict[str, dict]]:
    """(the ImpactStudyConfig, {node: {ROS name: value}}) of a run of the impact graph under
    ``namespace``, each node with the lockstep graph's QoS overrides
    (``topics.graph_qos_overrides``: reliable sensor topics; the start barrier, not a replay).

    The planner and the learner get the impact study's values under their IMPACT_SCHEMA names
    (``impact_parameter_values`` of the loaded configuration); ConfigError for a bad
    approach, regulation, scenario or override (the schema's message)."""
    check_approach(approach, regulation)
    cfg = load_run_config(scenario, overrides)
    sensing = sensing_scenario(cfg.time_step)
    params = _plant_and_sensor_values(cfg, sensing, record)
    params["contact_learner"] = _learner_values(cfg, sensing, is_learning(approach, cfg))
    params["impact_controller"] = _controller_values(cfg, approach, regulation)
    if approach == "maximal":
        params["impact_planner"] = _planner_values(cfg, sensing)
    assert sorted(params) == sorted(graph_nodes(approach)), params
    add_start_barrier(params, record)
    qos = topics.graph_qos_overrides(namespace)
    params = {name: {**values, **qos} for name, values in params.items()}
    # (no shared objects: the parameter file is YAML without aliases, which rcl refuses)
    return cfg, json.loads(json.dumps(params))


@dataclass
class ImpactGraphResult:
    """A run of the impact graph: its metrics (``run_metrics`` plus the learner's), the log and
    timing."""

    approach: str
    regulation: str
    metrics: dict[str, Any]
    log: dict[str, np.ndarray] = field(repr=False)
    sim_time: float = 0.0
    wall_time: float = 0.0
    startup_time: float = 0.0
    bag: dict | None = None
    safe: bool = False
    rejected: dict = field(default_factory=dict)
    plant_engine: str = "pybullet"  # the dice plant's simulator (plant.engine)

    @property
    def aborted(self) -> bool:
        """A reflex of the robot stopped it (``ffmpc_core.reflex``): the run was aborted."""
        return bool(self.metrics.get("aborted", False))

    @property
    def reflex_event(self) -> dict | None:
        """The reflex's event (``ReflexEvent.to_dict``), None without a crossing."""
        event: dict | None = (self.metrics.get("reflex") or {}).get("event")
        return event

    def summary(self) -> dict:
        return {
            "graph": "impact",
            "plant_engine": self.plant_engine,
            "approach": self.approach,
            "regulation": self.regulation,
            **json.loads(json.dumps(metrics_summary(self.metrics), default=float)),
            "safe": self.safe,
            "sim_time_s": self.sim_time,
            "wall_time_s": self.wall_time,
            "startup_time_s": self.startup_time,
            "rejected_messages": self.rejected,
            **({"bag": self.bag} if self.bag is not None else {}),
        }


def metrics_summary(metrics: dict[str, Any]) -> dict[str, Any]:
    """JSON-friendly metrics (violations as a dict with its total)."""
    from dataclasses import asdict

    out = dict(metrics)
    v = out.get("violations")
    if v is not None and is_dataclass(v):
        out["violations"] = {**asdict(v), "total": v.total}
    return out


class _Probe:
    """The bring-up's view of the run: the plant's true state and wrench, the controller's
    status and the learner's estimates, per cycle."""

    def __init__(
        self, node: Node, steps: int, nv: int, time_step: float, learning: bool = False
    ) -> None:
        self.steps, self.time_step = steps, time_step
        self.learning_strategy = learning
        self.q = np.full((steps + 1, nv), np.nan)
        self.v = np.full((steps + 1, nv), np.nan)
        self.wrench = np.full((steps + 1, 6), np.nan)
        self.tau = np.full((steps, nv), np.nan)
        self.status: dict[int, dict] = {}
        self.planner: dict | None = None  # the planner's newest status
        self.estimate: dict | None = None
        self.plant_status: dict | None = None  # the dice plant's newest (its reflex's event)
        self.cycle = -1

        def qos(topic: str) -> QoSProfile:
            return topics.graph_qos(topic, "subscription", True)

        node.create_subscription(
            JointState, topics.PLANT_JOINT_STATES, self._on_joints, qos(topics.PLANT_JOINT_STATES)
        )
        node.create_subscription(
            WrenchStamped, topics.PLANT_WRENCH, self._on_wrench, qos(topics.PLANT_WRENCH)
        )
        node.create_subscription(
            Float64MultiArray,
            topics.IMPACT_CONTROL_STATUS,
            self._on_status,
            qos(topics.IMPACT_CONTROL_STATUS),
        )
        node.create_subscription(
            Float64MultiArray,
            topics.CONTACT_ESTIMATE,
            self._on_estimate,
            qos(topics.CONTACT_ESTIMATE),
        )
        node.create_subscription(
            Float64MultiArray, topics.IMPACT_STATUS, self._on_planner, qos(topics.IMPACT_STATUS)
        )
        node.create_subscription(
            Float64MultiArray,
            topics.PLANT_STATUS,
            self._on_plant_status,
            topics.subscriber_qos(False, topics.PLANT_STATUS),
        )
        self.nv = nv

    def _k(self, stamp: TimeMsg) -> int:
        return int(round((stamp.sec * 1_000_000_000 + stamp.nanosec) * 1e-9 / self.time_step))

    def _on_joints(self, msg: JointState) -> None:
        k = self._k(msg.header.stamp)
        if 0 <= k <= self.steps:
            self.q[k], self.v[k] = msg.position, msg.velocity
            self.cycle = max(self.cycle, k)

    def _on_wrench(self, msg: WrenchStamped) -> None:
        k = self._k(msg.header.stamp)
        if 0 <= k <= self.steps:
            f, m = msg.wrench.force, msg.wrench.torque
            self.wrench[k] = (f.x, f.y, f.z, m.x, m.y, m.z)

    def _on_status(self, msg: Float64MultiArray) -> None:
        status = layouts.IMPACT_CONTROL.unpack(msg, nv=self.nv)
        k = int(round(status["t"] / self.time_step))
        if 0 <= k < self.steps:
            self.status[k] = status
            self.tau[k] = status["torque"]

    def _on_planner(self, msg: Float64MultiArray) -> None:
        status = layouts.IMPACT_STATUS.unpack(msg)
        if self.planner is None or status["t"] >= self.planner["t"]:
            self.planner = status

    def _on_plant_status(self, msg: Float64MultiArray) -> None:
        status = layouts.PLANT_STATUS.unpack(msg)
        if self.plant_status is None or status["t"] >= self.plant_status["t"]:
            self.plant_status = status

    def _on_estimate(self, msg: Float64MultiArray) -> None:
        estimate = layouts.CONTACT_ESTIMATE.unpack(msg)
        if int(round(estimate["t"] / self.time_step)) < self.steps:  # not the final state's
            self.estimate = estimate

    @property
    def complete(self) -> bool:
        """Every state, every controller cycle, and the learner's estimate after the last
        sample fed (the learner publishes from its third sample on)."""
        if len(self.status) < self.steps or np.isnan(self.q).any() or np.isnan(self.wrench).any():
            return False
        fed = int(self.status[self.steps - 1]["learner_samples"])
        if self.learning_strategy and (
            self.planner is None or int(round(self.planner["t"] / self.time_step)) < self.steps - 1
        ):
            return False
        return fed < 3 or (self.estimate is not None and self.estimate["samples"] == fed)


def _graph_metrics(
    cfg: ImpactStudyConfig, probe: _Probe, robot: RobotModel
) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """The run's metrics with the ROS-free run's code (``dice_measurement``, ``run_metrics``)."""
    from ffmpc_core.impact.limits import joint_limits
    from ffmpc_core.impact.metrics import run_metrics
    from ffmpc_core.impact.scenario import dice_measurement

    data = robot.create_data()
    steps = probe.steps
    log = {
        "t": np.arange(steps) * cfg.time_step,
        "speed": np.zeros(steps),
        "force": np.zeros(steps),
        "penetration": np.zeros(steps),
    }
    for k in range(steps):
        m = dice_measurement(robot, data, probe.q[k], probe.v[k], probe.wrench[k])
        log["speed"][k], log["force"][k] = m.speed, m.force
        log["penetration"][k] = cfg.dice.top_height - m.position[2]
    last = probe.status[steps - 1]
    contact = None if last["contact_time"] < 0 else last["contact_time"]
    metrics = run_metrics(
        cfg, log, probe.q, probe.v, probe.tau, joint_limits(robot), contact, last["touch_speed"]
    )
    est = probe.estimate
    nan = float("nan")
    metrics.update(
        learned_stiffness=nan if est is None else est["stiffness"],
        learned_damping=nan if est is None else est["damping"],
        learned_std=(nan, nan) if est is None else (est["stiffness_std"], est["damping_std"]),
        learner_samples=int(last["learner_samples"]),
        handover_time=nan if last["handover_time"] < 0 else last["handover_time"],
        safe_hold_cycles=int(sum(s["safe_hold"] > 0 for s in probe.status.values())),
        stopped_short=_stopped_short(cfg, last),
    )
    from ffmpc_ros.bringup import reflex_summary

    metrics.update(reflex_summary(probe.plant_status, robot.joint_names))
    if probe.learning_strategy:
        from ffmpc_core.impact.metrics import touch_metrics

        pl = probe.planner
        assert pl is not None  # (complete)

        def when(value: float) -> float | None:
            return None if value < 0 else value

        metrics.update(
            touch_metrics(
                log,
                when(pl["touch_time"]),
                None if pl["touch_time"] < 0 else pl["touch_velocity"],
                when(pl["decision_time"]),
            )
        )
    log["in_contact"] = np.array([probe.status[k]["in_contact"] for k in range(steps)])
    log["mpc_weight"] = np.array([probe.status[k]["mpc_weight"] for k in range(steps)])
    return metrics, log


def _stopped_short(cfg: ImpactStudyConfig, status: dict) -> str:
    """The run's ``stopped_short`` (``ImpactRun``'s: the message, "" if none) from the
    controller's last status."""
    from ffmpc_core.impact.control import StoppedShort

    if status["stopped_short_time"] < 0:
        return ""
    zbar = cfg.dice.max_penetration
    return StoppedShort(
        status["stopped_short_time"],
        status["stopped_short_force"],
        cfg.target_force,
        cfg.admittance.max_depth(zbar),
        zbar,
    ).message()


def is_safe(metrics: dict[str, Any]) -> bool:
    """A run is safe when no data-sheet joint limit was broken (position, velocity,
    acceleration, torque: ``violations``) and no cycle needed the controller's safe hold. The
    penetration is reported against z̄ (``within_max_penetration``), not part of the verdict:
    the paper's scheme plans with the prior material, whose certificate the true dice need not
    keep (the ROS-free study shows the same numbers)."""
    return metrics["violations"].total == 0 and metrics["safe_hold_cycles"] == 0


def _recorder_options(nodes: Sequence[str], approach: str, namespace: str) -> dict[str, Any]:
    """BagRecorder options of the impact graph (``graph_recorder_process``'s "options")."""
    names = [
        t
        for t, _, node in (*topics.IMPACT_GRAPH_TOPICS,)
        if node != "impact_planner" or approach == "maximal"
    ]
    return {
        "wait_for": [topics.resolve(t, namespace) for t in names],
        "gate_topic": topics.resolve(topics.PLANT_JOINT_STATES, namespace),
        "parameters_of": list(nodes),
        "final_topic": topics.resolve(topics.IMPACT_SUMMARY, namespace),
        "namespace": namespace,
        "lockstep_member": True,
    }


@dataclass(frozen=True)
class ImpactOptions:
    """How :func:`run_impact_graph` runs the experiment (``ffmpc run impact``'s defaults).

    scenario, overrides: the impact study's scenario and NAME=VALUE overrides.
    record: record every topic and parameter to this bag (must not exist).
    timeout: wall-time limit, s; stall_timeout: wall s without a plant cycle; start_timeout:
    wall s to the first plant cycle (GraphError beyond).
    domain_id: ROS domain (None: ROS_DOMAIN_ID or 0). quiet: keep the nodes' output in their
    logs (otherwise printed to stderr at the end). namespace: of the whole graph (None: root).
    allow_foreign: start even if other nodes publish on the graph's topics."""

    scenario: str = "impact"
    overrides: Sequence[str] = ()
    record: str | os.PathLike | None = None
    timeout: float = 900.0
    stall_timeout: float = 60.0
    start_timeout: float = 180.0
    domain_id: int | None = None
    quiet: bool = True
    namespace: str | None = None
    allow_foreign: bool = False


@dataclass
class ImpactPlan:
    """What a run of the impact graph will start, checked before anything starts
    (:func:`plan_impact_graph`)."""

    approach: str
    regulation: str
    options: ImpactOptions
    cfg: ImpactStudyConfig
    params: dict[str, dict[str, Any]]  # node → its parameters
    nodes: dict[str, str]  # node → "module:class"
    domain: int
    namespace: str  # normalised ("/" for the root)

    @property
    def steps(self) -> int:
        """Plant cycles of the run."""
        return int(round(self.cfg.duration / self.cfg.time_step))

    @property
    def learning(self) -> bool:
        """The planner learns before the strike (:func:`is_learning`)."""
        return is_learning(self.approach, self.cfg)


def plan_impact_graph(approach: str, regulation: str, options: ImpactOptions) -> ImpactPlan:
    """Every node's parameters and the run's settings; ConfigError (bad approach, regulation,
    scenario, override or namespace) or BagExistsError before anything starts."""
    o = options
    domain = _env_domain_id() if o.domain_id is None else o.domain_id
    namespace = topics.normalize_namespace(o.namespace)
    cfg, params = impact_node_parameters(
        approach, regulation, o.scenario, o.overrides, o.record is not None, namespace
    )
    if o.record is not None and os.path.exists(o.record):
        from ffmpc_ros.bag.errors import BagExistsError

        raise BagExistsError(f"{o.record} exists; a bag is never overwritten")
    nodes = graph_nodes(approach)
    return ImpactPlan(approach, regulation, o, cfg, params, nodes, domain, namespace)


class ImpactSession(NodeSession):
    """One run of an :class:`ImpactPlan`, in the steps of the polishing graph's session
    (``ffmpc_ros.bringup.NodeSession``): :meth:`spawn`, :meth:`bring_up`, :meth:`record`,
    :meth:`run`, :meth:`summarize`, then always :meth:`stop`, then :meth:`collect`."""

    def __init__(self, plan: ImpactPlan, start: float) -> None:
        from ffmpc_core.robots import load_robot

        super().__init__(plan.namespace, plan.domain, start, "ffmpc_impact_graph_")
        self.plan = plan
        self.robot = load_robot(ROBOT)
        self.probe: _Probe  # (spawn)
        self.summary_pub: Any = None  # impact_graph/summary (spawn)
        self.progress: ProgressWatch | None = None  # (run)
        self.done = start  # wall s the probe had every cycle
        self.metrics: dict[str, Any] = {}  # (summarize)
        self.log: dict[str, np.ndarray] = {}
        self.safe = False

    def spawn(self) -> None:
        """The bring-up's probe node (the foreign-publisher check, the summary's publisher, the
        probe of the run), then one child process per node."""
        plan = self.plan
        node = self.open_probe(plan.options.allow_foreign)
        self.summary_pub = node.create_publisher(
            String, topics.IMPACT_SUMMARY, topics.latched_qos()
        )
        self.probe = _Probe(node, plan.steps, self.robot.nv, plan.cfg.time_step, plan.learning)
        self.spawn_nodes(plan.params, plan.nodes)

    def bring_up(self) -> None:
        """Configure, then activate, every node, the dice plant last."""
        self.bring_up_nodes(list(self.plan.nodes), self.plan.options.start_timeout, "dice_plant")

    def record(self) -> None:
        """With ``record``: the recorder's process, which waits for every topic of the run."""
        plan, record = self.plan, self.plan.options.record
        if record is None:
            return
        from ffmpc_ros.bag.recorder import graph_recorder_metadata

        metadata = graph_recorder_metadata(None, plan.params, plan.namespace)
        metadata["ffmpc_run"]["impact"] = json.dumps(
            {
                "approach": plan.approach,
                "regulation": plan.regulation,
                "scenario": plan.options.scenario,
                "overrides": list(plan.options.overrides),
            }
        )
        options = _recorder_options(list(plan.nodes), plan.approach, plan.namespace)
        self.spawn_recorder(record, {"metadata": metadata, "options": options})

    def run(self) -> None:
        """Spin until the probe has every cycle (GraphError past the timeout, on a stall or a
        dead child)."""
        o, probe, steps = self.plan.options, self.probe, self.plan.steps
        end = self.start + o.timeout
        self.progress = ProgressWatch(self.start, o.stall_timeout, o.start_timeout)

        def progress() -> str:
            return f"plant at cycle {probe.cycle}, controller cycles {len(probe.status)}"

        while not probe.complete:
            now = time.perf_counter()
            if now > end:
                raise GraphError(
                    f"the impact graph did not finish within {o.timeout} s: plant at cycle "
                    f"{probe.cycle} of {steps}, {len(probe.status)} controller cycles"
                )
            self.turn(self.progress, probe.cycle, now, progress)
        self.done = time.perf_counter()

    def summarize(self) -> None:
        """The run's metrics (:func:`_graph_metrics`) and verdict, published once on
        ``impact_graph/summary``; then the recorder's end (it closes the bag once the summary
        is in; at most 15 s)."""
        plan = self.plan
        self.metrics, self.log = _graph_metrics(plan.cfg, self.probe, self.robot)
        peak = self.metrics["peak_penetration"]
        self.metrics["within_max_penetration"] = peak <= plan.cfg.dice.max_penetration
        self.safe = is_safe(self.metrics)
        payload = {"approach": plan.approach, "regulation": plan.regulation, "safe": self.safe}
        payload.update(metrics_summary(self.metrics))
        self.summary_pub.publish(String(data=json.dumps(payload, default=float)))
        if "recorder" in self.children:
            settle = time.perf_counter() + 15.0
            while self.children["recorder"].poll() is None and time.perf_counter() < settle:
                self.executor.spin_once(timeout_sec=0.05)

    def stop(self) -> GraphOutputs:
        """Stop the children, release the ROS context; the rejections and the bag's counts."""
        rejected = self.release(self.plan.options.quiet)
        outputs = GraphOutputs(rejected, bag=self.bag_report(self.plan.options.record))
        self.tmp.cleanup()
        return outputs

    def collect(self, outputs: GraphOutputs) -> ImpactGraphResult:
        """The run's result: metrics, log, timing, the bag's counts and the rejections."""
        plan, done = self.plan, self.done
        first = self.progress.first_step if self.progress is not None else None
        stepping = done - (first or done)
        return ImpactGraphResult(
            plant_engine=plan.cfg.engine,
            approach=plan.approach,
            regulation=plan.regulation,
            metrics=self.metrics,
            log=self.log,
            sim_time=plan.steps * plan.cfg.time_step,
            wall_time=stepping,
            startup_time=(done - self.start) - stepping,
            bag=outputs.bag,
            safe=self.safe,
            rejected=outputs.rejected,
        )


def run_impact_graph(
    approach: str = "maximal",
    regulation: str = "admittance",
    *,
    scenario: str = "impact",
    overrides: Sequence[str] = (),
    record: str | os.PathLike | None = None,
    timeout: float = 900.0,
    stall_timeout: float = 60.0,
    start_timeout: float = 180.0,
    domain_id: int | None = None,
    quiet: bool = True,
    namespace: str | None = None,
    allow_foreign: bool = False,
) -> ImpactGraphResult:
    """Run the impact experiment on the node graph (module docstring) and return its metrics.

    approach, regulation: as ``ffmpc study impact`` (maximal|baseline, admittance|ff_mpc);
    the keyword arguments: :class:`ImpactOptions`. The steps: :func:`plan_impact_graph`, then
    an :class:`ImpactSession`'s."""
    start = time.perf_counter()
    options = ImpactOptions(
        scenario,
        tuple(overrides),
        record,
        timeout,
        stall_timeout,
        start_timeout,
        domain_id,
        quiet,
        namespace,
        allow_foreign,
    )
    session = ImpactSession(plan_impact_graph(approach, regulation, options), start)
    try:
        session.spawn()
        session.bring_up()
        session.record()
        session.run()
        session.summarize()
    finally:
        outputs = session.stop()
    return session.collect(outputs)


def compare_with_runner(result: ImpactGraphResult, run: Any) -> dict[str, tuple[Any, Any]]:
    """{metric: (graph, ROS-free)} of every :data:`COMPARED` metric (and
    :data:`COMPARED_TOUCH` for a touch-first run) that differs (bit for bit;
    NaN equals NaN) between a graph run and ``studies.impact_study.run_impact``'s ImpactRun."""
    out = {}
    learning = run.strategy in ("touch_first", "strike_first")  # LEARNING_STRATEGIES
    names = COMPARED + (COMPARED_TOUCH if learning else ())
    for name in names:
        a, b = result.metrics.get(name), getattr(run, name)
        if not _same(a, b):
            out[name] = (a, b)
    return out
