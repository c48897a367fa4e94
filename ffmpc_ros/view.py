"""The live view (``ffmpc run --view``): a Foxglove WebSocket server that streams the run.

The view node bridges every ROS topic of the graph to Foxglove as it is: one channel per topic,
message encoding ``cdr``, schema ``ros2msg`` with the complete definition a bag holds
(``ffmpc_ros.bag.schema``), the raw CDR bytes of a raw subscription forwarded unchanged (the
recorder's subscription helper, ``ffmpc_ros.bag.ros_types.subscribe_raw``). A Foxglove layout
that names ROS topics therefore opens the live server and a bag of ``--record`` alike.

``robot_description``, ``/tf`` and ``/tf_static`` come from the graph's state publisher
(``ffmpc_ros.state_publisher_node``: the URDF, and the frames from the MEASURED joint states) and
are bridged like every topic (the latched ones' last message goes again to each new Foxglove
subscriber). What the robot view needs besides, published by this node:

* ``/view/markers`` (visualization_msgs/MarkerArray, in the robot's root link frame, which is
  pinocchio's world: it needs no ``/tf``, so a bag shows it too): the measured force
  ``/ft_sensor/wrench`` as an arrow at the contact frame origin (:data:`FORCE_ARROW_SCALE` m per
  N), and the MPC's planned contact-frame path (``/mpc/prediction``) as a line strip.

The markers are published every :data:`VIEW_PERIOD` s of the stamps of
``/plant/joint_states`` (simulated time); the raw topics are forwarded whenever a client
subscribes to them. Log times are the node's clock (simulated, ``use_sim_time``), as in a bag.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
from builtin_interfaces.msg import Time as TimeMsg
from foxglove import Channel, WebSocketServer
from foxglove.websocket import ChannelView, Client, ServerListener
from geometry_msgs.msg import Point, WrenchStamped
from rclpy.clock import Clock, ClockType
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import ColorRGBA, Float64MultiArray
from visualization_msgs.msg import Marker, MarkerArray

from ffmpc_core.errors import ConfigError, FfmpcError
from ffmpc_core.robots import RobotModel, load_robot
from ffmpc_ros import layouts, topics
from ffmpc_ros.bag.ros_types import offered_profiles, subscribe_raw
from ffmpc_ros.bag.schema import MESSAGE_ENCODING, SCHEMA_ENCODING, MessageDefinitions
from ffmpc_ros.robot_tree import WORLD_FRAME, robot_edges

#: Default port of the Foxglove WebSocket server.
DEFAULT_PORT = 8765
#: Host the server binds to (this machine only).
DEFAULT_HOST = "127.0.0.1"
#: Simulated s between two /view/markers messages (100 Hz).
VIEW_PERIOD = 0.01
#: Length of the force arrow, m per N (50 N → 0.25 m).
FORCE_ARROW_SCALE = 0.005
#: Messages the server buffers per client (foxglove-sdk drops the OLDEST data message when the
#: buffer is full: a live view drops rather than blocks). The default, 1024, is 0.06 s of a
#: 1 kHz graph's ~17 topics: a client on a loaded machine (the test's, in a Python thread) lost
#: every message of a topic (robot_description, mpc/prediction) in 3 of 6 runs of a 0.2 s run.
#: 32768 (~2 s of the graph, some MB) keeps a slow client whole through start-up.
CLIENT_BACKLOG = 32768
#: Wall s without a new channel or subscription before the run starts (``wait_for_client``) for a
#: client that does not subscribe to every channel of the graph (ViewNode.client_ready; a client
#: that subscribes to all of them starts the run at once). 0.5 s let the run start before a
#: loaded test client had subscribed to /tf_static and mpc/prediction (2 of 6 runs beside two
#: busy loops); a person's Foxglove waits 5 s after its last subscription.
CLIENT_SETTLE = 5.0
#: Wall s a channel of the graph may stay without the waiting client's subscription before it
#: is advertised again (ViewNode._readvertise).
READVERTISE = 1.0
#: Latched topics: their last message goes again to each new Foxglove subscriber (Foxglove
#: channels keep nothing; DDS reports a remote publisher's depth as 0, so the QoS cannot tell).
LATCHED = (topics.ROBOT_DESCRIPTION, topics.TF_STATIC)
#: Topics never bridged (parameter events are not data).
EXCLUDE = ("/parameter_events",)
#: History of every bridging subscription, messages.
BRIDGE_DEPTH = 100


class ViewError(FfmpcError):
    """The live view cannot start (a busy port, a bad robot)."""


def check_port_free(host: str, port: int) -> None:
    """ViewError unless ``host:port`` can be bound now (a busy port is refused up front)."""
    import socket

    if not 0 < int(port) < 65536:
        raise ConfigError(f"--view-port must be in 1..65535, got {port}")
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        try:
            sock.bind((host, int(port)))
        except OSError as exc:
            raise ViewError(
                f"the live view cannot listen on {host}:{port}: {exc.strerror} (choose another "
                "port with --view-port)"
            ) from None


def root_link(robot: RobotModel) -> str:
    """The URDF's root link (its frame is pinocchio's world: ``ffmpc_ros.robot_tree``)."""
    return next(
        e.child for e in robot_edges(robot) if e.parent == WORLD_FRAME and not e.world_aligned
    )


class ContactFromJointStates:
    """The contact frame's position from ``/plant/joint_states`` for the markers: given a
    JointState's CDR bytes, its stamp (ns) for the stamps on the grid of :data:`VIEW_PERIOD`
    (multiples of it; the first stamp after a grid point that had none), after pinocchio's
    forward kinematics of its q; None for the other stamps or for a bad message."""

    def __init__(self, robot: RobotModel) -> None:
        self.robot = robot
        self.data = robot.create_data()
        self.joint_index = {n: i for i, n in enumerate(robot.joint_names)}
        self._next_ns: int | None = None
        self.last: JointState | None = None

    def __call__(self, data: bytes) -> int | None:
        msg = deserialize_message(data, JointState)
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        period = int(round(VIEW_PERIOD * 1e9))
        if self._next_ns is None:  # the first point of the grid at or after the first stamp
            self._next_ns = -(-stamp_ns // period) * period
        if stamp_ns < self._next_ns:
            return None
        q = self.joint_positions(msg)
        if q is None:
            return None
        self._next_ns = (stamp_ns // period + 1) * period
        self.last = msg
        pin.framesForwardKinematics(self.robot.model, self.data, q)
        return stamp_ns

    def joint_positions(self, msg: JointState) -> np.ndarray | None:
        """q (rad) in the model's joint order from a JointState (by name when named)."""
        nq = self.robot.nq
        position = np.asarray(msg.position, dtype=float)
        if msg.name:
            if len(msg.name) != position.size:
                return None
            q = np.full(nq, np.nan)
            for name, value in zip(msg.name, position, strict=True):
                if name in self.joint_index:
                    q[self.joint_index[name]] = value
        else:
            q = position
        if q.shape != (nq,) or not np.all(np.isfinite(q)):
            return None
        return q

    def contact_position(self) -> np.ndarray:
        """The contact frame origin of the last q converted (m, world frame)."""
        return self.data.oMf[self.robot.contact_frame_id].translation.copy()


class ViewNode(Node):
    """The live view's node and Foxglove server (module docstring).

    Args:
        robot: robot model name (``iiwa``, ``panda``).
        host, port: where the Foxglove WebSocket server listens (port 0: any free port).
        use_sim_time: log and stamp on ``/clock``.
        discovery_period: wall s between two looks at the graph for new topics.
        wait_for_client: hold the run (the plant waits for this node's subscription to
            ``/plant/joint_states``) until a client subscribes to that topic.
    """

    def __init__(
        self,
        robot: str,
        *,
        host: str = DEFAULT_HOST,
        port: int = DEFAULT_PORT,
        context: Context | None = None,
        use_sim_time: bool = True,
        discovery_period: float = 0.1,
        node_name: str = "view",
        wait_for_client: bool = False,
    ) -> None:
        import foxglove

        super().__init__(
            node_name,
            context=context,
            parameter_overrides=[Parameter("use_sim_time", value=use_sim_time)],
        )
        self.namespace = self.get_namespace()
        self.robot = load_robot(robot)
        self.to_contact = ContactFromJointStates(self.robot)
        self.root = root_link(self.robot)
        self.definitions = MessageDefinitions()
        self.fox = foxglove.Context()
        self.mesh_root = Path(self.robot.urdf_path).resolve().parent
        self.wait_for_client = wait_for_client
        self.listener = _Subscriptions()
        # why the run started, or what client_ready still waits for (reported at the end)
        self.started_at = (
            "not started: no channel advertised yet" if wait_for_client else "did not wait"
        )
        self.server: WebSocketServer | None = None
        try:
            self.server = foxglove.start_server(
                name="ffmpc",
                host=host,
                port=port,
                context=self.fox,
                asset_handler=self._asset,
                server_listener=self.listener,
                message_backlog_size=CLIENT_BACKLOG,
            )
        except RuntimeError as exc:
            raise ViewError(f"the live view cannot listen on {host}:{port}: {exc}") from None
        self.host, self.port = host, int(self.server.port)
        self.channels: dict[str, Any] = {}
        self._latched: dict[str, bytes] = {}  # last message of each latched topic
        self._latched_at: dict[str, int] = {}
        self._latched_names = {self._name(t) for t in LATCHED}
        # latched topics a client subscribed to that have not sent it their last message yet
        # (the subscription came before the message, or while the server had not attached it)
        self._owed: set[str] = set()
        self._last_new_channel_at = time.monotonic()  # a topic's first advertisement
        self._schemas: dict[str, Any] = {}  # the Foxglove schema of each bridged topic
        self._advertised_at: dict[str, float] = {}  # monotonic s of each channel's advertisement
        self.readvertised: dict[str, int] = {}  # channels advertised again (_readvertise)
        self._bridges: dict[str, Any] = {}
        self.forwarded: dict[str, int] = {}  # messages sent to a client, per topic
        self.received: dict[str, int] = {}  # messages the bridge received, per topic
        self._force = np.zeros(3)
        self._path: np.ndarray | None = None
        self._hooks: dict[str, Callable[[bytes], None]] = {
            self._name(topics.PLANT_JOINT_STATES): self._on_joint_states,
            self._name(topics.SENSED_WRENCH): self._on_wrench,
            self._name(topics.MPC_PREDICTION): self._on_prediction,
        }
        self.pub_markers = self.create_publisher(
            MarkerArray, topics.VIEW_MARKERS, topics.publisher_qos(topics.VIEW_MARKERS)
        )
        self._timer = self.create_timer(
            discovery_period, self.discover, clock=Clock(clock_type=ClockType.STEADY_TIME)
        )
        self.discover()

    def _name(self, topic: str) -> str:
        """A graph topic's fully qualified name in this node's namespace (the graph's)."""
        return topics.resolve(topic, self.namespace)

    @property
    def address(self) -> str:
        """The server's WebSocket URL."""
        return f"ws://{self.host}:{self.port}"

    # -- assets --------------------------------------------------------------------------------
    def _asset(self, uri: str) -> bytes | None:
        """A mesh the URDF names, for a client that fetches it; only files under the URDF's
        directory are served (None otherwise)."""
        path = uri[len("file://") :] if uri.startswith("file://") else uri
        try:
            resolved = Path(path).resolve()
        except OSError:
            return None
        if self.mesh_root not in resolved.parents or not resolved.is_file():
            return None
        return resolved.read_bytes()

    # -- bridge --------------------------------------------------------------------------------
    @property
    def client_ready(self) -> bool:
        """A client has subscribed to ``/plant/joint_states``, every topic of the graph's
        contract (``topics.TOPICS``, ``topics.VIEW_TOPICS``: the state publisher's ``/tf`` and
        ``/tf_static`` included) is advertised, and either a client listens to every one of
        them (a client that subscribes to everything, such as the tests': nothing left to wait
        for) or :data:`CLIENT_SETTLE` s passed since the last channel was advertised and the
        last subscription came in (a Foxglove layout subscribes only to what its panels show).
        Meanwhile each channel no client took is advertised again (:meth:`_readvertise`)."""
        contract = [self._name(t) for t, _, _ in (*topics.TOPICS, *topics.VIEW_TOPICS)]
        self._readvertise(contract)
        unadvertised = [t for t in contract if t not in self.channels]
        if unadvertised:
            self.started_at = f"not started: no publisher seen yet on {unadvertised}"
            return False
        joint_states = self._name(topics.PLANT_JOINT_STATES)
        since = self.listener.subscribed.get(joint_states)
        if since is None:
            self.started_at = f"not started: no client has subscribed to {joint_states}"
            return False
        # subscribed (the server's listener) and attached (foxglove-sdk attaches a client's
        # sink to the channel a moment after the subscribe callback: a message logged before
        # is dropped)
        if all(t in self.listener.subscribed and self.channels[t].has_sinks() for t in contract):
            self.started_at = "all subscribed"
            return True
        last = max(since, self._last_new_channel_at, self.listener.last_at)
        missing = [t for t in contract if t not in self.listener.subscribed]
        if time.monotonic() - last >= CLIENT_SETTLE:
            self.started_at = f"settled; no client on {missing}"
            return True
        self.started_at = f"not started: settling, no client on {missing}"
        return False

    def _advertise(self, topic: str) -> Any:
        """A Foxglove channel of ``topic`` (its schema from :attr:`_schemas`), advertised to
        every client now and on connection."""
        import foxglove

        channel = foxglove.Channel(
            topic,
            schema=self._schemas[topic],
            message_encoding=MESSAGE_ENCODING,
            context=self.fox,
        )
        self.channels[topic] = channel
        self._advertised_at[topic] = time.monotonic()
        return channel

    def _readvertise(self, contract: list[str]) -> None:
        """``wait_for_client``: advertise again (close, then a new channel) each channel of the
        contract no client has subscribed to :data:`READVERTISE` s after it was advertised.
        foxglove-sdk 0.30.3 can miss the advertisement of a channel created while a client
        connects: the test's client, which subscribes to every channel, never heard of one or
        more of them in 4 of 6 runs beside two busy loops; when the one it missed was
        ``/plant/joint_states``, the run waited for ever (seen on CI), so this runs before any
        subscription. Advertising again is not a new channel: :data:`CLIENT_SETTLE` counts from
        the first advertisements (a layout's Foxglove never takes the channels it does not
        show)."""
        now = time.monotonic()
        for topic in contract:
            if topic in self.listener.subscribed or topic not in self._advertised_at:
                continue
            if now - self._advertised_at[topic] >= READVERTISE:
                self.channels[topic].close()
                self._advertise(topic)
                self.readvertised[topic] = self.readvertised.get(topic, 0) + 1

    def discover(self) -> None:
        """A channel and a raw subscription for every new topic that has a publisher (with
        ``wait_for_client``, ``/plant/joint_states`` is subscribed, and the plant may start,
        only once :attr:`client_ready`)."""
        import foxglove

        # a latched topic's last message for each new subscriber, as soon as there is one
        self._owed.update(t for t in self.listener.take_new() if t in self._latched_names)
        for topic in sorted(self._owed):
            if topic in self._latched and self.channels[topic].has_sinks():
                self.channels[topic].log(self._latched[topic], log_time=self._latched_at[topic])
                self.forwarded[topic] += 1
                self._owed.discard(topic)
        for topic, types in self.get_topic_names_and_types():
            if topic in self._bridges or topic in EXCLUDE:
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue
            type_name = publishers[0].topic_type or types[0]
            channel = self.channels.get(topic)
            if channel is None:
                try:
                    definition = self.definitions.full_text(type_name)
                except FfmpcError as exc:
                    self.get_logger().warning(f"{topic} not bridged: {exc}")
                    self._bridges[topic] = None
                    continue
                self._schemas[topic] = foxglove.Schema(
                    name=type_name, encoding=SCHEMA_ENCODING, data=definition.encode()
                )
                channel = self._advertise(topic)
                self._last_new_channel_at = self._advertised_at[topic]
                self.forwarded[topic] = 0
            if topic == self._name(topics.PLANT_JOINT_STATES) and self.wait_for_client:
                if not self.client_ready:
                    continue  # advertised; subscribed (the plant starts) once a client is in
            self._bridges[topic] = subscribe_raw(
                self,
                topic,
                type_name,
                offered_profiles(publishers),
                self._forwarder(topic, channel, topic in self._latched_names),
                BRIDGE_DEPTH,
            )

    def _forwarder(self, topic: str, channel: Channel, latched: bool) -> Callable[[bytes], None]:
        """The raw callback of a topic: forward to Foxglove while a client listens (a latched
        topic's last message is kept and sent again to each new subscriber), then the hook."""
        clock = self.get_clock()
        hook = self._hooks.get(topic)
        forwarded, received = self.forwarded, self.received
        received[topic] = 0

        channels = self.channels

        def on_message(data: bytes) -> None:
            now = clock.now().nanoseconds
            received[topic] += 1
            if latched:
                self._latched[topic], self._latched_at[topic] = data, now
            channel = channels[topic]  # (advertised again: _readvertise)
            if channel.has_sinks():
                channel.log(data, log_time=now)
                forwarded[topic] += 1
                self._owed.discard(topic)
            if hook is not None:
                hook(data)

        return on_message

    def report(self) -> dict[str, Any]:
        """What the view did: its address, the messages received and forwarded per topic, the
        wall s after the first subscription at which a client subscribed to each topic, why the
        run started (or what it still waited for) and the channels advertised again."""
        first = min(self.listener.subscribed.values(), default=0.0)
        return {
            "address": self.address,
            "forwarded": dict(self.forwarded),
            "received": dict(self.received),
            "subscribed": {t: round(at - first, 3) for t, at in self.listener.subscribed.items()},
            "started": self.started_at,
            "readvertised": dict(self.readvertised),
        }

    # -- robot view ----------------------------------------------------------------------------
    def _on_wrench(self, data: bytes) -> None:
        f = deserialize_message(data, WrenchStamped).wrench.force
        self._force = np.array([f.x, f.y, f.z])

    def _on_prediction(self, data: bytes) -> None:
        try:
            values = layouts.MPC_PREDICTION.unpack(deserialize_message(data, Float64MultiArray))
        except FfmpcError as exc:
            self.get_logger().warning(f"{topics.MPC_PREDICTION}: {exc}")
            return
        self._path = values["positions"].reshape(-1, 3)

    def _on_joint_states(self, data: bytes) -> None:
        if self.to_contact(data) is None:
            return
        assert self.to_contact.last is not None  # set with every conversion
        contact = self.to_contact.contact_position()
        self.pub_markers.publish(self.markers(self.to_contact.last.header.stamp, contact))

    def markers(self, stamp: TimeMsg, contact: np.ndarray) -> MarkerArray:
        """The force arrow at ``contact`` (m, world) and the planned path (module docstring),
        in the root link's frame (= world)."""
        arrow = Marker(ns="measured_force", id=0, type=Marker.ARROW, action=Marker.ADD)
        arrow.header.stamp, arrow.header.frame_id = stamp, self.root
        tip = contact + FORCE_ARROW_SCALE * self._force
        arrow.points = [_point(contact), _point(tip)]
        arrow.scale.x, arrow.scale.y, arrow.scale.z = 0.01, 0.02, 0.03
        arrow.pose.orientation.w = 1.0
        arrow.color = ColorRGBA(r=0.9, g=0.1, b=0.1, a=1.0)
        path = Marker(ns="planned_path", id=1, type=Marker.LINE_STRIP)
        path.header.stamp, path.header.frame_id = stamp, self.root
        path.pose.orientation.w = 1.0
        path.scale.x = 0.005
        path.color = ColorRGBA(r=0.1, g=0.8, b=0.2, a=1.0)
        if self._path is None:
            path.action = Marker.DELETE
        else:
            path.action = Marker.ADD
            path.points = [_point(p) for p in self._path]
        return MarkerArray(markers=[arrow, path])

    def close(self) -> None:
        """Stop the server and the bridge. Idempotent."""
        if self.server is not None:
            self._timer.cancel()
            for sub in self._bridges.values():
                if sub is not None:
                    self.destroy_subscription(sub)
            self.server.stop()
            self.server = None

    def destroy_node(self) -> None:
        self.close()
        super().destroy_node()


class _Subscriptions(ServerListener):
    """Server listener: the first time (monotonic s) a client subscribed to each topic, and
    the topics subscribed since the view last looked (``take_new``)."""

    def __init__(self) -> None:
        self.subscribed: dict[str, float] = {}
        self.last_at = -float("inf")  # monotonic s of the newest subscription
        self._new: list[str] = []

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        self.last_at = time.monotonic()
        self.subscribed.setdefault(channel.topic, self.last_at)
        self._new.append(channel.topic)

    def take_new(self) -> list[str]:
        new, self._new = self._new, []
        return new


def _point(p: np.ndarray) -> Point:
    return Point(x=float(p[0]), y=float(p[1]), z=float(p[2]))


def view_process(config_path: str) -> int:
    """The view node in its own process (``ffmpc run --view``).

    ``config_path``: JSON {"robot", "host", "port", "domain", "wait_for_client", "counts": path
    of the JSON written at the end}. Serves until SIGINT/SIGTERM (the bring-up stops it once the
    run is over; it dies with the bring-up through PR_SET_PDEATHSIG), then writes {"address",
    "forwarded", "tf"} to ``counts``. Exit 1 with the reason if the server cannot start."""
    from ffmpc_ros.child_process import child_ros_process

    with child_ros_process(config_path) as child:
        config, executor, stopping = child.config, child.executor, child.stopping
        try:
            node = ViewNode(
                config["robot"],
                host=config["host"],
                port=int(config["port"]),
                context=child.context,
                wait_for_client=bool(config.get("wait_for_client")),
            )
        except FfmpcError as exc:
            print(f"view: {exc}", flush=True)
            return 1
        print(f"view: Foxglove server on {node.address}", flush=True)
        executor.add_node(node)
        try:
            while not stopping:
                executor.spin_once(timeout_sec=0.05)
        finally:
            counts = node.report()
            node.close()
            if config.get("counts"):
                with open(config["counts"], "w", encoding="utf-8") as fh:
                    json.dump(counts, fh)
            executor.remove_node(node)
            node.destroy_node()
    return 0


def wait_for_port(host: str, port: int, timeout: float) -> bool:
    """Whether something accepts TCP connections on host:port within ``timeout`` wall s."""
    import socket

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
            sock.settimeout(0.2)
            if sock.connect_ex((host, int(port))) == 0:
                return True
        time.sleep(0.05)
    return False


if __name__ == "__main__":
    import sys

    raise SystemExit(view_process(sys.argv[1]))
