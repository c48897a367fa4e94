"""Topic names, message types, frames and QoS of the node graph (``msgs_notes/topics.md``).

QoS, as ROS 2 users expect (every profile is a function of this module; msgs_notes/README.md):

* SENSOR — joint states, wrenches, the contact flag: the simulated devices publish
  ``SensorDataQoS`` (BEST_EFFORT, VOLATILE, KEEP_LAST(5)) and every reader subscribes
  BEST_EFFORT, VOLATILE, so a standard driver's best-effort publisher connects;
* COMMAND — ``mpc/command``, the PID's torques, the impact planner's twist: RELIABLE, VOLATILE;
* STATE — status, truth, estimates, predictions, markers: RELIABLE, VOLATILE;
* STATE also holds ``/tf`` (tf2's dynamic broadcaster: RELIABLE, VOLATILE);
* LATCHED — ``robot_description``, ``/tf_static`` (tf2's static broadcaster profile),
  ``metrics/*``: RELIABLE, TRANSIENT_LOCAL, KEEP_LAST(1), the only replayed data;
* REFERENCE — the MPC's reference inputs (``mpc/reference``, ``mpc/force_setpoint``), written by
  an operator or a planner outside the graph: the MPC reads them RELIABLE, VOLATILE,
  KEEP_LAST(1), which matches a default ``ros2 topic pub`` (RELIABLE, VOLATILE) and a latched
  publisher alike (a TRANSIENT_LOCAL reader never matched the default publisher:
  docs/explanation/ros.md,
  ``ros2 topic pub --once`` waited for ever). The last target is kept by the MPC itself: a
  message sets its live parameter (``task.normal_force``, ``position_offset``), which holds until
  the next one and reads back with ``ros2 param get``;
* ``/clock``: RELIABLE, VOLATILE with a history of :data:`PUBLISHER_DEPTH` (rclpy's time source
  subscribes BEST_EFFORT, depth 1: only the newest time matters to a node; the recorder keeps
  them all). Every ffmpc node also reads it RELIABLE, depth 1 (:func:`clock_reader_qos`,
  feeding the same clock): a best-effort sample is lost while the reader's side of the match is
  not yet made.

Subscribers keep :data:`PUBLISHER_DEPTH` samples in lockstep (every sample is processed) and
only the newest in real time (``KEEP_LAST(1)``: a late sample is worthless). Every publisher and
subscription of an ffmpc node takes ROS 2's standard QoS override parameters (history, depth,
reliability: ``--ros-args -p qos_overrides./ft_sensor/wrench.subscription.reliability:=reliable``).
The graph's bring-up sets :func:`graph_qos_overrides` on its own nodes: the sensor topics become
RELIABLE with a history of :data:`PUBLISHER_DEPTH` on both ends, so the lockstep loop, the
metrics node and the recorder lose nothing; nothing is replayed: the plant publishes its first
state only once every node passed the start barrier (:data:`START_READY`: each writer of the
graph matched to every reader), and a reliable VOLATILE writer delivers every sample it sent
since it matched a reader.

Names. Every topic and service name of the graph is RELATIVE (``plant/joint_states``): it
resolves under the namespace of the node that uses it, so ``--ros-args -r __ns:=/arm1`` (or
``ffmpc run --namespace /arm1``) moves the whole graph to ``/arm1/plant/joint_states``, ... and
two robot cells run side by side on one ROS domain. Four names stay absolute
(:data:`ABSOLUTE_NAMES`):

* ``/clock``, ROS's convention (rclpy's time source subscribes the absolute ``/clock``). A
  namespaced graph remaps it to its own clock with the standard rule ``-r /clock:=clock``
  (:func:`graph_ros_args`; ``/arm1/clock``): two lockstep graphs on one ``/clock`` would each
  step on the other's time (measured: docs/explanation/ros.md, "Namespaces"). At the root the rule
  is the
  identity and nothing changes.
* ``/diagnostics``, the diagnostic aggregator's convention: every node of every graph reports
  there, its status named by the node's fully qualified name (``/arm1/mpc``).
* ``/tf`` and ``/tf_static``, tf2's names (``ffmpc_ros.state_publisher_node``). A namespaced
  graph remaps them like ``/clock`` (``-r /tf:=tf -r /tf_static:=tf_static``: ``/arm1/tf``),
  the rule Nav2 uses for several robots: each robot's tree stays its own.

:func:`resolve` gives the fully qualified name of a graph name under a namespace (what a bag
records, what ``ros2 topic list`` shows); it needs no node.
"""

from __future__ import annotations

from collections.abc import Iterable

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from ffmpc_core.errors import ConfigError

CLOCK = "/clock"
PLANT_JOINT_STATES = "plant/joint_states"
PLANT_WRENCH = "plant/wrench"
PLANT_TRUTH = "plant/truth"
PLANT_STATUS = "plant/status"
SENSED_JOINT_STATES = "joint_sensor/joint_states"
SENSED_WRENCH = "ft_sensor/wrench"
FILTERED_WRENCH = "ft_sensor/wrench_filtered"
IN_CONTACT = "ft_sensor/in_contact"
TARE_SERVICE = "ft_sensor/tare"
MPC_COMMAND = "mpc/command"
MOTOR_TORQUE = "pid/motor_torque"
DESIRED_TORQUE = "pid/desired_torque"
LOWLEVEL_STATUS = "pid/status"
METRICS_SUMMARY = "metrics/summary"
METRICS_READY = "metrics/ready"
#: Every node's status once a second (wall), diagnostic_msgs/DiagnosticArray; absolute, as the
#: diagnostic aggregator expects. Outside TOPICS: not part of the control chain's contract.
DIAGNOSTICS = "/diagnostics"

#: The MPC's reference inputs (relative names: ``/mpc/…`` in the root namespace, under the
#: graph's namespace otherwise), published by an operator or a higher-level planner. Outside
#: :data:`TOPICS`: no node of the graph publishes them (the recorder does not wait for them).
MPC_REFERENCE = "mpc/reference"
MPC_FORCE_SETPOINT = "mpc/force_setpoint"
REFERENCE_TOPICS: tuple[tuple[str, str, str], ...] = (
    (MPC_REFERENCE, "geometry_msgs/msg/PoseStamped", "(operator)"),
    (MPC_FORCE_SETPOINT, "std_msgs/msg/Float64", "(operator)"),
)
#: The world frame (the frame_id of a reference pose).
WORLD_FRAME = "world"
#: tf2's topics (tf2_msgs/msg/TFMessage), published by the state publisher from the measured
#: joint states (moving joints) and once, latched (fixed joints); absolute, as tf2 names them.
TF = "/tf"
TF_STATIC = "/tf_static"
#: The URDF of the graph's robot (std_msgs/String, latched), published by the state publisher;
#: relative, like robot_state_publisher's.
ROBOT_DESCRIPTION = "robot_description"
#: The only absolute names of the graph (module docstring); every other name here is relative.
ABSOLUTE_NAMES = frozenset({CLOCK, DIAGNOSTICS, TF, TF_STATIC})
#: The namespace of a graph started without one.
ROOT_NAMESPACE = "/"

#: The frame of every wrench: origin at the robot's ``contact`` frame, axes of ``world``
#: (pinocchio's LOCAL_WORLD_ALIGNED); the moment is about the contact frame origin.
WRENCH_FRAME = "contact_world_aligned"

#: The state publisher's topics (robot_state_publisher's), in every graph.
STATE_TOPICS: tuple[tuple[str, str, str], ...] = (
    (ROBOT_DESCRIPTION, "std_msgs/msg/String", "state_publisher"),
    (TF, "tf2_msgs/msg/TFMessage", "state_publisher"),
    (TF_STATIC, "tf2_msgs/msg/TFMessage", "state_publisher"),
)

#: (topic, ROS type, publisher node) of every topic; the notes list the same rows.
TOPICS: tuple[tuple[str, str, str], ...] = (
    (CLOCK, "rosgraph_msgs/msg/Clock", "plant"),
    (PLANT_JOINT_STATES, "sensor_msgs/msg/JointState", "plant"),
    (PLANT_WRENCH, "geometry_msgs/msg/WrenchStamped", "plant"),
    (PLANT_TRUTH, "std_msgs/msg/Float64MultiArray", "plant"),
    (PLANT_STATUS, "std_msgs/msg/Float64MultiArray", "plant"),
    (SENSED_JOINT_STATES, "sensor_msgs/msg/JointState", "joint_sensor"),
    (SENSED_WRENCH, "geometry_msgs/msg/WrenchStamped", "ft_sensor"),
    (FILTERED_WRENCH, "geometry_msgs/msg/WrenchStamped", "ft_sensor"),
    (IN_CONTACT, "std_msgs/msg/Bool", "ft_sensor"),
    (MPC_COMMAND, "ffmpc_msgs/msg/MpcCommand", "mpc"),
    (MOTOR_TORQUE, "sensor_msgs/msg/JointState", "pid"),
    (DESIRED_TORQUE, "sensor_msgs/msg/JointState", "pid"),
    (LOWLEVEL_STATUS, "std_msgs/msg/Float64MultiArray", "pid"),
    (METRICS_SUMMARY, "std_msgs/msg/String", "metrics"),
    (METRICS_READY, "std_msgs/msg/Bool", "metrics"),
    *STATE_TOPICS,
)

#: Topics and services of the impact nodes (Dehio & Kheddar 2020). They are kept out of
#: :data:`TOPICS`: the polishing graph (and its recorder, which waits for every topic there)
#: does not run these nodes.
IMPACT_COMMAND = "impact_planner/command"
IMPACT_STATUS = "impact_planner/status"
IMPACT_RESET_SERVICE = "impact_planner/reset"
CONTACT_ESTIMATE = "contact_learner/estimate"
CONTACT_LEARNER_RESET_SERVICE = "contact_learner/reset"

#: The frame of the impact planner's twist: the velocity of the contact frame origin, world axes
#: (the same frame as the wrenches).
COMMAND_FRAME = WRENCH_FRAME

#: The planner's whole Cartesian command (pose, twist, feed-forward acceleration) each cycle,
#: what the impact controller tracks.
IMPACT_REFERENCE = "impact_planner/reference"
#: The impact controller's joint torque (JointState effort, N·m) for the plant of the impact
#: graph, and its status (layout ``impact_control``).
IMPACT_TORQUE = "impact_controller/torque"
IMPACT_CONTROL_STATUS = "impact_controller/status"

IMPACT_TOPICS: tuple[tuple[str, str, str], ...] = (
    (IMPACT_COMMAND, "geometry_msgs/msg/TwistStamped", "impact_planner"),
    (IMPACT_STATUS, "std_msgs/msg/Float64MultiArray", "impact_planner"),
    (IMPACT_REFERENCE, "std_msgs/msg/Float64MultiArray", "impact_planner"),
    (CONTACT_ESTIMATE, "std_msgs/msg/Float64MultiArray", "contact_learner"),
    (IMPACT_TORQUE, "sensor_msgs/msg/JointState", "impact_controller"),
    (IMPACT_CONTROL_STATUS, "std_msgs/msg/Float64MultiArray", "impact_controller"),
)

#: The impact graph's summary (std_msgs/String, JSON: the run's metrics), published once by the
#: bring-up at the end (the recorder's last topic).
IMPACT_SUMMARY = "impact_graph/summary"

#: Every topic of the impact graph (``ffmpc run impact``, ``ffmpc_ros.impact_graph``): the
#: dice plant's, the two sensors' and the impact nodes'. The planner's topics are absent from a
#: baseline run (no planner node).
IMPACT_GRAPH_TOPICS: tuple[tuple[str, str, str], ...] = (
    (CLOCK, "rosgraph_msgs/msg/Clock", "dice_plant"),
    (PLANT_JOINT_STATES, "sensor_msgs/msg/JointState", "dice_plant"),
    (PLANT_WRENCH, "geometry_msgs/msg/WrenchStamped", "dice_plant"),
    (PLANT_STATUS, "std_msgs/msg/Float64MultiArray", "dice_plant"),
    (SENSED_JOINT_STATES, "sensor_msgs/msg/JointState", "joint_sensor"),
    (SENSED_WRENCH, "geometry_msgs/msg/WrenchStamped", "ft_sensor"),
    (FILTERED_WRENCH, "geometry_msgs/msg/WrenchStamped", "ft_sensor"),
    (IN_CONTACT, "std_msgs/msg/Bool", "ft_sensor"),
    *IMPACT_TOPICS,
    *STATE_TOPICS,
    (IMPACT_SUMMARY, "std_msgs/msg/String", "ffmpc_bringup"),
)

#: ros2_control's terms (graph parameter ``interfaces: ros2_control``, msgs_notes/topics.md,
#: docs/explanation/ros.md "MPC on a ros2_control robot"). The agimus linear_feedback_controller's
#: topics (its
#: ``~/control`` and ``~/sensor``, relative to its controller name ``linear_feedback_controller``):
#: the MPC publishes Control on LFC_CONTROL and reads Sensor on LFC_SENSOR; the low-level node of
#: the graph (the PID, or the LFC-law node ``lfc``) plays the controller's part. The effort
#: command topic of a forward_command_controller (``effort_controllers/JointGroupEffortController``
#: named ``effort_controller``: its ``~/commands``, std_msgs/Float64MultiArray, one effort per
#: configured joint, N·m, in that order, no stamp) drives the plant, which also publishes
#: ``joint_states`` like joint_state_broadcaster. Remap them to a robot's names.
LFC_CONTROL = "linear_feedback_controller/control"
LFC_SENSOR = "linear_feedback_controller/sensor"
EFFORT_COMMANDS = "effort_controller/commands"
JOINT_STATES = "joint_states"
#: The LFC-law node's stamped record of the effort it sent (JointState effort, N·m) and its
#: status (layout ``lowlevel_status``), what the metrics node and the bring-up read.
LFC_EFFORT = "lfc/effort"
LFC_STATUS = "lfc/status"
#: The interfaces of a graph node (graph parameter ``interfaces``).
FFMPC_INTERFACES, ROS2_CONTROL_INTERFACES = "ffmpc", "ros2_control"
INTERFACES = (FFMPC_INTERFACES, ROS2_CONTROL_INTERFACES)
#: The topics that replace or join :data:`TOPICS` with ``interfaces: ros2_control``: the MPC's
#: Control, the low level's Sensor and efforts, the plant's joint_states (the LFC-law node's
#: rows; the PID node publishes the Sensor and the efforts in its place when it is the low level).
ROS2_CONTROL_TOPICS: tuple[tuple[str, str, str], ...] = (
    (LFC_CONTROL, "linear_feedback_controller_msgs/msg/Control", "mpc"),
    (LFC_SENSOR, "linear_feedback_controller_msgs/msg/Sensor", "lfc"),
    (EFFORT_COMMANDS, "std_msgs/msg/Float64MultiArray", "lfc"),
    (JOINT_STATES, "sensor_msgs/msg/JointState", "plant"),
    (LFC_EFFORT, "sensor_msgs/msg/JointState", "lfc"),
    (LFC_STATUS, "std_msgs/msg/Float64MultiArray", "lfc"),
)


def low_level_topics(low_level: str) -> tuple[str, str, str]:
    """(desired torque, motor torque, status) topics of the graph's low-level node: the PID's
    (``pid/desired_torque``, ``pid/motor_torque``, ``pid/status``) or the LFC-law node's
    (``lfc/effort`` twice, ``lfc/status``: it sends what it computes)."""
    if low_level == "lfc":
        return LFC_EFFORT, LFC_EFFORT, LFC_STATUS
    return DESIRED_TORQUE, MOTOR_TORQUE, LOWLEVEL_STATUS


#: Topics of the live view (``ffmpc run --view``, ffmpc_ros.view): the MPC's horizon, which the
#: MPC node publishes only while something subscribes, and the markers of the view node.
MPC_PREDICTION = "mpc/prediction"
VIEW_MARKERS = "view/markers"

VIEW_TOPICS: tuple[tuple[str, str, str], ...] = (
    (MPC_PREDICTION, "std_msgs/msg/Float64MultiArray", "mpc"),
    (VIEW_MARKERS, "visualization_msgs/msg/MarkerArray", "view"),
)


#: History of the publishers that must lose nothing (commands, states; the sensor topics' in the
#: graph, through :func:`graph_qos_overrides`) and of lockstep subscribers, samples: 1 s of a
#: 1 kHz graph, so the readers outside the lockstep loop (metrics node, recorder) may lag that
#: much without losing a sample (a reliable KEEP_LAST writer drops what a slow reader has not
#: taken once its history is full; msgs_notes/README.md, QoS).
PUBLISHER_DEPTH = 1000
#: History of a SensorDataQoS publisher (rclpy's ``qos_profile_sensor_data``: KEEP_LAST(5)).
SENSOR_DEPTH = 5

#: The QoS classes (module docstring, msgs_notes/README.md "QoS").
SENSOR, COMMAND, STATE, LATCHED = "sensor", "command", "state", "latched"
REFERENCE = "reference"
#: The class of every topic of the graph but ``/clock`` (:func:`clock_qos`). A topic not listed
#: (a new node's) is a STATE topic: reliable, volatile.
QOS_CLASSES: dict[str, str] = {
    PLANT_JOINT_STATES: SENSOR,
    PLANT_WRENCH: SENSOR,
    SENSED_JOINT_STATES: SENSOR,
    SENSED_WRENCH: SENSOR,
    FILTERED_WRENCH: SENSOR,
    IN_CONTACT: SENSOR,
    MPC_COMMAND: COMMAND,
    MOTOR_TORQUE: COMMAND,
    DESIRED_TORQUE: COMMAND,
    IMPACT_COMMAND: COMMAND,
    IMPACT_REFERENCE: COMMAND,
    IMPACT_TORQUE: COMMAND,
    IMPACT_CONTROL_STATUS: STATE,
    PLANT_TRUTH: STATE,
    PLANT_STATUS: STATE,
    LOWLEVEL_STATUS: STATE,
    IMPACT_STATUS: STATE,
    CONTACT_ESTIMATE: STATE,
    MPC_PREDICTION: STATE,
    VIEW_MARKERS: STATE,
    TF: STATE,
    TF_STATIC: LATCHED,
    METRICS_SUMMARY: LATCHED,
    IMPACT_SUMMARY: LATCHED,
    METRICS_READY: LATCHED,
    ROBOT_DESCRIPTION: LATCHED,
    MPC_REFERENCE: REFERENCE,
    MPC_FORCE_SETPOINT: REFERENCE,
    # ros2_control's terms: the agimus controller's best-effort Sensor is a sensor topic; the
    # Control, the efforts and their record are commands; joint_state_broadcaster's topic is
    # reliable by default: a STATE topic here
    LFC_SENSOR: SENSOR,
    LFC_CONTROL: COMMAND,
    EFFORT_COMMANDS: COMMAND,
    LFC_EFFORT: COMMAND,
    LFC_STATUS: STATE,
    JOINT_STATES: STATE,
}


def qos_class(topic: str | None) -> str:
    """The QoS class of a graph topic (relative name, as in this module); STATE when unknown."""
    return QOS_CLASSES.get(topic or "", STATE)


def _profile(reliable: bool, depth: int, latched: bool = False) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
    )


def publisher_qos(topic: str | None = None) -> QoSProfile:
    """The default publisher profile of ``topic``'s class: SENSOR is ``SensorDataQoS``
    (BEST_EFFORT, VOLATILE, KEEP_LAST(5)), COMMAND and STATE RELIABLE, VOLATILE,
    KEEP_LAST(PUBLISHER_DEPTH), LATCHED RELIABLE, TRANSIENT_LOCAL, KEEP_LAST(1)."""
    kind = qos_class(topic)
    if kind == SENSOR:
        return _profile(False, SENSOR_DEPTH)
    if kind == LATCHED:
        return latched_qos()
    if kind == REFERENCE:
        return reference_qos()
    return _profile(True, PUBLISHER_DEPTH)


def subscriber_qos(lockstep: bool, topic: str | None = None) -> QoSProfile:
    """The default subscription profile of ``topic``'s class: SENSOR BEST_EFFORT, VOLATILE
    (it matches a SensorDataQoS driver and a reliable publisher alike), COMMAND and STATE
    RELIABLE, VOLATILE; history PUBLISHER_DEPTH in lockstep (every sample is processed), 1 in
    real time (only the newest matters); LATCHED as its publisher (the last sample, also to a
    late reader)."""
    kind = qos_class(topic)
    if kind == LATCHED:
        return latched_qos()
    if kind == REFERENCE:
        return reference_qos()
    return _profile(kind != SENSOR, PUBLISHER_DEPTH if lockstep else 1)


def latched_qos() -> QoSProfile:
    """Latched data (``robot_description``, ``metrics/*``): RELIABLE, TRANSIENT_LOCAL,
    KEEP_LAST(1): a reader that comes late still gets the last sample."""
    return _profile(True, 1, latched=True)


def reference_qos() -> QoSProfile:
    """The MPC's reference inputs (REFERENCE, module docstring): RELIABLE, VOLATILE,
    KEEP_LAST(1): it matches ``ros2 topic pub``'s default publisher and a latched one; only
    the newest target matters, and the MPC keeps it as its live parameter."""
    return _profile(True, 1)


#: What the bring-up overrides on the graph's own nodes (``ffmpc run``, ``ffmpc launch``), per
#: class, through ROS 2's QoS override parameters, in both modes: the simulated devices' sensor
#: topics become RELIABLE both ways with a history of PUBLISHER_DEPTH, so the lockstep loop and
#: the metrics node and recorder lose nothing.
GRAPH_OVERRIDES: dict[str, dict[str, dict[str, str | int]]] = {
    SENSOR: {
        "publisher": {"reliability": "reliable", "depth": PUBLISHER_DEPTH},
        "subscription": {"reliability": "reliable"},
    },
}
#: The lockstep start barrier (``GraphNode`` in ffmpc_ros.base; msgs_notes/README.md, QoS): a
#: node subscribes this topic (std_msgs/Empty, never published) once it has discovered every
#: member's :data:`START_MEMBER` marker (so every reader of the graph) and each of its writers has
#: matched every compatible reader discovered on its topic. The plant counts these readers
#: (``start_nodes``) before it publishes cycle 0: every writer of the graph then delivers every
#: sample to every reader (reliable, volatile: nothing is replayed, nothing is lost). Before it,
#: the lockstep topics were TRANSIENT_LOCAL, since a sample a writer sent before ITS side of a
#: match was made was lost, and 2 of 54 graph tests beside two busy loops stalled at cycle 0.
START_READY = "lockstep/ready"
#: The start barrier's membership marker (std_msgs/Empty, never published): every member of a
#: lockstep graph (each node, the graph's recorder) subscribes it as its LAST reader, once all its
#: other readers exist. A node that has discovered every member's marker has discovered every
#: reader of the graph (a participant announces its readers in the order it creates them). Other
#: readers of /clock (the live view, a ``ros2 topic echo``) are no members: they do not count.
START_MEMBER = "lockstep/member"
#: Writers the start barrier does not wait for: the domain-wide diagnostics (any number of
#: monitors) and LATCHED topics (a late reader gets the last sample anyway).
BARRIER_EXEMPT = frozenset({DIAGNOSTICS})


def barrier_writer(topic: str) -> bool:
    """Whether a node's writer of ``topic`` (as created, relative) must have matched every
    compatible reader of the graph before the node declares itself ready (:data:`START_READY`)."""
    return topic not in BARRIER_EXEMPT and (topic == CLOCK or qos_class(topic) != LATCHED)


def qos_override_name(topic: str, role: str, policy: str, namespace: str | None = None) -> str:
    """ROS 2's parameter that overrides ``policy`` of the ``role`` ("publisher" or
    "subscription") of ``topic`` in a graph under ``namespace``:
    ``qos_overrides./ft_sensor/wrench.subscription.reliability``."""
    return f"qos_overrides.{resolve(topic, namespace)}.{role}.{policy}"


def _graph_policies(topic: str, role: str) -> dict[str, str | int]:
    return dict(GRAPH_OVERRIDES.get(qos_class(topic), {}).get(role, {}))


def graph_qos_overrides(namespace: str | None = None) -> dict[str, str | int]:
    """{parameter: value} of :data:`GRAPH_OVERRIDES` for every topic of the graph under
    ``namespace`` (a node ignores the ones of topics it does not use); the same in lockstep and
    real time (the lockstep start is a barrier, :data:`START_READY`, not a replay)."""
    out: dict[str, str | int] = {}
    for topic in QOS_CLASSES:
        for role in ("publisher", "subscription"):
            for policy, value in _graph_policies(topic, role).items():
                out[qos_override_name(topic, role, policy, namespace)] = value
    return out


def graph_qos(topic: str, role: str, lockstep: bool = True) -> QoSProfile:
    """The profile a graph node's ``role`` ("publisher" or "subscription") of ``topic`` has with
    :func:`graph_qos_overrides` applied: for the bring-up's own readers and writers (status
    probe, fault injector), made without those parameters."""
    qos = publisher_qos(topic) if role == "publisher" else subscriber_qos(lockstep, topic)
    for policy, value in _graph_policies(topic, role).items():
        if policy == "reliability":
            qos.reliability = ReliabilityPolicy[str(value).upper()]
        elif policy == "durability":
            qos.durability = DurabilityPolicy[str(value).upper()]
        elif policy == "depth":
            qos.depth = int(value)
    return qos


def start_ready_qos() -> QoSProfile:
    """A node's start-barrier token (:data:`START_READY`): RELIABLE, VOLATILE, KEEP_LAST(1)
    (nothing is ever published on it; only the reader's existence counts)."""
    return _profile(True, 1)


def clock_reader_qos() -> QoSProfile:
    """Each node's own /clock reader (beside rclpy's best-effort one): RELIABLE, VOLATILE,
    KEEP_LAST(1): only the newest time matters, but no sample sent after the match is lost."""
    return _profile(True, 1)


#: /clock readers per node: rclpy's time source and the node's reliable one (clock_reader_qos).
CLOCK_READERS_PER_NODE = 2


def clock_qos() -> QoSProfile:
    """/clock: RELIABLE, VOLATILE, KEEP_LAST(PUBLISHER_DEPTH). A reliable writer drops what a
    slow reader has not taken once its history is full: with a history of 1 the recorder (its
    own process) lost 30 of 201 /clock samples of a lockstep run on a loaded machine. rclpy's
    time source still subscribes with its own depth-1 best-effort profile (the newest time)."""
    return _profile(True, PUBLISHER_DEPTH)


# -- names under a namespace ---------------------------------------------------------------------
def normalize_namespace(namespace: str | None) -> str:
    """A namespace as ROS writes it: absolute, no trailing slash (``arm1`` → ``/arm1``; None,
    ``""`` and ``/`` → ``/``). ConfigError for a name ROS refuses (rcl's own rules: letters,
    digits and underscores, tokens not starting with a digit, no ``//``)."""
    from rclpy.exceptions import InvalidNamespaceException
    from rclpy.validate_namespace import validate_namespace

    text = (namespace or "").strip()
    if text in ("", ROOT_NAMESPACE):
        return ROOT_NAMESPACE
    full = text if text.startswith("/") else "/" + text
    if len(full) > 1 and full.endswith("/"):
        full = full[:-1]  # "/arm1/" is "/arm1" (a second slash is left for the check)
    try:
        validate_namespace(full)
    except InvalidNamespaceException as exc:
        reason = str(exc).splitlines()[0].rstrip(": ")
        raise ConfigError(f"namespace {namespace!r} is not a ROS namespace: {reason}") from None
    return full


def resolve(name: str, namespace: str | None = ROOT_NAMESPACE) -> str:
    """The fully qualified name of a graph topic or service in a graph under ``namespace``, with
    the graph's clock remap (:func:`graph_ros_args`): ``resolve(MPC_COMMAND, "/arm1")`` is
    ``/arm1/mpc/command``, ``resolve(CLOCK, "/arm1")`` ``/arm1/clock``, ``/diagnostics``
    stays. At the root every name resolves as before (``/mpc/command``, ``/clock``)."""
    ns = normalize_namespace(namespace)
    if name in GRAPH_REMAPS:
        if ns == ROOT_NAMESPACE:
            return name
        name = GRAPH_REMAPS[name]
    elif name.startswith("/"):
        return name
    return f"{ns.rstrip('/')}/{name}"


#: Where a namespaced graph's ``/clock`` goes (relative: ``<namespace>/clock``).
CLOCK_REMAP_TARGET = "clock"
#: The absolute names a namespaced graph remaps into its namespace (module docstring).
GRAPH_REMAPS: dict[str, str] = {CLOCK: CLOCK_REMAP_TARGET, TF: "tf", TF_STATIC: "tf_static"}


def graph_ros_args(namespace: str | None) -> list[str]:
    """The ROS arguments (after ``--ros-args``) that put a node or a whole rclpy context into
    the graph under ``namespace``: ``-r __ns:=/arm1 -r /clock:=clock -r /tf:=tf -r
    /tf_static:=tf_static``; none at the root (the graph then runs exactly as without a
    namespace)."""
    ns = normalize_namespace(namespace)
    if ns == ROOT_NAMESPACE:
        return []
    out = ["-r", f"__ns:={ns}"]
    for name, target in GRAPH_REMAPS.items():
        out += ["-r", f"{name}:={target}"]
    return out


def resolved_topics(namespace: str | None = ROOT_NAMESPACE) -> tuple[tuple[str, str, str], ...]:
    """:data:`TOPICS` with each name fully qualified under ``namespace`` (:func:`resolve`)."""
    return tuple((resolve(t, namespace), ty, node) for t, ty, node in TOPICS)


def namespace_of(topic_names: Iterable[str], name: str = PLANT_JOINT_STATES) -> str:
    """The namespace of a graph from the fully qualified topic names it used (a bag's): the
    prefix of the one name that ends with ``/<name>``; the root when there is none or several."""
    found = {t[: -len(name) - 1] or ROOT_NAMESPACE for t in topic_names if t.endswith("/" + name)}
    return found.pop() if len(found) == 1 else ROOT_NAMESPACE
