"""A piece of the static scene moved partway through a window (``data.static_shift``)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from lidarflow.train.augment import shift_patch
from lidarflow.train.data import Windows


def _window(seed: int, t: int = 12, size: int = 40) -> np.ndarray:
    rng = np.random.default_rng(seed)
    window = np.zeros((t, 2, size, size), dtype=bool)
    window[:, 0] = rng.random((size, size)) < 0.05  # the same static scene every frame
    window[:, 1] = rng.random((size, size)) < 0.6
    return window


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), first=st.integers(0, 10))
def test_one_box_moves_from_one_frame_on_and_stays_moved(seed: int, first: int) -> None:
    window = _window(seed)
    before = window.copy()
    out = shift_patch(window, np.random.default_rng(seed), first, max_half=4, max_step=2)
    assert np.array_equal(window, before)  # the recording's maps are not touched
    changed = np.nonzero((out != window).any(axis=(1, 2, 3)))[0]
    if len(changed) == 0:
        return
    k = changed[0]
    assert first <= k <= len(window) - 2
    assert np.array_equal(changed, np.arange(k, len(window)))  # moved from k on, for good
    # Where it differs is one box, the same in every frame; the scene is static, so the moved
    # frames are all the same map.
    diff = (out[k:] != window[k:]).any(axis=(0, 1))
    ys, xs = np.nonzero(diff)
    assert ys.max() - ys.min() <= 8 and xs.max() - xs.min() <= 8
    assert (out[k:] == out[k]).all()
    # Inside the box the content is the scene moved by an integer step of at most 2 cells.
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    found = False
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            src = window[k, :, y0 + dy : y1 + dy, x0 + dx : x1 + dx]
            if src.shape == out[k, :, y0:y1, x0:x1].shape and np.array_equal(
                src, out[k, :, y0:y1, x0:x1]
            ):
                found = True
    assert found


def test_an_empty_window_is_served_unchanged() -> None:
    window = np.zeros((10, 2, 30, 30), dtype=bool)
    out = shift_patch(window, np.random.default_rng(0), 4)
    assert np.array_equal(out, window)


def test_only_windows_of_a_sensor_standing_still_are_shifted() -> None:
    maps = [_window(1, t=400), _window(2, t=400)]
    motions = [np.zeros((400, 3), np.float32), np.full((400, 3), 0.5, np.float32)]
    index = [(r, s) for r in range(2) for s in range(0, 380, 4)]
    windows = Windows(maps, index, 12, motions=motions, static_shift=0.5, shift_first=5)
    shifted = [windows.shifted(i) for i in range(len(index))]
    still = [s for s, (r, _) in zip(shifted, index, strict=True) if r == 0]
    assert not any(s for s, (r, _) in zip(shifted, index, strict=True) if r == 1)
    assert 0.3 < np.mean(still) < 0.7
    assert shifted == [windows.shifted(i) for i in range(len(index))]  # fixed per window
    i = shifted.index(True)
    maps_i = windows[i][0].numpy().astype(bool)
    rec, start = index[i]
    assert not np.array_equal(maps_i, maps[rec][start : start + 12])
    assert np.array_equal(maps_i[:5], maps[rec][start : start + 5])
    plain = Windows(maps, index, 12, motions=motions)
    assert not any(plain.shifted(i) for i in range(len(index)))
