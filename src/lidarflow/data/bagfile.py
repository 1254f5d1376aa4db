"""Opening a bag for reading: which inputs are bags, and the reader each kind is read with.

A ROS 1 ``.bag`` (or ``.bag.zip``, :mod:`lidarflow.data.unzip`), a ROS 2 bag folder, or an
``.mcap`` file of ROS 2 or ROS 1 messages (:mod:`lidarflow.data.mcapfile`); a bag cut short is
read by lidarflow's own readers (:mod:`lidarflow.data.readers`). Anything else is a
:class:`BagError`.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lidarflow.data.inputs import check_regular
from lidarflow.data.mcapfile import MAGIC as MCAP_MAGIC
from lidarflow.data.mcapfile import McapReader, channel_encoding
from lidarflow.data.ros1bag import MAGIC as ROS1_MAGIC
from lidarflow.data.ros1bag import Ros1BagSequentialReader
from lidarflow.data.unzip import unzipped_bag
from lidarflow.errors import BagError

__all__ = ["TopicInfo", "cut_short_reader", "list_topics", "not_a_bag", "open_bag", "why_failed"]


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a bag: its name, message type and message count."""

    topic: str
    msgtype: str
    count: int


_BAG_SUFFIXES = (".bag", ".bag.zip", ".mcap", ".db3")


def _is_bag_like(path: Path) -> bool:
    name = path.name.lower()
    return path.is_dir() or name == "metadata.yaml" or name.endswith(_BAG_SUFFIXES)


@contextlib.contextmanager
def open_bag(path: str | Path) -> Iterator[Any]:
    """Open a bag for reading; yields a ``rosbags.highlevel.AnyReader``, or where rosbags
    cannot read the file, a reader of :mod:`lidarflow.data.readers`' kind, read the same way
    (``getattr(reader, "recovered", None)`` is ``None`` for a whole bag).

    Raises :class:`BagError` for missing, unsupported or corrupt inputs.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise BagError(f"{path}: no such file or folder")
    check_regular(path, BagError, folder=True)
    if not _is_bag_like(path):
        raise BagError(
            f"{path}: not a bag; expected a ROS 1 .bag (or .bag.zip), a ROS 2 bag folder, "
            "or an .mcap file"
        )
    with contextlib.ExitStack() as stack:
        target = path
        if path.name.lower().endswith(".bag.zip"):
            target = stack.enter_context(unzipped_bag(path))
        elif path.suffix.lower() == ".db3" or path.name.lower() == "metadata.yaml":
            target = path.parent  # a ROS 2 bag is read through its folder
            check_regular(target, BagError, folder=True)
        if target.is_dir() and not (target / "metadata.yaml").exists():
            target = _folder_without_metadata(path, target)
        encoding = channel_encoding(target) if target.suffix.lower() == ".mcap" else None
        ros1 = target.suffix.lower() == ".bag" or encoding == "ros1"
        store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
        try:
            if encoding == "ros1":  # `mcap convert` of a ROS 1 bag: rosbags reads MCAP as ROS 2
                reader = McapReader(target, "ros1", store)
            else:
                reader = stack.enter_context(AnyReader([target], default_typestore=store))
        except Exception as err:  # rosbags raises many types for damaged files
            reader = cut_short_reader(target, store)
            foreign = not_a_bag(target) if reader is None else None
            if foreign is not None:
                raise BagError(f"{path}: {foreign}") from err
            if reader is None and target.is_file() and target.suffix.lower() == ".mcap":
                # the library's own words for this (`ord() expected a character`) say nothing
                raise BagError(
                    f"{path}: cannot open as a bag: it holds no ROS message that can be read, "
                    "not a complete MCAP file (it ends after its header, or is damaged before "
                    "its first message)"
                ) from err
            if reader is None:
                why = why_failed(err)
                raise BagError(f"{path}: cannot open as a bag ({why}); is it complete?") from err
        yield reader


def _folder_without_metadata(path: Path, folder: Path) -> Path:
    """The MCAP file of a ROS 2 bag folder that lacks its ``metadata.yaml`` (which ``ros2 bag
    record`` writes last, so an interrupted recording has none)."""
    mcaps = sorted(folder.glob("*.mcap"))
    if len(mcaps) == 1:
        return mcaps[0]
    raise BagError(
        f"{path}: cannot open as a bag (a folder with no metadata.yaml"
        + (f" and {len(mcaps)} .mcap files" if mcaps else "")
        + " is no ROS 2 bag); if its recording was interrupted, `ros2 bag reindex` rebuilds it"
    )


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


def why_failed(err: BaseException) -> str:
    """What ``err`` says, in one line: its type and the first line of its message."""
    text = str(err).strip().splitlines()
    return f"{type(err).__name__}: {text[0]}" if text else type(err).__name__


def list_topics(path: str | Path) -> list[TopicInfo]:
    """Every topic of the bag with its message type and count."""
    with open_bag(path) as reader:
        counts: dict[tuple[str, str], int] = {}
        for c in reader.connections:
            key = (c.topic, c.msgtype)
            counts[key] = counts.get(key, 0) + c.msgcount
    return [TopicInfo(t, m, n) for (t, m), n in sorted(counts.items())]
