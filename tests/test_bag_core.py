"""The ROS-free MCAP core: schemas as rosbag2 writes them, BagWriter/BagReader round trips read
back by rosbags and mcap-ros2-support, refusal to overwrite, and what a writer killed with
SIGKILL leaves behind (readable up to its last complete chunk, recovered into a complete bag)."""

from __future__ import annotations

import io
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from ffmpc_ros.bag.errors import BagError, BagExistsError
from ffmpc_ros.bag.reader import BagReader, recover_bag
from ffmpc_ros.bag.schema import MessageDefinitions, qos_profile_dict
from ffmpc_ros.bag.writer import BagWriter

ROOT = Path(__file__).resolve().parents[1]
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
#: Every message type of the graph's topics (msgs_notes/topics.md) and /rosout.
GRAPH_TYPES = (
    "rosgraph_msgs/msg/Clock",
    "sensor_msgs/msg/JointState",
    "geometry_msgs/msg/WrenchStamped",
    "std_msgs/msg/Float64MultiArray",
    "std_msgs/msg/Bool",
    "std_msgs/msg/String",
    "rcl_interfaces/msg/Log",
)


def test_the_core_imports_no_ros():
    code = (
        "import sys, ffmpc_ros.bag.writer, ffmpc_ros.bag.reader, ffmpc_ros.bag.schema;"
        "bad = sorted(m for m in sys.modules if m.split('.')[0] in "
        "('rclpy', 'rosidl_runtime_py', 'std_msgs', 'sensor_msgs', 'rosgraph_msgs'));"
        "print(bad); sys.exit(1 if bad else 0)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stdout + done.stderr


@pytest.mark.parametrize("type_name", GRAPH_TYPES)
def test_full_definitions_parse_to_the_jazzy_types(type_name):
    """Our ros2msg text, parsed by rosbags, gives exactly the Jazzy definitions of the type and
    of every type it depends on; the first section is the installed .msg file itself."""
    text = MessageDefinitions().full_text(type_name)
    parsed = get_types_from_msg(text, type_name)
    assert type_name in parsed
    for name, fields in parsed.items():
        assert fields == TYPESTORE.fielddefs[name], name
    package, _, short = type_name.split("/")
    msg_file = Path(sys.prefix, "share", package, "msg", f"{short}.msg").read_text()
    assert text.startswith(msg_file)
    sections = text.count("=" * 80 + "\nMSG: ")
    assert sections == len(parsed) - 1  # each dependency exactly once


def test_joint_state_definition_has_rosbag2_layout():
    text = MessageDefinitions().full_text("sensor_msgs/JointState")
    heads = [line for line in text.splitlines() if line.startswith("MSG: ")]
    assert heads == ["MSG: std_msgs/Header", "MSG: builtin_interfaces/Time"]


def test_unknown_types_are_refused():
    with pytest.raises(BagError, match="no .msg definition"):
        MessageDefinitions().full_text("std_msgs/msg/NoSuchType")
    with pytest.raises(BagError, match="not a ROS message type"):
        MessageDefinitions().full_text("JointState")


# -- round trip ------------------------------------------------------------------------------
def _messages(rng: np.random.Generator, n: int) -> dict[str, list]:
    """Random messages of the graph's types (rosbags classes), by topic."""
    t = TYPESTORE.types
    out: dict[str, list] = {"/clock": [], "/js": [], "/wrench": [], "/array": [], "/flag": []}
    out["/text"] = []
    for k in range(n):
        stamp = t["builtin_interfaces/msg/Time"](sec=k // 1000, nanosec=(k % 1000) * 1_000_000)
        header = t["std_msgs/msg/Header"](stamp=stamp, frame_id="contact_world_aligned")
        out["/clock"].append(t["rosgraph_msgs/msg/Clock"](clock=stamp))
        out["/js"].append(
            t["sensor_msgs/msg/JointState"](
                header=header,
                name=[f"j{i}" for i in range(7)],
                position=rng.normal(size=7),
                velocity=rng.normal(size=7),
                effort=rng.normal(size=7) * 100,
            )
        )
        vec = t["geometry_msgs/msg/Vector3"]
        out["/wrench"].append(
            t["geometry_msgs/msg/WrenchStamped"](
                header=header,
                wrench=t["geometry_msgs/msg/Wrench"](
                    force=vec(*rng.normal(size=3)), torque=vec(*rng.normal(size=3))
                ),
            )
        )
        dim = t["std_msgs/msg/MultiArrayDimension"](label="ffmpc/mpc_command/1", size=3, stride=3)
        layout = t["std_msgs/msg/MultiArrayLayout"](dim=[dim], data_offset=0)
        out["/array"].append(
            t["std_msgs/msg/Float64MultiArray"](layout=layout, data=rng.normal(size=3))
        )
        out["/flag"].append(t["std_msgs/msg/Bool"](data=bool(k % 2)))
        out["/text"].append(t["std_msgs/msg/String"](data=json.dumps({"k": k, "é": "ü"})))
    return out


TOPIC_TYPES = {
    "/clock": "rosgraph_msgs/msg/Clock",
    "/js": "sensor_msgs/msg/JointState",
    "/wrench": "geometry_msgs/msg/WrenchStamped",
    "/array": "std_msgs/msg/Float64MultiArray",
    "/flag": "std_msgs/msg/Bool",
    "/text": "std_msgs/msg/String",
}


def _write_bag(target, rng, n=40, **options):
    messages = _messages(rng, n)
    written = []
    qos = [qos_profile_dict(depth=100, durability="transient_local")]
    with BagWriter(target, **options) as writer:
        for topic, type_name in TOPIC_TYPES.items():
            writer.add_topic(topic, type_name, qos_profiles=qos, type_hash="RIHS01_test")
        writer.add_parameters("/mpc", {"dt": 0.1 + 0.2, "tiny": 1e-300, "n": 5, "w": [1.5, 2.0]})
        writer.add_metadata("note", {"what": "test"})
        for k in range(n):
            for topic, type_name in TOPIC_TYPES.items():
                data = bytes(TYPESTORE.serialize_cdr(messages[topic][k], type_name))
                log_time = k * 1_000_000 + len(written)
                writer.write(topic, data, log_time, publish_time=log_time + 7, sequence=k)
                written.append((topic, log_time, data))
    return messages, written


def test_round_trip_bytes_times_metadata_and_parameters(tmp_path):
    path = tmp_path / "rt.mcap"
    _, written = _write_bag(path, np.random.default_rng(1), chunk_size=4096)
    with BagReader(path) as bag:
        assert bag.recovery.complete and bag.recovery.chunks > 1
        read = [(m.topic, m.log_time, m.data) for m in bag.messages()]
        assert read == written
        assert {t: i.type for t, i in bag.topics.items()} == TOPIC_TYPES
        assert all(i.count == 40 for i in bag.topics.values())
        info = bag.topics["/js"]
        assert info.qos_profiles == [qos_profile_dict(depth=100, durability="transient_local")]
        assert info.type_hash == "RIHS01_test"
        params = bag.parameters["/mpc"]
        assert params == {"dt": 0.1 + 0.2, "tiny": 1e-300, "n": 5, "w": [1.5, 2.0]}
        assert isinstance(params["n"], int) and isinstance(params["dt"], float)
        assert bag.metadata_named("note") == {"what": "test"}
        rosbag2 = yaml.safe_load(bag.metadata_named("rosbag2")["serialized_metadata"])
        assert rosbag2["version"] == 9 and rosbag2["message_count"] == len(written)
        counts = {
            x["topic_metadata"]["name"]: x["message_count"]
            for x in rosbag2["topics_with_message_count"]
        }
        assert counts == dict.fromkeys(TOPIC_TYPES, 40)
        only = [m.topic for m in bag.messages(["/flag", "/clock"])]
        assert sorted(set(only)) == ["/clock", "/flag"] and len(only) == 80


def test_rosbags_and_mcap_ros2_decode_what_was_written(tmp_path):
    path = tmp_path / "dec.mcap"
    messages, _ = _write_bag(path, np.random.default_rng(2))
    with AnyReader([path], default_typestore=TYPESTORE) as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == dict.fromkeys(TOPIC_TYPES, 40)
        seen = {t: 0 for t in TOPIC_TYPES}
        for connection, _, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            sent = messages[connection.topic][seen[connection.topic]]
            seen[connection.topic] += 1
            if connection.topic == "/js":
                np.testing.assert_array_equal(msg.effort, sent.effort)
                assert msg.name == sent.name and msg.header.stamp == sent.header.stamp
            elif connection.topic == "/array":
                np.testing.assert_array_equal(msg.data, sent.data)
                assert msg.layout.dim[0].label == "ffmpc/mpc_command/1"
            elif connection.topic == "/text":
                assert msg.data == sent.data
    decoded = {t: [] for t in TOPIC_TYPES}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _, channel, _, ros_msg in reader.iter_decoded_messages():
            decoded[channel.topic].append(ros_msg)
    assert all(len(v) == 40 for v in decoded.values())
    for k in (0, 17, 39):
        w = decoded["/wrench"][k].wrench.force
        sent = messages["/wrench"][k].wrench.force
        assert (w.x, w.y, w.z) == (sent.x, sent.y, sent.z)
        assert decoded["/flag"][k].data == messages["/flag"][k].data
        assert decoded["/clock"][k].clock.nanosec == messages["/clock"][k].clock.nanosec


def test_a_folder_target_is_a_rosbag2_bag_that_rosbags_opens(tmp_path, capsys):
    """A path without ``.mcap``: the folder ``run/`` with ``run_0.mcap`` and ``metadata.yaml``,
    which rosbags' rosbag2 reader opens; BagReader and ``ffmpc bag info`` read both forms."""
    folder = tmp_path / "run"
    messages, written = _write_bag(folder, np.random.default_rng(3))
    assert sorted(p.name for p in folder.iterdir()) == ["metadata.yaml", "run_0.mcap"]
    info = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    with BagReader(folder) as bag:
        assert bag.folder == folder and bag.path == folder / "run_0.mcap"
        assert [(m.topic, m.log_time, m.data) for m in bag.messages()] == written
        assert yaml.safe_load(bag.metadata_named("rosbag2")["serialized_metadata"]) == info
    assert info["relative_file_paths"] == ["run_0.mcap"] and info["storage_identifier"] == "mcap"
    with Rosbag2Reader(folder) as reader:  # rosbags' rosbag2 reader, through metadata.yaml
        assert reader.message_count == len(written)
        assert {c.topic: c.msgcount for c in reader.connections} == dict.fromkeys(TOPIC_TYPES, 40)
        js = [c for c in reader.connections if c.topic == "/js"]
        efforts = [
            TYPESTORE.deserialize_cdr(raw, "sensor_msgs/msg/JointState").effort
            for _, _, raw in reader.messages(connections=js)
        ]
    for got, sent in zip(efforts, messages["/js"], strict=True):
        np.testing.assert_array_equal(got, sent.effort)
    from ffmpc_ros.cli import main

    assert main(["bag", "info", str(folder), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["folder"] == str(folder) and doc["messages"] == len(written)
    with pytest.raises(BagExistsError, match="never overwritten"):
        BagWriter(folder)


def test_a_folder_bag_without_metadata_is_read_and_recovered(tmp_path):
    """A killed writer leaves the folder without ``metadata.yaml``: read through its MCAP file,
    and ``recover`` writes a complete rosbag2 folder."""
    folder = tmp_path / "killed"
    _, written = _write_bag(folder, np.random.default_rng(4), n=10)
    (folder / "metadata.yaml").unlink()
    with BagReader(folder) as bag:
        assert bag.message_count == len(written)
        assert "no metadata.yaml: recover it" in bag.describe()
    report = recover_bag(folder, tmp_path / "fixed")
    assert report.complete and report.messages == len(written)
    with Rosbag2Reader(tmp_path / "fixed") as reader:
        assert reader.message_count == len(written)
    (folder / "killed_0.mcap").rename(folder / "other.txt")
    with pytest.raises(BagError, match="no bag file in .*0 MCAP files"):
        BagReader(folder)


def test_writers_never_overwrite(tmp_path):
    path = tmp_path / "exists.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(BagExistsError, match="never overwritten"):
        BagWriter(path)
    assert path.read_bytes() == b"precious"
    used = io.BytesIO(b"precious")
    with pytest.raises(BagExistsError, match="existing data"):
        BagWriter(used)
    assert used.getvalue() == b"precious"
    stream = io.BytesIO()
    with BagWriter(stream) as writer:  # an empty file object is fine, and stays open
        writer.add_topic("/flag", "std_msgs/msg/Bool")
        writer.write(
            "/flag",
            bytes(
                TYPESTORE.serialize_cdr(
                    TYPESTORE.types["std_msgs/msg/Bool"](data=True), "std_msgs/msg/Bool"
                )
            ),
            5,
        )
    assert not stream.closed and stream.getvalue().startswith(b"\x89MCAP0\r\n")
    with pytest.raises(BagError, match="compression"):
        BagWriter(tmp_path / "x.mcap", compression="gzip")
    assert not (tmp_path / "x.mcap").exists()


def test_a_topic_keeps_its_type(tmp_path):
    with BagWriter(tmp_path / "t.mcap") as writer:
        assert writer.add_topic("/a", "std_msgs/Bool") == writer.add_topic(
            "/a", "std_msgs/msg/Bool"
        )
        with pytest.raises(BagError, match="already recorded"):
            writer.add_topic("/a", "std_msgs/msg/String")
        with pytest.raises(BagError, match="not registered"):
            writer.write("/b", b"", 0)


# -- durability --------------------------------------------------------------------------------
_KILLED_WRITER = textwrap.dedent(
    """
    import struct, sys, time
    from ffmpc_ros.bag.writer import BagWriter
    with BagWriter(sys.argv[1], chunk_size=1 << 30, flush_interval=0.05) as writer:
        writer.add_topic("/counter", "std_msgs/msg/Float64MultiArray")
        i = 0
        while True:
            # CDR of a Float64MultiArray with no dims and data [i] (4 bytes pad the double)
            data = b"\\x00\\x01\\x00\\x00" + struct.pack("<IIIId", 0, 0, 1, 0, i)
            writer.write("/counter", data, i * 1000)
            if i % 50 == 0:
                print(i, time.monotonic(), flush=True)
            i += 1
            time.sleep(0.0002)
    """
)


def _counter(data: bytes) -> int:
    return int(np.frombuffer(data[-8:], dtype="<f8")[0])


def test_sigkill_leaves_a_bag_readable_up_to_its_last_complete_chunk(tmp_path, capsys):
    path = tmp_path / "killed.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-c", _KILLED_WRITER, str(path)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    lines = []
    start = time.monotonic()
    while time.monotonic() - start < 1.5 or len(lines) < 20:
        lines.append(proc.stdout.readline().split())
        assert time.monotonic() - start < 30, "the writer did not start"
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    proc.stdout.close()
    with BagReader(path) as bag:
        report = bag.recovery
        assert not report.complete
        counters = [_counter(m.data) for m in bag.messages()]
    # Every message up to the last complete chunk, in order, none after.
    assert counters == list(range(len(counters))) and report.messages == len(counters)
    assert report.chunks >= 5 and report.readable_bytes <= report.file_size
    # A message written more than 0.3 s before the last sign of life is in a complete chunk
    # (chunks are closed every 0.05 s).
    last_time = float(lines[-1][1])
    old_enough = max(int(i) for i, t in lines if float(t) <= last_time - 0.3)
    assert len(counters) > old_enough
    # The tools say how much was recovered; recover writes a complete bag.
    from ffmpc_ros.cli import main

    assert main(["bag", "info", str(path)]) == 3
    out = capsys.readouterr().out
    assert f"recovered {len(counters)} messages in {report.chunks} complete chunks" in out
    fixed = tmp_path / "recovered.mcap"
    assert main(["bag", "recover", str(path), str(fixed)]) == 0
    with BagReader(fixed) as bag:
        assert bag.recovery.complete and bag.message_count == len(counters)
        assert bag.metadata_named("ffmpc_recovery")["messages"] == str(len(counters))
    with AnyReader([fixed], default_typestore=TYPESTORE) as reader:
        values = [reader.deserialize(raw, c.msgtype).data[0] for c, _, raw in reader.messages()]
    assert values == [float(i) for i in range(len(counters))]
