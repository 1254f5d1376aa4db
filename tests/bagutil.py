"""Write small real bags (ROS 1, ROS 2 sqlite3/mcap) with rosbags, for tests."""

from __future__ import annotations

import dataclasses
import struct
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_typestore

from lidarflow.data.mcapfile import MAGIC as MCAP_MAGIC


def _header(ts, stamp_ns: int, frame: str):
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    if "seq" in Header.__dataclass_fields__:  # ROS 1 headers carry a sequence number
        return Header(seq=0, stamp=stamp, frame_id=frame)
    return Header(stamp=stamp, frame_id=frame)


def _scan_msg(ts, ranges: np.ndarray, stamp_ns: int, frame: str = "laser", inc: float = 0.01):
    LaserScan = ts.types["sensor_msgs/msg/LaserScan"]
    n = len(ranges)
    return LaserScan(
        header=_header(ts, stamp_ns, frame),
        angle_min=-inc * (n - 1) / 2,
        angle_max=inc * (n - 1) / 2,
        angle_increment=inc,
        time_increment=0.0,
        scan_time=0.1,
        range_min=0.05,
        range_max=8.0,
        ranges=np.asarray(ranges, dtype=np.float32),
        intensities=np.zeros(0, dtype=np.float32),
    )


def _odom_msg(ts, stamp_ns: int, x: float, y: float, yaw: float):
    t = ts.types
    Odometry = t["nav_msgs/msg/Odometry"]
    Pose, PoseWC = t["geometry_msgs/msg/Pose"], t["geometry_msgs/msg/PoseWithCovariance"]
    Point, Quat = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Quaternion"]
    Twist, TwistWC = t["geometry_msgs/msg/Twist"], t["geometry_msgs/msg/TwistWithCovariance"]
    Vec = t["geometry_msgs/msg/Vector3"]
    pose = Pose(
        position=Point(x=x, y=y, z=0.0),
        orientation=Quat(x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2))),
    )
    zero = Vec(x=0.0, y=0.0, z=0.0)
    return Odometry(
        header=_header(ts, stamp_ns, "odom"),
        child_frame_id="base_link",
        pose=PoseWC(pose=pose, covariance=np.zeros(36)),
        twist=TwistWC(twist=Twist(linear=zero, angular=zero), covariance=np.zeros(36)),
    )


def _tf_msg(ts, stamp_ns: int, links: list[tuple[str, str, tuple[float, ...]]]):
    """A ``tf2_msgs/TFMessage`` of ``(parent, child, (x, y, yaw[, roll]))`` links, each rotation
    ``Rz(yaw) Rx(roll)`` (registers the type, which the bundled typestores lack)."""
    if "tf2_msgs/msg/TFMessage" not in ts.types:
        from rosbags.typesys import get_types_from_msg

        definition = "geometry_msgs/TransformStamped[] transforms"
        ts.register(get_types_from_msg(definition, "tf2_msgs/msg/TFMessage"))
    t = ts.types
    TF, Stamped = t["tf2_msgs/msg/TFMessage"], t["geometry_msgs/msg/TransformStamped"]
    Transform, Vec, Quat = (
        t["geometry_msgs/msg/Transform"],
        t["geometry_msgs/msg/Vector3"],
        t["geometry_msgs/msg/Quaternion"],
    )
    return TF(
        transforms=[
            Stamped(
                header=_header(ts, stamp_ns, parent),
                child_frame_id=child,
                transform=Transform(
                    translation=Vec(x=x, y=y, z=0.3),
                    rotation=Quat(**_quaternion(yaw, *roll)),
                ),
            )
            for parent, child, (x, y, yaw, *roll) in links
        ]
    )


def _quaternion(yaw: float, roll: float = 0.0) -> dict[str, float]:
    """``Rz(yaw) Rx(roll)`` as quaternion fields."""
    cy, sy, cr, sr = np.cos(yaw / 2), np.sin(yaw / 2), np.cos(roll / 2), np.sin(roll / 2)
    return {"x": float(cy * sr), "y": float(sy * sr), "z": float(sy * cr), "w": float(cy * cr)}


def write_bag(
    path: Path,
    kind: str = "ros1",
    scans: dict[str, Sequence[np.ndarray]] | None = None,
    rate_hz: float = 10.0,
    odom: bool | Sequence[str] = False,
    extra_string_topic: bool = False,
    mount: tuple[float, ...] | None = None,
    copies: int = 1,
    multi_echo_topic: bool = False,
    overrides: dict[int, dict[str, float]] | None = None,
    header_stamps: Sequence[int] | None = None,
    clock: Callable[[int], int] | None = None,
    compression: str | None = None,
    echoes: Sequence[Sequence[Sequence[float]]] | dict[str, Sequence] | None = None,
) -> Path:
    """Write a bag with LaserScan topics ``{topic: [ranges, ...]}``.

    kind: "ros1" (a .bag file), "sqlite3" or "mcap" (a ROS 2 bag folder). ``mount``: also a
    ``/tf`` message placing the scans' frame ``laser`` on ``base_link`` (via ``chassis``):
    ``(x, y, yaw)``, or ``(x, y, yaw, roll)`` (``roll`` pi: mounted upside down).
    ``odom``: also a ``/odom`` topic of ``nav_msgs/Odometry`` (or the topics named, the k-th
    driving k + 1 times as fast). ``copies``: each scan message written that many times.
    ``multi_echo_topic``: also an ``/echoes`` topic of ``sensor_msgs/MultiEchoLaserScan``.
    ``overrides``: LaserScan fields to change in scan ``i`` of each topic
    (``{i: {"range_max": nan}}``). ``header_stamps``: scan ``i``'s header stamp (ns) instead
    of its log time. ``clock``: the header stamp of every scan and odometry message as a
    function of its log time (a header clock that jumps, say). ``compression``: "bz2" or
    "lz4" chunks (ROS 1), "file" or "message" zstd (ROS 2). ``echoes``: also a
    ``/horizontal_laser_2d`` topic of ``sensor_msgs/MultiEchoLaserScan`` (as Cartographer's
    backpack records; or ``{topic: frames}``), one message per frame of per-beam echo lists,
    0.01 rad apart.
    """
    scans = scans if scans is not None else {"/scan": [np.full(50, 3.0)] * 25}
    ros1 = kind == "ros1"
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    ser = ts.serialize_ros1 if ros1 else ts.serialize_cdr
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
        if compression is not None:  # "bz2" or "lz4" chunks
            writer.set_compression(getattr(Writer.CompressionFormat, compression.upper()))
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
        if compression is not None:  # zstd, by "file" or by "message"
            from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

            mode = getattr(CompressionMode, compression.upper())
            writer.set_compression(mode, CompressionFormat.ZSTD)
    t0 = 1_700_000_000 * 10**9
    period = int(1e9 / rate_hz)
    with writer:

        def conn(topic, msgtype):
            if ros1:
                return writer.add_connection(topic, msgtype, typestore=ts)
            return writer.add_connection(topic, msgtype, typestore=ts)

        for topic, frames in scans.items():
            c = conn(topic, "sensor_msgs/msg/LaserScan")
            for i, ranges in enumerate(frames):
                stamp = t0 + i * period
                header_stamp = stamp if header_stamps is None else header_stamps[i]
                header_stamp = header_stamp if clock is None else clock(header_stamp)
                msg = _scan_msg(ts, np.asarray(ranges), header_stamp)
                msg = dataclasses.replace(msg, **(overrides or {}).get(i, {}))
                raw = ser(msg, "sensor_msgs/msg/LaserScan")
                for _ in range(copies):
                    writer.write(c, stamp, raw)
        for k, topic in enumerate(["/odom"] if odom is True else list(odom or [])):
            c = conn(topic, "nav_msgs/msg/Odometry")
            n = max(len(f) for f in scans.values()) if scans else 10
            for i in range(2 * n + 1):
                stamp = t0 + i * period // 2
                header_stamp = stamp if clock is None else clock(stamp)
                # the k-th topic drives (k + 1) times as fast: tells the topics apart
                msg = _odom_msg(ts, header_stamp, 0.05 * i * (k + 1), 0.0, 0.01 * i)
                writer.write(c, stamp, ser(msg, "nav_msgs/msg/Odometry"))
        if mount is not None:
            msg = _tf_msg(
                ts,
                t0,
                [
                    ("base_link", "chassis", (0.2, 0.0, 0.0)),
                    ("chassis", "laser", (mount[0] - 0.2, *mount[1:])),
                ],
            )
            c = conn("/tf", "tf2_msgs/msg/TFMessage")
            writer.write(c, t0, ser(msg, "tf2_msgs/msg/TFMessage"))
        if multi_echo_topic:
            c = conn("/echoes", "sensor_msgs/msg/MultiEchoLaserScan")
            Echoes = ts.types["sensor_msgs/msg/MultiEchoLaserScan"]
            Echo = ts.types["sensor_msgs/msg/LaserEcho"]
            msg = Echoes(
                header=_header(ts, t0, "laser"), angle_min=-0.1, angle_max=0.1,
                angle_increment=0.1, time_increment=0.0, scan_time=0.1, range_min=0.05,
                range_max=8.0, ranges=[Echo(echoes=np.full(1, 3.0, np.float32))] * 3,
                intensities=[],
            )  # fmt: skip
            writer.write(c, t0, ser(msg, "sensor_msgs/msg/MultiEchoLaserScan"))
        echo_topics = echoes if isinstance(echoes, dict) else {"/horizontal_laser_2d": echoes}
        for topic, frames in echo_topics.items() if echoes is not None else ():
            c = conn(topic, "sensor_msgs/msg/MultiEchoLaserScan")
            Echoes = ts.types["sensor_msgs/msg/MultiEchoLaserScan"]
            Echo = ts.types["sensor_msgs/msg/LaserEcho"]
            for i, frame in enumerate(frames):
                stamp, n = t0 + i * period, len(frame)
                msg = Echoes(
                    header=_header(ts, stamp, "laser"), angle_min=-0.005 * (n - 1),
                    angle_max=0.005 * (n - 1), angle_increment=0.01, time_increment=0.0,
                    scan_time=0.1, range_min=0.05, range_max=8.0,
                    ranges=[Echo(echoes=np.asarray(e, np.float32)) for e in frame],
                    intensities=[],
                )  # fmt: skip
                writer.write(c, stamp, ser(msg, "sensor_msgs/msg/MultiEchoLaserScan"))
        if extra_string_topic:
            c = conn("/chatter", "std_msgs/msg/String")
            String = ts.types["std_msgs/msg/String"]
            writer.write(c, t0, ser(String(data="hello"), "std_msgs/msg/String"))
    return path


def _mcap_record(op: int, *fields: bytes) -> bytes:
    body = b"".join(fields)
    return bytes([op]) + struct.pack("<Q", len(body)) + body


def _mcap_string(text: str | bytes) -> bytes:
    data = text.encode() if isinstance(text, str) else text
    return struct.pack("<I", len(data)) + data


def write_ros1_mcap(
    path: Path,
    scans: Sequence[np.ndarray],
    rate_hz: float = 10.0,
    odom: bool | Sequence[str] = False,
    mount: tuple[float, float, float] | None = None,
    compression: str | None = "",
    summary: bool = False,
    angle_increment: float = 0.01,
) -> Path:
    """The MCAP file that ``mcap convert`` makes of :func:`write_bag`'s ROS 1 bag with the
    same arguments (one ``/scan`` topic): ROS 1 messages, ``ros1msg`` schemas, written in one
    chunk (``compression`` "", "lz4" or "zstd") or, with ``compression=None``, unchunked; with
    ``summary``, followed by a summary section (the schemas and channels again and a
    Statistics record) as ``mcap`` writes one. The scans' beams are ``angle_increment`` apart."""
    ts = get_typestore(Stores.ROS1_NOETIC)
    t0, period = 1_700_000_000 * 10**9, int(1e9 / rate_hz)
    messages: list[tuple[str, str, int, object]] = [
        ("/scan", "sensor_msgs/msg/LaserScan", t0 + i * period,
         _scan_msg(ts, np.asarray(r), t0 + i * period, inc=angle_increment))
        for i, r in enumerate(scans)
    ]  # fmt: skip
    if odom:
        messages += [
            ("/odom", "nav_msgs/msg/Odometry", t0 + i * period // 2,
             _odom_msg(ts, t0 + i * period // 2, 0.05 * i, 0.0, 0.01 * i))
            for i in range(2 * len(scans) + 1)
        ]  # fmt: skip
    if mount is not None:
        messages.append(("/tf", "tf2_msgs/msg/TFMessage", t0, _tf_msg(
            ts, t0, [("base_link", "chassis", (0.2, 0.0, 0.0)),
                     ("chassis", "laser", (mount[0] - 0.2, mount[1], mount[2]))])))  # fmt: skip
    records, channels, counts = [], {}, {}
    for topic, msgtype, _, _ in messages:
        if topic in channels:
            continue
        channels[topic] = key = len(channels) + 1
        text, _ = ts.generate_msgdef(msgtype)
        name = msgtype.replace("/msg/", "/")
        records.append(_mcap_record(0x03, struct.pack("<H", key), _mcap_string(name),
                                    _mcap_string("ros1msg"), _mcap_string(text)))  # fmt: skip
        records.append(_mcap_record(0x04, struct.pack("<HH", key, key), _mcap_string(topic),
                                    _mcap_string("ros1"), struct.pack("<I", 0)))  # fmt: skip
    described = list(records)
    for seq, (topic, msgtype, stamp, msg) in enumerate(sorted(messages, key=lambda m: m[2])):
        counts[channels[topic]] = counts.get(channels[topic], 0) + 1
        raw = ts.serialize_ros1(msg, msgtype)
        records.append(_mcap_record(0x05, struct.pack("<HIQQ", channels[topic], seq, stamp, stamp),
                                    bytes(raw)))  # fmt: skip
    data = b"".join(records)
    if compression is not None:
        if compression == "lz4":
            from lz4.frame import compress

            packed = compress(data)
        elif compression == "zstd":
            from rosbags.rosbag2.storage_mcap import zstd

            packed = zstd.compress(data)
        else:
            packed = data
        chunk = struct.pack("<QQQI", t0, t0, len(data), 0), _mcap_string(compression)
        data = _mcap_record(0x06, *chunk, struct.pack("<Q", len(packed)), packed)
    header = _mcap_record(0x01, _mcap_string("ros1"), _mcap_string("lidarflow tests"))
    data_end = _mcap_record(0x0F, struct.pack("<I", 0))
    summary_start, section = 0, b""
    if summary:
        summary_start = len(MCAP_MAGIC + header + data + data_end)
        entries = b"".join(struct.pack("<HQ", c, n) for c, n in counts.items())
        totals = struct.pack("<QHIIIIQQ", len(messages), len(channels), len(channels), 0, 0,
                             int(compression is not None), t0, t0)  # fmt: skip
        stats = _mcap_record(0x0B, totals, struct.pack("<I", len(entries)), entries)
        section = b"".join(described) + stats
    footer = _mcap_record(0x02, struct.pack("<QQI", summary_start, 0, 0))
    path.write_bytes(MCAP_MAGIC + header + data + data_end + section + footer + MCAP_MAGIC)
    return path


def write_legs_bag(
    path: Path,
    scans: Sequence[np.ndarray],
    legs: Sequence[Sequence[tuple[float, float]]],
    legs_first: bool = True,
) -> Path:
    """A ROS 1 bag as leg_tracker's extracted bags are: per labelled scan a ``/training_scan``
    of ``scans[i]``'s ranges (stamps unlike any recording's) and a ``/leg_cluster_positions``
    PoseArray of ``legs[i]`` (x, y; no stamp), the PoseArray logged just before its scan
    (``legs_first``) or just after; ``len(legs)`` may differ from ``len(scans)``."""
    from rosbags.rosbag1 import Writer

    ts = get_typestore(Stores.ROS1_NOETIC)
    t = ts.types
    PoseArray, Pose = t["geometry_msgs/msg/PoseArray"], t["geometry_msgs/msg/Pose"]
    Point, Quat = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Quaternion"]
    t0 = 1_400_000_000 * 10**9
    with Writer(path) as writer:
        c_scan = writer.add_connection("/training_scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        c_legs = writer.add_connection(
            "/leg_cluster_positions", "geometry_msgs/msg/PoseArray", typestore=ts
        )
        for i in range(max(len(scans), len(legs))):
            stamp = t0 + i * 10**8
            if i < len(legs):
                poses = [
                    Pose(
                        position=Point(x=float(x), y=float(y), z=0.0),
                        orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0),
                    )
                    for x, y in legs[i]
                ]
                msg = PoseArray(header=_header(ts, 0, "laser"), poses=poses)
                writer.write(
                    c_legs,
                    stamp + (0 if legs_first else 2000),
                    ts.serialize_ros1(msg, "geometry_msgs/msg/PoseArray"),
                )
            if i < len(scans):
                raw = ts.serialize_ros1(
                    _scan_msg(ts, scans[i], 5 * 10**9 + i), "sensor_msgs/msg/LaserScan"
                )
                writer.write(c_scan, stamp + 1000, raw)
    return path


#: leg_tracker's ``Person`` message, as ``/ground_truth_people_tracks`` carries it.
PERSON = "leg_tracker/msg/Person"


def write_people_bag(path: Path, people: Sequence[tuple[int, float, float]]) -> Path:
    """A ROS 1 bag of ``/ground_truth_people_tracks``: one ``leg_tracker/Person`` per
    ``(log time ns, x, y)``."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import get_types_from_msg

    ts = get_typestore(Stores.ROS1_NOETIC)
    ts.register(get_types_from_msg("geometry_msgs/Pose pose\nuint32 id", PERSON))
    t = ts.types
    Person, Pose = t[PERSON], t["geometry_msgs/msg/Pose"]
    Point, Quat = t["geometry_msgs/msg/Point"], t["geometry_msgs/msg/Quaternion"]
    with Writer(path) as writer:
        c = writer.add_connection("/ground_truth_people_tracks", PERSON, typestore=ts)
        for i, (stamp, x, y) in enumerate(people):
            pose = Pose(
                position=Point(x=x, y=y, z=0.0), orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0)
            )
            writer.write(c, stamp, ts.serialize_ros1(Person(pose=pose, id=i), PERSON))
    return path
