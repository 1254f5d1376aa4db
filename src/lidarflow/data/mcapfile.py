"""MCAP files that rosbags does not read: ROS 1 messages (as ``mcap convert`` leaves a ROS 1
bag), and any MCAP file cut short (no summary, no footer, its last chunk cut).

The ``mcap`` library reads the records; rosbags' typestore, built from the file's schemas,
deserialises the messages. Opening reads the summary where there is one with statistics, else
the data section in file order up to the last intact record (of a chunk cut in two, the records
its first part decompresses to).
"""

from __future__ import annotations

import contextlib
import io
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

from lidarflow.data.readers import CutShort, typestore_from

__all__ = ["MAGIC", "McapReader", "channel_encoding"]

MAGIC = b"\x89MCAP0\r\n"

# what the library raises where a file ends inside a record or holds no record
_UNREADABLE = (struct.error, ValueError, EOFError, MemoryError, OverflowError, KeyError)


def _library_errors() -> tuple[type[BaseException], ...]:
    from mcap.exceptions import McapError

    return (McapError, *_UNREADABLE)


def _decompressed(compression: str, data: bytes) -> bytes:
    """As much of a chunk's content as the first part of its data holds."""
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(data)
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompressobj().decompress(data)
    return data


class _DataSection:
    """The data section's schema, channel and message records in file order, chunks opened,
    up to the last intact one (``cut``: whether the file ended inside a record; ``read_to``:
    where the last intact record ends, within a chunk read in part by its uncompressed share)."""

    def __init__(self, path: Path) -> None:
        self.path, self.read_to, self.cut = path, 0, False

    def __iter__(self) -> Iterator[Any]:
        from mcap.records import Channel, Chunk, DataEnd, Footer, Message, Schema
        from mcap.stream_reader import StreamReader, breakup_chunk

        wanted = (Schema, Channel, Message)
        with self.path.open("rb") as stream:
            if stream.read(len(MAGIC)) != MAGIC:
                raise ValueError("not an MCAP file (no magic)")
            records = StreamReader(stream, skip_magic=True, emit_chunks=True).records
            self.read_to = at = len(MAGIC)
            while True:
                try:
                    record = next(records)
                    if isinstance(record, Chunk):
                        inner = [r for r in breakup_chunk(record) if isinstance(r, wanted)]
                except StopIteration:
                    return
                except _library_errors():
                    self.cut = True  # the file ends in this record, or it is damaged
                    yield from self._cut_chunk(stream, at)
                    return
                if isinstance(record, (DataEnd, Footer)):
                    return  # the summary after it repeats the schemas and channels
                if isinstance(record, Chunk):
                    yield from inner
                elif isinstance(record, wanted):
                    yield record
                self.read_to = at = stream.tell()

    def _cut_chunk(self, stream: BinaryIO, at: int) -> Iterator[Any]:
        """The records in the first part of a chunk cut short at the end of the file, where
        the record at ``at`` is a chunk."""
        from mcap.data_stream import ReadDataStream
        from mcap.opcode import Opcode
        from mcap.records import Channel, Chunk, Message, Schema
        from mcap.stream_reader import StreamReader

        stream.seek(at)
        head = stream.read(9)
        if head[:1] != bytes([Opcode.CHUNK]):
            return
        start = stream.tell()
        try:
            chunk = Chunk.read(ReadDataStream(stream))
            content = _decompressed(chunk.compression, chunk.data)
        except Exception:  # no chunk data, or data that does not decompress: nothing to read
            return
        fields = 8 * 3 + 4 * 2 + len(chunk.compression.encode()) + 8  # before the data
        whole = int.from_bytes(head[1:], "little") - fields  # the chunk's data, uncut
        inner = io.BytesIO(content)
        records = StreamReader(inner, skip_magic=True).records
        with contextlib.suppress(*_library_errors()):
            for record in records:
                if isinstance(record, (Schema, Channel, Message)):
                    yield record
                share = inner.tell() / max(chunk.uncompressed_size, len(content))
                self.read_to = start + fields + round(whole * share)


def _summary(path: Path) -> tuple[list[Any], list[Any], dict[int, int]] | None:
    """The summary's schemas, channels and message count per channel; ``None`` where the file
    has no intact summary with statistics."""
    from mcap.reader import make_reader

    try:
        with path.open("rb") as stream:
            summary = make_reader(stream).get_summary()
    except Exception:  # a file cut short or damaged at its end: the data section says it all
        return None
    if summary is None or summary.statistics is None:
        return None
    counts = dict(summary.statistics.channel_message_counts)
    return list(summary.schemas.values()), list(summary.channels.values()), counts


def channel_encoding(path: str | Path) -> str | None:
    """The message encoding of the first channel of an MCAP file (``ros1``, ``cdr``, ...),
    ``None`` where it has none or cannot be read."""
    path = Path(path)
    found = _summary(path)
    if found is not None:
        return found[1][0].message_encoding if found[1] else None
    from mcap.records import Channel

    with contextlib.suppress(Exception):  # a probe: whatever fails here, the reader reports
        for record in _DataSection(path):
            if isinstance(record, Channel):
                return record.message_encoding
    return None


def _definition(schema: Any) -> Any:
    """A schema as rosbags' message definition."""
    from rosbags.interfaces import MessageDefinition, MessageDefinitionFormat

    kind = {"ros1msg": "MSG", "ros2msg": "MSG", "ros2idl": "IDL"}.get(schema.encoding, "NONE")
    text = schema.data.decode() if kind != "NONE" else ""
    return MessageDefinition(MessageDefinitionFormat[kind], text)


#: The start of a zstd frame: ``ros2 bag record --compression-mode message`` compresses each
#: message (its metadata.yaml says so, which a recording cut short lacks); CDR data never
#: starts so.
_ZSTD_FRAME = b"\x28\xb5\x2f\xfd"


class McapReader:
    """The messages of one encoding (``ros1`` or ``cdr``) in an MCAP file, read like a rosbags
    ``AnyReader`` (:mod:`lidarflow.data.readers`); channels of other encodings are left out."""

    def __init__(self, path: str | Path, encoding: str, default_typestore: Any) -> None:
        from mcap.records import Channel, Message, Schema
        from rosbags.interfaces import Connection, ConnectionExtRosbag1, ConnectionExtRosbag2
        from rosbags.typesys.msg import normalize_msgtype

        self.path, self.encoding = Path(path), encoding
        summary = _summary(self.path)
        section = _DataSection(self.path)
        if summary is None:
            schemas, channels, counts = [], [], {}
            for record in section:
                if isinstance(record, Schema):
                    schemas.append(record)
                elif isinstance(record, Channel):
                    channels.append(record)
                elif isinstance(record, Message):
                    counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
        else:
            schemas, channels, counts = summary
        by_id = {s.id: s for s in schemas}
        self.connections = []
        for channel in channels:
            schema = by_id.get(channel.schema_id)
            if channel.message_encoding != encoding or schema is None:
                continue
            if any(c.id == channel.id for c in self.connections):
                continue  # a channel record repeated in a later chunk
            if encoding == "ros1":
                latching = channel.metadata.get("latching", "")
                ext: Any = ConnectionExtRosbag1(
                    channel.metadata.get("callerid"), int(latching) if latching.isdigit() else None
                )
            else:
                ext = ConnectionExtRosbag2(encoding, [])
            self.connections.append(
                Connection(
                    id=channel.id,
                    topic=channel.topic,
                    msgtype=normalize_msgtype(schema.name),
                    msgdef=_definition(schema),
                    digest="",
                    msgcount=counts.get(channel.id, 0),
                    ext=ext,
                    owner=self,
                )
            )
        if summary is None and not any(c.msgcount for c in self.connections):
            raise ValueError("no intact message in the file")
        self.typestore = typestore_from(self.connections, default_typestore)
        if encoding == "ros1":  # the MD5 sum a ROS 1 bag writer asks for: the type's own
            self.connections = [
                c._replace(digest=self.typestore.generate_msgdef(c.msgtype)[1])
                for c in self.connections
            ]
        size = self.path.stat().st_size
        self.recovered = CutShort(size, section.read_to) if section.cut else None

    def messages(self, connections: Iterable[Any] = ()) -> Iterator[tuple[Any, int, bytes]]:
        """``(connection, log time ns, raw message)`` of ``connections`` (default all), in the
        order written."""
        from mcap.records import Message

        wanted = {c.id: c for c in connections} or {c.id: c for c in self.connections}
        for record in _DataSection(self.path):
            if isinstance(record, Message) and record.channel_id in wanted:
                data = record.data
                if data[:4] == _ZSTD_FRAME and self.encoding == "cdr":
                    data = _decompressed("zstd", data)
                yield wanted[record.channel_id], record.log_time, data

    def deserialize(self, raw: bytes, msgtype: str) -> Any:
        if self.encoding == "ros1":
            return self.typestore.deserialize_ros1(raw, msgtype)
        return self.typestore.deserialize_cdr(raw, msgtype)
