"""``ffmpc run --view``: a Foxglove WebSocket client (``foxglove.sdk.v1``) connects to the
live view of a short lockstep run, subscribes to every channel advertised and decodes what
arrives; the run is recorded at the same time, and the bag holds the view's topics too. The
robot's frames (/tf, /tf_static) and URDF are the state publisher's, bridged as they are."""

from __future__ import annotations

import json
import socket
import struct
import threading
import time

import numpy as np
import pinocchio as pin
import pytest
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import MarkerArray

from ffmpc_core.polishing import mpc_config
from ffmpc_core.robots import load_robot
from ffmpc_core.scenario import load_scenario
from ffmpc_ros import layouts, topics
from ffmpc_ros.bag.reader import BagReader
from ffmpc_ros.bag.schema import MessageDefinitions
from ffmpc_ros.bringup import GraphError, GraphOptions, run_graph
from ffmpc_ros.robot_tree import WORLD_FRAME
from ffmpc_ros.view import ViewError, check_port_free

websockets_sync = pytest.importorskip("websockets.sync.client")
from websockets.exceptions import InvalidHandshake  # noqa: E402  (websockets is there)

#: foxglove-sdk 0.30.3 accepts only this subprotocol (a handshake offering only
#: "foxglove.websocket.v1" gets HTTP 400 "Missing expected sec-websocket-protocol header");
#: its operations are those of foxglove.websocket.v1 (advertise, subscribe, message data).
SUBPROTOCOL = "foxglove.sdk.v1"
DURATION = 0.2  # simulated s


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


class FoxgloveClient(threading.Thread):
    """Connects (retrying until the server is up: a refused connection, or a handshake the
    starting server does not complete), subscribes to each advertised channel and keeps every
    message: {topic: [(log time ns, payload)]}."""

    def __init__(
        self,
        port: int,
        timeout: float,
        only: frozenset[str] | None = None,
        deaf_once: frozenset[str] = frozenset(),
    ) -> None:
        """``only``: subscribe to these topics alone (a Foxglove layout's panels; None: every
        channel); ``deaf_once``: ignore the first advertisement of these topics (a client that
        missed it, as foxglove-sdk's clients sometimes do while the server creates channels)."""
        super().__init__(daemon=True)
        self.url = f"ws://127.0.0.1:{port}"
        self.timeout = timeout
        self.only = only
        self.deaf = set(deaf_once)
        self.channels: dict[int, dict] = {}
        self.messages: dict[str, list[tuple[int, bytes]]] = {}
        self.server_info: dict | None = None
        self.error: BaseException | None = None

    def run(self) -> None:
        end = time.monotonic() + self.timeout
        try:
            while True:
                try:
                    ws = websockets_sync.connect(self.url, subprotocols=[SUBPROTOCOL])
                    break
                except (OSError, InvalidHandshake):
                    if time.monotonic() > end:
                        raise
                    time.sleep(0.1)
            with ws:
                assert ws.subprotocol == SUBPROTOCOL
                subscriptions: dict[int, str] = {}
                while time.monotonic() < end:
                    try:
                        frame = ws.recv(timeout=1.0)
                    except TimeoutError:
                        continue
                    except Exception:  # noqa: BLE001  (the server closed: the run is over)
                        return
                    if isinstance(frame, bytes):
                        assert frame[0] == 0x01, f"binary opcode {frame[0]}"
                        sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
                        self.messages.setdefault(subscriptions[sub_id], []).append(
                            (log_time, frame[13:])
                        )
                        continue
                    msg = json.loads(frame)
                    if msg["op"] == "serverInfo":
                        self.server_info = msg
                    elif msg["op"] == "advertise":
                        new = []
                        for channel in msg["channels"]:
                            if channel["topic"] in self.deaf:
                                self.deaf.discard(channel["topic"])
                                continue
                            if self.only is not None and channel["topic"] not in self.only:
                                continue
                            self.channels[channel["id"]] = channel
                            sub_id = len(subscriptions) + 1
                            subscriptions[sub_id] = channel["topic"]
                            new.append({"id": sub_id, "channelId": channel["id"]})
                        if new:
                            ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
        except BaseException as exc:  # noqa: BLE001  (reported by the test)
            self.error = exc


@pytest.fixture(scope="module")
def live_run(tmp_path_factory):
    port = _free_port()
    bag = tmp_path_factory.mktemp("view") / "run"
    client = FoxgloveClient(port, timeout=120.0)
    client.start()
    try:
        result = run_graph(
            load_scenario("polishing"),
            GraphOptions(
                duration=DURATION, timeout=120, record=bag, view=port, view_wait=True
            ),  # the run starts once the client is subscribed: nothing is missed
        )
    except GraphError as exc:  # (a graph that waited for the client: say what the client saw)
        raise GraphError(f"{exc}; the Foxglove client: error {client.error!r}") from exc
    client.join(timeout=15.0)
    assert not client.is_alive(), "the server did not close when the run ended"
    assert client.error is None, repr(client.error)
    return result, client, bag


def _by_topic(client: FoxgloveClient) -> dict[str, dict]:
    return {c["topic"]: c for c in client.channels.values()}


def test_channels_are_ros_topics_with_their_full_definitions(live_run):
    result, client, _ = live_run
    assert client.server_info is not None
    channels = _by_topic(client)
    expected = {
        topics.TF: "tf2_msgs/msg/TFMessage",
        topics.TF_STATIC: "tf2_msgs/msg/TFMessage",
        topics.resolve(topics.PLANT_JOINT_STATES): "sensor_msgs/msg/JointState",
        topics.resolve(topics.SENSED_WRENCH): "geometry_msgs/msg/WrenchStamped",
        topics.resolve(topics.MPC_COMMAND): "ffmpc_msgs/msg/MpcCommand",
        topics.resolve(topics.MPC_PREDICTION): "std_msgs/msg/Float64MultiArray",
        topics.resolve(topics.ROBOT_DESCRIPTION): "std_msgs/msg/String",
        topics.resolve(topics.VIEW_MARKERS): "visualization_msgs/msg/MarkerArray",
        topics.CLOCK: "rosgraph_msgs/msg/Clock",
    }
    for topic, schema_name in expected.items():
        assert topic in channels, f"{topic} not advertised: {sorted(channels)}"
        channel = channels[topic]
        assert channel["schemaName"] == schema_name
        assert channel["encoding"] == "cdr" and channel["schemaEncoding"] == "ros2msg"
    definitions = MessageDefinitions()
    assert channels[topics.resolve(topics.PLANT_JOINT_STATES)]["schema"] == definitions.full_text(
        "sensor_msgs/msg/JointState"
    )
    assert channels[topics.TF]["schema"] == definitions.full_text("tf2_msgs/msg/TFMessage")
    assert "MSG: geometry_msgs/TransformStamped" in channels[topics.TF]["schema"]
    assert result.view is not None and result.view["forwarded"][topics.TF] > 0


def _edges(tf) -> dict[str, tuple[str, pin.SE3]]:
    """{child: (parent, placement in parent)} of a decoded TFMessage."""
    edges = {}
    for t in tf.transforms:
        r, p = t.transform.rotation, t.transform.translation
        rotation = pin.Quaternion(r.w, r.x, r.y, r.z).toRotationMatrix()
        edges[t.child_frame_id] = (t.header.frame_id, pin.SE3(rotation, np.array([p.x, p.y, p.z])))
    return edges


def _chain(transforms: dict[str, tuple[str, pin.SE3]], frame: str) -> pin.SE3:
    placement = pin.SE3.Identity()
    while frame != WORLD_FRAME:
        parent, edge = transforms[frame]
        placement = edge * placement
        frame = parent
    return placement


def test_tf_is_the_forward_kinematics_of_the_joint_states(live_run):
    """The bridged /tf (and /tf_static, latched: sent to the client that subscribed late) give
    the contact frame of the MEASURED joint state with the same stamp."""
    _, client, _ = live_run
    robot = load_robot(load_scenario("polishing").robot)
    data = robot.create_data()
    states = {}
    for _, payload in client.messages[topics.resolve(topics.SENSED_JOINT_STATES)]:
        msg = deserialize_message(payload, JointState)
        states[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = np.array(msg.position)
    # latched: a client that subscribed again (a re-advertised channel) may get it twice
    statics = {payload for _, payload in client.messages[topics.TF_STATIC]}
    assert len(statics) == 1, f"{len(statics)} different /tf_static messages"
    static = _edges(deserialize_message(statics.pop(), TFMessage))
    compared = 0
    for _, payload in client.messages[topics.TF]:
        tf = deserialize_message(payload, TFMessage)
        stamp = tf.transforms[0].header.stamp
        q = states.get((stamp.sec, stamp.nanosec))
        if q is None:
            continue  # its joint state came before the client's subscription
        tool = _chain({**static, **_edges(tf)}, "contact")
        expected = robot.contact_placement(q, data)
        assert np.allclose(tool.translation, expected.translation, rtol=0, atol=1e-9)
        assert np.allclose(tool.rotation, expected.rotation, rtol=0, atol=1e-9)
        compared += 1
    assert compared >= 5, f"only {compared} /tf messages matched a joint state"


def test_prediction_description_and_markers_decode_with_sane_values(live_run):
    _, client, _ = live_run
    scenario = load_scenario("polishing")
    robot = load_robot(scenario.robot)
    horizon = mpc_config(scenario).ocp.horizon
    predictions = client.messages[topics.resolve(topics.MPC_PREDICTION)]
    assert len(predictions) >= 10
    contact_now = {}
    for _, payload in client.messages[topics.resolve(topics.PLANT_JOINT_STATES)]:
        msg = deserialize_message(payload, JointState)
        t = round(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, 6)
        contact_now[t] = robot.contact_placement(np.array(msg.position)).translation
    near = 0
    for _, payload in predictions:
        values = layouts.MPC_PREDICTION.unpack(deserialize_message(payload, Float64MultiArray))
        assert values["nodes"] == horizon + 1
        positions = values["positions"].reshape(-1, 3)
        assert np.all(np.abs(values["normal_force"]) < 500.0)
        assert np.all(np.abs(values["reference_force"]) < 500.0)
        truth = contact_now.get(round(values["t"], 6))
        if truth is not None:  # node 0: the measured state (sensor noise and delay: mm)
            assert np.linalg.norm(positions[0] - truth) < 0.01
            near += 1
    assert near >= 5
    (_, description), *_ = client.messages[topics.resolve(topics.ROBOT_DESCRIPTION)]
    urdf = deserialize_message(description, String).data
    assert "<robot" in urdf and "file://" in urdf
    markers = [
        deserialize_message(p, MarkerArray)
        for _, p in client.messages[topics.resolve(topics.VIEW_MARKERS)]
    ]
    assert markers and {m.ns for m in markers[-1].markers} == {"measured_force", "planned_path"}
    path = next(m for m in markers[-1].markers if m.ns == "planned_path")
    assert len(path.points) == horizon + 1


def test_the_bag_of_the_same_run_holds_the_view_topics_and_tf(live_run):
    from rosbags.rosbag2 import Reader as Rosbag2Reader
    from rosbags.typesys import Stores, get_typestore

    _, client, bag = live_run
    with BagReader(bag) as reader:
        for topic in (
            topics.resolve(topics.ROBOT_DESCRIPTION),
            topics.resolve(topics.VIEW_MARKERS),
            topics.resolve(topics.MPC_PREDICTION),
        ):
            assert reader.topics[topic].count > 0, topic
        # /tf: the state publisher's, from the measured joint states (10 ms of stamps apart);
        # /tf_static once
        assert reader.topics[topics.TF].count == -(
            -reader.topics[topics.resolve(topics.SENSED_JOINT_STATES)].count // 10
        )
        assert reader.topics[topics.TF_STATIC].count == 1
    store = get_typestore(Stores.ROS2_JAZZY)
    robot = load_robot(load_scenario("polishing").robot)
    states, tfs = {}, []
    with Rosbag2Reader(bag) as reader:
        wanted = [
            c
            for c in reader.connections
            if c.topic in (topics.TF, topics.TF_STATIC, topics.resolve(topics.SENSED_JOINT_STATES))
        ]
        for connection, _, raw in reader.messages(connections=wanted):
            msg = store.deserialize_cdr(raw, connection.msgtype)
            if connection.topic == topics.TF:
                tfs.append(msg)
            elif connection.topic == topics.TF_STATIC:
                static = _edges(msg)
            else:
                states[(msg.header.stamp.sec, msg.header.stamp.nanosec)] = msg.position
    for tf in tfs:
        stamp = tf.transforms[0].header.stamp
        tool = _chain({**static, **_edges(tf)}, "contact")
        expected = robot.contact_placement(np.asarray(states[(stamp.sec, stamp.nanosec)]))
        assert np.allclose(tool.homogeneous, expected.homogeneous, rtol=0, atol=1e-9)
    live = {
        deserialize_message(p, TFMessage).transforms[0].header.stamp.nanosec
        for _, p in client.messages[topics.TF]
    }
    assert live and live <= {tf.transforms[0].header.stamp.nanosec for tf in tfs}  # one /tf


def test_playing_the_bag_publishes_tf_too(live_run):
    """tf2_msgs is installed (generated from the wheels): every topic of the bag is played."""
    from ffmpc_ros.bag.player import play_bag

    _, _, bag = live_run
    report = play_bag(bag, rate=4.0, delay=0.1)
    assert report.skipped == [] and report.published[topics.TF] > 0
    assert report.published[topics.TF_STATIC] == 1
    assert report.published[topics.resolve(topics.ROBOT_DESCRIPTION)] == 1


def _waiting_run(client: FoxgloveClient, port: int) -> tuple[dict, FoxgloveClient]:
    """A short single-process run that waits for ``client`` on ``port``; the view's report."""
    client.start()
    try:
        result = run_graph(
            load_scenario("polishing"),
            GraphOptions(duration=0.02, single_process=True, timeout=60, view=port, view_wait=True),
        )
    except GraphError as exc:
        raise GraphError(f"{exc}; the Foxglove client: error {client.error!r}") from exc
    client.join(timeout=15.0)
    assert client.error is None, repr(client.error)
    return result.view, client


def test_a_client_that_missed_the_joint_states_advertisement_still_starts_the_run():
    """The run waits for a subscription to /plant/joint_states: a client that never heard of
    that channel (seen on CI: the graph waited 120 s) hears of it again READVERTISE s later."""
    port = _free_port()
    deaf = frozenset({topics.resolve(topics.PLANT_JOINT_STATES)})
    view, client = _waiting_run(FoxgloveClient(port, timeout=60.0, deaf_once=deaf), port)
    assert view["readvertised"].get(topics.resolve(topics.PLANT_JOINT_STATES), 0) >= 1
    assert view["started"] == "all subscribed"
    assert len(client.messages[topics.resolve(topics.PLANT_JOINT_STATES)]) >= 10


def test_a_client_on_some_topics_starts_the_run_once_it_settled():
    """A Foxglove layout subscribes only to what its panels show: the run starts CLIENT_SETTLE
    s after its last subscription, although the other channels are advertised again."""
    from ffmpc_ros.view import CLIENT_SETTLE

    port = _free_port()
    shown = frozenset({topics.resolve(topics.PLANT_JOINT_STATES), topics.TF})
    start = time.monotonic()
    view, client = _waiting_run(FoxgloveClient(port, timeout=60.0, only=shown), port)
    assert view["started"].startswith("settled; no client on")
    assert topics.resolve(topics.SENSED_WRENCH) in view["started"]
    assert time.monotonic() - start >= CLIENT_SETTLE
    assert topics.resolve(topics.PLANT_JOINT_STATES) in client.messages
    assert set(client.messages) <= shown


def test_a_run_nobody_looks_at_times_out_saying_what_the_view_waits_for():
    joint_states = topics.resolve(topics.PLANT_JOINT_STATES)
    with pytest.raises(GraphError, match=f"the view: not started: no client .* {joint_states}"):
        run_graph(
            load_scenario("polishing"),
            GraphOptions(
                duration=0.02, single_process=True, timeout=5, view=_free_port(), view_wait=True
            ),
        )


def test_a_busy_port_is_refused_with_a_clear_error():
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        port = sock.getsockname()[1]
        with pytest.raises(ViewError, match=f"127.0.0.1:{port}.*--view-port"):
            check_port_free("127.0.0.1", port)
        with pytest.raises(ViewError, match="--view-port"):
            run_graph(load_scenario("polishing"), GraphOptions(duration=DURATION, view=port))


def test_the_committed_layout_is_the_generated_one_and_fits_the_scenarios():
    from ffmpc_ros.ament import foxglove_layout_path
    from ffmpc_ros.view_layout import NODES, foxglove_layout

    committed = json.loads(foxglove_layout_path().read_text(encoding="utf-8"))
    assert committed == foxglove_layout()
    assert mpc_config(load_scenario("polishing")).ocp.horizon + 1 == NODES
    text = json.dumps(committed)
    for topic in (
        topics.resolve(topics.ROBOT_DESCRIPTION),
        topics.resolve(topics.VIEW_MARKERS),
        topics.resolve(topics.MPC_PREDICTION),
    ):
        assert f'"{topic}' in text


def test_markers_are_derived_on_one_grid_of_stamps_whatever_the_first_joint_state():
    """The view's markers come on one grid of stamps (multiples of VIEW_PERIOD): a view that
    sees the joint states from 3 ms and one from 0 ms place them at the same stamps."""
    from rclpy.serialization import serialize_message

    from ffmpc_ros.view import VIEW_PERIOD, ContactFromJointStates

    robot = load_robot("iiwa")

    def stamps(first_ms: int, last_ms: int, skip: tuple[int, ...] = ()) -> list[int]:
        convert = ContactFromJointStates(robot)
        out = []
        for ms in range(first_ms, last_ms):
            if ms in skip:
                continue
            msg = JointState(name=list(robot.joint_names), position=robot.q_nominal.tolist())
            msg.header.stamp.sec, msg.header.stamp.nanosec = 0, ms * 1_000_000
            result = convert(serialize_message(msg))
            if result is not None:
                out.append(result // 1_000_000)
        return out

    assert VIEW_PERIOD == 0.01
    assert stamps(0, 35) == [0, 10, 20, 30]
    assert stamps(3, 35) == [10, 20, 30]
    assert stamps(0, 35, skip=(20, 21)) == [0, 10, 22, 30]  # a missed grid point: the next one
