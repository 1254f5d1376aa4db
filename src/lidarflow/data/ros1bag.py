"""A ROS 1 bag read record by record, for a bag rosbags cannot open: one cut short or never
closed by its writer (no index, or one that points past the end).

Opening walks the data section in file order up to the last intact message (of a chunk cut in
two, what its first part decompresses to), noting where each message is: the index the bag
lacks, so that reading a topic opens only the chunks that hold it. Messages are deserialised by
rosbags' typestore built from the bag's own message definitions.

Format (ROS bag 2.0): ``#ROSBAG V2.0\\n``, then records of a ``u32`` header length, header
fields (each a ``u32`` length and ``name=value``; ``op`` the record type), a ``u32`` data length
and the data; integers little-endian.
"""

from __future__ import annotations

import bz2
import mmap
import struct
from array import array
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lidarflow.data.readers import CutShort, typestore_from

__all__ = ["MAGIC", "Ros1BagSequentialReader"]

MAGIC = b"#ROSBAG V2.0\n"
_MESSAGE, _BAG_HEADER, _CHUNK, _CONNECTION = 0x02, 0x03, 0x05, 0x07
_U32 = struct.Struct("<I")


def _fields(data: bytes) -> dict[str, bytes] | None:
    """A record header's ``name=value`` fields; ``None`` where they do not parse."""
    out: dict[str, bytes] = {}
    at, size = 0, len(data)
    while at < size:
        if at + 4 > size:
            return None
        end = at + 4 + _U32.unpack_from(data, at)[0]
        equals = data.find(b"=", at + 4, end)
        if end > size or equals < 0:
            return None
        out[data[at + 4 : equals].decode("latin-1")] = data[equals + 1 : end]
        at = end
    return out


def _record(buf: Any, at: int) -> tuple[dict[str, bytes], int, int] | None:
    """The record at ``at``: its header fields and where its data starts and would end (past
    the buffer where it was cut); ``None`` where even its header is cut or is no header."""
    if at + 4 > len(buf):
        return None
    end_header = at + 4 + _U32.unpack_from(buf, at)[0]
    if end_header + 4 > len(buf):
        return None
    header = _fields(buf[at + 4 : end_header])
    if header is None or len(header.get("op", b"")) != 1:
        return None
    start = end_header + 4
    return header, start, start + _U32.unpack_from(buf, end_header)[0]


def _decompressed(compression: bytes, data: bytes, whole: bool) -> bytes:
    """A chunk's records; of a chunk cut short, as many as its first part decompresses to."""
    if compression == b"none":
        return data
    if compression == b"bz2":
        return bz2.decompress(data) if whole else bz2.BZ2Decompressor().decompress(data)
    if compression == b"lz4":
        import lz4.frame  # rosbags depends on it, for its own reading of lz4 chunks

        if whole:
            return lz4.frame.decompress(data)
        return lz4.frame.LZ4FrameDecompressor().decompress(data)
    raise ValueError(f"chunk compression {compression.decode(errors='replace')!r}")


def _conn(header: dict[str, bytes]) -> int:
    return int.from_bytes(header.get("conn", b""), "little")


@dataclass
class _Chunk:
    """Where a chunk's data is in the file (``length`` bytes whole, ``read`` of them there),
    and its messages, flat: ``(connection, log time ns, start, end)`` in its records."""

    start: int
    length: int
    read: int
    compression: bytes
    messages: array = field(default_factory=lambda: array("q"))
    connections: set[int] = field(default_factory=set)

    def content(self, stream: Any) -> bytes:
        stream.seek(self.start)
        data = stream.read(self.read)
        return _decompressed(self.compression, data, self.read == self.length)


class Ros1BagSequentialReader:
    """A ROS 1 bag read in file order without its index; ``recovered`` says how much of the
    file was read."""

    def __init__(self, path: str | Path, default_typestore: Any) -> None:
        self.path = Path(path)
        self.size = self.path.stat().st_size
        if self.size <= len(MAGIC):
            raise ValueError("not a ROS 1 bag (empty)")
        with self.path.open("rb") as stream:
            if stream.read(len(MAGIC)) != MAGIC:
                raise ValueError("not a ROS 1 bag (no '#ROSBAG V2.0' line)")
            with mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as buf:
                found, index_pos, read_to = self._walk(buf)
        counts: dict[int, int] = {}
        for chunk in self._chunks:
            for conn in chunk.messages[::4]:
                counts[conn] = counts.get(conn, 0) + 1
        if not any(counts.get(conn) for conn in found):
            raise ValueError("no intact message in the bag")
        self.connections = [self._connection(i, found[i], counts.get(i, 0)) for i in sorted(found)]
        self.typestore = typestore_from(self.connections, default_typestore)
        if read_to < self.size:
            why = "cut short"
        elif index_pos == 0:
            why = "never closed by its writer (no index)"
        else:
            why = "its index damaged"
        self.recovered = CutShort(self.size, read_to, index_pos or None, why)

    def _walk(self, buf: Any) -> tuple[dict[int, dict[str, bytes]], int, int]:
        """Walk the records up to the first one cut or damaged, filling ``_chunks``; returns the
        connections' fields, the header's index position and where the last intact record
        ends (within a chunk read in part, by its uncompressed share)."""
        found: dict[int, dict[str, bytes]] = {}
        self._chunks: list[_Chunk] = []
        index_pos, at = 0, len(MAGIC)
        read_to = at
        while (record := _record(buf, at)) is not None:
            header, start, end = record
            op, whole = header["op"][0], end <= len(buf)
            if op == _BAG_HEADER:
                index_pos = int.from_bytes(header.get("index_pos", b""), "little")
            elif op == _CONNECTION and whole:  # the index section repeats them
                self._connection_record(found, header, buf[start:end])
            if op == _CHUNK:
                chunk = _Chunk(start, end - start, min(end, len(buf)) - start,
                               header.get("compression", b"none"))  # fmt: skip
                try:
                    content = _decompressed(chunk.compression, buf[start:end], whole)
                except Exception:  # a damaged chunk: what came before it stands
                    break
                last = self._chunk_records(chunk, content, found)
                if not whole:  # the share of the chunk's data up to there, uncompressed
                    size = max(int.from_bytes(header.get("size", b""), "little"), len(content))
                    read_to = start + round(chunk.length * last / size)
                self._chunks.append(chunk)
            if not whole:
                break
            read_to = at = end
        return found, index_pos, read_to

    def _chunk_records(
        self, chunk: _Chunk, content: bytes, found: dict[int, dict[str, bytes]]
    ) -> int:
        """Note a chunk's connections and messages; returns where its last intact record ends."""
        place = 0
        while (inner := _record(content, place)) is not None and inner[2] <= len(content):
            header, start, place = inner
            if header["op"][0] == _CONNECTION:
                self._connection_record(found, header, content[start:place])
            elif header["op"][0] == _MESSAGE:
                time = header.get("time", b"").ljust(8, b"\0")
                stamp = _U32.unpack_from(time)[0] * 1_000_000_000 + _U32.unpack_from(time, 4)[0]
                chunk.messages.extend((_conn(header), stamp, start, place))
                chunk.connections.add(_conn(header))
        return place

    @staticmethod
    def _connection_record(
        found: dict[int, dict[str, bytes]], header: dict[str, bytes], data: bytes
    ) -> None:
        """Note a connection record's fields (its data is a header of them; the topic is in its
        own header)."""
        fields = _fields(data)
        if _conn(header) not in found and fields is not None and "type" in fields:
            found[_conn(header)] = {**fields, "topic": header.get("topic", b"")}

    def _connection(self, conn: int, fields: dict[str, bytes], count: int) -> Any:
        from rosbags.interfaces import (
            Connection,
            ConnectionExtRosbag1,
            MessageDefinition,
            MessageDefinitionFormat,
        )
        from rosbags.typesys.msg import normalize_msgtype

        text = fields.get("message_definition", b"").decode()
        latching = fields.get("latching", b"")
        return Connection(
            id=conn,
            topic=fields["topic"].decode(),
            msgtype=normalize_msgtype(fields["type"].decode()),
            msgdef=MessageDefinition(
                MessageDefinitionFormat.MSG if text else MessageDefinitionFormat.NONE, text
            ),
            digest=fields.get("md5sum", b"").decode(),
            msgcount=count,
            ext=ConnectionExtRosbag1(
                fields["callerid"].decode() if "callerid" in fields else None,
                int(latching) if latching.isdigit() else None,
            ),
            owner=self,
        )

    def messages(self, connections: Iterable[Any] = ()) -> Iterator[tuple[Any, int, bytes]]:
        """``(connection, log time ns, raw message)`` of ``connections`` (default all), in file
        order; only the chunks that hold them are read."""
        wanted = {c.id: c for c in connections} or {c.id: c for c in self.connections}
        with self.path.open("rb") as stream:
            for chunk in self._chunks:
                if chunk.connections.isdisjoint(wanted):
                    continue
                content = chunk.content(stream)
                entries = chunk.messages
                for i in range(0, len(entries), 4):
                    connection = wanted.get(entries[i])
                    if connection is not None:
                        yield connection, entries[i + 1], content[entries[i + 2] : entries[i + 3]]

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self.typestore.deserialize_ros1(raw, msgtype)
