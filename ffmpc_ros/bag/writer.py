"""BagWriter: raw CDR messages into a rosbag2-compatible MCAP file. No ROS import.

The file is what rosbag2's MCAP storage plugin writes: profile ``ros2``, one ``ros2msg`` schema
per type (the complete definition, :mod:`ffmpc_ros.bag.schema`), one ``cdr`` channel per topic
with the ``offered_qos_profiles`` (and ``topic_type_hash``) metadata, log and publish times in
nanoseconds, chunked and compressed (zstd by default), with a summary and a ``rosbag2`` metadata
record (``serialized_metadata``) at the end. ffmpc adds metadata records of its own: the
parameters of every node (``ros_parameters:<node>``, values as JSON) and whatever the caller
adds.

Two forms, chosen by the target path: ``run.mcap`` (a path ending in ``.mcap``) is a single MCAP
file; any other path is a **rosbag2 folder** as ``ros2 bag record`` writes it: the folder
``run/`` holds ``run_0.mcap`` and, once the bag is closed, ``metadata.yaml``
(``rosbag2_bagfile_information``: the same BagMetadata as the record inside the MCAP file), so
``ros2 bag info run`` and ``rosbags``' rosbag2 reader open it. A folder without
``metadata.yaml`` is a bag whose writer was killed: :class:`~ffmpc_ros.bag.reader.BagReader`
reads its MCAP file, and ``ffmpc bag recover`` writes a complete copy.

Durability. The writer never overwrites: a path that exists is refused (the file is created
with ``O_EXCL``), and so is a file object that already holds data after its position. Chunks go
straight to the operating system (no user-space buffer) and a chunk is closed at least every
``flush_interval`` seconds (wall time) as well as when it reaches ``chunk_size`` bytes, so a
writer killed with SIGKILL leaves a file that :class:`~ffmpc_ros.bag.reader.BagReader` reads up
to its last complete chunk (with ``fsync=True`` that also holds after a power loss).
"""

from __future__ import annotations

import io
import json
import os
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import IO, Any

import yaml
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from ffmpc_ros.bag.errors import BagError, BagExistsError
from ffmpc_ros.bag.schema import (
    MESSAGE_ENCODING,
    PROFILE,
    SCHEMA_ENCODING,
    MessageDefinitions,
    normalize_type,
    qos_yaml,
)

#: Prefix of the metadata record holding one node's parameters (``ros_parameters:/mpc``).
PARAMETERS_PREFIX = "ros_parameters:"
#: Name of rosbag2's own metadata record, and its key.
ROSBAG2_METADATA = "rosbag2"
ROSBAG2_METADATA_KEY = "serialized_metadata"
#: rosbag2 metadata version written (Jazzy).
ROSBAG2_VERSION = 9
#: Suffix of a single-file bag; a target path without it is a rosbag2 folder.
MCAP_SUFFIX = ".mcap"
#: The file of a rosbag2 folder that describes the bag, and its top-level key.
FOLDER_METADATA = "metadata.yaml"
FOLDER_METADATA_KEY = "rosbag2_bagfile_information"
LIBRARY = "ffmpc bag writer (mcap-python)"

_COMPRESSION = {
    "zstd": CompressionType.ZSTD,
    "lz4": CompressionType.LZ4,
    "none": CompressionType.NONE,
}


class _DirectStream:
    """A write-only stream that hands every write to the OS at once (no user-space buffer), so
    whatever the MCAP writer has written survives the process being killed."""

    def __init__(self, raw: io.FileIO, fsync: bool) -> None:
        self._raw = raw
        self._fsync = fsync
        self._position = 0

    def write(self, data: bytes | bytearray | memoryview) -> int:
        view = memoryview(data).cast("B")
        size = len(view)
        while view:
            n = self._raw.write(view)
            view = view[n:]
        self._position += size
        return size

    def tell(self) -> int:
        return self._position

    def flush(self) -> None:
        if self._fsync:
            os.fsync(self._raw.fileno())

    def close(self) -> None:
        self._raw.close()


def _open_exclusive(path: Path, fsync: bool) -> _DirectStream:
    try:
        raw = open(path, "xb", buffering=0)  # noqa: SIM115  (closed by BagWriter.close)
    except FileExistsError:
        raise BagExistsError(f"{path} exists; a bag is never overwritten") from None
    except OSError as exc:
        raise BagError(f"cannot create {path}: {exc.strerror}") from None
    return _DirectStream(raw, fsync)


def is_folder_bag(path: str | os.PathLike) -> bool:
    """Whether a bag path names a rosbag2 folder (it does not end in ``.mcap``)."""
    return Path(path).suffix != MCAP_SUFFIX


def _make_folder(folder: Path) -> Path:
    """Create the folder of a rosbag2 bag (never an existing one); returns its MCAP file path,
    ``<folder>/<folder name>_0.mcap`` as rosbag2 names it."""
    try:
        folder.mkdir()
    except FileExistsError:
        raise BagExistsError(f"{folder} exists; a bag is never overwritten") from None
    except OSError as exc:
        raise BagError(f"cannot create {folder}: {exc.strerror}") from None
    return folder / f"{folder.name}_0{MCAP_SUFFIX}"


def _check_empty_after_position(stream: IO[bytes]) -> None:
    """Refuse a file object that holds data after its current position."""
    try:
        if not stream.seekable():
            return
        position = stream.tell()
        end = stream.seek(0, os.SEEK_END)
        stream.seek(position)
    except (OSError, ValueError):
        return
    if end > position:
        raise BagExistsError(
            f"the file object holds {end - position} bytes after its position; a bag is never "
            "written over existing data"
        )


class BagWriter:
    """Writes a rosbag2-compatible MCAP bag (module docstring); a context manager.

    Args:
        target: a path (must not exist): ``*.mcap`` is a single file, any other path a rosbag2
            folder (module docstring); or a binary file object (written from its position,
            which must be its end; not closed by the writer).
        chunk_size: uncompressed bytes after which a chunk is closed.
        compression: ``zstd``, ``lz4`` or ``none`` (per chunk).
        flush_interval: wall seconds after which a write closes the current chunk and hands it to
            the OS (None: only at ``chunk_size``); bounds what a killed writer loses.
        fsync: fsync the file at every flush (survives power loss; slower).
        definitions: where ``.msg`` definitions come from (default: the installed ones).
    """

    def __init__(
        self,
        target: str | os.PathLike | IO[bytes],
        *,
        chunk_size: int = 1 << 20,
        compression: str = "zstd",
        flush_interval: float | None = 1.0,
        fsync: bool = False,
        definitions: MessageDefinitions | None = None,
    ) -> None:
        if compression not in _COMPRESSION:
            raise BagError(f"compression {compression!r}: expected one of {sorted(_COMPRESSION)}")
        if chunk_size < 1:
            raise BagError(f"chunk_size must be >= 1 byte, got {chunk_size}")
        if flush_interval is not None and not flush_interval > 0:
            raise BagError(f"flush_interval must be > 0 s or None, got {flush_interval}")
        self.path: Path | None = None  # the MCAP file
        self.folder: Path | None = None  # the rosbag2 folder holding it, if any
        if isinstance(target, str | os.PathLike):
            self.path = Path(target)
            if is_folder_bag(self.path):
                self.folder = self.path
                self.path = _make_folder(self.folder)
            self._stream: Any = _open_exclusive(self.path, fsync)
            self._owns_stream = True
        else:
            _check_empty_after_position(target)
            self._stream = target
            self._owns_stream = False
        self.compression = compression
        self.flush_interval = flush_interval
        self.definitions = definitions or MessageDefinitions()
        self._mcap = McapWriter(
            self._stream, chunk_size=chunk_size, compression=_COMPRESSION[compression]
        )
        self._mcap.start(profile=PROFILE, library=LIBRARY)
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._topics: dict[int, dict[str, Any]] = {}
        self.counts: dict[str, int] = {}
        self.first_log_time: int | None = None
        self.last_log_time: int | None = None
        self._last_flush = time.monotonic()
        self.closed = False

    # -- context manager --------------------------------------------------------------------
    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- content ----------------------------------------------------------------------------
    def add_topic(
        self,
        topic: str,
        msg_type: str,
        *,
        qos_profiles: Sequence[Mapping[str, Any]] = (),
        type_hash: str = "",
        definition: str | None = None,
    ) -> int:
        """Register a topic of type ``pkg/msg/Type``; returns its channel id. Registering the
        same topic again with the same type returns the same id.

        Args:
            qos_profiles: the publishers' offered QoS (see ``schema.qos_profile_dict``).
            type_hash: the type's ``RIHS01_…`` hash, when known.
            definition: the complete ``ros2msg`` text (default: built from the ``.msg`` files).
        """
        self._check_open()
        msg_type = normalize_type(msg_type)
        if topic in self._channels:
            known = self._topics[self._channels[topic]]["type"]
            if known != msg_type:
                raise BagError(f"{topic} is already recorded as {known}, not {msg_type}")
            return self._channels[topic]
        if msg_type not in self._schemas:
            text = definition if definition is not None else self.definitions.full_text(msg_type)
            self._schemas[msg_type] = self._mcap.register_schema(
                msg_type, SCHEMA_ENCODING, text.encode("utf-8")
            )
        metadata = {"offered_qos_profiles": qos_yaml(qos_profiles), "topic_type_hash": type_hash}
        channel = self._mcap.register_channel(
            topic, MESSAGE_ENCODING, self._schemas[msg_type], metadata
        )
        self._channels[topic] = channel
        self._topics[channel] = {
            "topic": topic,
            "type": msg_type,
            "qos": list(qos_profiles),
            "type_hash": type_hash,
        }
        self.counts[topic] = 0
        return channel

    def write(
        self,
        topic: str | int,
        data: bytes,
        log_time: int,
        publish_time: int | None = None,
        sequence: int = 0,
    ) -> None:
        """One serialized (CDR) message of a registered topic (name or channel id); times in ns."""
        channel = self._channels.get(topic) if isinstance(topic, str) else topic
        if channel not in self._topics:
            raise BagError(f"topic {topic!r} is not registered (call add_topic first)")
        self._mcap.add_message(
            channel,
            log_time=log_time,
            data=data,
            publish_time=log_time if publish_time is None else publish_time,
            sequence=sequence,
        )
        self.counts[self._topics[channel]["topic"]] += 1
        if self.first_log_time is None or log_time < self.first_log_time:
            self.first_log_time = log_time
        if self.last_log_time is None or log_time > self.last_log_time:
            self.last_log_time = log_time
        if self.flush_interval is not None:
            now = time.monotonic()
            if now - self._last_flush >= self.flush_interval:
                self.flush(now)

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """A metadata record (name and string key/values)."""
        self._check_open()
        self._mcap.add_metadata(name, {str(k): str(v) for k, v in data.items()})

    def add_parameters(self, node: str, values: Mapping[str, Any]) -> None:
        """The parameters a node ran with, as metadata ``ros_parameters:<node>`` (JSON values;
        floats round-trip exactly)."""
        self.add_metadata(
            PARAMETERS_PREFIX + node, {k: json.dumps(v) for k, v in sorted(values.items())}
        )

    def flush(self, now: float | None = None) -> None:
        """Close the current chunk and hand everything written so far to the OS."""
        self._check_open()
        self._mcap.flush()
        self._last_flush = time.monotonic() if now is None else now

    @property
    def message_count(self) -> int:
        return sum(self.counts.values())

    def close(self) -> None:
        """Write the rosbag2 metadata record, the summary and the footer; close the file; in a
        rosbag2 folder, then write ``metadata.yaml``."""
        if self.closed:
            return
        self.closed = True
        info = self._rosbag2_info()
        try:
            self._mcap.add_metadata(
                ROSBAG2_METADATA, {ROSBAG2_METADATA_KEY: yaml.safe_dump(info, sort_keys=False)}
            )
            self._mcap.finish()
        finally:
            if self._owns_stream:
                self._stream.close()
            elif hasattr(self._stream, "flush"):
                self._stream.flush()
        if self.folder is not None:
            out = _open_exclusive(self.folder / FOLDER_METADATA, fsync=False)
            try:
                out.write(yaml.safe_dump({FOLDER_METADATA_KEY: info}, sort_keys=False).encode())
            finally:
                out.close()

    def _check_open(self) -> None:
        if self.closed:
            raise BagError("the bag is closed")

    def _rosbag2_info(self) -> dict[str, Any]:
        """rosbag2's BagMetadata (version 9), as its MCAP plugin stores it in the file (file
        paths relative to the bag's folder)."""
        start = self.first_log_time or 0
        duration = (self.last_log_time or 0) - start
        name = self.path.name if self.path is not None else ""
        info = {
            "version": ROSBAG2_VERSION,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": duration},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": self.message_count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": t["topic"],
                        "type": t["type"],
                        "serialization_format": MESSAGE_ENCODING,
                        "offered_qos_profiles": t["qos"],
                        "type_description_hash": t["type_hash"],
                    },
                    "message_count": self.counts[t["topic"]],
                }
                for t in self._topics.values()
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [name] if name else [],
            "files": [
                {
                    "path": name,
                    "starting_time": {"nanoseconds_since_epoch": start},
                    "duration": {"nanoseconds": duration},
                    "message_count": self.message_count,
                }
            ]
            if name
            else [],
            "custom_data": {},
            "ros_distro": "jazzy",
        }
        return info
