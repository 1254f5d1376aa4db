"""``Prediction.tracks``: the tracker's objects handed to the robot's own code in metres and
metres per second, checked against a simulated recording's walkers."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.geometry import cell_to_metric
from lidarflow.predict import Predictor
from lidarflow.predict.decision import DecisionPolicy
from lidarflow.sim import SimConfig, simulate
from lidarflow.sim.people import PeopleConfig

FRAMES = 60


@pytest.fixture(scope="module")
def walkers():
    """A still sensor and four people walking about (seed 0 keeps some in view throughout)."""
    config = SimConfig(scenario="static", people=PeopleConfig(count=4), episode_frames=FRAMES)
    return simulate(FRAMES, seed=0, config=config)


def test_tracks_lie_on_the_walkers_and_move_as_they_do(walkers):
    predictor = Predictor(decision=DecisionPolicy(tracks=True))
    grid = predictor.grid
    moving, flow = walkers.extras["moving"], walkers.extras["flow_forward"]
    distances, cosines, ratios = [], [], []
    for t in range(FRAMES):
        p = predictor.update(walkers.scan(t))
        assert p.tracks is not None
        for track in p.tracks:
            if p.step_ns is None:  # no step yet: no speed in seconds
                assert track.velocity is None
                continue
            assert track.velocity == pytest.approx(track.frame_velocity * 1e9 / p.step_ns)
            on = moving[t][track.cells[:, 0], track.cells[:, 1]]
            if on.mean() < 0.5 or not track.velocity.any():  # not a walker, or just started
                continue
            rows, cols = track.cells[on, 0], track.cells[on, 1]
            x, y = cell_to_metric(rows, cols, grid.height, grid.width, grid.res)
            distances.append(np.hypot(*(track.position - [x.mean(), y.mean()])))
            # the true forward flow (column, row) in cells per frame; x is up the rows, y left
            f_col, f_row = (flow[t][i][rows, cols].astype(np.float64).mean() for i in (0, 1))
            truth = np.array([-f_row, -f_col]) * grid.res * 1e9 / p.step_ns
            if np.linalg.norm(truth) > 0.3:  # m/s: walking, not turning on the spot
                speed = np.linalg.norm(track.velocity)
                cosines.append(track.velocity @ truth / speed / np.linalg.norm(truth))
                ratios.append(speed / np.linalg.norm(truth))
    assert len(cosines) >= 20
    assert max(distances) < 0.3  # metres: each track's centroid on its walker's cells
    assert np.median(cosines) > 0.8  # heading the walker's way
    assert 0.5 < np.median(ratios) < 2.0  # at about the walker's speed


def test_no_tracks_where_the_policy_runs_no_tracker(walkers):
    predictor = Predictor(decision=DecisionPolicy())
    assert all(predictor.update(walkers.scan(t)).tracks is None for t in range(3))
