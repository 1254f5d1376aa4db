"""The HTML report renders in a real browser: headless Chromium, which `scripts/test.sh` (the
README's test command, which `.ci/run` runs) installs (Debian's chromium-headless-shell) where it
is missing. Not skipped without it: it fails, saying
what to install, so that CI cannot pass without having looked at the page."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from lidarflow.evaluate.report import build_report
from lidarflow.evaluate.runner import evaluate_maps
from lidarflow.predict.baselines import CopyLast
from lidarflow.viz.html import write_html_report
from lidarflow.viz.overlay import overlay_rgb, write_gif

BROWSERS = ("chromium-headless-shell", "chromium", "chromium-browser")


def find_chromium() -> str:
    for name in BROWSERS:
        if found := shutil.which(name):
            return found
    pytest.fail(
        "no headless Chromium found (looked for " + ", ".join(BROWSERS) + "): "
        "apt-get install chromium-headless-shell, as scripts/test.sh does"
    )


def test_report_renders_in_headless_chromium(tmp_path):
    import imageio.v2 as imageio

    chromium = find_chromium()
    maps = np.zeros((14, 20, 20), bool)
    maps[:, 5:9, 5:9] = True
    report = build_report([("rec.npz", evaluate_maps(maps, maps, [CopyLast()], warmup=2))])
    gif = write_gif([overlay_rgb(maps[0], maps[1], scale=8)] * 2, tmp_path / "o.gif")
    page = write_html_report(report, tmp_path / "index.html", {"rec.npz": [("overlay", gif)]})
    shot = tmp_path / "shot.png"
    subprocess.run(
        [
            chromium,
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            f"--user-data-dir={tmp_path / 'profile'}",
            f"--screenshot={shot}",
            "--window-size=800,600",
            page.as_uri(),
        ],
        capture_output=True,
        timeout=120,
        check=False,
    )
    image = imageio.imread(shot)
    assert image.shape[0] == 600 and image.shape[1] == 800
    colours = {tuple(c) for c in image[..., :3].reshape(-1, 3)[::97]}
    assert len(colours) > 5  # text, table lines and the yellow overlay, not a blank page
    assert (np.abs(image[..., :3].astype(int) - [240, 200, 0]).sum(-1) < 30).any()
