"""Which of lidarflow's own readers reads a bag rosbags gave up on (:mod:`lidarflow.data.readers`
says what they share)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lidarflow.data.mcapfile import MAGIC as MCAP_MAGIC
from lidarflow.data.mcapfile import McapReader, channel_encoding
from lidarflow.data.ros1bag import MAGIC as ROS1_MAGIC
from lidarflow.data.ros1bag import Ros1BagSequentialReader

__all__ = ["cut_short_reader", "not_a_bag"]

_KINDS = {".bag": ("a ROS 1 bag", ROS1_MAGIC), ".mcap": ("an MCAP file", MCAP_MAGIC)}


def not_a_bag(target: Path) -> str | None:
    """Why ``target``, a file rosbags could not open, is no bag at all, judged by its first
    bytes; ``None`` where it begins as its kind does (a damaged bag, not a foreign file)."""
    kind = _KINDS.get(target.suffix.lower()) if target.is_file() else None
    if kind is None:
        return None
    what, magic = kind
    with target.open("rb") as f:
        start = f.read(len(magic))
    if not start:
        return "the file is empty"
    if start != magic:
        return f"not {what}: it does not begin with the header every one begins with"
    return None


def cut_short_reader(target: Path, store: Any) -> Any:
    """A reader of a bag cut short (a ROS 1 bag or MCAP file, or a ROS 2 folder around one) up
    to its last intact message; ``None`` where that finds no message either."""
    if target.is_dir():
        mcaps = sorted(target.glob("*.mcap"))
        target = mcaps[0] if len(mcaps) == 1 else target
    try:
        if target.is_file() and target.suffix.lower() == ".bag":
            return Ros1BagSequentialReader(target, store)
        if target.is_file() and target.suffix.lower() == ".mcap":
            return McapReader(target, channel_encoding(target) or "cdr", store)
    except Exception:  # what rosbags said of the file is the better message
        return None
    return None
