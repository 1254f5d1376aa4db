"""Pictures: colours mean what the legend says; files are real images."""

from __future__ import annotations

import numpy as np

from lidarflow.flowcolor import flow_to_rgb
from lidarflow.viz.overlay import overlay_rgb, write_gif
from lidarflow.viz.plots import plot_pr_curves


def test_overlay_colours_and_scale():
    pred = np.array([[1, 1, 0, 0]], bool)
    truth = np.array([[1, 0, 1, 0]], bool)
    vis = np.array([[1, 1, 1, 0]], bool)
    img = overlay_rgb(pred, truth, vis, scale=2)
    assert img.shape == (2, 8, 3)
    yellow, red, green, grey = img[0, 0], img[0, 2], img[0, 4], img[0, 6]
    assert yellow.tolist() == [240, 200, 0] and red.tolist() == [220, 40, 40]
    assert green.tolist() == [40, 180, 40] and grey.tolist() == [225, 225, 225]


def test_flow_colours_distinguish_directions_and_zero_is_white():
    flow = np.zeros((2, 1, 5))
    flow[:, 0, 1] = (1, 0)
    flow[:, 0, 2] = (-1, 0)
    flow[:, 0, 3] = (0, 1)
    flow[:, 0, 4] = (0, -1)
    rgb = flow_to_rgb(flow)
    assert rgb[0, 0].tolist() == [255, 255, 255]
    colours = {tuple(rgb[0, k]) for k in range(1, 5)}
    assert len(colours) == 4
    half = flow_to_rgb(flow * 0.5, max_magnitude=1.0)
    assert half[0, 1].astype(int).sum() > rgb[0, 1].astype(int).sum()  # weaker flow, paler


def test_gif_and_pr_plot_are_written(tmp_path):
    frames = [
        overlay_rgb(np.roll(np.eye(4, dtype=bool), k, 1), np.eye(4, dtype=bool)) for k in range(3)
    ]
    gif = write_gif(frames, tmp_path / "a.gif")
    assert gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
    import imageio.v2 as imageio

    assert len(imageio.mimread(gif)) == 3
    png = plot_pr_curves(
        {"x": (np.array([1.0, 0.5]), np.array([0.2, 1.0]), 0.6)}, tmp_path / "pr.png", "t"
    )
    assert png.read_bytes()[:4] == b"\x89PNG"


def test_the_maps_picture_says_what_its_colours_mean(tmp_path, monkeypatch):
    from lidarflow.viz import maps

    drawn = []
    monkeypatch.setattr(maps, "save_figure", lambda fig, path: drawn.append(fig) or path)
    occupancy = np.zeros((10, 10), bool)
    occupancy[3, 4] = True
    flow = np.zeros((2, 10, 10))
    flow[0, 3, 4] = 1.0
    maps.draw_maps(occupancy, np.ones((10, 10)), tmp_path / "m.png", flow=flow, moving=occupancy)
    texts = [[t.get_text() for t in ax.get_legend().get_texts()] for ax in drawn[0].axes[:2]]
    assert texts[0] == ["occupied", "free or unseen", "sensor", "moving", "flow to the next frame"]
    assert texts[1][0] == "seen" and texts[1][1].startswith("unseen")
