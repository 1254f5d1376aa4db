"""The verdict's margins over the frames: the block bootstrap, its F1s, the per-frame counts it
resamples, and how the report and its line carry the intervals."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.baselines import CopyLast, TemporalAverage
from lidarflow.evaluate.metrics import Counts
from lidarflow.evaluate.movers import TolerantCounts, tolerant_f1
from lidarflow.evaluate.report import add_horizon_verdict, build_report, format_comparison
from lidarflow.evaluate.resampling import (
    all_cell_f1,
    draw_starts,
    margin_interval,
    resampled_sums,
)
from lidarflow.evaluate.runner import evaluate_maps, horizon_scores
from tests.evaluate.test_evaluate import Oracle, moving_square

counts = st.integers(0, 6)


@settings(max_examples=200, deadline=None)
@given(counts, counts, counts, counts)
def test_the_vectorized_f1s_are_the_counts_own_to_the_bit(a, b, c, d):
    assert all_cell_f1(np.array([a]), np.array([b]), np.array([c]))[0] == Counts(a, b, c).f1
    assert tolerant_f1(*(np.array([v]) for v in (a, b, c, d)))[0] == TolerantCounts(a, b, c, d).f1


def _weights(frames: int, starts: np.ndarray, block: int) -> np.ndarray:
    """``(draws, frames)``: how often each frame is taken, from the runs' definition."""
    weights = np.zeros((len(starts), frames), np.int64)
    for d, row in enumerate(starts):
        taken = [(s + i) % frames for s in row for i in range(block)][:frames]
        np.add.at(weights[d], taken, 1)
    return weights


@pytest.mark.parametrize("frames", [1, 4, 9, 50, 51])
def test_each_draw_sums_frames_taken_in_runs_of_consecutive_ones(frames):
    starts, block = draw_starts(frames, draws=64, seed=3)
    assert block == int(np.ceil(np.sqrt(frames))) and starts.shape == (64, -(-frames // block))
    rows = np.random.default_rng(frames).integers(0, 9, (frames, 3))
    weights = _weights(frames, starts, block)
    assert (weights.sum(axis=1) == frames).all()  # every draw takes F frames
    assert (resampled_sums(rows, starts, block) == weights @ rows).all()
    assert (draw_starts(frames, draws=64, seed=3)[0] == starts).all()  # seeded


def test_a_draw_is_runs_of_consecutive_frames_wrapping_at_the_end():
    # 4 frames: runs of 2, two of them a draw, each starting anywhere (frame 3 runs into 0)
    runs = [np.bincount([s, (s + 1) % 4], minlength=4) for s in range(4)]
    possible = {tuple(a + b) for a, b in itertools.product(runs, repeat=2)}
    starts, block = draw_starts(4, draws=200, seed=0)
    drawn = {tuple(w) for w in resampled_sums(np.eye(4, dtype=np.int64), starts, block)}
    assert drawn <= possible and len(drawn) > 5  # not one draw repeated


def test_a_method_against_itself_ties_exactly():
    rows = np.random.default_rng(0).integers(0, 20, (30, 3))
    assert margin_interval(rows, rows, all_cell_f1) == (0.0, 0.0)
    assert margin_interval(rows[:0], rows[:0], all_cell_f1) is None


def test_a_method_better_on_every_frame_has_its_whole_interval_above_zero():
    rng = np.random.default_rng(1)
    base = rng.integers(5, 20, (40, 3))
    better = base + np.array([2, -2, -2])  # two more hits, two fewer misses each frame
    low, high = margin_interval(better, base, all_cell_f1)
    assert 0 < low <= high


def test_the_interval_narrows_with_more_frames_and_flips_with_the_pair():
    rng = np.random.default_rng(2)

    def frames(n):  # a method and a baseline alike but for noise
        truth = rng.integers(5, 15, n)
        hits_a, hits_b = rng.binomial(truth, 0.7), rng.binomial(truth, 0.7)
        return (
            np.stack([hits_a, rng.integers(0, 5, n), truth - hits_a], 1),
            np.stack([hits_b, rng.integers(0, 5, n), truth - hits_b], 1),
        )

    few, many = frames(20), frames(2000)
    low_few, high_few = margin_interval(*few, all_cell_f1)
    low_many, high_many = margin_interval(*many, all_cell_f1)
    assert high_many - low_many < (high_few - low_few) / 3
    flipped = margin_interval(few[1], few[0], all_cell_f1)
    assert flipped == pytest.approx((-high_few, -low_few))


def test_the_frames_counts_sum_to_the_scorers_totals():
    maps, region = moving_square(), np.zeros((24, 24), bool)
    region[6:14] = True  # the square's rows
    scored = evaluate_maps(
        maps, maps, [Oracle(maps), CopyLast(), TemporalAverage()], warmup=2,
        region=lambda t: region,
    )  # fmt: skip
    for scorer in scored.values():
        counts = np.reshape(scorer.counts_rows, (-1, 3))
        assert len(counts) == scorer.frames == 17
        assert tuple(counts.sum(0)) == scorer.counts.row()
        assert tuple(np.reshape(scorer.changed_rows, (-1, 3)).sum(0)) == scorer.changed.row()
        tolerant = np.reshape(scorer.mover_rows, (-1, 4))
        assert tuple(tolerant.sum(0)) == scorer.movers.tolerant.row()
    merged = scored["copy_last"] + scored["copy_last"]  # overall: the frames of both
    assert len(merged.counts_rows) == 2 * 3 * 17


def test_the_verdict_carries_its_intervals_and_names_the_margins_within_the_noise():
    maps, region = moving_square(), np.zeros((24, 24), bool)
    region[6:14] = True
    scored = evaluate_maps(
        maps, maps, [Oracle(maps), CopyLast(), TemporalAverage()], warmup=2,
        region=lambda t: region,
    )  # fmt: skip
    verdict = build_report([("a", scored)])["recordings"][0]["against_baselines"]["oracle"]
    assert set(verdict["intervals"]) == {"f1", "changed_f1", "mover_f1"}
    intervals = verdict["intervals"]
    assert 0 < intervals["f1"][0] <= verdict["f1_margin"] <= intervals["f1"][1]
    assert intervals["changed_f1"] == [1.0, 1.0]  # copy-last finds no changed cell, ever
    # the square steps within the tolerance but where it wraps round: a tie on movers
    low, high = intervals["mover_f1"]
    assert low <= 0 < verdict["mover_f1_margin"] <= high
    line = format_comparison({"oracle": verdict})
    assert line.endswith(
        f"wins; within the noise (90% interval over the frames holds 0): "
        f"tolerant mover F1 {low:+.4f}..{high:+.4f}"
    )
    verdict["intervals"]["mover_f1"] = [0.01, 0.02]
    assert format_comparison({"oracle": verdict}).endswith(": wins")


def test_the_horizon_verdict_takes_the_interval_of_its_margin_at_k():
    maps, region = moving_square(), np.zeros((24, 24), bool)
    region[6:14] = True
    scores = horizon_scores(
        maps, maps, [TemporalAverage()], horizon=3, warmup=2, region=lambda t: region
    )
    interval = scores["mover_f1_tolerant_interval"]
    assert set(interval) == {"temporal_average"}
    low, high = interval["temporal_average"]
    margin = (
        scores["mover_f1_tolerant"]["temporal_average"][-1]
        - scores["mover_f1_tolerant"]["copy_last"][-1]
    )
    assert low <= margin <= high
    entry = {
        "horizon_mover_f1_tolerant": scores["mover_f1_tolerant"],
        "horizon_mover_f1_tolerant_interval": interval,
        "against_baselines": {"temporal_average": {"wins": True, "intervals": {}}},
    }
    add_horizon_verdict(entry)
    assert entry["against_baselines"]["temporal_average"]["intervals"]["mover_f1_horizon"] == [
        low,
        high,
    ]


def test_the_docstrings_examples_hold():
    import doctest

    from lidarflow.evaluate import movers, resampling

    assert doctest.testmod(resampling, raise_on_error=True).attempted >= 1
    assert doctest.testmod(movers, raise_on_error=True).attempted >= 1


def test_the_horizon_keeps_the_frames_counts_k_ahead_only():
    from lidarflow.evaluate.horizon import HorizonScore

    maps, region = moving_square(), np.zeros((24, 24), bool)
    region[6:14] = True
    score = HorizonScore(3, (24, 24), lambda t: region)
    for t in range(2, 12):
        score.add(np.stack([maps[t]] * 3).astype(np.float32), maps, t)  # copy-last 1..3 ahead
    rows = np.reshape(score.last_mover_rows, (-1, 4))
    assert len(rows) == score.frames == 10
    assert tuple(rows.sum(0)) == score.movers[-1].tolerant.row()
    assert tuple(rows.sum(0)) != score.movers[0].tolerant.row()  # k = 3, not k = 1


def test_a_loss_within_the_noise_is_counted_apart_in_the_overall_line():
    from lidarflow.evaluate.report import count_recordings_won
    from lidarflow.evaluate.resampling import lost_within_noise

    def verdict(wins, mover, interval):
        return {
            "wins": wins, "f1_margin": 0.01, "changed_f1_margin": 0.1, "mover_f1_margin": mover,
            "intervals": {"f1": [0.005, 0.02], "changed_f1": [0.05, 0.2], "mover_f1": interval},
        }  # fmt: skip

    tie = verdict(False, -0.01, [-0.05, 0.03])  # lost on movers, within the noise
    real = verdict(False, -0.04, [-0.08, -0.01])  # lost beyond it
    won = verdict(True, 0.02, [-0.01, 0.05])  # a win, however unsure, is no loss
    assert [lost_within_noise(v) for v in (tie, real, won)] == [True, False, False]
    beyond_f1 = verdict(False, -0.01, [-0.05, 0.03]) | {"f1_margin": -0.01}  # F1's is beyond
    beyond_f1["intervals"]["f1"] = [-0.02, -0.001]
    assert not lost_within_noise(beyond_f1)
    report = {
        "recordings": [{"against_baselines": {"m": v}} for v in (tie, real, won)],
        "against_baselines": {"m": {"wins": False, "f1_margin": 0.0, "f1_baseline": "copy_last",
                                    "changed_f1_margin": 0.0, "changed_f1_baseline": "copy_last"}},
    }  # fmt: skip
    count_recordings_won(report)
    overall = report["against_baselines"]["m"]
    assert (overall["recordings_won"], overall["recordings_lost_within_noise"]) == (1, 1)
    line = format_comparison(report["against_baselines"])
    assert line.endswith("loses; won 1 of 3 recordings (1 more lost only within the noise)")
