"""Branch and bound finds exactly what scoring every placement finds: the same best placement
(ties in the reading order), its score, standing still's, and the peak's neighbours."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.motion import correlative
from lidarflow.motion.correlative import MAX_SHIFT, YAWS, correlate
from lidarflow.motion.odometry import cells_in_new_frame


def _every_placement(previous: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Scores ``(turns, 2 MAX_SHIFT + 3, 2 MAX_SHIFT + 3)`` of every shift -13 ... 13, the
    plain way: each turned cell (once) adds the current map around where it lands."""
    h, w = current.shape
    reach = MAX_SHIFT + 1
    grid = np.zeros((h + 2 * reach, w + 2 * reach), np.int64)
    grid[reach : reach + h, reach : reach + w] = current
    scores = np.zeros((len(YAWS), 2 * reach + 1, 2 * reach + 1), np.int64)
    rows, cols = np.nonzero(previous)
    for k, yaw in enumerate(YAWS):
        r, c = cells_in_new_frame(rows, cols, np.array([0.0, 0.0, yaw]), h, w)
        inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        for i, j in set(zip(r[inside].tolist(), c[inside].tolist(), strict=True)):
            scores[k] += grid[i : i + 2 * reach + 1, j : j + 2 * reach + 1]
    return scores


def _first_best(scores: np.ndarray) -> tuple[int, int, int]:
    """The best placement within MAX_SHIFT, the first in the order turn, row shift, column
    shift, each shift read 0 ... MAX_SHIFT, then -MAX_SHIFT ... -1."""
    shifts = [*range(MAX_SHIFT + 1), *range(-MAX_SHIFT, 0)]
    reach = MAX_SHIFT + 1
    best, where = -1, (0, 0, 0)
    for k in range(len(YAWS)):
        for a in shifts:
            for b in shifts:
                if scores[k, a + reach, b + reach] > best:
                    best, where = int(scores[k, a + reach, b + reach]), (k, a, b)
    return where


def _walls(shape: tuple[int, int]) -> np.ndarray:
    world = np.zeros(shape, bool)
    h, w = shape
    world[h // 5, w // 10 : w - 10] = world[h // 5 : h - 20, w // 6] = True
    world[h // 2 : h - 30, w - 30] = world[h - 15, w // 3 : w // 2] = True
    return world


def _cases() -> list[tuple[str, np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(46)
    cases = []
    for density, shape in ((0.01, (100, 100)), (0.04, (100, 100)), (0.02, (64, 48))):
        previous = rng.random(shape) < density
        current = rng.random(shape) < density
        cases.append((f"random {density} {shape}", previous, current))
    walls = _walls((100, 100))
    # the world moved 3 cells down, 2 right: the turned walls must land on it
    moved = np.zeros_like(walls)
    moved[3:, 2:] = walls[:-3, :-2]
    noisy = moved ^ (rng.random(walls.shape) < 0.005)
    cases.append(("walls moved", walls, noisy))
    # moved to the far corner of a block: its bound must cover the whole block
    far = np.zeros_like(walls)
    far[6:, 11:] = walls[:-6, :-11]
    cases.append(("walls moved far", walls, far ^ (rng.random(walls.shape) < 0.005)))
    one = np.zeros((100, 100), bool)
    one[40, 50] = True
    cases.append(("one cell each", one, one.copy()))
    # one cell, and two equally good places for it: the one shifted down is read first,
    # though the block that holds the one shifted up is scored first
    near, two = np.zeros((100, 100), bool), np.zeros((100, 100), bool)
    near[80, 50] = two[77, 50] = two[83, 50] = True
    cases.append(("a tie across blocks", near, two))
    return cases


@pytest.mark.parametrize("first_blocks", [1, correlative.FIRST_BLOCKS])
@pytest.mark.parametrize("name, previous, current", _cases(), ids=[c[0] for c in _cases()])
def test_branch_and_bound_finds_what_scoring_every_placement_finds(
    monkeypatch, name, previous, current, first_blocks
):
    # one block first: the pruning by bounds decides, not the first round's luck
    monkeypatch.setattr(correlative, "FIRST_BLOCKS", first_blocks)
    scores = _every_placement(previous, current)
    found = correlate(previous, current)
    assert found is not None
    k, a, b = _first_best(scores)
    reach = MAX_SHIFT + 1
    assert (found.k, found.a, found.b) == (k, a, b)
    assert found.score == scores[k, a + reach, b + reach]
    assert found.still == scores[len(YAWS) // 2, reach, reach]
    i, j = a + reach, b + reach
    expected = [scores[k, i - 1, j], scores[k, i + 1, j], scores[k, i, j - 1], scores[k, i, j + 1]]
    if 0 < k < len(YAWS) - 1:
        expected += [scores[k - 1, i, j], scores[k + 1, i, j]]
    else:
        expected += [None, None]
    assert list(found.neighbours) == expected


def test_the_walls_moved_are_found_where_they_were_moved():
    walls = _walls((100, 100))
    moved = np.zeros_like(walls)
    moved[3:, 2:] = walls[:-3, :-2]
    found = correlate(walls, moved)
    assert found is not None
    assert (found.k, found.a, found.b) == (len(YAWS) // 2, 3, 2)
    assert found.score == int(moved.sum()) and found.still < found.score


def test_an_empty_map_gives_no_placement():
    walls = _walls((100, 100))
    assert correlate(np.zeros_like(walls), walls) is None
    assert correlate(walls, np.zeros_like(walls)) is None
