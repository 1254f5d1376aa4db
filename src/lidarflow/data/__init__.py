"""Recordings in and out: bag/MCAP readers, the recording format, training sequences."""

from lidarflow.data.bagfile import list_topics
from lidarflow.data.bags import read_bag
from lidarflow.data.gaps import frames_after_gaps
from lidarflow.data.info import describe_recording, find_gaps
from lidarflow.data.recordfile import load_recording
from lidarflow.data.recording import Recording
from lidarflow.data.samples import SAMPLE_TOPIC, sample_bag_path
from lidarflow.data.sequences import SequenceSet, split_segments
from lidarflow.data.sources import load_any

__all__ = [
    "SAMPLE_TOPIC",
    "Recording",
    "SequenceSet",
    "describe_recording",
    "find_gaps",
    "frames_after_gaps",
    "list_topics",
    "load_any",
    "load_recording",
    "read_bag",
    "sample_bag_path",
    "split_segments",
]
