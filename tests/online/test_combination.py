"""The online combination in the Predictor: causal, reset, saved and loaded; and what it is
given checked."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.errors import PredictError
from lidarflow.online.combination import Combination
from lidarflow.predict import Predictor

FRAMES = 24


def maps(recording, n=FRAMES):
    return [recording.scan(i) for i in range(n)]


def run(predictor, frames):
    return [predictor.update(f) for f in frames]


@pytest.mark.slow
def test_nothing_predicted_depends_on_a_later_frame(sample_recording):
    """Causal: frames after t changed, every prediction made up to t stays bit for bit."""
    frames = maps(sample_recording)
    first = run(Predictor(horizon=3, combine=True), frames)
    cut = 15
    changed = frames[:cut] + frames[cut:][::-1]
    second = run(Predictor(horizon=3, combine=True), changed)
    for a, b in zip(first[:cut], second[:cut], strict=True):
        np.testing.assert_array_equal(a.horizon, b.horizon)
        np.testing.assert_array_equal(a.horizon_occupied, b.horizon_occupied)
    assert any(
        not np.array_equal(a.horizon, b.horizon)
        for a, b in zip(first[cut:], second[cut:], strict=True)
    )


def test_it_learns_reset_starts_over_and_what_it_learnt_saves_and_loads(sample_recording, tmp_path):
    frames = maps(sample_recording)
    predictor = Predictor(horizon=2, combine=True)
    first = run(predictor, frames)
    learnt = predictor.combination.state()
    start = Combination(2).state()
    assert any(not np.array_equal(learnt[k], start[k]) for k in start)
    path = predictor.save_learned(tmp_path / "learnt.npz")
    predictor.reset()
    assert all(np.array_equal(predictor.combination.state()[k], start[k]) for k in start)
    again = run(predictor, frames)
    for a, b in zip(first, again, strict=True):
        np.testing.assert_array_equal(a.horizon, b.horizon)
    other = Predictor(horizon=2, combine=True)
    other.load_learned(path)
    assert all(np.array_equal(other.combination.state()[k], learnt[k]) for k in learnt)


def test_the_combination_starts_as_the_model_and_its_horizon_is_the_predictors(sample_recording):
    frames = maps(sample_recording, 3)
    plain = Predictor(horizon=2)
    combined = Predictor(horizon=2, combine=True)
    a, b = plain.update(frames[0]), combined.update(frames[0])
    # before any label has come, the model decides (its own map, without the tracked objects)
    assert b.horizon.shape == a.horizon.shape == (2, 100, 100)
    assert np.mean(a.horizon_occupied != b.horizon_occupied) < 0.01


def test_saving_or_loading_without_the_combination_and_a_wrong_file_are_refused(tmp_path):
    with pytest.raises(PredictError, match="neither combines nor learns"):
        Predictor().save_learned(tmp_path / "x.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an npz")
    with pytest.raises(PredictError, match="not what save_learned wrote"):
        Predictor(combine=True).load_learned(bad)
    saved = Predictor(horizon=1, combine=True).save_learned(tmp_path / "one.npz")
    with pytest.raises(PredictError, match="fewer than 3"):
        Predictor(horizon=3, combine=True).load_learned(saved)


def test_seldom_is_the_mover_metrics_share():
    from lidarflow.evaluate.dynamic import SHARE
    from lidarflow.online.experts import SELDOM

    assert SELDOM == SHARE


def test_by_default_it_decides_the_frames_after_the_first_and_the_model_the_first(
    sample_recording, tmp_path
):
    """The default (``combine=None``) with a horizon above 1: frame 1 ahead is the model's own
    prediction, frames 2.. the combination's; one frame ahead, or ``combine=False``, no
    combination at all."""
    frames = maps(sample_recording, 40)
    default = Predictor(horizon=3)
    plain = Predictor(horizon=3, combine=False)
    every = Predictor(horizon=3, combine=True)
    assert default.combined_from == 2 and default.combination is not None
    assert plain.combination is None and Predictor().combination is None
    differs = False
    for a, b, c in zip(run(default, frames), run(plain, frames), run(every, frames), strict=True):
        np.testing.assert_array_equal(a.probability, b.probability)
        np.testing.assert_array_equal(a.occupied, b.occupied)
        np.testing.assert_array_equal(a.horizon[0], b.horizon[0])
        np.testing.assert_array_equal(a.horizon[1:], c.horizon[1:])
        np.testing.assert_array_equal(a.horizon_occupied[1:], c.horizon_occupied[1:])
        differs |= not np.array_equal(a.horizon_occupied[1:], b.horizon_occupied[1:])
    assert differs  # the combination did decide something the model alone would not
    # it learns nothing for the frame it leaves to the model
    assert default.combination.first == 2 and default.combination.stacks[0].learned == 0
    assert every.combination.stacks[0].learned > 0
    with pytest.raises(ValueError, match="first <= horizon"):
        Combination(3, first=4)
    # what the default learnt saves and loads as the combination's on every frame does
    other = Predictor(horizon=3)
    other.load_learned(default.save_learned(tmp_path / "default.npz"))
    learnt = default.combination.state()
    assert all(np.array_equal(other.combination.state()[k], learnt[k]) for k in learnt)


def test_the_flags_choose_every_frame_none_or_the_default_and_not_both(capsys, tmp_path):
    from lidarflow.cli.app import combine_choice
    from tests.test_cli import run

    assert combine_choice(False, False) is None
    assert combine_choice(True, False) is True and combine_choice(False, True) is False
    code, _, err = run(
        ["predict", "in.bag", "-o", str(tmp_path / "o.mcap"), "--combine", "--no-combine"], capsys
    )
    assert code != 0 and "--combine or --no-combine, not both" in err
