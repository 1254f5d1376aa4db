"""The OccupancyGrids one prediction becomes: topics, data, stamps and layout, written once for
every writer (the bag output, the live nodes) so that a grid on a robot's topic and in a bag are
the same message.

Layout (design notes §8): the ``(H, W)`` map of ``res`` metre cells lies in the scan's frame
with ``origin = (0, -W/2 * res, yaw 0)``, ``width = H`` cells along x (forward), ``height = W``
along y; values probability x 100, -1 unknown. Stamps: a grid ``k`` frames ahead is stamped
``prediction.stamp_ahead_ns(k)``, ``info.map_load_time`` the scan's stamp; a grid of the
current map carries the scan's stamp in both.
"""

from __future__ import annotations

from collections.abc import Container
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from lidarflow.scan import GridSpec

if TYPE_CHECKING:
    from lidarflow.predict.predictor import Prediction

__all__ = [
    "FLOW_RGB_FULL_CELLS",
    "FLOW_RGB_TOPIC",
    "TOPIC_PREFIX",
    "GridLayout",
    "OutGrid",
    "grid_data",
    "grid_topics",
    "grid_values",
    "laid_out",
    "map_from_grid_data",
    "planner_topic",
    "prediction_grids",
]

TOPIC_PREFIX = "/lidarflow"
#: The forward flow as an ``rgb8`` colour wheel (:func:`lidarflow.flowcolor.flow_to_rgb`): the
#: flow as viewers can show it, as neither RViz nor Foxglove shows a 32FC2 image.
FLOW_RGB_TOPIC = f"{TOPIC_PREFIX}/flow_forward_rgb"
#: Flow (cells per frame) drawn in full colour on the colour wheels: a fixed scale, so that
#: colours compare across frames.
FLOW_RGB_FULL_CELLS = 2.0


@dataclass(frozen=True)
class GridLayout:
    """``nav_msgs/MapMetaData`` of a map grid laid in the scan's frame (yaw 0, z 0).

    >>> GridLayout.of(GridSpec(6, 4, 0.5))
    GridLayout(width=6, height=4, resolution=0.5, origin_x=0.0, origin_y=-1.0)
    """

    width: int  # cells along the scan frame's x (forward): the map's rows, H
    height: int  # cells along y (left): the map's columns, W
    resolution: float
    origin_x: float
    origin_y: float

    @classmethod
    def of(cls, grid: GridSpec) -> GridLayout:
        return cls(grid.height, grid.width, float(grid.res), 0.0, -grid.width / 2 * grid.res)


@dataclass(frozen=True)
class OutGrid:
    """One OccupancyGrid to publish or write: its topic, ``data`` (int8, ``H * W``), header
    stamp and ``info.map_load_time`` (the stamp of the scan it was made from)."""

    topic: str
    data: np.ndarray
    stamp_ns: int
    scan_stamp_ns: int


def grid_values(probability: np.ndarray, unknown: np.ndarray | None = None) -> np.ndarray:
    """The ``(H, W)`` int8 map (design notes §2 layout) of a probability map in [0, 1]:
    probability x 100, rounded, ``-1`` where ``unknown``.

    >>> grid_values(np.array([[0.004, 0.5, 1.2]]), np.array([[False, False, True]])).tolist()
    [[0, 50, -1]]
    """
    p = np.clip(np.nan_to_num(np.asarray(probability, np.float64)), 0.0, 1.0)
    values = np.rint(p * 100).astype(np.int8)
    if unknown is not None:
        values[np.asarray(unknown, bool)] = -1
    return values


def laid_out(values: np.ndarray) -> np.ndarray:
    """OccupancyGrid ``data`` (int8, ``H * W``) of an ``(H, W)`` int8 map, in the layout of
    :class:`GridLayout` (the inverse: :func:`map_from_grid_data`)."""
    return np.ascontiguousarray(np.asarray(values, np.int8)[::-1, ::-1].T).ravel()


def grid_data(probability: np.ndarray, unknown: np.ndarray | None = None) -> np.ndarray:
    """OccupancyGrid ``data`` (int8, ``H * W``) of a probability map ``(H, W)`` in [0, 1]:
    :func:`laid_out` of :func:`grid_values`.

    >>> m = np.zeros((2, 3)); m[0, 0] = 1.0  # far-left cell
    >>> grid_data(m).reshape(3, 2).tolist()  # rows j (along y), columns i (along x)
    [[0, 0], [0, 0], [0, 100]]
    """
    return laid_out(grid_values(probability, unknown))


def map_from_grid_data(data: np.ndarray, height: int, width: int) -> np.ndarray:
    """Inverse of :func:`grid_data`: the ``(H, W)`` int8 map (-1 unknown, 0..100)."""
    return np.asarray(data, np.int8).reshape(width, height).T[::-1, ::-1].copy()


def _suffix(k: int) -> str:
    return f"_k{k}" if k > 1 else ""


def planner_topic(prefix: str = TOPIC_PREFIX) -> str:
    """The planner grid's topic (:func:`lidarflow.outputs.planner.planner_grid`)."""
    return f"{prefix}/planner_grid"


def grid_topics(
    horizon: int = 1,
    moving: bool = True,
    occupancy: bool = True,
    prefix: str = TOPIC_PREFIX,
    planner: bool = False,
) -> list[str]:
    """The topics of :func:`prediction_grids` for a Predictor ``horizon`` frames ahead, in order:
    ``/occupancy``, ``/predicted`` and ``/decided`` (``_kK`` for ``K > 1``), ``/moving``,
    ``/planner_grid``, each optional one where its flag says."""
    topics = [f"{prefix}/occupancy"] if occupancy else []
    for k in range(1, horizon + 1):
        topics += [f"{prefix}/predicted{_suffix(k)}", f"{prefix}/decided{_suffix(k)}"]
    if moving:
        topics.append(f"{prefix}/moving")
    return [*topics, planner_topic(prefix)] if planner else topics


def prediction_grids(
    prediction: Prediction, wanted: Container[str] | None = None, prefix: str = TOPIC_PREFIX
) -> list[OutGrid]:
    """The grids of one prediction on :func:`grid_topics`' topics, in order, only those
    ``wanted`` where given (the rest is not computed); ``/moving`` only for a model with flow,
    the planner grid (:mod:`lidarflow.outputs.planner`) only where ``wanted`` names it.
    Unknown (-1): a cell the scan did not see, unless a predicted one is decided occupied.
    """
    p = prediction
    scan_ns = int(p.stamp_ns)
    unseen = ~np.asarray(p.visibility, bool)
    out: list[OutGrid] = []

    def want(topic: str) -> bool:
        return wanted is None or topic in wanted

    if want(topic := f"{prefix}/occupancy"):
        out.append(OutGrid(topic, grid_data(p.occupancy, unseen), scan_ns, scan_ns))
    for k, (probability, occupied) in enumerate(
        zip(p.horizon, p.horizon_occupied, strict=True), start=1
    ):
        unknown = unseen & ~occupied
        ahead = p.stamp_ahead_ns(k)
        if want(topic := f"{prefix}/predicted{_suffix(k)}"):
            out.append(OutGrid(topic, grid_data(probability, unknown), ahead, scan_ns))
        if want(topic := f"{prefix}/decided{_suffix(k)}"):
            out.append(OutGrid(topic, grid_data(occupied, unknown), ahead, scan_ns))
    if want(topic := f"{prefix}/moving") and p.forward_flow is not None:
        assert p.moving is not None
        out.append(OutGrid(topic, grid_data(p.moving, unseen), scan_ns, scan_ns))
    if wanted is not None and (topic := planner_topic(prefix)) in wanted:
        # imported here: the planner module builds on this one's values
        from lidarflow.outputs.planner import planner_grid

        out.append(OutGrid(topic, laid_out(planner_grid(p)), scan_ns, scan_ns))
    return out
