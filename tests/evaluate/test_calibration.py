"""Calibration: reliability bins, expected calibration error and Brier score."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.evaluate.calibration import Calibration


def expected_calibration_error(probability: np.ndarray, target: np.ndarray) -> float:
    calibration = Calibration()
    calibration.add(probability, target)
    return calibration.ece()


def brier_score(probability: np.ndarray, target: np.ndarray) -> float:
    calibration = Calibration()
    calibration.add(probability, target)
    return calibration.brier()


def test_ece_and_brier_known_values():
    p, y = np.array([0.2, 0.2, 0.9, 0.9]), np.array([0, 1, 1, 1])
    # (2/4)|0.2 - 1/2| + (2/4)|0.9 - 1|
    assert expected_calibration_error(p, y) == pytest.approx(0.2)
    assert brier_score(np.array([1.0, 0.5]), np.array([1, 0])) == 0.125


def test_perfectly_calibrated_predictor_has_ece_near_zero():
    rng = np.random.default_rng(0)
    p = rng.random(200_000)
    y = rng.random(p.size) < p  # occupied with exactly the predicted probability
    # Sampling error per bin is about sqrt(0.25 / 20000) = 0.0035.
    assert expected_calibration_error(p, y) < 0.01
    # The same probabilities against the wrong truth are far from calibrated.
    assert expected_calibration_error(p, ~y) > 0.3


@settings(max_examples=40, deadline=None)
@given(st.floats(0, 1), st.integers(1, 400), st.integers(0, 2**32 - 1))
def test_constant_predictor_ece_is_distance_to_base_rate(p, n, seed):
    y = np.random.default_rng(seed).random(n) < 0.3
    assert expected_calibration_error(np.full(n, p), y) == pytest.approx(abs(p - y.mean()))


def test_hand_computed_example():
    p = np.array([0.05, 0.05, 0.05, 0.05, 0.55, 0.55, 1.0, 1.0])
    y = np.array([0, 0, 0, 1, 1, 0, 1, 1], bool)
    # bins: [0, .1): mean .05 vs 1/4 -> 4 * .20; [.5, .6): .55 vs 1/2 -> 2 * .05; last: 1 vs 1
    assert expected_calibration_error(p, y) == pytest.approx((4 * 0.2 + 2 * 0.05) / 8)
    brier = (3 * 0.05**2 + 0.95**2 + 0.45**2 + 0.55**2) / 8
    assert brier_score(p, y) == pytest.approx(brier)
    cal = Calibration()
    cal.add(p, y)
    summary = cal.summary()
    assert [b["count"] for b in summary["bins"]] == [4, 0, 0, 0, 0, 2, 0, 0, 0, 2]
    assert summary["bins"][0]["frequency"] == pytest.approx(0.25)
    assert summary["bins"][5]["mean_probability"] == pytest.approx(0.55)
    assert summary["bins"][1]["frequency"] is None and summary["cells"] == 8


def test_bin_edges_left_closed_and_one_in_the_last_bin():
    cal = Calibration(bins=10)
    cal.add(np.array([0.0, 0.1, 0.5, 0.999, 1.0, 1.7, -0.2]), np.zeros(7, bool))
    assert cal.count.tolist() == [2, 1, 0, 0, 0, 1, 0, 0, 0, 3]  # out of [0, 1] is clipped


def test_sums_add_up_over_frames_and_recordings():
    rng = np.random.default_rng(3)
    p, y = rng.random((6, 8, 8)), rng.random((6, 8, 8)) < 0.4
    whole, first, second = Calibration(), Calibration(), Calibration()
    whole.add(p, y)
    first.add(p[:2], y[:2])
    second.add(p[2:], y[2:])
    both = first + second
    assert both.ece() == pytest.approx(whole.ece())
    assert both.brier() == pytest.approx(whole.brier())
    np.testing.assert_array_equal(both.count, whole.count)


def test_binary_predictions_extremes_and_empty():
    y = np.array([1, 0, 1, 0], bool)
    assert brier_score(y.astype(float), y) == 0.0
    assert expected_calibration_error(y.astype(float), y) == 0.0
    assert brier_score((~y).astype(float), y) == 1.0
    assert Calibration().ece() == 0.0 and Calibration().brier() == 0.0


def test_bad_inputs():
    with pytest.raises(ValueError, match="differ in shape"):
        Calibration().add(np.zeros(3), np.zeros(4, bool))
    with pytest.raises(ValueError, match="bins"):
        Calibration(bins=0)
    with pytest.raises(ValueError, match="cannot add"):
        Calibration(bins=5) + Calibration(bins=10)


def test_active_ece_ignores_the_lowest_bin():
    p = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0.45, 0.45])
    y = np.array([0, 0, 0, 1, 1, 0, 1, 1], bool)
    cal = Calibration()
    cal.add(p, y)
    # above the lowest bin: p=1 -> freq 1/2 (2 cells), p=0.45 -> freq 1 (2 cells)
    assert cal.ece_active() == pytest.approx((2 * 0.5 + 2 * 0.55) / 4)
    assert cal.ece() == pytest.approx((1 + 2 * 0.5 + 2 * 0.55) / 8)
    assert cal.summary()["ece_active"] == cal.ece_active()
    empty = Calibration()
    empty.add(np.zeros(3), np.ones(3, bool))
    assert empty.ece_active() == 0.0 and empty.ece() == 1.0
