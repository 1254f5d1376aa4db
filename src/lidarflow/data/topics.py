"""Which topics of a bag to read: the scan topic and the odometry topic, named or chosen.

``lidarflow evaluate SOME.bag`` works on any bag as it is (design notes, section 9): of several
scan (or odometry) topics and none named, one is chosen by a fixed preference and the choice is
said (``read_bag``'s ``meta["topic_choice"]``, ``meta["pose_topic_choice"]``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from lidarflow.errors import BagError

__all__ = [
    "LASERSCAN",
    "MULTI_ECHO",
    "POSE_TYPES",
    "PREFERRED_ODOMETRY",
    "SCAN_TYPES",
    "choose_pose_topic",
    "choose_scan_topic",
]

LASERSCAN = "sensor_msgs/msg/LaserScan"
MULTI_ECHO = "sensor_msgs/msg/MultiEchoLaserScan"
SCAN_TYPES = (LASERSCAN, MULTI_ECHO)
POSE_TYPES = (
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
)


def _match_name(name: str, topics: Iterable[str]) -> str | None:
    """The topic among ``topics`` that ``name`` names: itself, or else the only one equal to it
    up to leading and trailing slashes (``scan`` in a ROS 1 bag, ``/scan`` in a ROS 2 one)."""
    topics = set(topics)
    if name in topics:
        return name
    loose = [t for t in topics if t.strip("/") == name.strip("/")]
    return loose[0] if len(loose) == 1 else None


def _message_counts(reader: Any, msgtypes: tuple[str, ...]) -> dict[str, int]:
    """Messages per topic of the types ``msgtypes``, over all of its connections."""
    counts: dict[str, int] = {}
    for c in reader.connections:
        if c.msgtype in msgtypes:
            counts[c.topic] = counts.get(c.topic, 0) + c.msgcount
    return counts


def _scan_rank(topic: str, count: int) -> tuple[int, int, int, str]:
    # REP 105 robots publish their scanner on ``scan``; Cartographer's backpack its horizontal
    # one beside a vertical one (whose plane makes no map); else the busiest, then by name
    name = topic.strip("/")
    return (name.split("/")[-1] != "scan", "horizontal" not in name, -count, topic)


def choose_scan_topic(path: Path, reader: Any, topic: str | None) -> tuple[str, str | None]:
    """The scan topic to read, and a note on the choice where the bag offered several."""
    counts = _message_counts(reader, SCAN_TYPES)
    kinds = {c.topic: c.msgtype for c in reader.connections if c.msgtype in SCAN_TYPES}
    if topic is None:  # multi-echo topics only where no LaserScan one holds messages
        published = [t for t, n in counts.items() if n > 0] or list(counts)
        if any(kinds[t] == LASERSCAN for t in published):
            counts = {t: n for t, n in counts.items() if kinds[t] == LASERSCAN}
    scan_topics = sorted(counts)
    if topic is not None:
        found = _match_name(topic, scan_topics)
        if found is not None:
            return found, None
        others = {c.topic: c.msgtype for c in reader.connections}
        other = _match_name(topic, others)
        if other is not None:
            raise BagError(
                f"{path}: topic {other} is {others[other]}, not a LaserScan (or MultiEchoLaserScan)"
            )
        hint = f"scan topics here: {', '.join(scan_topics)}" if scan_topics else "it has none"
        raise BagError(f"{path}: no topic {topic}; {hint}")
    if not scan_topics:
        raise BagError(
            f"{path}: no sensor_msgs/LaserScan (or MultiEchoLaserScan) topic in this bag"
        )
    return _choose(counts, _scan_rank, "--topic")


def _choose(
    counts: dict[str, int], rank: Callable[[str, int], tuple[Any, ...]], option: str
) -> tuple[str, str | None]:
    """The topic ``rank`` puts first of ``counts``' (at least one), and a note on the others."""
    # A ROS 2 bag lists every topic it subscribed to, published on or not: an unused topic
    # beside the sensor's is no real choice. (Without counts, as in an MCAP file with no
    # summary, every topic counts 0 and all stay candidates.)
    live = [t for t in sorted(counts) if counts[t] > 0] or sorted(counts)
    if len(live) == 1:
        return live[0], None
    chosen = min(live, key=lambda t: rank(t, counts[t]))
    others = ", ".join(t for t in live if t != chosen)
    return chosen, f"{chosen} chosen over {others}; {option} to pick another"


#: Where a bag has several odometry topics and none is named: robot_localization's fused
#: estimate first (wheels and IMU), then REP 105's ``odom``; else the busiest topic.
PREFERRED_ODOMETRY = ("odometry/filtered", "odom")


def _odometry_rank(topic: str, count: int) -> tuple[int, int, str]:
    name = topic.strip("/")
    known = [i for i, p in enumerate(PREFERRED_ODOMETRY) if name == p or name.endswith("/" + p)]
    return (known[0] if known else len(PREFERRED_ODOMETRY), -count, topic)


def choose_pose_topic(
    path: Path, reader: Any, odom_topic: str | None
) -> tuple[str | None, str | None]:
    """The pose topic to read, and a note on the choice where the bag offered several."""
    pose_topics = {c.topic: c.msgtype for c in reader.connections if c.msgtype in POSE_TYPES}
    if odom_topic is None:
        counts = _message_counts(reader, POSE_TYPES[:1])
        return _choose(counts, _odometry_rank, "--odom-topic") if counts else (None, None)
    found = _match_name(odom_topic, pose_topics)
    if found is None:
        hint = ", ".join(sorted(pose_topics)) or "none"
        raise BagError(f"{path}: no odometry/pose topic {odom_topic} (pose topics here: {hint})")
    return found, None
