"""The choice of the candidate that decides each kind of cell, by the F1s it scored lately."""

from __future__ import annotations

import numpy as np
import pytest

import lidarflow.online.leader as leader_module
from lidarflow.online.leader import (
    Arrived,
    Leader,
    choose_each,
    score_counts,
    score_counts_each,
)

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


@pytest.mark.usefixtures("compile_now")
@pytest.mark.parametrize("compiled", [True, False])
def test_horizons_scored_together_count_as_each_alone(compiled, monkeypatch):
    """Several horizons' candidates against one frame: the counts each would get alone, also
    where one horizon guesses cells no other does (the NumPy pass counts over their union)."""
    if not compiled:
        monkeypatch.setattr(leader_module, "ready", lambda *args, **kwargs: False)
    rng = np.random.default_rng(2)
    occupied, region = rng.random(SHAPE) < 0.1, rng.random(SHAPE) < 0.4
    arrived = Arrived(occupied, region)
    share = np.array([0.0, 0.05, 0.3])[None, :, None, None]
    decided = rng.random((4, 3, *SHAPE)) < share
    decided[2, 1, :5] = True  # cells only this horizon's candidate guesses
    rare = rng.random((4, *SHAPE)) < 0.5
    before = occupied ^ (rng.random((4, *SHAPE)) < 0.1)
    f1, tolerant = score_counts_each(decided, rare, before, arrived)
    assert f1.shape == (4, 3, 4, 3) and tolerant.shape == (4, 3, 4)
    for k in range(4):
        alone = score_counts(decided[k], rare[k], before[k], Arrived(occupied, region))
        np.testing.assert_array_equal(f1[k], alone[0])
        np.testing.assert_array_equal(tolerant[k], alone[1])
    assert f1[2, 1].sum() > f1[1, 1].sum()  # the extra guesses were counted


@pytest.mark.usefixtures("compile_now")
@pytest.mark.parametrize("compiled", [True, False])
@pytest.mark.parametrize("baselines", [(), (1, 3)])
def test_leaders_choosing_together_choose_as_each_alone(compiled, baselines, monkeypatch):
    """Several horizons' leaders choose in one pass what each chooses alone, a leader with
    nothing counted yet keeping its first."""
    if not compiled:
        monkeypatch.setattr(leader_module, "ready", lambda *args, **kwargs: False)
    rng = np.random.default_rng(5)
    leaders = [Leader(4, first=2, baselines=baselines) for _ in range(4)]
    for k, leader in enumerate(leaders[1:], start=1):
        for before, occupied, rare in stream(rng, 2 + k):
            decided = rng.random((4, *SHAPE)) < np.array([0.02, 0.1, 0.2, 0.05])[:, None, None]
            decided[k] |= occupied
            leader.add(*score_counts(decided, rare, before, Arrived(occupied, rare)), choose=False)
    alone = [leader._best() for leader in leaders]
    choose_each(leaders)
    assert [leader.choice for leader in leaders] == alone
    assert alone[0] == (2, 2) and len(set(alone)) > 1
