"""Read one scan topic of a bag (and optionally its odometry) as a :class:`Recording`.

:func:`read_bag` in named steps: open the bag (:mod:`lidarflow.data.bagfile`: ROS 1 bags, zipped
ones, ROS 2 bag folders, MCAP files); choose the topics (:mod:`lidarflow.data.topics`); read the
scan messages (:mod:`lidarflow.data.messages`), the odometry (:mod:`lidarflow.data.poses`) and
the TF tree in one pass; clean the scans (:mod:`lidarflow.data.cleaning`); order them in
sessions where the header clock jumps back (:mod:`lidarflow.data.sessions`); move the poses
onto the scanner (:func:`lidarflow.data.poses.on_the_scanner`); and say in the recording's
``meta`` what each step did.

A bag cut short (a robot that lost power, a writer stopped early: a ROS 1 bag without its index,
an MCAP file without its summary or footer) is read up to its last intact message
(:mod:`lidarflow.data.ros1bag`, :mod:`lidarflow.data.mcapfile`), and the recording says how
much in ``meta["recovered"]``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lidarflow.data.bagfile import open_bag, why_failed
from lidarflow.data.cleaning import Cleaned, clean_scans
from lidarflow.data.messages import check_beams, scan_of
from lidarflow.data.poses import PoseLog, on_the_scanner
from lidarflow.data.readers import CutShort
from lidarflow.data.recording import Recording
from lidarflow.data.sessions import in_sessions
from lidarflow.data.tf import TF_TYPE, TransformTree
from lidarflow.data.topics import (
    MULTI_ECHO,
    choose_pose_topic,
    choose_scan_topic,
)
from lidarflow.errors import BagError, ScanError
from lidarflow.scan import Scan

__all__ = ["read_bag"]


def read_bag(
    path: str | Path,
    topic: str | None = None,
    odom_topic: str | None = None,
    progress: Callable[[int], None] | None = None,
) -> Recording:
    """Read one LaserScan topic (and optionally the poses of an odometry topic) as a recording.

    Args:
        path: the bag: a ROS 1 bag (zipped or not), a ROS 2 bag folder or an MCAP file
            (:func:`~lidarflow.data.bagfile.open_bag`).
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
        topics = _topics(path, reader, topic, odom_topic)
        read = _read_messages(path, reader, topics, progress)
    _refuse_no_scans(path, topics, read)
    cleaned = clean_scans(read.scans, read.log_times)
    odometry = read.odometry.arrays() if topics.pose is not None else None
    scans, poses, clock_jumps = in_sessions(cleaned.scans, cleaned.arrivals, odometry)
    meta = _meta(path, topics, read, cleaned, len(scans), clock_jumps)
    if poses is not None:
        poses, mount = on_the_scanner(poses, read.tree, read.odometry.body, read.frame_id)
        meta.update(mount)
    recording = Recording.from_scans(scans, poses=poses, meta=meta)
    recording.meta["frame_rate_hz"] = round(recording.frame_rate, 3)
    if read.recovered is not None:
        seconds = (int(recording.stamps_ns[-1]) - int(recording.stamps_ns[0])) / 1e9
        recording.meta["recovered"] = read.recovered.note(len(recording), seconds)
    return recording


@dataclass(frozen=True)
class _Topics:
    """The topics :func:`read_bag` reads: the scan topic (``multi_echo``: of
    ``MultiEchoLaserScan``) and the odometry topic (``None``: none), each with the note on the
    choice made among several (``None``: named, or the only one)."""

    scan: str
    scan_choice: str | None
    multi_echo: bool
    pose: str | None
    pose_choice: str | None


def _topics(path: Path, reader: Any, topic: str | None, odom_topic: str | None) -> _Topics:
    """The topics of ``reader``'s bag to read: ``topic`` and ``odom_topic`` where named, else
    those :func:`~lidarflow.data.topics.choose_scan_topic` and ``choose_pose_topic`` choose."""
    scan_topic, topic_choice = choose_scan_topic(path, reader, topic)
    multi_echo = any(c.topic == scan_topic and c.msgtype == MULTI_ECHO for c in reader.connections)
    pose_topic, pose_choice = choose_pose_topic(path, reader, odom_topic)
    return _Topics(scan_topic, topic_choice, multi_echo, pose_topic, pose_choice)


@dataclass
class _Read:
    """What one pass over a bag's messages gathers, before any cleaning: the scans and their
    log times (ns) in arrival order, the errors of the malformed scans dropped, the scans'
    frame (the first message's), the odometry (empty without a pose topic), the TF tree (read
    only with a pose topic), the scan topic's message count, and how much of a bag cut short
    was read (``None``: the whole bag)."""

    scans: list[Scan] = field(default_factory=list)
    log_times: list[int] = field(default_factory=list)
    malformed: list[ScanError] = field(default_factory=list)
    frame_id: str = ""
    odometry: PoseLog = field(default_factory=PoseLog)
    tree: TransformTree = field(default_factory=TransformTree)
    total: int = 0
    recovered: CutShort | None = None


def _read_messages(
    path: Path, reader: Any, topics: _Topics, progress: Callable[[int], None] | None
) -> _Read:
    """Every message of ``topics``' scan and odometry topics, and with an odometry topic the TF
    tree, in one pass in the order ``reader`` gives them; ``progress(1)`` after each scan kept.

    Empty scans are skipped and malformed ones (:func:`~lidarflow.data.messages.scan_of`'s
    :class:`ScanError`) kept apart: one glitched message must not cost the whole recording.
    Raises :class:`BagError` for a scan of too many beams
    (:func:`~lidarflow.data.messages.check_beams`) and for messages that cannot be read.
    """
    read = _Read()
    wanted = [c for c in reader.connections if c.topic in {topics.scan, topics.pose}]
    if topics.pose is not None:  # the TF tree, to find the scanner's mount on the base
        wanted += [c for c in reader.connections if c.msgtype == TF_TYPE]
    try:
        for conn, log_time, raw in reader.messages(connections=wanted):
            if conn.msgtype == TF_TYPE:
                read.tree.add(reader.deserialize(raw, conn.msgtype))
                continue
            if conn.topic == topics.scan:
                check_beams(path, topics.scan, raw, conn)
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == topics.pose:
                read.odometry.add(msg, log_time)
                continue
            read.frame_id = read.frame_id or str(msg.header.frame_id).lstrip("/")
            try:
                scan = scan_of(msg, conn.msgtype)
            except ScanError as err:
                read.malformed.append(err)  # a topic of nothing but these is refused later
                continue
            if scan is None:
                continue  # an empty scan carries nothing; counted in meta
            read.scans.append(scan)
            read.log_times.append(int(log_time))
            if progress is not None:
                progress(1)
    except BagError:
        raise
    except Exception as err:  # truncated chunks, bad CDR, ... all end here
        raise BagError(
            f"{path}: cannot read messages on {topics.scan} ({why_failed(err)}); "
            "the bag may be truncated or corrupt"
        ) from err
    read.total = sum(c.msgcount for c in reader.connections if c.topic == topics.scan)
    read.recovered = getattr(reader, "recovered", None)
    return read


def _refuse_no_scans(path: Path, topics: _Topics, read: _Read) -> None:
    """Raise :class:`BagError` where the scan topic gave no scan: every one malformed (chained
    to the first's error) or empty; where the topic was chosen among several, the error names
    the others."""
    others = f" ({topics.scan_choice})" if topics.scan_choice else ""
    if not read.scans and read.malformed:
        raise BagError(
            f"{path}: topic {topics.scan}: every scan is a malformed LaserScan "
            f"({read.malformed[0]}){others}"
        ) from read.malformed[0]
    if not read.scans:
        raise BagError(f"{path}: topic {topics.scan} holds no non-empty scans{others}")


def _meta(
    path: Path,
    topics: _Topics,
    read: _Read,
    cleaned: Cleaned,
    kept: int,
    clock_jumps: list[dict[str, Any]],
) -> dict[str, Any]:
    """The recording's ``meta`` on what was read of ``path``: the topics and how they were
    chosen, the scans' frame, the scans dropped as empty (the topic's messages that are neither
    among the ``kept`` scans nor copies nor malformed), as copies and as malformed, the stamps
    used and the clock jumps."""
    meta: dict[str, Any] = {
        "source": str(path),
        "topic": topics.scan,
        "frame_id": read.frame_id,
        "pose_topic": topics.pose,
        "empty_scans_dropped": int(read.total - kept - cleaned.duplicates - len(read.malformed)),
        "duplicate_scans_dropped": cleaned.duplicates,
        "stamps": cleaned.stamps,
        "clock_jumps": clock_jumps,
        "malformed_scans_dropped": len(read.malformed),
    }
    if topics.multi_echo:
        meta["scan_type"] = "MultiEchoLaserScan (each beam's nearest echo)"
    if topics.scan_choice is not None:
        meta["topic_choice"] = topics.scan_choice
    if topics.pose_choice is not None:
        meta["pose_topic_choice"] = topics.pose_choice
    return meta
