"""Read LaserScan topics (and optional odometry) from ROS 1 bags, ROS 2 bags and MCAP files.

A ``MultiEchoLaserScan`` topic (Cartographer's backpack recordings, scanners that report every
echo of a beam) is read where a bag has no LaserScan one, or where ``--topic`` names it: each
beam's nearest valid echo (:func:`nearest_echoes`), the first surface it met.

Uses ``rosbags`` (pure Python, no ROS install). Accepted inputs: a ROS 1 ``.bag``, a zipped
``.bag.zip`` (unpacked to a temporary file, :mod:`lidarflow.data.unzip`), a ROS 2 bag folder
(sqlite3 or mcap storage), or a bare ``.mcap`` file: ROS 2 (CDR) messages, or ROS 1 messages as
``mcap convert`` leaves a ROS 1 bag (read by :mod:`lidarflow.data.mcapfile`).

A bag cut short (a robot that lost power, a writer stopped early: a ROS 1 bag without its index,
an MCAP file without its summary or footer) is read up to its last intact message
(:mod:`lidarflow.data.ros1bag`, :mod:`lidarflow.data.mcapfile`), and the recording says how
much in ``meta["recovered"]``.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lidarflow.data.bagfile import TopicInfo, list_topics, open_bag, why_failed
from lidarflow.data.messages import check_beams, declared_beams, nearest_echoes, scan_of, stamp_ns
from lidarflow.data.poses import pose_of
from lidarflow.data.recording import Recording
from lidarflow.data.sessions import in_sessions
from lidarflow.data.tf import TF_TYPE, TransformTree, compose_poses, mirrored
from lidarflow.data.topics import (
    LASERSCAN,
    MULTI_ECHO,
    POSE_TYPES,
    SCAN_TYPES,
    choose_pose_topic,
    choose_scan_topic,
)
from lidarflow.data.unzip import unzip_folder, unzipped_bag
from lidarflow.errors import BagError, ScanError
from lidarflow.scan import MAX_BEAMS, BeamGeometry, Scan

__all__ = [
    "LASERSCAN",
    "MAX_BEAMS",
    "MULTI_ECHO",
    "POSE_TYPES",
    "SCAN_TYPES",
    "TopicInfo",
    "declared_beams",
    "list_topics",
    "nearest_echoes",
    "open_bag",
    "pose_of",
    "read_bag",
    "unzip_folder",
    "unzipped_bag",
]


#: Header stamps all below a day after the epoch are a simulator's clock (ROS ``/clock``).
SIM_CLOCK_NS = 86_400 * 1_000_000_000


def _zero_stamps_filled(header_ns: np.ndarray, log_ns: np.ndarray) -> np.ndarray:
    """Header stamps with each zero (a driver that left the stamp unset) replaced by its log
    time. On a simulator's clock, which starts at 0, zeros before its first other stamp are its
    first instants and stay; a later zero is unset, and the log time (a wall clock) no stand-in
    there: it gets the stamps around it, interpolated by position."""
    zero = header_ns <= 0
    if not zero.any():
        return header_ns
    rest = np.flatnonzero(~zero)
    if rest.size == 0 or header_ns[rest].max() >= SIM_CLOCK_NS:
        return np.where(zero, log_ns, header_ns)
    out = np.maximum(header_ns, 0)
    later = np.flatnonzero(zero)
    later = later[later > rest[0]]
    out[later] = np.rint(np.interp(later, rest, header_ns[rest])).astype(np.int64)
    return out


_COPIES_WITHIN_NS = 1_000_000_000  # log times of one message recorded twice: well within 1 s


def _stuck(stamps_ns: np.ndarray) -> bool:
    """Whether stamps in arrival order advance between fewer than half of the messages."""
    advancing = np.count_nonzero(np.diff(stamps_ns) > 0)
    return len(stamps_ns) > 1 and advancing < (len(stamps_ns) - 1) / 2


def _stamped(scans: list[Scan], stamps_ns: np.ndarray) -> list[Scan]:
    """``scans`` with these stamps instead of their own."""
    return [Scan(s.ranges, s.geometry, int(t)) for s, t in zip(scans, stamps_ns, strict=True)]


def read_bag(
    path: str | Path,
    topic: str | None = None,
    odom_topic: str | None = None,
    progress: Callable[[int], None] | None = None,
) -> Recording:
    """Read one LaserScan topic (and optionally the poses of an odometry topic) as a recording.

    Args:
        path: the bag (see module docstring for accepted kinds).
        topic: the scan topic; by default the bag's LaserScan topic, and of several the one
            named ``scan``, else the busiest (``meta["topic_choice"]`` says which, over which).
        odom_topic: an Odometry/PoseStamped topic; by default the bag's ``nav_msgs/Odometry``
            topic, and of several the first of
            :data:`~lidarflow.data.topics.PREFERRED_ODOMETRY` there, else the one with the most
            messages (``meta["pose_topic_choice"]`` says which, over which).
            Poses are those of the odometry frame's child (usually the robot base),
            interpolated at the scan stamps, then moved to the scan's frame by the static TF
            between the two when the bag has it
            (``meta["sensor_mount"]`` = that ``(x, y, yaw)``; ``None``: poses stay the base's).
            A scanner mounted upside down (``meta["sensor_upside_down"]``) sees the world
            mirrored: its poses are given in the mirrored world, so that their motions are its.
        progress: called with the number of scans read since the last call.

    A bag cut short is read up to its last intact message; ``meta["recovered"]`` says how much
    (see :class:`~lidarflow.data.readers.CutShort`).

    Scans that are empty, malformed (impossible geometry) or the same message recorded twice
    are dropped and counted in ``meta`` (``*_scans_dropped``). Scans are ordered by their
    header stamps, or by their log times where the header stamps do not advance
    (``meta["stamps"]``); a zero header stamp is replaced by the log time, except on a
    simulator's clock (all stamps within a day of 0), which starts at 0 (later zeros there get
    the stamps around them). Where the header
    clock goes back (more than 5 median frame periods and 0.5 s behind the latest stamp, in
    arrival order), a new session begins: sessions stay in arrival order, each in header
    order, and each later one is shifted to begin twice that tolerance after the one before
    ends (``meta["clock_jumps"]``); its poses come from the odometry's own session, or are NaN
    where the odometry's clock did not jump with the scans'.
    """
    path = Path(path)
    with open_bag(path) as reader:
        scan_topic, topic_choice = choose_scan_topic(path, reader, topic)
        multi_echo = any(
            c.topic == scan_topic and c.msgtype == MULTI_ECHO for c in reader.connections
        )
        pose_topic, pose_choice = choose_pose_topic(path, reader, odom_topic)
        wanted = [c for c in reader.connections if c.topic in {scan_topic, pose_topic}]
        if pose_topic is not None:  # the TF tree, to find the scanner's mount on the base
            wanted += [c for c in reader.connections if c.msgtype == TF_TYPE]
        tree, body = TransformTree(), ""
        scans: list[Scan] = []
        pose_stamps: list[int] = []
        pose_log_times: list[int] = []
        pose_values: list[tuple[float, float, float]] = []
        frame_id = ""
        malformed: list[ScanError] = []
        log_times: list[int] = []
        try:
            for conn, log_time, raw in reader.messages(connections=wanted):
                if conn.msgtype == TF_TYPE:
                    tree.add(reader.deserialize(raw, conn.msgtype))
                    continue
                if conn.topic == scan_topic:
                    check_beams(path, scan_topic, raw, conn)
                msg = reader.deserialize(raw, conn.msgtype)
                if conn.topic == pose_topic:
                    body = body or str(getattr(msg, "child_frame_id", "")).lstrip("/")
                    pose_stamps.append(stamp_ns(msg))
                    pose_log_times.append(int(log_time))
                    pose_values.append(pose_of(msg))
                    continue
                frame_id = frame_id or str(msg.header.frame_id).lstrip("/")
                try:
                    scan = scan_of(msg, conn.msgtype)
                except ScanError as err:
                    # One glitched message (a driver's first scan, say) must not cost the whole
                    # recording; a topic of nothing but malformed scans is refused below.
                    malformed.append(err)
                    continue
                if scan is None:
                    continue  # an empty scan carries nothing; counted below
                scans.append(scan)
                log_times.append(int(log_time))
                if progress is not None:
                    progress(1)
        except BagError:
            raise
        except Exception as err:  # truncated chunks, bad CDR, ... all end here
            raise BagError(
                f"{path}: cannot read messages on {scan_topic} ({why_failed(err)}); "
                "the bag may be truncated or corrupt"
            ) from err
        total = sum(c.msgcount for c in reader.connections if c.topic == scan_topic)
        recovered = getattr(reader, "recovered", None)  # a bag cut short: how much was read
    # where the topic was chosen among several, the error says which others there are
    others = f" ({topic_choice})" if topic_choice else ""
    if not scans and malformed:
        raise BagError(
            f"{path}: topic {scan_topic}: every scan is a malformed LaserScan ({malformed[0]})"
            + others
        ) from malformed[0]
    if not scans:
        raise BagError(f"{path}: topic {scan_topic} holds no non-empty scans{others}")
    header = np.array([s.stamp_ns for s in scans], dtype=np.int64)
    filled = _zero_stamps_filled(header, np.array(log_times, dtype=np.int64))
    if not np.array_equal(filled, header):
        scans = _stamped(scans, filled)
    # The same message recorded twice (two connections on one topic, merged bags) is one
    # measurement: kept twice, it would make a copy of the last map a perfect prediction. Its
    # copies arrive together; the same scan at the same stamp a session later is a simulator
    # replaying itself after its clock was reset (data.sessions), and is kept.
    # (a digest of the ranges: their bytes as keys held a second copy of every scan)
    seen: dict[tuple[int, BeamGeometry, bytes], int] = {}
    unique: list[tuple[Scan, int]] = []
    for scan, log_time in zip(scans, log_times, strict=True):
        digest = hashlib.blake2b(np.ascontiguousarray(scan.ranges), digest_size=16).digest()
        key = (scan.stamp_ns, scan.geometry, digest)
        if key not in seen or abs(int(log_time) - seen[key]) > _COPIES_WITHIN_NS:
            unique.append((scan, log_time))
            seen[key] = int(log_time)
    duplicates = len(scans) - len(unique)
    scans, stamps = [scan for scan, _ in unique], "header"
    arrivals = np.array([log_time for _, log_time in unique], dtype=np.int64)
    if _stuck(np.array([s.stamp_ns for s in scans])) and not _stuck(arrivals):
        # A driver that never advances its header stamps (all one value) would leave every scan
        # at one instant: no frame rate, every frame a gap, every scan at one odometry pose.
        scans = _stamped(scans, arrivals)
        stamps = "log time (the header stamps do not advance)"
    odometry = None
    if pose_topic is not None:
        pose_logged = np.array(pose_log_times, dtype=np.int64)
        odometry = (
            _zero_stamps_filled(np.array(pose_stamps, dtype=np.int64), pose_logged),
            pose_logged,
            np.array(pose_values, dtype=np.float64).reshape(-1, 3),
        )
    scans, poses, clock_jumps = in_sessions(scans, arrivals, odometry)
    mount, upside_down = None, False
    if poses is not None:
        found = tree.mount(body, frame_id) if body and frame_id else None
        if found is not None:
            mount, upside_down = found
            poses = compose_poses(poses, mount)
            if upside_down:  # the scanner sees the world mirrored, and so moves in it
                poses = mirrored(poses)
    meta = {
        "source": str(path),
        "topic": scan_topic,
        "frame_id": frame_id,
        "pose_topic": pose_topic,
        "empty_scans_dropped": int(total - len(scans) - duplicates - len(malformed)),
        "duplicate_scans_dropped": duplicates,
        "stamps": stamps,
        "clock_jumps": clock_jumps,
        "malformed_scans_dropped": len(malformed),
    }
    if multi_echo:
        meta["scan_type"] = "MultiEchoLaserScan (each beam's nearest echo)"
    if topic_choice is not None:
        meta["topic_choice"] = topic_choice
    if pose_choice is not None:
        meta["pose_topic_choice"] = pose_choice
    if pose_topic is not None:
        meta["sensor_mount"] = None if mount is None else [round(v, 6) for v in mount]
        if upside_down:
            meta["sensor_upside_down"] = True
    recording = Recording.from_scans(scans, poses=poses, meta=meta)
    recording.meta["frame_rate_hz"] = round(recording.frame_rate, 3)
    if recovered is not None:
        seconds = (int(recording.stamps_ns[-1]) - int(recording.stamps_ns[0])) / 1e9
        recording.meta["recovered"] = recovered.note(len(recording), seconds)
    return recording
