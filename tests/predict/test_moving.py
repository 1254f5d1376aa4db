"""Moving-object segmentation from forward flow: properties on maps whose motion is known."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.evaluate.metrics import confusion
from lidarflow.predict.moving import (
    MIN_BACKGROUND_CELLS,
    MOVING_THRESHOLD,
    background_flow,
    moving_mask,
)

SIZE = 24

occupancies = st.integers(0, 2**32 - 1).map(
    lambda seed: np.random.default_rng(seed).random((SIZE, SIZE)) < 0.15
)


def uniform(d_col: float, d_row: float, size: int = SIZE) -> np.ndarray:
    return np.stack([np.full((size, size), d_col), np.full((size, size), d_row)])


def rotation_flow(angle: float, size: int = SIZE) -> np.ndarray:
    """Exact flow of a rotation by ``angle`` about the sensor (middle of the bottom edge)."""
    rows, cols = np.indices((size, size)).astype(float)
    u, v = cols - size / 2, rows - size
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * u - s * v - u, s * u + c * v - v])


@settings(max_examples=30, deadline=None)
@given(occupancies, st.booleans())
def test_zero_flow_marks_nothing(occupancy, compensate):
    assert not moving_mask(occupancy, np.zeros((2, SIZE, SIZE)), compensate=compensate).any()


@settings(max_examples=30, deadline=None)
@given(occupancies, st.integers(-4, 4), st.integers(-4, 4))
def test_shift_beyond_threshold_marks_exactly_the_occupied_cells(occupancy, d_col, d_row):
    flow = uniform(d_col, d_row)
    mask = moving_mask(occupancy, flow, threshold=0.5, compensate=False)
    expected = occupancy if np.hypot(d_col, d_row) > 0.5 else np.zeros_like(occupancy)
    np.testing.assert_array_equal(mask, expected)


@settings(max_examples=30, deadline=None)
@given(occupancies, st.floats(-3, 3), st.floats(-3, 3), st.floats(-0.1, 0.1))
def test_whole_scene_rigid_motion_is_the_platform_not_moving_objects(
    occupancy, d_col, d_row, angle
):
    occupancy[0, :] = True  # enough cells for the background fit
    flow = rotation_flow(angle) + uniform(d_col, d_row)
    np.testing.assert_allclose(
        background_flow(occupancy, flow), flow, atol=1e-6
    )  # a similarity transform explains a rigid motion exactly
    assert not moving_mask(occupancy, flow, 0.1).any()


@pytest.mark.parametrize("platform", [(0.0, 0.0), (0.0, -0.8), (1.5, 0.3)])
def test_an_object_moving_against_the_background_is_found_exactly(platform):
    occupancy = np.zeros((SIZE, SIZE), bool)
    occupancy[2, :] = occupancy[:, 1] = occupancy[:, SIZE - 2] = True  # walls
    person = np.zeros_like(occupancy)
    person[12:14, 10:12] = True
    occupancy |= person
    flow = uniform(*platform)
    flow[:, person] += np.array([1.0, 0.0])[:, None]  # one cell a frame to the right
    np.testing.assert_array_equal(moving_mask(occupancy, flow, MOVING_THRESHOLD), person)
    # Without compensation a driving platform makes the walls "move" too.
    if np.hypot(*platform) > MOVING_THRESHOLD:
        assert (moving_mask(occupancy, flow, compensate=False) & ~person).any()


def test_threshold_is_strict_and_compared_in_cells():
    occupancy = np.zeros((4, 4), bool)
    occupancy[1, 1] = occupancy[2, 2] = True
    flow = np.zeros((2, 4, 4))
    flow[:, 1, 1] = (0.3, 0.4)  # 0.5 cells
    flow[:, 2, 2] = (0.3, 0.41)
    mask = moving_mask(occupancy, flow, threshold=0.5, compensate=False)
    assert mask.tolist()[1][1] is False and mask.tolist()[2][2] is True


def test_flow_off_the_occupied_cells_is_ignored():
    occupancy = np.zeros((SIZE, SIZE), bool)
    occupancy[5, 5] = True
    assert not moving_mask(occupancy, uniform(3, 3), compensate=False)[~occupancy].any()


def test_too_few_cells_means_no_background_motion():
    occupancy = np.zeros((SIZE, SIZE), bool)
    occupancy[3, : MIN_BACKGROUND_CELLS - 1] = True
    assert not background_flow(occupancy, uniform(2, 0)).any()
    occupancy[3, :MIN_BACKGROUND_CELLS] = True
    np.testing.assert_allclose(background_flow(occupancy, uniform(2, 0)), uniform(2, 0), atol=1e-9)


def test_bad_inputs_are_refused_with_the_shapes():
    with pytest.raises(ValueError, match=r"flow must be \(2, H, W\)"):
        moving_mask(np.zeros((4, 4)), np.zeros((2, 4, 5)))
    with pytest.raises(ValueError, match="occupancy must be"):
        moving_mask(np.zeros(4), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="threshold"):
        moving_mask(np.zeros((4, 4)), np.zeros((2, 4, 4)), threshold=-1)


@settings(max_examples=30, deadline=None)
@given(occupancies)
def test_iou_of_a_mask_with_itself_is_one(mask):
    assert confusion(mask, mask).iou == 1.0


def test_iou_hand_computed():
    predicted = np.array([1, 1, 0, 0, 1], bool)
    truth = np.array([1, 0, 1, 0, 1], bool)
    assert confusion(predicted, truth).iou == pytest.approx(2 / 4)
    assert confusion(predicted, ~predicted).iou == 0.0
