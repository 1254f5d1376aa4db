"""Pictures of calibration and moving cells."""

from __future__ import annotations

import numpy as np

from lidarflow.evaluate.calibration import Calibration
from lidarflow.viz.overlay import moving_rgb
from lidarflow.viz.plots import plot_reliability


def test_moving_colours_with_and_without_truth():
    occ = np.array([[1, 1, 1, 1, 0, 0]], bool)
    moving = np.array([[1, 1, 0, 0, 0, 0]], bool)
    truth = np.array([[1, 0, 1, 0, 0, 0]], bool)
    vis = np.array([[1, 1, 1, 1, 1, 0]], bool)
    img = moving_rgb(occ, moving, truth, vis, scale=2)
    assert img.shape == (2, 12, 3)
    both, found, missed, static, free, unseen = (img[0, 2 * k].tolist() for k in range(6))
    assert both == [240, 200, 0] and found == [220, 40, 40] and missed == [40, 180, 40]
    assert static == [90, 90, 90] and free == [255, 255, 255] and unseen == [225, 225, 225]
    plain = moving_rgb(occ, moving, scale=1)
    assert plain[0, 0].tolist() == [220, 40, 40] and plain[0, 2].tolist() == [90, 90, 90]


def test_reliability_diagram_is_written(tmp_path):
    rng = np.random.default_rng(0)
    p = rng.random(5000)
    good, binary = Calibration(), Calibration()
    good.add(p, rng.random(p.size) < p)
    binary.add(p > 0.5, rng.random(p.size) < p)
    png = plot_reliability(
        {"calibrated": good.summary(), "binary": binary.summary()}, tmp_path / "r.png", "t"
    )
    assert png.read_bytes()[:4] == b"\x89PNG"
