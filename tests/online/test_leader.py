"""The choice of the candidate that decides each kind of cell, by the F1s it scored lately."""

from __future__ import annotations

import numpy as np

from lidarflow.online.leader import Arrived, Leader

SHAPE = (30, 30)


def stream(rng, frames=20):
    for _ in range(frames):
        before = rng.random(SHAPE) < 0.1
        occupied = before.copy()
        occupied[rng.random(SHAPE) < 0.05] ^= True
        rare = np.zeros(SHAPE, bool)
        rare[:, 15:] = True
        yield before, occupied, rare


def test_it_starts_on_its_first_and_moves_to_the_candidates_that_score_best():
    rng = np.random.default_rng(0)
    leader = Leader(3, first=2)
    assert leader.choice == (2, 2)
    for before, occupied, rare in stream(rng):
        noise = rng.random(SHAPE) < 0.1
        # candidate 0 right on the common cells only, candidate 1 on the rare ones only
        zero = np.where(rare, noise, occupied)
        one = np.where(rare, occupied, noise)
        leader.score(np.stack([zero, one, noise]), rare, before, Arrived(occupied, rare))
    assert leader.choice == (0, 1)


def test_its_counts_go_back_as_they_were():
    rng = np.random.default_rng(1)
    leader = Leader(2)
    for before, occupied, rare in stream(rng, 3):
        leader.score(np.stack([occupied, before]), rare, before, Arrived(occupied, rare))
    other = Leader(2)
    other.load_state(leader.state())
    assert other.choice == leader.choice
    np.testing.assert_array_equal(other.state()["f1_counts"], leader.state()["f1_counts"])
