"""The HTML report renders in a real browser: headless Chromium, which `scripts/test.sh` (the
README's test command, which `.ci/run` runs) installs (Debian's chromium-headless-shell) where it
is missing. Not skipped without it: it fails, saying
what to install, so that CI cannot pass without having looked at the page."""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from lidarflow.baselines import CopyLast
from lidarflow.evaluate.report import build_report
from lidarflow.evaluate.runner import evaluate_maps
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


def _table_fit(chromium: str, page, tmp_path, width: int) -> tuple[int, int]:
    """The first table's (scrollWidth, clientWidth) in pixels, laid out by Chromium at
    ``width`` pixels: a table wider than its box is cut off or scrolls."""
    probe = tmp_path / "probe.html"
    measure = (
        "<script>const t = document.querySelector('table');"
        "const box = t.parentElement.tagName === 'BODY' ? document.body : t.parentElement;"
        "document.title = 'fit ' + t.scrollWidth + ' ' + box.clientWidth;</script>"
    )
    probe.write_text(page.read_text().replace("</body>", measure + "</body>"))
    done = subprocess.run(
        [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         f"--user-data-dir={tmp_path / 'profile2'}", f"--window-size={width},800",
         "--dump-dom", probe.as_uri()],
        capture_output=True, text=True, timeout=120, check=False,
    )  # fmt: skip
    found = re.search(r"<title>fit (\d+) (\d+)</title>", done.stdout)
    assert found, done.stdout[-500:] + done.stderr[-500:]
    return int(found[1]), int(found[2])


def test_the_first_table_fits_a_1200_pixel_window(tmp_path):
    # every column the main table can have, and a long method name
    columns = ("f1", "precision", "recall", "ap", "changed_f1", "mover_f1", "mover_f1_tolerant",
               "mover_auc", "mover_soft_iou", "epe")  # fmt: skip
    methods = {name: dict.fromkeys(columns, 0.123456) for name in
               ("copy_last", "temporal_average", "constant_velocity", "tracker",
                "copy_last_ego", "runs/my_robot_head_only_seed_1")}  # fmt: skip
    report = {"recordings": [{"path": "rec.npz", "frames_evaluated": 10, "methods": methods,
                              "against_baselines": {}}], "config": {}}  # fmt: skip
    page = write_html_report(report, tmp_path / "index.html", {})
    wide, room = _table_fit(find_chromium(), page, tmp_path, 1200)
    assert wide <= room, (wide, room)
