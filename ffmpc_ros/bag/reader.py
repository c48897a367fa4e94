"""BagReader: read a bag written by :class:`~ffmpc_ros.bag.writer.BagWriter` (or rosbag2's MCAP
plugin, or any ``ros2`` MCAP file), complete or truncated. No ROS import.

A complete bag (footer and summary intact) is read through its summary and indexes. A truncated
one — a recorder killed mid-run — is scanned record by record from the start: every complete
record is kept (schemas, channels, metadata, and chunks whose CRC checks), and the scan stops at
the first incomplete or corrupt record. :attr:`BagReader.recovery` says what was kept and what
was lost; :func:`recover_bag` writes what was kept into a new, complete bag that every MCAP tool
opens.

A rosbag2 folder (``metadata.yaml`` beside one MCAP file, as ``ros2 bag record`` and
:class:`~ffmpc_ros.bag.writer.BagWriter` write it) is read through that file; a folder without
``metadata.yaml`` (its writer was killed) through its only MCAP file.

Messages are bytes (CDR); decode them with ``rclpy.serialization.deserialize_message`` (ROS
side) or ``mcap_ros2.decoder`` (no ROS needed).
"""

from __future__ import annotations

import io
import json
import os
import struct
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import yaml
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Message, Metadata, Schema
from mcap.stream_reader import MAGIC_SIZE, breakup_chunk

from ffmpc_ros.bag.errors import BagError
from ffmpc_ros.bag.schema import PROFILE, parse_qos_yaml
from ffmpc_ros.bag.writer import (
    FOLDER_METADATA,
    FOLDER_METADATA_KEY,
    MCAP_SUFFIX,
    PARAMETERS_PREFIX,
    ROSBAG2_METADATA,
    BagWriter,
)

MAGIC = b"\x89MCAP0\r\n"
_FOOTER_SIZE = 1 + 8 + 8 + 8 + 4  # opcode, length, summary_start, summary_offset_start, crc


@dataclass(frozen=True)
class TopicInfo:
    """One recorded topic."""

    topic: str
    type: str  # pkg/msg/Type
    count: int
    qos_profiles: list[dict[str, Any]] = field(default_factory=list)
    type_hash: str = ""
    definition: str = ""


@dataclass(frozen=True)
class BagMessage:
    """One message: serialized CDR ``data`` and its times (ns)."""

    topic: str
    type: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes


@dataclass(frozen=True)
class RecoveryReport:
    """How much of a bag file is readable.

    ``complete``: footer and summary intact. Otherwise the file was scanned up to its last
    complete record: ``readable_bytes`` of ``file_size`` were kept, ``chunks`` complete chunks
    holding ``messages`` messages; ``discarded_bytes`` after them (an incomplete chunk) were lost.
    """

    complete: bool
    file_size: int
    readable_bytes: int
    chunks: int
    messages: int
    reason: str = ""

    @property
    def discarded_bytes(self) -> int:
        return self.file_size - self.readable_bytes

    def describe(self) -> str:
        if self.complete:
            return f"complete: {self.messages} messages in {self.chunks} chunks"
        return (
            f"TRUNCATED ({self.reason}): recovered {self.messages} messages in {self.chunks} "
            f"complete chunks ({self.readable_bytes} of {self.file_size} bytes); "
            f"{self.discarded_bytes} bytes after the last complete chunk discarded"
        )


def _footer_ok(fh: BinaryIO, size: int) -> bool:
    if size < 2 * MAGIC_SIZE + _FOOTER_SIZE:
        return False
    fh.seek(size - MAGIC_SIZE - _FOOTER_SIZE)
    tail = fh.read(MAGIC_SIZE + _FOOTER_SIZE)
    return tail[-MAGIC_SIZE:] == MAGIC and tail[0] == Opcode.FOOTER


def folder_storage_file(folder: Path) -> Path:
    """The MCAP file of a rosbag2 folder: the one ``metadata.yaml`` names, or without it (a
    killed writer) the folder's only ``*.mcap`` file. BagError for anything else (this reader
    takes single-file bags: a split bag is refused with its file count)."""
    meta = folder / FOLDER_METADATA
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text(encoding="utf-8"))[FOLDER_METADATA_KEY]
            files = list(info["relative_file_paths"])
        except (yaml.YAMLError, TypeError, KeyError) as exc:
            raise BagError(f"{meta} is not rosbag2 bag metadata: {exc!r}") from None
        if info.get("storage_identifier") != "mcap":
            raise BagError(f"{folder}: storage {info.get('storage_identifier')!r}, not mcap")
        if len(files) != 1:
            raise BagError(f"{folder}: a bag of {len(files)} files (only single-file bags)")
        return folder / files[0]
    found = sorted(folder.glob("*" + MCAP_SUFFIX))
    if len(found) != 1:
        raise BagError(
            f"no bag file in {folder}: no {FOLDER_METADATA} and {len(found)} MCAP files (want one)"
        )
    return found[0]


class BagReader:
    """A bag file, complete or truncated (module docstring); a context manager.

    Attributes:
        topics: {topic: TopicInfo}.
        metadata: [(name, {key: value})] in file order.
        recovery: what could be read (:class:`RecoveryReport`).
        start_time, end_time: first and last log time, ns (None without messages).
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)  # the MCAP file
        self.folder: Path | None = None  # the rosbag2 folder holding it, if any
        if self.path.is_dir():
            self.folder, self.path = self.path, folder_storage_file(self.path)
        if not self.path.is_file():
            raise BagError(f"no bag file {self.path}")
        self._fh = open(self.path, "rb")  # noqa: SIM115  (closed by close())
        self.file_size = self.path.stat().st_size
        self.topics: dict[str, TopicInfo] = {}
        self.metadata: list[tuple[str, dict[str, str]]] = []
        self.start_time: int | None = None
        self.end_time: int | None = None
        self.profile = ""
        self.library = ""
        self.compression: set[str] = set()
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_offsets: list[int] = []  # truncated bags: complete chunks
        self._loose: list[Message] = []  # truncated bags: messages outside chunks
        self._reader: SeekingReader | None = None  # complete bags: mcap's indexed reader
        try:
            self._magic()
            if _footer_ok(self._fh, self.file_size) and self._read_summary():
                pass
            else:
                self._scan()
        except BaseException:
            self._fh.close()
            raise

    # -- opening ---------------------------------------------------------------------------
    def _magic(self) -> None:
        self._fh.seek(0)
        if self._fh.read(MAGIC_SIZE) != MAGIC:
            raise BagError(f"{self.path} is not an MCAP file (bad magic)")
        stream = ReadDataStream(self._fh)
        try:
            if stream.read1() != Opcode.HEADER:
                raise BagError(f"{self.path}: no MCAP header record")
            stream.read8()
            self.profile = stream.read_prefixed_string()
            self.library = stream.read_prefixed_string()
        except (McapError, struct.error) as exc:
            raise BagError(f"{self.path}: unreadable MCAP header ({exc!r})") from None
        if self.profile != PROFILE:
            raise BagError(f"{self.path}: MCAP profile {self.profile!r}, expected {PROFILE!r}")

    def _read_summary(self) -> bool:
        """Complete bag: topics, counts and times from the summary; False if unusable."""
        self._fh.seek(0)
        try:
            reader = SeekingReader(self._fh, validate_crcs=True)
            summary = reader.get_summary()
            if summary is None or summary.statistics is None:
                return False
            metadata = [(m.name, dict(m.metadata)) for m in reader.iter_metadata()]
        except (McapError, struct.error, ValueError, OSError):
            return False
        self._reader = reader
        self._schemas = dict(summary.schemas)
        self._channels = dict(summary.channels)
        stats = summary.statistics
        counts = dict(stats.channel_message_counts)
        self.metadata = metadata
        self.compression = {c.compression or "none" for c in summary.chunk_indexes}
        if stats.message_count:
            self.start_time, self.end_time = stats.message_start_time, stats.message_end_time
        self._build_topics(counts)
        self.recovery = RecoveryReport(
            True, self.file_size, self.file_size, len(summary.chunk_indexes), stats.message_count
        )
        return True

    def _scan(self) -> None:
        """Truncated bag: keep every complete record up to the first incomplete one."""
        self._reader = None
        fh = self._fh
        fh.seek(MAGIC_SIZE)
        counts: dict[int, int] = {}
        chunks = messages = 0
        readable = MAGIC_SIZE
        reason = "no footer"
        while True:
            offset = fh.tell()
            head = fh.read(9)
            if len(head) < 9:
                reason = (
                    "ends inside a record"
                    if head
                    else "not closed: no summary or footer after the last record"
                )
                break
            opcode, length = struct.unpack("<BQ", head)
            if offset + 9 + length > self.file_size:
                reason = f"ends inside a {_opname(opcode)} record"
                break
            body = fh.read(length)
            stream = ReadDataStream(io.BytesIO(body))
            try:
                if opcode == Opcode.CHUNK:
                    chunk = Chunk.read(stream)
                    records = breakup_chunk(chunk, validate_crc=True)
                    self.compression.add(chunk.compression or "none")
                    found = [r for r in records if isinstance(r, Message)]
                    for record in records:
                        self._keep(record)
                    for m in found:
                        counts[m.channel_id] = counts.get(m.channel_id, 0) + 1
                        self._times(m.log_time)
                    self._chunk_offsets.append(offset)
                    chunks += 1
                    messages += len(found)
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL, Opcode.METADATA):
                    read: Callable[[ReadDataStream], Schema | Channel | Metadata] = {
                        Opcode.SCHEMA: Schema.read,
                        Opcode.CHANNEL: Channel.read,
                        Opcode.METADATA: Metadata.read,
                    }[Opcode(opcode)]
                    record = read(stream)
                    self._keep(record)
                elif opcode == Opcode.MESSAGE:
                    m = Message.read(stream, length)
                    self._loose.append(m)
                    counts[m.channel_id] = counts.get(m.channel_id, 0) + 1
                    self._times(m.log_time)
                    messages += 1
                elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                    readable = offset + 9 + length
                    reason = "damaged summary or footer"
                    break
            except (McapError, struct.error, ValueError, KeyError, UnicodeDecodeError) as exc:
                reason = f"corrupt {_opname(opcode)} record ({type(exc).__name__})"
                break
            readable = offset + 9 + length
        self._build_topics(counts)
        self.recovery = RecoveryReport(False, self.file_size, readable, chunks, messages, reason)

    def _keep(self, record: object) -> None:
        if isinstance(record, Schema):
            self._schemas[record.id] = record
        elif isinstance(record, Channel):
            self._channels[record.id] = record
        elif isinstance(record, Metadata):
            self.metadata.append((record.name, dict(record.metadata)))

    def _times(self, t: int) -> None:
        self.start_time = t if self.start_time is None else min(self.start_time, t)
        self.end_time = t if self.end_time is None else max(self.end_time, t)

    def _build_topics(self, counts: dict[int, int]) -> None:
        for cid, channel in sorted(self._channels.items()):
            schema = self._schemas.get(channel.schema_id)
            meta = channel.metadata or {}
            self.topics[channel.topic] = TopicInfo(
                topic=channel.topic,
                type=schema.name if schema else "",
                count=counts.get(cid, 0),
                qos_profiles=parse_qos_yaml(meta.get("offered_qos_profiles", "")),
                type_hash=meta.get("topic_type_hash", ""),
                definition=schema.data.decode("utf-8") if schema else "",
            )

    # -- content ---------------------------------------------------------------------------
    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    @property
    def duration(self) -> float:
        """Last minus first log time, s."""
        if self.start_time is None or self.end_time is None:
            return 0.0
        return (self.end_time - self.start_time) * 1e-9

    def metadata_named(self, name: str) -> dict[str, str] | None:
        """The last metadata record called ``name``, or None."""
        found = [data for n, data in self.metadata if n == name]
        return found[-1] if found else None

    @property
    def parameters(self) -> dict[str, dict[str, Any]]:
        """{node: {parameter: value}} recorded by the recorder (``ros_parameters:<node>``)."""
        out: dict[str, dict[str, Any]] = {}
        for name, data in self.metadata:
            if name.startswith(PARAMETERS_PREFIX):
                node = name[len(PARAMETERS_PREFIX) :]
                out[node] = {k: json.loads(v) for k, v in data.items()}
        return out

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
        """Messages in log-time order (a truncated bag: chunk by chunk, each in log-time order),
        only of ``topics`` if given."""
        wanted = set(topics) if topics is not None else None
        if wanted is not None and not wanted <= set(self.topics):
            raise BagError(f"not in the bag: {sorted(wanted - set(self.topics))}")
        channels = {
            cid: c for cid, c in self._channels.items() if wanted is None or c.topic in wanted
        }
        if self._reader is not None:
            self._fh.seek(0)
            for _, channel, m in self._reader.iter_messages(
                topics=sorted({c.topic for c in channels.values()}), log_time_order=True
            ):
                yield self._message(channel, m)
            return
        for offset in self._chunk_offsets:
            self._fh.seek(offset + 9)
            chunk = Chunk.read(ReadDataStream(self._fh))
            found = [r for r in breakup_chunk(chunk) if isinstance(r, Message)]
            found.sort(key=lambda m: m.log_time)
            for m in found:
                if m.channel_id in channels:
                    yield self._message(channels[m.channel_id], m)
        for m in sorted(self._loose, key=lambda m: m.log_time):
            if m.channel_id in channels:
                yield self._message(channels[m.channel_id], m)

    def _message(self, channel: Channel, m: Message) -> BagMessage:
        return BagMessage(
            topic=channel.topic,
            type=self.topics[channel.topic].type,
            log_time=m.log_time,
            publish_time=m.publish_time,
            sequence=m.sequence,
            data=m.data,
        )

    def describe(self) -> str:
        """A ``ros2 bag info``-like summary."""
        lines = [
            f"Files:             {self.path}"
            + (
                ""
                if self.folder is None
                else f" (rosbag2 folder {self.folder}, "
                + (
                    f"with {FOLDER_METADATA})"
                    if (self.folder / FOLDER_METADATA).is_file()
                    else f"no {FOLDER_METADATA}: recover it)"
                )
            ),
            f"Bag size:          {_size(self.file_size)}",
            f"Storage id:        mcap (profile {self.profile}; chunks: "
            f"{', '.join(sorted(self.compression)) or 'none'}; written by {self.library})",
            f"Duration:          {self.duration:.9f} s",
            f"Start:             {_stamp(self.start_time)}",
            f"End:               {_stamp(self.end_time)}",
            f"Messages:          {self.message_count}",
            f"Chunks:            {self.recovery.chunks}",
            f"Integrity:         {self.recovery.describe()}",
        ]
        width = max((len(t) for t in self.topics), default=0)
        for i, info in enumerate(self.topics.values()):
            label = "Topic information: " if i == 0 else " " * 19
            lines.append(
                f"{label}Topic: {info.topic:<{width}} | Type: {info.type} | Count: {info.count} "
                "| Serialization Format: cdr"
            )
        params = self.parameters
        if params:
            lines.append(
                "Parameters:        "
                + ", ".join(f"{node} ({len(values)})" for node, values in params.items())
            )
        others = [n for n, _ in self.metadata if not n.startswith(PARAMETERS_PREFIX)]
        if others:
            lines.append(f"Metadata:          {', '.join(others)}")
        return "\n".join(lines)

    # -- context manager ---------------------------------------------------------------------
    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _opname(opcode: int) -> str:
    try:
        return Opcode(opcode).name
    except ValueError:
        return f"opcode {opcode:#x}"


def _size(n: float) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.1f} {unit}" if unit != "B" else f"{n} B"
        n /= 1024
    return f"{n} B"


def _stamp(t: int | None) -> str:
    return "-" if t is None else f"{t // 1_000_000_000}.{t % 1_000_000_000:09d} s ({t} ns)"


def recover_bag(source: str | os.PathLike, target: str | os.PathLike) -> RecoveryReport:
    """Write everything readable of ``source`` (complete or truncated) into a new complete bag
    ``target`` (refused if it exists): same topics, definitions, QoS, metadata and messages,
    plus a ``ffmpc_recovery`` metadata record. Returns the source's :class:`RecoveryReport`."""
    with BagReader(source) as src, BagWriter(target) as dst:
        for info in src.topics.values():
            dst.add_topic(
                info.topic,
                info.type,
                qos_profiles=info.qos_profiles,
                type_hash=info.type_hash,
                definition=info.definition,
            )
        for name, data in src.metadata:
            if name != ROSBAG2_METADATA:
                dst.add_metadata(name, data)
        for m in src.messages():
            dst.write(m.topic, m.data, m.log_time, m.publish_time, m.sequence)
        report = src.recovery
        dst.add_metadata(
            "ffmpc_recovery",
            {
                "source": str(source),
                "complete": str(report.complete).lower(),
                "file_size": str(report.file_size),
                "readable_bytes": str(report.readable_bytes),
                "chunks": str(report.chunks),
                "messages": str(report.messages),
                "reason": report.reason,
            },
        )
    return report
