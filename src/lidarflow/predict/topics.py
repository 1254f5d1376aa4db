"""The grids lidarflow publishes per scan: topic, values, unknown cells and stamp, in one place.

Every output of predictions (a bag, the live Foxglove server, a ROS node) lays a
:class:`~lidarflow.predict.predictor.Prediction` out as the same grids, under the team's topic
names and stamp convention:

- ``/lidarflow/occupancy``: the current map (occupied 1, free 0), unknown where not visible;
  the scan's stamp;
- ``/lidarflow/predicted``, ``/lidarflow/decided`` (and ``_k{K}`` for K frames ahead, K > 1):
  the predicted probability and the decided map, unknown where the current scan saw nothing
  and nothing is predicted; stamped with the time they predict,
  :meth:`~lidarflow.predict.predictor.Prediction.stamp_ahead_ns` (``k``), made from the scan
  at ``Prediction.stamp_ns``;
- ``/lidarflow/moving``: the occupied cells of the current map that move on their own (flow
  models only), unknown where not visible; the scan's stamp.

The flow goes out beside them as images (``/lidarflow/flow_backward`` / ``_forward``, raw
``32FC2``) and, where a person looks at it, as the colour wheel under :data:`FLOW_RGB_TOPIC`.
"""

from __future__ import annotations

from collections.abc import Container
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from lidarflow.predict.predictor import Prediction

__all__ = ["FLOW_RGB_TOPIC", "TOPIC_PREFIX", "GridOut", "grid_topics", "prediction_grids"]

TOPIC_PREFIX = "/lidarflow"
#: The forward flow as an ``rgb8`` colour-wheel image (:func:`lidarflow.viz.flow.flow_to_rgb`):
#: where each occupied cell of the current map goes next, hue the direction, saturation the
#: length; the flow viewers can show, as neither RViz nor Foxglove shows a 32FC2 image.
FLOW_RGB_TOPIC = f"{TOPIC_PREFIX}/flow_forward_rgb"


class GridOut(NamedTuple):
    """One grid to publish: ``values`` ``(H, W)`` in [0, 1], ``unknown`` ``(H, W)`` bool."""

    topic: str
    values: np.ndarray
    unknown: np.ndarray
    stamp_ns: int


def _suffix(k: int) -> str:
    return f"_k{k}" if k > 1 else ""


def grid_topics(horizon: int = 1, flow: bool = True) -> list[str]:
    """The topics :func:`prediction_grids` fills for a Predictor of ``horizon`` frames ahead
    (``flow``: a model with flow, which also has moving cells), in the order it fills them."""
    topics = [f"{TOPIC_PREFIX}/occupancy"]
    for k in range(1, horizon + 1):
        topics += [f"{TOPIC_PREFIX}/predicted{_suffix(k)}", f"{TOPIC_PREFIX}/decided{_suffix(k)}"]
    return [*topics, f"{TOPIC_PREFIX}/moving"] if flow else topics


def prediction_grids(p: Prediction, wanted: Container[str] | None = None) -> list[GridOut]:
    """The grids of one prediction, as the module docstring lays them out; only the topics
    ``wanted`` where given (what nobody asked for is not computed: the moving cells cost about
    as much as the rest together)."""

    def want(topic: str) -> bool:
        return wanted is None or topic in wanted

    unseen = ~p.visibility
    grids = []
    if want(topic := f"{TOPIC_PREFIX}/occupancy"):
        grids.append(GridOut(topic, p.occupancy.astype(float), unseen, p.stamp_ns))
    for k, (probability, occupied) in enumerate(
        zip(p.horizon, p.horizon_occupied, strict=True), start=1
    ):
        unknown = unseen & ~occupied
        ahead = p.stamp_ahead_ns(k)
        if want(topic := f"{TOPIC_PREFIX}/predicted{_suffix(k)}"):
            grids.append(GridOut(topic, probability, unknown, ahead))
        if want(topic := f"{TOPIC_PREFIX}/decided{_suffix(k)}"):
            grids.append(GridOut(topic, occupied.astype(float), unknown, ahead))
    if want(topic := f"{TOPIC_PREFIX}/moving") and p.moving is not None:
        grids.append(GridOut(topic, p.moving.astype(float), unseen, p.stamp_ns))
    return grids
