"""ROS 1 messages in an MCAP file, which rosbags does not read.

``mcap convert recording.bag recording.mcap`` (the MCAP tools' way from ROS 1 to Foxglove) keeps
the ROS 1 serialisation: channels with message encoding ``ros1`` and schemas ``ros1msg`` (the
bag's full message definitions). rosbags reads MCAP only as ROS 2 (CDR) storage and fails on
these, so :class:`Ros1McapReader` reads them itself: the MCAP records in file order (chunks
uncompressed with the lz4 / zstd that rosbags already depends on), messages deserialised by
rosbags' ROS 1 typestore, with the three things :mod:`lidarflow.data.bags` asks of a reader:
``connections``, ``messages(connections=...)`` and ``deserialize(raw, msgtype)``.

Record layout: https://mcap.dev/spec (opcode ``u8``, length ``u64``, fields little-endian,
strings and byte arrays with a ``u32`` length). Opening a file reads its summary section (the
schemas, channels and per-channel message counts that ``mcap`` writes after the data) where
there is one with a Statistics record, so that a multi-gigabyte file is read once, for the
messages; without one (a writer stopped early, or one that writes no summary) opening reads
the data section for them instead.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

from lidarflow.errors import BagError

__all__ = ["MAGIC", "Ros1McapReader", "channel_encoding"]

MAGIC = b"\x89MCAP0\r\n"
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _DATA_END, _FOOTER = 0x03, 0x04, 0x05, 0x06, 0x0F, 0x02
_STATISTICS = 0x0B
_FOOTER_SIZE = 9 + 8 + 8 + 4  # opcode, length, summary start, summary offset start, crc


@dataclass(frozen=True)
class Connection:
    """One channel, named as rosbags names its connections (``sensor_msgs/msg/LaserScan``)."""

    id: int
    topic: str
    msgtype: str
    msgcount: int


class _Fields:
    """Reads one record's fields in order."""

    def __init__(self, data: bytes) -> None:
        self.data, self.at = data, 0

    def take(self, n: int) -> bytes:
        if self.at + n > len(self.data):
            raise BagError("an MCAP record ends early")
        out = self.data[self.at : self.at + n]
        self.at += n
        return out

    def u16(self) -> int:
        return struct.unpack("<H", self.take(2))[0]

    def u32(self) -> int:
        return struct.unpack("<I", self.take(4))[0]

    def u64(self) -> int:
        return struct.unpack("<Q", self.take(8))[0]

    def string(self) -> str:
        return self.take(self.u32()).decode()

    def rest(self) -> bytes:
        return self.take(len(self.data) - self.at)


def _decompress(compression: str, data: bytes) -> bytes:
    if compression == "":
        return data
    if compression == "lz4":
        from lz4.frame import decompress

        return decompress(data)
    if compression == "zstd":
        try:
            from compression import zstd  # type: ignore[import-not-found]
        except ImportError:
            from backports import zstd  # type: ignore[import-not-found,no-redef]
        return zstd.decompress(data)
    raise BagError(f"MCAP chunk compression {compression!r} is not supported")


def _split(data: bytes) -> Iterator[tuple[int, bytes]]:
    """The records of a chunk's (uncompressed) content."""
    at = 0
    while at < len(data):
        if at + 9 > len(data):
            raise BagError("an MCAP chunk ends inside a record")
        op, length = data[at], struct.unpack("<Q", data[at + 1 : at + 9])[0]
        yield op, data[at + 9 : at + 9 + length]
        at += 9 + length


def _records(stream: BinaryIO) -> Iterator[tuple[int, bytes]]:
    """The data section's records in file order, chunks opened."""
    if stream.read(len(MAGIC)) != MAGIC:
        raise BagError("not an MCAP file (no magic)")
    while True:
        head = stream.read(9)
        if len(head) < 9:
            return  # no footer: a file whose writer was stopped; read what is there
        op, length = head[0], struct.unpack("<Q", head[1:])[0]
        if op in (_DATA_END, _FOOTER):
            return  # the summary after it repeats schemas and channels
        body = stream.read(length)
        if len(body) < length:
            raise BagError("the MCAP file ends inside a record (truncated?)")
        if op != _CHUNK:
            yield op, body
            continue
        fields = _Fields(body)
        fields.u64(), fields.u64(), fields.u64(), fields.u32()  # times, size, crc
        compression = fields.string()
        size = fields.u64()
        yield from _split(_decompress(compression, fields.take(size)))


def _summary(stream: BinaryIO) -> tuple[list[tuple[int, bytes]], dict[int, int]] | None:
    """The summary section's schema and channel records and its Statistics record's message
    count per channel; ``None`` where the file has no summary or the summary no statistics."""
    size = stream.seek(0, os.SEEK_END)
    tail = _FOOTER_SIZE + len(MAGIC)
    if size < len(MAGIC) + tail:
        return None
    stream.seek(size - tail)
    end = stream.read(tail)
    if end[_FOOTER_SIZE:] != MAGIC or end[0] != _FOOTER:
        return None
    start, offsets = struct.unpack("<QQ", end[9:25])
    stop = offsets or size - tail
    if not len(MAGIC) <= start < stop <= size - tail:
        return None
    stream.seek(start)
    records: list[tuple[int, bytes]] = []
    counts: dict[int, int] | None = None
    for op, body in _split(stream.read(stop - start)):
        if op in (_SCHEMA, _CHANNEL):
            records.append((op, body))
        elif op == _STATISTICS:
            fields = _Fields(body)
            fields.take(8 + 2 + 4 * 4 + 8 + 8)  # totals and the time span
            entries = _Fields(fields.take(fields.u32()))
            counts = {}
            while entries.at < len(entries.data):
                channel = entries.u16()
                counts[channel] = entries.u64()
    return None if counts is None else (records, counts)


def channel_encoding(path: str | Path) -> str | None:
    """The message encoding of the first channel of an MCAP file (``ros1``, ``cdr``, ...),
    ``None`` where it has none or cannot be read."""
    try:
        with Path(path).open("rb") as stream:
            for op, body in _records(stream):
                if op == _CHANNEL:
                    fields = _Fields(body)
                    fields.u16(), fields.u16(), fields.string()  # id, schema, topic
                    return fields.string()
    except Exception:  # a probe: whatever fails here, rosbags' reader reports it
        return None
    return None


def _rosbags_name(name: str) -> str:
    """``sensor_msgs/LaserScan`` -> ``sensor_msgs/msg/LaserScan``."""
    package, _, message = name.rpartition("/")
    return name if "/msg/" in name or not package else f"{package}/msg/{message}"


class Ros1McapReader:
    """An MCAP file of ROS 1 messages, read like a rosbags ``AnyReader`` (see the module)."""

    def __init__(self, path: str | Path, typestore: Any) -> None:
        from rosbags.typesys import get_types_from_msg

        self.path, self.typestore = Path(path), typestore
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[str, str]] = {}
        with self.path.open("rb") as stream:
            try:
                summary = _summary(stream)
            except BagError:
                summary = None  # a damaged summary: the data section says the same
            stream.seek(0)
            records, counts = summary if summary is not None else (_records(stream), {})
            for op, body in records:
                fields = _Fields(body)
                if op == _SCHEMA:
                    schema_id, name, encoding = fields.u16(), fields.string(), fields.string()
                    msgtype = _rosbags_name(name)
                    schemas[schema_id] = msgtype
                    if encoding == "ros1msg" and msgtype not in typestore.types:
                        text = fields.take(fields.u32()).decode()
                        typestore.register(get_types_from_msg(text, msgtype))
                elif op == _CHANNEL:
                    channel_id, schema_id, topic = fields.u16(), fields.u16(), fields.string()
                    if fields.string() == "ros1":  # others (JSON annotations, ...) are no scans
                        channels[channel_id] = (topic, schemas.get(schema_id, ""))
                elif op == _MESSAGE:
                    channel_id = fields.u16()
                    counts[channel_id] = counts.get(channel_id, 0) + 1
        self.connections = [
            Connection(i, topic, msgtype, counts.get(i, 0))
            for i, (topic, msgtype) in sorted(channels.items())
        ]

    def messages(
        self, connections: Iterable[Connection] = ()
    ) -> Iterator[tuple[Connection, int, bytes]]:
        """``(connection, log time ns, raw message)`` of ``connections`` (default all), in the
        order they were written."""
        wanted = {c.id: c for c in connections} or {c.id: c for c in self.connections}
        with self.path.open("rb") as stream:
            for op, body in _records(stream):
                if op != _MESSAGE:
                    continue
                fields = _Fields(body)
                connection = wanted.get(fields.u16())
                if connection is None:
                    continue
                fields.u32()  # sequence
                log_time = fields.u64()
                fields.u64()  # publish time
                yield connection, log_time, fields.rest()

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self.typestore.deserialize_ros1(raw, msgtype)
