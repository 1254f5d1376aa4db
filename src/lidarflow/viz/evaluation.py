"""Figures of an evaluation run: overlay animations per method and PR curves per recording."""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from lidarflow.evaluate.metrics import THRESHOLD
from lidarflow.evaluate.scoring import Scorer
from lidarflow.viz.overlay import overlay_rgb, write_gif
from lidarflow.viz.plots import plot_pr_curves

__all__ = ["OverlayCollector", "pr_figure", "safe_stem"]


def safe_stem(path: str | Path) -> str:
    """A file-name-safe stem for a recording path (``a/b/run 1.bag`` -> ``run_1``)."""
    name = Path(path).name
    for suffix in (".bag.zip", ".bag", ".mcap", ".npz", ".db3"):
        if name.lower().endswith(suffix):
            name = name[: -len(suffix)]
            break
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "recording"


class OverlayCollector:
    """Collects the first ``max_frames`` scored predictions of each method as overlay frames
    (``evaluate_maps(..., on_prediction=collector)``) and writes them as GIFs."""

    def __init__(
        self, occupancy: np.ndarray, visibility: np.ndarray, max_frames: int = 100, scale: int = 3
    ) -> None:
        self.occupancy = occupancy
        self.visibility = visibility
        self.max_frames = max_frames
        self.scale = scale
        self.frames: dict[str, list[np.ndarray]] = {}

    def __call__(self, method: str, t: int, probability: np.ndarray) -> None:
        frames = self.frames.setdefault(method, [])
        if len(frames) < self.max_frames:
            frames.append(
                overlay_rgb(
                    probability >= THRESHOLD,
                    self.occupancy[t + 1],
                    self.visibility[t + 1],
                    self.scale,
                )
            )

    def write(self, folder: Path, stem: str, fps: float) -> list[tuple[str, Path]]:
        out = []
        for method, frames in self.frames.items():
            if frames:
                path = write_gif(frames, folder / f"{stem}_{method}.gif", fps=fps)
                out.append((f"{method}: prediction vs next map", path))
        return out


def pr_figure(scorers: Mapping[str, Scorer], path: Path, title: str) -> Path:
    curves = {}
    for name, scorer in scorers.items():
        _, precision, recall = scorer.pr_curve()
        curves[name] = (precision, recall, scorer.average_precision())
    return plot_pr_curves(curves, path, title)
