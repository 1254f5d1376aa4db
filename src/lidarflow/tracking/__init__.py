"""Following moving objects from frame to frame (:class:`Tracker`) and what it hands on: run by
the engine beside the model at deployment and scored by ``evaluate`` as a baseline.
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
