"""The planner grid on hand-made predictions: the largest probability over the horizon, scaled
to 0..100, unknown cells, the steps moved back into the scan's frame, and its place among the
grids of a prediction."""

from __future__ import annotations

import dataclasses

import numpy as np

from lidarflow.outputs.grids import laid_out, planner_topic, prediction_grids
from lidarflow.outputs.planner import planner_grid
from lidarflow.outputs.rosout import map_from_grid_data
from lidarflow.predict.predictor import Prediction
from lidarflow.scan import GridSpec

GRID = GridSpec(6, 4, 0.5)  # not square: rows along x, columns along y
SCAN_NS = 10_000_000_000


def prediction(horizon: np.ndarray, decided: np.ndarray | None = None, **kw) -> Prediction:
    horizon = np.asarray(horizon, np.float64)
    decided = horizon >= 0.5 if decided is None else decided
    return Prediction(
        probability=horizon[0], occupied=decided[0], backward_flow=None, forward_flow=None,
        horizon=horizon, horizon_occupied=decided, occupancy=np.zeros(GRID.shape, bool),
        visibility=kw.pop("visibility", np.ones(GRID.shape, bool)), stamp_ns=SCAN_NS,
        step_ns=100_000_000, **kw,
    )  # fmt: skip


def test_largest_probability_over_the_horizon_scaled_to_percent():
    rng = np.random.default_rng(0)
    horizon = rng.random((3, *GRID.shape))
    horizon[1, 2, 3] = 1.0
    horizon[:, 0, 0] = [0.004, 0.006, 0.0]  # rounds to 0, to 1
    got = planner_grid(prediction(horizon))
    assert got.dtype == np.int8 and got.shape == GRID.shape
    np.testing.assert_array_equal(got, np.rint(horizon.max(axis=0) * 100))
    assert got[2, 3] == 100 and got[0, 0] == 1


def test_one_step_is_the_predicted_grid():
    horizon = np.full((1, *GRID.shape), 0.3)
    visibility = np.ones(GRID.shape, bool)
    visibility[5] = False
    p = prediction(horizon, visibility=visibility)
    grids = {
        g.topic: g.data for g in prediction_grids(p, {"/lidarflow/predicted", planner_topic()})
    }
    np.testing.assert_array_equal(grids[planner_topic()], grids["/lidarflow/predicted"])


def test_unknown_where_unseen_unless_some_step_decides_it_occupied():
    horizon = np.stack([np.full(GRID.shape, 0.2), np.full(GRID.shape, 0.1)])
    decided = np.zeros(horizon.shape, bool)
    decided[1, 5, 1] = True  # the second step decides an unseen cell occupied
    visibility = np.ones(GRID.shape, bool)
    visibility[5] = False  # the near row unseen
    got = planner_grid(prediction(horizon, decided, visibility=visibility))
    assert got[5].tolist() == [-1, 20, -1, -1]
    assert (got[:5] == 20).all()


def test_steps_ahead_are_moved_back_into_the_scan_frame():
    """The sensor moves one cell forward a step: what lies at row r in the frame k steps ahead
    lies k rows further away (row r - k) in the scan's; the near row no step covers."""
    horizon = np.zeros((2, *GRID.shape))
    horizon[0, 3, 1] = 0.9  # one step ahead
    horizon[1, 3, 2] = 0.6  # two steps ahead
    still = planner_grid(prediction(horizon))
    assert still[3, 1] == 90 and still[3, 2] == 60
    moving = planner_grid(prediction(horizon, ahead_motion=np.array([1.0, 0.0, 0.0])))
    assert moving[2, 1] == 90 and moving[1, 2] == 60
    assert moving[3, 1] == moving[3, 2] == 0
    assert (moving[5] == -1).all() and (moving[:5] >= 0).all()
    # no motion is no move
    zero = planner_grid(prediction(horizon, ahead_motion=np.zeros(3)))
    np.testing.assert_array_equal(zero, still)


def test_a_turn_moves_cells_sideways():
    """A turn each step moves the steps' cells too: not the unmoved grid."""
    horizon = np.zeros((1, *GRID.shape))
    horizon[0, 1, 1] = 1.0
    p = prediction(horizon, ahead_motion=np.array([0.0, 0.0, 0.3]))
    assert not np.array_equal(
        planner_grid(p), planner_grid(dataclasses.replace(p, ahead_motion=None))
    )


def test_the_planner_grid_only_where_asked_for_at_the_scan_stamp():
    horizon = np.stack([np.full(GRID.shape, 0.2), np.full(GRID.shape, 0.7)])
    p = prediction(horizon)
    assert planner_topic() not in {g.topic for g in prediction_grids(p)}
    (grid,) = prediction_grids(p, {planner_topic()})
    assert grid.topic == "/lidarflow/planner_grid"
    assert grid.stamp_ns == grid.scan_stamp_ns == SCAN_NS  # the frame it lies in is the scan's
    np.testing.assert_array_equal(grid.data, laid_out(planner_grid(p)))
    assert (map_from_grid_data(grid.data, *GRID.shape) == 70).all()
