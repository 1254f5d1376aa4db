"""The input bag's messages copied into a prediction output, so that it stands on its own
(docs/guide/outputs.md: what is copied, names, latching).

Where the output serialises as the input does, the bytes are copied as they are; across ROS 1
and CDR each message is converted as ``rosbags-convert`` does, on the bytes where only the
header differs, else field by field. Types the output's type store lacks are taken from the
input's. The reader is what :func:`lidarflow.data.bagfile.open_bag` yields.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from functools import partial
from typing import Any

import numpy as np

from lidarflow.errors import BagError, LidarflowError
from lidarflow.outputs.rosout import BagOutput

__all__ = ["copied_messages", "output_topic", "scan_log_times", "serialization"]

_COPIES_WITHIN_NS = 1_000_000_000  # one message recorded twice arrives well within 1 s


def serialization(reader: Any, connection: Any) -> str:
    """``ros1`` or ``cdr``: how the input stores ``connection``'s messages (a rosbags ROS 2
    connection says so; the reader of ROS 1 messages in MCAP files has no ``is2``)."""
    ext = getattr(connection, "ext", None)
    fmt = getattr(ext, "serialization_format", None)
    if fmt:
        return str(fmt)
    if ext is not None and hasattr(ext, "latching"):
        return "ros1"
    return "cdr" if getattr(reader, "is2", False) else "ros1"


def output_topic(topic: str, ros1: bool) -> str:
    """The name ``topic`` takes in the output: as recorded in a ROS 1 bag, absolute in ROS 2."""
    return topic if ros1 or topic.startswith("/") else "/" + topic


def _latched(connection: Any) -> bool:
    ext = getattr(connection, "ext", None)
    if getattr(ext, "latching", None):
        return True
    profiles = getattr(ext, "offered_qos_profiles", None) or []
    durability = [getattr(getattr(q, "durability", None), "name", "") for q in profiles]
    return "TRANSIENT_LOCAL" in durability


def _needed(store: Any, msgtype: str) -> set[str]:
    """``msgtype`` and every message type its fields use, in ``store``."""
    from rosbags.interfaces import Nodetype

    out: set[str] = set()
    todo = [msgtype]
    while todo:
        name = todo.pop()
        if name in out or name not in store.fielddefs:
            continue
        out.add(name)
        for _, (kind, detail) in store.fielddefs[name][1]:
            if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
                kind, detail = detail[0]
            if kind == Nodetype.NAME:
                todo.append(detail)
    return out


def _take_types(source: Any, target: Any, msgtype: str) -> None:
    """Register in ``target`` the types ``msgtype`` needs that it lacks, as ``source`` defines
    them; never a header (each ROS has its own)."""
    wanted = {
        name: source.fielddefs[name]
        for name in _needed(source, msgtype)
        if name not in target.fielddefs and name != "std_msgs/msg/Header"
    }
    if wanted:
        target.register(wanted)


def _converter(
    source: Any, target: Any, msgtype: str, from_ros1: bool, to_ros1: bool, cache: dict[str, Any]
) -> Callable[[bytes], Any]:
    """The converter of ``msgtype``'s messages from the input's serialisation to the output's
    (``cache``: rosbags' migration functions, one per direction)."""
    from rosbags.convert.converter import is_same_wireformat, migrate_bytes

    if from_ros1 == to_ros1:
        return bytes  # the input's bytes are the output's
    if is_same_wireformat(source, target, msgtype, msgtype):  # but the header
        if from_ros1:
            return partial(target.ros1_to_cdr, typename=msgtype)
        return partial(source.cdr_to_ros1, typename=msgtype)
    return partial(
        migrate_bytes, source, target, msgtype, msgtype, cache,
        src_is2=not from_ros1, dst_is2=not to_ros1,
    )  # fmt: skip


def _definition(store: Any, connection: Any, msgtype: str, ros1: bool) -> tuple[str, str]:
    """The message definition and hash (md5sum in ROS 1, RIHS01 in ROS 2) to record for
    ``msgtype``: the input connection's own where it recorded one in the output's format, else
    made from ``store``'s types."""
    recorded = getattr(connection, "msgdef", None)
    digest = getattr(connection, "digest", "")
    if (
        recorded is not None
        and getattr(recorded.format, "name", "") == "MSG"
        and digest
        and digest.startswith("RIHS01_") != ros1
    ):
        return str(recorded.data), str(digest)
    if ros1:
        return store.generate_msgdef(msgtype)
    return store.generate_msgdef(msgtype, ros_version=2)[0], store.hash_rihs01(msgtype)


def copied_messages(
    reader: Any, out: BagOutput, keep: Callable[[str], bool] = lambda topic: True
) -> Iterator[tuple[int, Any, Any]]:
    """``(log time ns, output connection, bytes)`` of every message of ``reader`` on a topic
    ``keep`` keeps, in order, converted for ``out``. A message that cannot be read or converted
    raises :class:`BagError`."""
    try:
        yield from _copied(reader, out, keep)
    except LidarflowError:
        raise
    except Exception as err:  # rosbags raises many types for damaged or unusual messages
        text = str(err).strip().splitlines()
        why = f"{type(err).__name__}: {text[0]}" if text else type(err).__name__
        raise BagError(
            f"cannot copy the input bag's messages ({why}); --topics without 'input' "
            "writes the predictions alone"
        ) from err


def _copied(
    reader: Any, out: BagOutput, keep: Callable[[str], bool]
) -> Iterator[tuple[int, Any, Any]]:
    connections = [c for c in reader.connections if keep(c.topic)]
    source = getattr(reader, "typestore", None)
    if source is None:  # a reader that keeps no types of its own: the standard ones
        from rosbags.typesys import Stores, get_typestore

        ros1 = bool(connections) and serialization(reader, connections[0]) == "ros1"
        source = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    # by identity: the reader yields its own connection objects, which may not hash (ROS 2
    # connections hold lists of QoS profiles)
    routes: dict[int, tuple[Any, Callable[[bytes], Any]]] = {}
    caches: dict[bool, dict[str, Any]] = {True: {}, False: {}}
    for conn in connections:
        from_ros1 = serialization(reader, conn) == "ros1"
        same = from_ros1 == out.ros1
        if not same:
            _take_types(source, out.typestore, conn.msgtype)
        convert = _converter(
            source, out.typestore, conn.msgtype, from_ros1, out.ros1, caches[from_ros1]
        )
        msgdef, digest = _definition(
            source if same else out.typestore, conn if same else None, conn.msgtype, out.ros1
        )
        ext = getattr(conn, "ext", None)
        target = out.add_copy(
            output_topic(conn.topic, out.ros1),
            conn.msgtype,
            msgdef,
            digest,
            latching=_latched(conn),
            callerid=getattr(ext, "callerid", None),
            qos=getattr(ext, "offered_qos_profiles", None) if same else None,
        )
        routes[id(conn)] = (target, convert)
    if not routes:
        return
    for conn, log_time, raw in reader.messages(connections=connections):
        target, convert = routes[id(conn)]
        yield int(log_time), target, convert(raw)


def scan_log_times(
    reader: Any, topic: str, header_stamps: np.ndarray, fallback_ns: np.ndarray
) -> np.ndarray:
    """Each scan's log time in the input: that of the next message on ``topic`` whose header
    stamp is the scan's (``header_stamps``, as the bag has them; copies recorded together count
    once), else ``fallback_ns``; made non-decreasing, so that predictions logged at them keep
    their scans' order."""
    by_stamp: dict[int, deque[int]] = {}
    connections = [c for c in reader.connections if c.topic == topic]
    for conn, log_time, raw in reader.messages(connections=connections):
        stamp = reader.deserialize(raw, conn.msgtype).header.stamp
        key = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
        by_stamp.setdefault(key, deque()).append(int(log_time))
    out = np.array(fallback_ns, dtype=np.int64)
    for i, stamp in enumerate(np.asarray(header_stamps, dtype=np.int64)):
        queue = by_stamp.get(int(stamp))
        if not queue:
            continue
        out[i] = first = queue.popleft()
        while queue and queue[0] - first <= _COPIES_WITHIN_NS:
            queue.popleft()
    return np.maximum.accumulate(out) if out.size else out
