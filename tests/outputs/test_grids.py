"""The grids one prediction becomes: topics, stamps (the team's convention), unknown cells."""

from __future__ import annotations

import numpy as np

from lidarflow.outputs.grids import GridLayout, grid_topics, prediction_grids
from lidarflow.outputs.rosout import map_from_grid_data
from lidarflow.predict.predictor import Prediction
from lidarflow.scan import GridSpec

GRID = GridSpec(6, 4, 0.5)  # not square: rows along x, columns along y


def prediction(step_ns: int | None, moving_flow: bool = True) -> Prediction:
    occupancy = np.zeros(GRID.shape, bool)
    occupancy[0, 0] = occupancy[4, 2] = True
    visibility = np.ones(GRID.shape, bool)
    visibility[5, :] = False  # the near row unseen
    horizon = np.stack([np.full(GRID.shape, 0.25), np.full(GRID.shape, 0.75)])
    decided = horizon >= 0.5
    decided[0, 5, 1] = True  # decided occupied in a cell nobody saw: not unknown
    flow = np.zeros((2, *GRID.shape))
    flow[0, 4, 2] = 3.0  # the cell at (4, 2) moves three columns a frame
    return Prediction(
        probability=horizon[0], occupied=decided[0], backward_flow=flow if moving_flow else None,
        forward_flow=flow if moving_flow else None, horizon=horizon, horizon_occupied=decided,
        occupancy=occupancy, visibility=visibility, stamp_ns=10_000_000_000, step_ns=step_ns,
    )  # fmt: skip


def test_topics_and_stamps_follow_the_convention():
    grids = prediction_grids(prediction(100_000_000))
    stamps = {g.topic: (g.stamp_ns, g.scan_stamp_ns) for g in grids}
    scan = 10_000_000_000
    assert list(stamps) == [
        "/lidarflow/occupancy", "/lidarflow/predicted", "/lidarflow/decided",
        "/lidarflow/predicted_k2", "/lidarflow/decided_k2", "/lidarflow/moving",
    ]  # fmt: skip
    assert stamps["/lidarflow/predicted"] == stamps["/lidarflow/decided"] == (scan + 10**8, scan)
    assert stamps["/lidarflow/predicted_k2"] == (scan + 2 * 10**8, scan)
    assert stamps["/lidarflow/moving"] == stamps["/lidarflow/occupancy"] == (scan, scan)


def test_the_first_scan_predicts_for_its_own_stamp_and_flowless_models_have_no_moving():
    grids = prediction_grids(prediction(None, moving_flow=False))
    assert [g.topic for g in grids][-1] == "/lidarflow/decided_k2"
    assert all(g.stamp_ns == g.scan_stamp_ns == 10_000_000_000 for g in grids)
    unwanted = prediction_grids(prediction(1), grid_topics(2, moving=False, occupancy=False))
    assert {g.topic for g in unwanted} == {
        "/lidarflow/predicted", "/lidarflow/decided", "/lidarflow/predicted_k2",
        "/lidarflow/decided_k2",
    }  # fmt: skip


def test_values_and_unknown_cells():
    maps = {g.topic: map_from_grid_data(g.data, *GRID.shape) for g in prediction_grids(
        prediction(1))}  # fmt: skip
    predicted = maps["/lidarflow/predicted"]
    assert (predicted[:5] == 25).all()
    assert predicted[5].tolist() == [-1, 25, -1, -1]  # unseen, unless decided occupied
    assert maps["/lidarflow/decided"][5, 1] == 100  # decided occupied, though unseen
    assert (maps["/lidarflow/decided_k2"][:5] == 100).all()
    occupancy = maps["/lidarflow/occupancy"]
    assert occupancy[0, 0] == occupancy[4, 2] == 100 and (occupancy[5] == -1).all()
    moving = maps["/lidarflow/moving"]
    assert moving[4, 2] == 100 and moving[0, 0] == 0 and (moving[5] == -1).all()


def test_layout_is_the_scan_frame_one():
    assert GridLayout.of(GRID) == GridLayout(6, 4, 0.5, 0.0, -1.0)
