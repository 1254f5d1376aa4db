"""Which of lidarflow's own readers reads a bag rosbags gave up on (:mod:`lidarflow.data.readers`
says what they share)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from lidarflow.data.mcapfile import McapReader, channel_encoding
from lidarflow.data.ros1bag import Ros1BagSequentialReader

__all__ = ["cut_short_reader"]


def cut_short_reader(target: Path, store: Any) -> Any:
    """A reader of what a bag cut short holds up to its last intact message, where rosbags
    could not open it (a ROS 1 bag without its index, an MCAP file without its summary or
    footer, a ROS 2 folder around one); ``None`` where that finds no message either (a file
    that is no bag, or damaged from its start)."""
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

