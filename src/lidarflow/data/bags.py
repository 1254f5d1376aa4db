"""Read one scan topic of a bag (and optionally its odometry) as a :class:`Recording`.

:func:`read_bag` in named steps: open the bag (:mod:`lidarflow.data.bagfile`), choose the topics
(:mod:`lidarflow.data.topics`), read scans, odometry and TF in one pass, clean the scans
(:mod:`lidarflow.data.cleaning`), order them in sessions (:mod:`lidarflow.data.sessions`), move
the poses onto the scanner (:mod:`lidarflow.data.poses`), and say in ``meta`` what each step did.
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
        path: a ROS 1 bag (zipped or not), a ROS 2 bag folder or an MCAP file.
        topic: the scan topic; by default the one :func:`~lidarflow.data.topics.choose_scan_topic`
            chooses (``meta["topic_choice"]`` says which, over which).
        odom_topic: an Odometry/PoseStamped topic; by default the one
            :func:`~lidarflow.data.topics.choose_pose_topic` chooses
            (``meta["pose_topic_choice"]``). Its poses are interpolated at the scan stamps and
            moved onto the scanner by the bag's TF (:func:`~lidarflow.data.poses.on_the_scanner`).
        progress: called with the number of scans read since the last call.

    What reading drops or replaces is said in ``meta``: scans dropped (``*_scans_dropped``), the
    stamps used (``stamps``), sessions where the header clock went back (``clock_jumps``), and
    how much of a bag cut short was read (``recovered``). Raises :class:`BagError`.
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
    """The scan and odometry topics to read, each with the note on the choice made among
    several (``None``: named, or the only one)."""

    scan: str
    scan_choice: str | None
    multi_echo: bool
    pose: str | None
    pose_choice: str | None


def _topics(path: Path, reader: Any, topic: str | None, odom_topic: str | None) -> _Topics:
    scan_topic, topic_choice = choose_scan_topic(path, reader, topic)
    multi_echo = any(c.topic == scan_topic and c.msgtype == MULTI_ECHO for c in reader.connections)
    pose_topic, pose_choice = choose_pose_topic(path, reader, odom_topic)
    return _Topics(scan_topic, topic_choice, multi_echo, pose_topic, pose_choice)


@dataclass
class _Read:
    """What one pass over a bag's messages gathers, in arrival order, before any cleaning
    (``total``: the scan topic's message count)."""

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
    """Every message of the scan and odometry topics (and with odometry, the TF tree) in one
    pass; ``progress(1)`` after each scan kept. Malformed scans are kept apart, not raised: one
    glitched message must not cost the whole recording. Raises :class:`BagError` for a scan of
    too many beams and for messages that cannot be read."""
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
    """Raise :class:`BagError` where the scan topic gave no scan (every one malformed or empty)."""
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
    """The recording's ``meta`` on what was read of ``path`` (empty scans: the topic's messages
    neither ``kept`` nor copies nor malformed)."""
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
    choices = {"topic_choice": topics.scan_choice, "pose_topic_choice": topics.pose_choice}
    meta.update({key: note for key, note in choices.items() if note is not None})
    return meta
