"""The peers' metrics: WMSE's class weights by hand, SSIM against scikit-image, and their
properties (SSIM(x, x) = 1, symmetric, within [-1, 1]; WMSE 0 only for a perfect prediction)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from lidarflow.evaluate.peer_metrics import SSIM_C1, SSIM_C2, gaussian_window, ssim, wmse


def _maps(min_side: int = 11, max_side: int = 24):
    """Pairs of maps of one shape: a probability map in [0, 1] and a 0/1 target."""
    return st.tuples(
        st.integers(min_side, max_side), st.integers(min_side, max_side)
    ).flatmap(
        lambda shape: st.tuples(
            arrays(np.float64, shape, elements=st.floats(0.0, 1.0)),
            arrays(np.bool_, shape),
        )
    )


# --- WMSE -------------------------------------------------------------------------------------


def test_wmse_weighs_the_classes_equally_by_hand():
    target = np.zeros((4, 5))
    target[0, :2] = 1.0  # 2 occupied cells, 18 free
    predicted = np.zeros((4, 5))
    # every occupied cell missed: MSE over occupied 1, over free 0 -> (1 + 0) / 2
    assert float(wmse(predicted, target)) == pytest.approx(0.5)
    # a plain MSE would have called that 2 / 20 = 0.1
    assert float(wmse(predicted, target, weights=(1.0, 1.0))) == pytest.approx(0.1)
    # 0.5 everywhere: 0.25 on each class
    assert float(wmse(np.full((4, 5), 0.5), target)) == pytest.approx(0.25)
    # one free cell called occupied at 0.9: free MSE 0.81 / 18, occupied MSE 0
    predicted = target.copy()
    predicted[3, 4] = 0.9
    assert float(wmse(predicted, target)) == pytest.approx(0.81 / 18 / 2)


def test_wmse_fixed_weights_are_a_weighted_mean():
    target = np.array([[1.0, 0.0, 0.0, 0.0]])
    predicted = np.array([[0.5, 0.2, 0.0, 0.0]])
    # occupied squared error 0.25 at weight 3; free 0.04, 0, 0 at weight 1 -> / (3 + 3)
    assert float(wmse(predicted, target, weights=(1.0, 3.0))) == pytest.approx(
        (3 * 0.25 + 0.04) / 6
    )
    # only the occupied cells count
    assert float(wmse(predicted, target, weights=(0.0, 1.0))) == pytest.approx(0.25)
    with pytest.raises(ValueError, match="weights"):
        wmse(predicted, target, weights=(0.0, 0.0))


def test_wmse_of_a_map_with_one_class_is_its_mse():
    predicted = np.array([[0.1, 0.3], [0.0, 0.2]])
    assert float(wmse(predicted, np.zeros((2, 2)))) == pytest.approx(np.mean(predicted**2))
    assert float(wmse(predicted, np.ones((2, 2)))) == pytest.approx(np.mean((1 - predicted) ** 2))


def test_wmse_is_one_value_per_map_of_a_stack():
    rng = np.random.default_rng(0)
    predicted = rng.random((3, 2, 7, 9))
    target = rng.random((3, 2, 7, 9)) > 0.8
    stacked = wmse(predicted, target)
    assert stacked.shape == (3, 2)
    assert stacked[2, 1] == pytest.approx(float(wmse(predicted[2, 1], target[2, 1])))


@settings(max_examples=60, deadline=None)
@given(_maps(min_side=1, max_side=12))
def test_wmse_is_the_mean_of_the_per_class_mses(pair):
    predicted, target = pair
    error = (predicted - target) ** 2
    means = [error[target == c].mean() for c in (False, True) if (target == c).any()]
    assert float(wmse(predicted, target)) == pytest.approx(np.mean(means), abs=1e-12)
    assert float(wmse(target.astype(float), target)) == 0.0  # perfect: 0
    assert 0.0 <= float(wmse(predicted, target)) <= 1.0


def test_wmse_refuses_maps_of_different_shapes():
    with pytest.raises(ValueError, match="one shape"):
        wmse(np.zeros((4, 4)), np.zeros((4, 5)))
    with pytest.raises(ValueError, match="maps"):
        wmse(np.zeros(4), np.zeros(4))


# --- SSIM -------------------------------------------------------------------------------------


def test_ssim_of_constant_maps_by_hand():
    # no variance anywhere: only the luminance term, (2 a b + C1) / (a^2 + b^2 + C1)
    a, b = 0.8, 0.2
    expected = (2 * a * b + SSIM_C1) / (a * a + b * b + SSIM_C1)
    assert float(ssim(np.full((15, 13), a), np.full((15, 13), b))) == pytest.approx(expected)
    # an empty prediction of an empty map is perfect; of a full one, almost as wrong as can be
    assert float(ssim(np.zeros((11, 11)), np.zeros((11, 11)))) == 1.0
    assert float(ssim(np.zeros((11, 11)), np.ones((11, 11)))) == pytest.approx(
        SSIM_C1 / (1 + SSIM_C1)
    )


def test_ssim_of_one_window_by_hand():
    # an 11 x 11 map has one window: the Gaussian-weighted statistics of the whole map
    rng = np.random.default_rng(3)
    x, y = rng.random((11, 11)), (rng.random((11, 11)) > 0.7).astype(float)
    w = np.outer(gaussian_window(), gaussian_window())
    mx, my = (w * x).sum(), (w * y).sum()
    vx, vy = (w * (x - mx) ** 2).sum(), (w * (y - my) ** 2).sum()
    cxy = (w * (x - mx) * (y - my)).sum()
    expected = ((2 * mx * my + SSIM_C1) * (2 * cxy + SSIM_C2)) / (
        (mx * mx + my * my + SSIM_C1) * (vx + vy + SSIM_C2)
    )
    assert float(ssim(x, y)) == pytest.approx(expected, abs=1e-6)


@pytest.mark.parametrize("shape", [(11, 11), (100, 100), (37, 64)])
def test_ssim_matches_scikit_image(shape):
    from skimage.metrics import structural_similarity

    rng = np.random.default_rng(sum(shape))
    x = rng.random(shape) ** 3  # mostly low probabilities, as predictions are
    y = (rng.random(shape) > 0.9).astype(np.float64)
    reference = structural_similarity(
        x, y, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1.0
    )
    assert float(ssim(x, y)) == pytest.approx(reference, abs=1e-6)


@settings(max_examples=60, deadline=None)
@given(_maps())
def test_ssim_is_one_for_identical_maps_symmetric_and_bounded(pair):
    x, target = pair
    y = target.astype(np.float64)
    assert float(ssim(x, x)) == pytest.approx(1.0, abs=1e-6)
    assert float(ssim(x, y)) == pytest.approx(float(ssim(y, x)), abs=1e-6)
    assert -1.0 - 1e-6 <= float(ssim(x, y)) <= 1.0 + 1e-6


def test_ssim_is_one_value_per_map_of_a_stack():
    rng = np.random.default_rng(1)
    x, y = rng.random((4, 20, 16)), rng.random((4, 20, 16)) > 0.5
    stacked = ssim(x, y)
    assert stacked.shape == (4,)
    assert stacked[3] == pytest.approx(float(ssim(x[3], y[3])))


def test_ssim_refuses_maps_smaller_than_its_window():
    with pytest.raises(ValueError, match="at least 11 x 11"):
        ssim(np.zeros((10, 40)), np.zeros((10, 40)))
