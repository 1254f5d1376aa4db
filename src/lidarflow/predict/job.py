"""``lidarflow predict``: a recording in, a bag out with the scans and their predictions.

Topics written (all stamped with the scan's stamp as the bag had it, in the scan's frame; where
the bag's header clock went back, reading re-stamps its later sessions, and this undoes that):

- the input scan topic: the scans themselves (ranges and geometry; intensities are not kept);
- ``/lidarflow/occupancy``: the current occupancy map (``nav_msgs/OccupancyGrid``);
- ``/lidarflow/predicted``: the predicted next map, probability x 100 (calibrated, for an
  occupancy-head model; ``-1`` where the current scan saw nothing and nothing is predicted);
- ``/lidarflow/decided``: the next map as the model's decision policy decides it (100 occupied,
  0 free, ``-1`` as above): ``Prediction.occupied``;
- ``/lidarflow/predicted_k{K}``, ``/lidarflow/decided_k{K}``: K frames ahead, for ``--horizon``
  K > 1;
- ``/lidarflow/flow_backward``, ``/lidarflow/flow_forward``: ``sensor_msgs/Image`` ``32FC2``,
  per map cell the (column, row) displacement in cells (flow models only);
- ``/lidarflow/moving``: the moving-object segmentation of the current map
  (``nav_msgs/OccupancyGrid``; 100 on occupied cells that move on their own, 0 on other visible
  cells, -1 where not visible; flow models only; see :mod:`lidarflow.predict.moving`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from lidarflow.data.recording import Recording
from lidarflow.data.sessions import recorded_stamps
from lidarflow.errors import PredictError
from lidarflow.predict.grids import TOPIC_PREFIX
from lidarflow.predict.predictor import Predictor
from lidarflow.predict.rosout import BagOutput

__all__ = ["TOPIC_PREFIX", "check_poses", "predict_to_bag"]


def check_poses(recording: Recording, predictor: Predictor) -> None:
    """Refuse (:class:`PredictError`) to run an ego-motion model over a recording without
    sensor poses, unless the model may run without (``poses_optional``: the Predictor then
    matches the motion from the scans)."""
    if predictor.uses_motion and not recording.has_poses and not predictor.poses_optional:
        source = recording.meta.get("source") or "the recording"
        raise PredictError(
            f"{source}: no sensor poses, but the model compensates ego motion; convert the bag "
            "with --odom-topic, or use a model trained without --ego-motion"
        )


def predict_to_bag(
    recording: Recording,
    predictor: Predictor,
    output: str | Path,
    progress: Callable[[int], None] | None = None,
    force: bool = False,
) -> dict[str, int]:
    """Run ``predictor`` over ``recording`` and write everything to ``output``; returns the
    number of messages per topic. An ego-motion model gets the recording's poses; a recording
    without any is refused (:class:`PredictError`) unless the model may run without
    (``poses_optional``: the Predictor then matches the motion from the scans). An existing
    ``output`` is refused unless ``force`` (:class:`BagOutput`)."""
    check_poses(recording, predictor)
    poses = recording.poses
    scan_topic = recording.meta.get("topic") or "/scan"
    if not scan_topic.startswith("/"):
        scan_topic = "/" + scan_topic  # ROS 2 requires absolute names; ROS 1 accepts them
    frame_id = recording.meta.get("frame_id") or "laser"
    grid = predictor.grid
    counts: dict[str, int] = {}

    def count(topic: str) -> None:
        counts[topic] = counts.get(topic, 0) + 1

    # Where the bag's header clock went back, reading re-stamped its later sessions to follow
    # the first (lidarflow.data.sessions): headers get the bag's own stamps back, to line up
    # with it, and the log times stay the re-stamped ones, in order, so that a reader (Foxglove,
    # read_bag) takes the sessions one after the other as they were recorded.
    stamps = recorded_stamps(recording.stamps_ns, recording.meta.get("clock_jumps") or [])
    predictor.reset()
    with BagOutput(output, force) as out:
        for i, scan in enumerate(recording):
            p = predictor.update(scan, None if poses is None else poses[i])
            stamp, at = int(stamps[i]), scan.stamp_ns  # header stamp, log time
            out.write_scan(scan_topic, dataclasses.replace(scan, stamp_ns=stamp), frame_id, at)
            count(scan_topic)
            grids = [(f"{TOPIC_PREFIX}/occupancy", p.occupancy.astype(float), ~p.visibility)]
            for k, (probability, occupied) in enumerate(
                zip(p.horizon, p.horizon_occupied, strict=True), start=1
            ):
                suffix = f"_k{k}" if k > 1 else ""
                unknown = ~p.visibility & ~occupied
                grids.append((f"{TOPIC_PREFIX}/predicted{suffix}", probability, unknown))
                grids.append((f"{TOPIC_PREFIX}/decided{suffix}", occupied.astype(float), unknown))
            if p.moving is not None:
                grids.append((f"{TOPIC_PREFIX}/moving", p.moving.astype(float), ~p.visibility))
            for topic, values, unknown in grids:
                out.write_grid(topic, values, grid, stamp, frame_id, unknown, log_time_ns=at)
                count(topic)
            if p.backward_flow is not None and p.forward_flow is not None:
                for name, flow in (("backward", p.backward_flow), ("forward", p.forward_flow)):
                    out.write_flow(f"{TOPIC_PREFIX}/flow_{name}", flow, stamp, frame_id, at)
                    count(f"{TOPIC_PREFIX}/flow_{name}")
            if progress is not None:
                progress(1)
    return counts
