"""One entry point for every input a command accepts: a recording ``.npz`` or any bag."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from lidarflow.data.bags import read_bag
from lidarflow.data.recordfile import load_recording
from lidarflow.data.recording import Recording
from lidarflow.errors import BagError, RecordingError, ScanError

__all__ = ["is_recording_file", "load_any", "recovered_notes", "topic_notes"]


def is_recording_file(path: str | Path) -> bool:
    return Path(path).suffix.lower() == ".npz"


def load_any(
    path: str | Path,
    topic: str | None = None,
    odom_topic: str | None = None,
    progress: Callable[[int], None] | None = None,
) -> Recording:
    """Load a recording, or read a bag/MCAP (:func:`read_bag`); ``topic`` and ``odom_topic``
    apply to bags only, and naming them for a recording is an error."""
    path = Path(path)
    if is_recording_file(path):
        if topic is not None or odom_topic is not None:
            raise RecordingError(f"{path}: --topic/--odom-topic apply to bags, not recordings")
        return _checked_recording(path)
    if not path.exists():
        raise BagError(f"{path}: no such file or folder")
    return read_bag(path, topic=topic, odom_topic=odom_topic, progress=progress)


def _checked_recording(path: Path) -> Recording:
    """:func:`load_recording`, with what is wrong inside the file (arrays of mismatched
    lengths, an impossible beam geometry) said of the file now, not when it is rasterized."""
    try:
        recording = load_recording(path)
        for start, _ in recording.geometry_runs():
            try:
                recording.geometry(start)
            except ScanError as err:
                raise RecordingError(f"frame {start}: {err}") from err
    except RecordingError as err:
        if str(err).startswith(str(path)):  # named already ("PATH: ...", "PATH (-> ...): ...")
            raise
        raise RecordingError(f"{path}: not a usable recording: {err}") from err
    return recording


def topic_notes(path: str | Path, recording: Recording) -> list[str]:
    """What a command says of how ``recording`` was read from the bag ``path``: the topics
    chosen among several (none for a recording file, which has no topics to pick from) and
    :func:`recovered_notes`."""
    if is_recording_file(path):
        return recovered_notes(path, recording)
    name = Path(path).name
    keys = ("topic_choice", "pose_topic_choice")
    notes = [f"{name}: {recording.meta[k]}" for k in keys if recording.meta.get(k)]
    return notes + recovered_notes(path, recording)


def recovered_notes(path: str | Path, recording: Recording) -> list[str]:
    """Where ``recording`` was read from a bag cut short, the note that says how much of it,
    named for the bag (a recording converted from one keeps it)."""
    if not recording.meta.get("recovered"):
        return []
    source = recording.meta.get("source") if is_recording_file(path) else None
    return [f"{Path(source or path).name}: {recording.meta['recovered']}"]
