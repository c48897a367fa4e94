"""Topic names, message types, frames and QoS of the node graph (``msgs_notes/topics.md``).

QoS. The control chain of the study (plant → sensors → MPC → PID → plant) must lose nothing in
lockstep, whatever the start order of the processes:

* every data topic is published RELIABLE + TRANSIENT_LOCAL with a history of
  :data:`PUBLISHER_DEPTH` samples, so a node that starts late still receives the samples it
  missed, and a slow recorder (the metrics node) can lag without losing any;
* subscribers keep :data:`PUBLISHER_DEPTH` samples in lockstep (every sample is processed) and
  only the newest in real time (``KEEP_LAST(1)``: a late sample is worthless);
* ``/clock`` is RELIABLE + VOLATILE with the same history (rclpy's time source subscribes
  BEST_EFFORT, depth 1: only the newest time matters to a node; the recorder keeps them all).
  Every ffmpc node also reads it RELIABLE, depth 1 (:func:`clock_reader_qos`, feeding the same
  clock): a best-effort sample is lost while the reader's side of the match is not yet made.

Names. Every topic and service name of the graph is RELATIVE (``plant/joint_states``): it
resolves under the namespace of the node that uses it, so ``--ros-args -r __ns:=/arm1`` (or
``ffmpc run --namespace /arm1``) moves the whole graph to ``/arm1/plant/joint_states``, ... and
two robot cells run side by side on one ROS domain. Three names stay absolute
(:data:`ABSOLUTE_NAMES`):

* ``/clock``, ROS's convention (rclpy's time source subscribes the absolute ``/clock``). A
  namespaced graph remaps it to its own clock with the standard rule ``-r /clock:=clock``
  (:func:`graph_ros_args`; ``/arm1/clock``): two lockstep graphs on one ``/clock`` would each
  step on the other's time (measured: README, "Namespaces"). At the root the rule is the
  identity and nothing changes.
* ``/diagnostics``, the diagnostic aggregator's convention: every node of every graph reports
  there, its status named by the node's fully qualified name (``/arm1/mpc``).
* ``/tf`` of the live view, tf2's name: a Foxglove channel and a topic of the bag, never
  published through ROS (``ffmpc_ros.view``).

:func:`resolve` gives the fully qualified name of a graph name under a namespace (what a bag
records, what ``ros2 topic list`` shows); it needs no node.
"""

from __future__ import annotations

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
#: The Foxglove-only channel of the view (no tf2_msgs wheel exists for the ROS 2 of this venv);
#: absolute, as tf2 names it (it is a Foxglove channel and a bag topic, never a ROS publication).
TF = "/tf"
#: The only absolute names of the graph (module docstring); every other name here is relative.
ABSOLUTE_NAMES = frozenset({CLOCK, DIAGNOSTICS, TF})
#: The namespace of a graph started without one.
ROOT_NAMESPACE = "/"

#: The frame of every wrench: origin at the robot's ``contact`` frame, axes of ``world``
#: (pinocchio's LOCAL_WORLD_ALIGNED); the moment is about the contact frame origin.
WRENCH_FRAME = "contact_world_aligned"

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

IMPACT_TOPICS: tuple[tuple[str, str, str], ...] = (
    (IMPACT_COMMAND, "geometry_msgs/msg/TwistStamped", "impact_planner"),
    (IMPACT_STATUS, "std_msgs/msg/Float64MultiArray", "impact_planner"),
    (CONTACT_ESTIMATE, "std_msgs/msg/Float64MultiArray", "contact_learner"),
)

#: Topics of the live view (``ffmpc run --view``, ffmpc_ros.view): the MPC's horizon, which the
#: MPC node publishes only while something subscribes, the URDF and the markers of the view node.
MPC_PREDICTION = "mpc/prediction"
ROBOT_DESCRIPTION = "robot_description"
VIEW_MARKERS = "view/markers"

VIEW_TOPICS: tuple[tuple[str, str, str], ...] = (
    (MPC_PREDICTION, "std_msgs/msg/Float64MultiArray", "mpc"),
    (ROBOT_DESCRIPTION, "std_msgs/msg/String", "view"),
    (VIEW_MARKERS, "visualization_msgs/msg/MarkerArray", "view"),
)


def latched_qos() -> QoSProfile:
    """Latched data (``/robot_description``): RELIABLE, TRANSIENT_LOCAL, KEEP_LAST(1)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


#: History kept by every data publisher (and by lockstep subscribers), samples: 1 s of a 1 kHz
#: graph, so the nodes outside the lockstep loop
#: (metrics, recorder) may lag that much without losing a sample (msgs_notes/README.md, QoS).
PUBLISHER_DEPTH = 1000


def publisher_qos() -> QoSProfile:
    """Data topics: RELIABLE, TRANSIENT_LOCAL, KEEP_LAST(PUBLISHER_DEPTH)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=PUBLISHER_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


def subscriber_qos(lockstep: bool) -> QoSProfile:
    """Data topics: as the publisher; depth 1 in real time (only the newest sample matters)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=PUBLISHER_DEPTH if lockstep else 1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


def reference_qos() -> QoSProfile:
    """The MPC's reference inputs: RELIABLE, TRANSIENT_LOCAL, KEEP_LAST(1): only the newest
    target matters, and a node that starts after it was published still gets it."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


def clock_reader_qos() -> QoSProfile:
    """Each node's own /clock reader (beside rclpy's best-effort one): RELIABLE, VOLATILE,
    KEEP_LAST(1): only the newest time matters, but no sample sent after the match is lost."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=1,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


#: /clock readers per node: rclpy's time source and the node's reliable one (clock_reader_qos).
CLOCK_READERS_PER_NODE = 2


def clock_qos() -> QoSProfile:
    """/clock: RELIABLE, VOLATILE, KEEP_LAST(PUBLISHER_DEPTH). A reliable writer drops what a
    slow reader has not taken once its history is full: with a history of 1 the recorder (its
    own process) lost 30 of 201 /clock samples of a lockstep run on a loaded machine. rclpy's
    time source still subscribes with its own depth-1 best-effort profile (the newest time)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=PUBLISHER_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


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
    if name == CLOCK:
        name = CLOCK_REMAP_TARGET
    elif name.startswith("/"):
        return name
    return f"{ns.rstrip('/')}/{name}"


#: Where a namespaced graph's ``/clock`` goes (relative: ``<namespace>/clock``).
CLOCK_REMAP_TARGET = "clock"


def graph_ros_args(namespace: str | None) -> list[str]:
    """The ROS arguments (after ``--ros-args``) that put a node or a whole rclpy context into
    the graph under ``namespace``: ``-r __ns:=/arm1 -r /clock:=clock``; none at the root (the
    graph then runs exactly as without a namespace)."""
    ns = normalize_namespace(namespace)
    if ns == ROOT_NAMESPACE:
        return []
    return ["-r", f"__ns:={ns}", "-r", f"{CLOCK}:={CLOCK_REMAP_TARGET}"]


def resolved_topics(namespace: str | None = ROOT_NAMESPACE) -> tuple[tuple[str, str, str], ...]:
    """:data:`TOPICS` with each name fully qualified under ``namespace`` (:func:`resolve`)."""
    return tuple((resolve(t, namespace), ty, node) for t, ty, node in TOPICS)


def namespace_of(topic_names, name: str = PLANT_JOINT_STATES) -> str:
    """The namespace of a graph from the fully qualified topic names it used (a bag's): the
    prefix of the one name that ends with ``/<name>``; the root when there is none or several."""
    found = {t[: -len(name) - 1] or ROOT_NAMESPACE for t in topic_names if t.endswith("/" + name)}
    return found.pop() if len(found) == 1 else ROOT_NAMESPACE
