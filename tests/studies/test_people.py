import numpy as np
import pytest

from lidarflow.scan import GridSpec, cell_centres
from studies.people import RADIUS, PeopleCounts, frames_of, people_found

GRID = GridSpec(20, 20, 0.1)


def occupied_at(x: float, y: float) -> np.ndarray:
    """A map of GRID with the one cell whose centre is nearest to (x, y) occupied."""
    cx, cy = cell_centres(GRID)
    out = np.zeros(GRID.shape, bool)
    out[np.unravel_index(np.argmin(np.hypot(cx - x, cy - y)), GRID.shape)] = True
    return out


def test_a_person_beside_an_occupied_cell_is_found_one_farther_is_not():
    decided = occupied_at(1.05, 0.05)  # the centre of cell (9, 9)
    people = np.array([[1.05 + RADIUS - 0.01, 0.05], [1.05, 0.05 + RADIUS + 0.01]])
    assert people_found(decided, people, GRID) == PeopleCounts(1, 2)


def test_people_outside_the_grid_are_not_counted():
    decided = occupied_at(0.55, 0.95)
    people = np.array([[-0.1, 0.0], [2.5, 0.0], [0.5, 1.1], [0.55, 0.95]])
    counts = people_found(decided, people, GRID)
    assert counts == PeopleCounts(1, 1) and counts.share == 1.0


def test_an_empty_map_finds_nobody_and_no_people_gives_no_share():
    assert people_found(np.zeros(GRID.shape, bool), np.array([[1.0, 0.0]]), GRID).share == 0.0
    assert people_found(occupied_at(1, 0), np.zeros((0, 2)), GRID).share is None
    assert PeopleCounts(1, 2) + PeopleCounts(2, 2) == PeopleCounts(3, 4)


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="decided must be"):
        people_found(np.zeros((3, 3), bool), np.zeros((1, 2)), GRID)
    with pytest.raises(ValueError, match="radius"):
        people_found(np.zeros(GRID.shape, bool), np.zeros((1, 2)), GRID, radius=-1)
    with pytest.raises(ValueError, match="ascending"):
        frames_of(np.array([1]), np.array([2, 1]))


def test_frames_of_takes_the_scan_nearest_to_the_stamp_less_the_lag():
    scans = np.arange(5) * 133_000_000  # 7.5 Hz
    logged = scans[1:] + 133_000_000 + np.array([-10, 5, 20_000_000, -20_000_000])
    assert frames_of(logged, scans).tolist() == [2, 3, 4, 4]  # without the lag: one late
    assert frames_of(logged, scans, lag_ns=133_000_000).tolist() == [1, 2, 3, 4]
    assert frames_of(np.array([5]), np.array([7])).tolist() == [0]
