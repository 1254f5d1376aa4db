"""The sensor's own motion: odometry checked against the scans, scan matching, ICP, and the
pacing of the motion guess after long steps in time. Reads recordings; estimates; never imports
training, evaluation, prediction or the command line."""

from lidarflow.motion.icp import align, recording_points, scan_points, streamed_points
from lidarflow.motion.odometry import (
    OdometryCheck,
    cells_in_new_frame,
    metres_to_cells,
    relative_motions,
)
from lidarflow.motion.pacing import StepClock, paced_motion, paces_after_long_steps
from lidarflow.motion.scanmatch import ScanOdometry, checked_motion, match_maps, scan_motions

__all__ = [
    "OdometryCheck",
    "ScanOdometry",
    "StepClock",
    "align",
    "cells_in_new_frame",
    "checked_motion",
    "match_maps",
    "metres_to_cells",
    "paced_motion",
    "paces_after_long_steps",
    "recording_points",
    "relative_motions",
    "scan_motions",
    "scan_points",
    "streamed_points",
]
