"""Prediction overlays as the paper shows them: truth green, prediction red, both yellow; and
moving-object overlays in the same colours over the current map."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

__all__ = ["moving_rgb", "overlay_rgb", "write_gif"]

_GREEN = np.array([40, 180, 40], np.uint8)
_RED = np.array([220, 40, 40], np.uint8)
_YELLOW = np.array([240, 200, 0], np.uint8)
_UNSEEN = np.array([225, 225, 225], np.uint8)
_STATIC = np.array([90, 90, 90], np.uint8)


def overlay_rgb(
    predicted: np.ndarray,
    truth: np.ndarray,
    visibility: np.ndarray | None = None,
    scale: int = 4,
) -> np.ndarray:
    """``(H*scale, W*scale, 3)`` uint8 image: truth only green, prediction only red, both
    yellow, free white, and (if ``visibility`` is given) cells not visible light grey.

    >>> overlay_rgb(np.array([[1, 0]], bool), np.array([[1, 1]], bool), scale=1)[0].tolist()
    [[240, 200, 0], [40, 180, 40]]
    """
    return _coloured(predicted, truth, visibility, None, scale)


def moving_rgb(
    occupancy: np.ndarray,
    moving: np.ndarray,
    truth: np.ndarray | None = None,
    visibility: np.ndarray | None = None,
    scale: int = 4,
) -> np.ndarray:
    """``(H*scale, W*scale, 3)`` uint8 picture of moving-object segmentation on the current map:
    occupied cells dark grey, cells found moving red; with ``truth`` (the true moving cells)
    truly moving cells that were missed green and those found yellow; not visible light grey.

    >>> occ = np.array([[1, 1, 1, 0]], bool)
    >>> moving_rgb(occ, np.array([[1, 0, 0, 0]], bool), np.array([[1, 1, 0, 0]], bool),
    ...            scale=1)[0].tolist()
    [[240, 200, 0], [40, 180, 40], [90, 90, 90], [255, 255, 255]]
    """
    truth = np.zeros(np.shape(moving), bool) if truth is None else truth
    return _coloured(moving, truth, visibility, occupancy, scale)


def _coloured(
    found: np.ndarray,
    truth: np.ndarray,
    visibility: np.ndarray | None,
    occupied: np.ndarray | None,
    scale: int,
) -> np.ndarray:
    """Only ``truth`` green, only ``found`` red, both yellow, on white, grey where ``occupied``
    and light grey where not visible; each cell ``scale`` x ``scale`` pixels."""
    p, t = np.asarray(found, bool), np.asarray(truth, bool)
    image = np.full((*p.shape, 3), 255, np.uint8)
    if visibility is not None:
        image[~np.asarray(visibility, bool)] = _UNSEEN
    if occupied is not None:
        image[np.asarray(occupied, bool)] = _STATIC
    image[t & ~p] = _GREEN
    image[p & ~t] = _RED
    image[p & t] = _YELLOW
    return np.repeat(np.repeat(image, scale, axis=0), scale, axis=1)


def write_gif(frames: Sequence[np.ndarray], path: str | Path, fps: float = 7.5) -> Path:
    """Write RGB frames as an animated GIF that loops."""
    import imageio.v3 as iio

    from lidarflow.atomic import write_bytes

    # encoded in memory: a writer that fails on a full disk is then ours to clean up, not a
    # file plugin that complains again when collected
    gif = iio.imwrite("<bytes>", list(frames), extension=".gif", duration=1000 / fps, loop=0)
    return write_bytes(path, gif)
