"""The walkers study: its statistics on made-up tracks, and a tiny run on simulated data."""

from __future__ import annotations

import numpy as np
import pytest

from studies import walkers


def test_statistics_of_a_walk_with_one_stop_and_one_turn():
    rate = 10.0
    v = np.array([[1.0, 0.0]] * 20 + [[0.0, 0.0]] * 5 + [[0.0, 1.0]] * 20)
    xy = np.cumsum(v, axis=0) / rate
    got = walkers.statistics([(xy, v)], rate)
    assert got["speed"] == [1.0] * 40
    assert got["stop_duration"] == [pytest.approx(0.5)]
    assert max(got["heading_change"]) == 0.0  # the turn happened while standing
    assert walkers.statistics([(xy[:5], v[:5])], rate)["speed"] == []  # too short


def test_tiny_run_writes_the_table(tmp_path):
    args = ["-o", str(tmp_path), "--data", str(tmp_path / "none"), "--seeds", "1"]
    results = walkers.main([*args, "--frames", "60", "--walkers", "social"])
    assert "tracker: simulated social" in results["summary"]
    assert "| tracker: simulated social |" in (tmp_path / "walkers.md").read_text()


def test_ks_d_of_two_samples():
    assert walkers.ks([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])["D"] == 0.0
    assert walkers.ks([1.0, 2.0], [5.0, 6.0])["D"] == 1.0
    assert walkers.ks([], [1.0]) == {"D": None, "p": None}
