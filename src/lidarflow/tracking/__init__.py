"""Following moving objects from frame to frame (:class:`Tracker`) and what it hands on.

A room of its own, neither ``predict`` nor ``baselines``: the engine runs it at deployment
beside the model and ``evaluate`` scores it as a baseline, and it is built from neither.
"""

from lidarflow.tracking.clusters import associate, cluster_labels, foreground
from lidarflow.tracking.tracker import Tracker, TrackerConfig
from lidarflow.tracking.tracks import Track, Tracks, composed_motion

__all__ = [
    "Track",
    "Tracker",
    "TrackerConfig",
    "Tracks",
    "associate",
    "cluster_labels",
    "composed_motion",
    "foreground",
]
