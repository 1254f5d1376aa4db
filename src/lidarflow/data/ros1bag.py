"""A ROS 1 bag read record by record, for a bag rosbags cannot open: one cut short (a robot that
lost power mid-recording) or never closed by its writer (the header's index position 0).

rosbags' reader starts from the index that ``rosbag record`` writes after the data when it
closes the bag; a bag cut short has none, or one that points past its end. Its data section is
still there, in order: the bag header record, then chunks (each holding the connection records
it introduces and its messages; uncompressed, bz2 or lz4), each followed by its index records.
This reader walks them in file order up to the last intact message, a chunk cut in two
included (its first part decompressed as far as it goes), and deserialises with rosbags'
typestore built from the bag's own message definitions.

Format (ROS bag 2.0): ``#ROSBAG V2.0\\n``, then records of a ``u32`` header length, header
fields (each a ``u32`` length and ``name=value``; ``op`` the record type), a ``u32`` data length
and the data; integers little-endian.
"""

from __future__ import annotations

import bz2
import contextlib
import mmap
from collections.abc import Generator, Iterable, Iterator
from pathlib import Path
from typing import Any

from lidarflow.data.readers import CutShort, typestore_from

__all__ = ["MAGIC", "Ros1BagSequentialReader"]

MAGIC = b"#ROSBAG V2.0\n"
_MESSAGE, _BAG_HEADER, _CHUNK, _CONNECTION = 0x02, 0x03, 0x05, 0x07


def _u32(buf: Any, at: int) -> int:
    return int.from_bytes(buf[at : at + 4], "little")


def _fields(data: bytes) -> dict[str, bytes] | None:
    """A record header's ``name=value`` fields; ``None`` where they do not parse (the bytes are
    no header: a cut or damaged file)."""
    out: dict[str, bytes] = {}
    at = 0
    while at < len(data):
        n = _u32(data, at)
        field = data[at + 4 : at + 4 + n]
        if at + 4 > len(data) or len(field) < n or b"=" not in field:
            return None
        name, _, value = field.partition(b"=")
        out[name.decode("latin-1")] = value
        at += 4 + n
    return out


def _record(buf: Any, at: int) -> tuple[dict[str, bytes], int, int] | None:
    """The record at ``at``: its header fields and where its data starts and would end (past
    the buffer where the record was cut in its data); ``None`` where even its header is cut or
    is no header."""
    if at + 4 > len(buf):
        return None
    start_header = at + 4
    end_header = start_header + _u32(buf, at)
    if end_header + 4 > len(buf):
        return None
    header = _fields(bytes(buf[start_header:end_header]))
    if header is None or len(header.get("op", b"")) != 1:
        return None
    start = end_header + 4
    return header, start, start + _u32(buf, end_header)


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


class Ros1BagSequentialReader:
    """A ROS 1 bag read in file order without its index (see the module). Opening reads the
    whole data section once, for the connections and their message counts; ``recovered`` says
    how much of the file that was."""

    def __init__(self, path: str | Path, default_typestore: Any) -> None:
        self.path = Path(path)
        self.size = self.path.stat().st_size
        self._index_pos, self._read_to, self._cut = 0, 0, False
        found: dict[int, dict[str, bytes]] = {}
        counts: dict[int, int] = {}
        for op, header, data in self._records():
            conn = _u32(header.get("conn", b""), 0)
            if op == _CONNECTION and conn not in found:
                fields = _fields(data)
                if fields is not None and "type" in fields:
                    found[conn] = {**fields, "topic": header.get("topic", b"")}
            elif op == _MESSAGE and conn in found:
                counts[conn] = counts.get(conn, 0) + 1
        if not counts:
            raise ValueError("no intact message in the bag")
        self.connections = [self._connection(i, found[i], counts.get(i, 0)) for i in sorted(found)]
        self.typestore = typestore_from(self.connections, default_typestore)
        if self._cut:
            why = "cut short"
        elif self._index_pos == 0:
            why = "never closed by its writer (no index)"
        else:
            why = "its index damaged"
        self.recovered = CutShort(self.size, self._read_to, self._index_pos or None, why)

    def _connection(self, conn: int, fields: dict[str, bytes], count: int) -> Any:
        """A connection record's fields as rosbags' connection."""
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

    def _records(self) -> Iterator[tuple[int, dict[str, bytes], bytes]]:
        """``(op, header, data)`` of each record in file order, those in chunks in their place,
        up to the first record cut or damaged (``_cut``: whether there was one; ``_read_to``:
        where the last intact record ends; in a compressed chunk read in part, the share of
        the chunk's data that its records up to there take uncompressed)."""
        with self.path.open("rb") as stream, contextlib.ExitStack() as stack:
            if self.size <= len(MAGIC) or stream.read(len(MAGIC)) != MAGIC:
                raise ValueError("not a ROS 1 bag (no '#ROSBAG V2.0' line)")
            buf = stack.enter_context(mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ))
            at = self._read_to = len(MAGIC)
            while (found := _record(buf, at)) is not None:
                header, start, end = found
                op, whole = header["op"][0], end <= len(buf)
                if op == _BAG_HEADER:
                    self._index_pos = int.from_bytes(header.get("index_pos", b""), "little")
                if op == _CHUNK:
                    data = bytes(buf[start:end])
                    intact = yield from self._chunk(header, data, start, end - start)
                    if not (whole and intact):
                        break
                elif not whole:
                    break
                else:
                    yield op, header, bytes(buf[start:end])
                self._read_to = at = end
            self._cut = self._read_to < self.size

    def _chunk(
        self, header: dict[str, bytes], data: bytes, start: int, length: int
    ) -> Generator[tuple[int, dict[str, bytes], bytes], None, bool]:
        """The records of a chunk whose ``length`` bytes of data start at ``start`` (of one cut
        short, those its first part ``data`` holds); returns whether it decompressed."""
        whole = len(data) == length
        try:
            content = _decompressed(header.get("compression", b"none"), data, whole)
        except Exception:  # a damaged chunk: what came before it stands
            return False
        place = 0
        while (inner := _record(content, place)) is not None and inner[2] <= len(content):
            inner_header, inner_start, place = inner
            if not whole:  # the share of the chunk's data up to here, uncompressed
                size = max(_u32(header.get("size", b""), 0), len(content))
                self._read_to = start + round(length * place / size)
            yield inner_header["op"][0], inner_header, content[inner_start:place]
        return True

    def messages(self, connections: Iterable[Any] = ()) -> Iterator[tuple[Any, int, bytes]]:
        """``(connection, log time ns, raw message)`` of ``connections`` (default all), in file
        order, up to the last intact message."""
        wanted = {c.id: c for c in connections} or {c.id: c for c in self.connections}
        for op, header, data in self._records():
            if op != _MESSAGE:
                continue
            connection = wanted.get(_u32(header.get("conn", b""), 0))
            if connection is not None:
                time = header.get("time", b"")
                yield connection, _u32(time, 0) * 1_000_000_000 + _u32(time, 4), data

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        return self.typestore.deserialize_ros1(raw, msgtype)
