"""Figures of an evaluation run: overlay animations per method (predictions, flow, moving
cells), PR curves and reliability diagrams per recording."""

from __future__ import annotations

import contextlib
import json
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.atomic import write_text
from lidarflow.data.blocks import Frames, streamed_maps
from lidarflow.data.info import find_gaps
from lidarflow.data.recording import Recording
from lidarflow.evaluate.metrics import THRESHOLD
from lidarflow.evaluate.report import build_report
from lidarflow.evaluate.scoring import Scorer
from lidarflow.evaluate.stream import (
    evaluate_recording,
    has_ground_truth,
    other_recorded_grid,
)
from lidarflow.flowcolor import flow_to_rgb
from lidarflow.predict.baselines import Method
from lidarflow.scan import GridSpec
from lidarflow.viz.html import write_html_report
from lidarflow.viz.overlay import moving_rgb, overlay_rgb, write_gif
from lidarflow.viz.plots import plot_epe_per_frame, plot_pr_curves, plot_reliability

__all__ = ["OverlayCollector", "evaluate_and_report", "pr_figure", "safe_stem"]


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
        self, occupancy: Frames, visibility: Frames, max_frames: int = 100, scale: int = 3
    ) -> None:
        self.occupancy = occupancy
        self.visibility = visibility
        self.max_frames = max_frames
        self.scale = scale
        self.frames: dict[str, list[np.ndarray]] = {}
        self.flow_frames: dict[str, list[np.ndarray]] = {}
        self.moving_frames: dict[str, list[np.ndarray]] = {}
        self.moving_has_truth = False

    def add_moving(
        self, method: str, t: int, moving: np.ndarray, truth: np.ndarray | None = None
    ) -> None:
        """Draw one frame's moving cells on ``O^t`` (``evaluate_maps(..., on_moving=...)``)."""
        frames = self.moving_frames.setdefault(method, [])
        if len(frames) < self.max_frames:
            self.moving_has_truth |= truth is not None
            frames.append(
                moving_rgb(self.occupancy[t], moving, truth, self.visibility[t], self.scale)
            )

    def add_flow(self, method: str, flow: np.ndarray) -> None:
        """Colour-code a backward flow ``(2, H, W)`` (colour wheel, 3 cells = full colour)."""
        frames = self.flow_frames.setdefault(method, [])
        if len(frames) < self.max_frames:
            rgb = flow_to_rgb(flow, max_magnitude=3.0)
            frames.append(np.repeat(np.repeat(rgb, self.scale, axis=0), self.scale, axis=1))

    def __call__(
        self, method: str, t: int, probability: np.ndarray, flow: np.ndarray | None = None
    ) -> None:
        if flow is not None:
            self.add_flow(method, flow)
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
        for method, frames in self.flow_frames.items():
            if frames:
                path = write_gif(frames, folder / f"{stem}_{method}_flow.gif", fps=fps)
                out.append((f"{method}: backward flow (colour wheel, 3 cells = full colour)", path))
        for method, frames in self.moving_frames.items():
            if frames:
                path = write_gif(frames, folder / f"{stem}_{method}_moving.gif", fps=fps)
                legend = (
                    "found red, missed green, both yellow"
                    if self.moving_has_truth
                    else "moving red, static grey"
                )
                out.append((f"{method}: moving cells ({legend})", path))
        return out


def pr_figure(scorers: Mapping[str, Scorer], path: Path, title: str) -> Path:
    curves = {}
    for name, scorer in scorers.items():
        _, precision, recall = scorer.pr_curve()
        curves[name] = (precision, recall, scorer.average_precision())
    return plot_pr_curves(curves, path, title)


def evaluate_and_report(
    named_recordings: Sequence[tuple[str, Recording]],
    methods: Sequence[Method],
    grid: GridSpec,
    warmup: int,
    config: dict[str, Any],
    report_dir: Path | None = None,
    gif_frames: int = 100,
    progress: Callable[[str, int], Any] | None = None,
) -> dict[str, Any]:
    """Score ``methods`` on each recording; with ``report_dir``, also write PR curves, overlay
    GIFs, ``report.json`` and a self-contained ``index.html`` there. Returns the report.

    ``progress(name, total)`` may return a context manager with ``update(n)`` (a tqdm bar)."""
    results = []
    figures: dict[str, list[tuple[str, Path]]] = {}
    stems: set[str] = set()
    for name, recording in named_recordings:
        collector = None
        if report_dir is not None:
            collector = OverlayCollector(*streamed_maps(recording, grid), max_frames=gif_frames)
        bar = progress(name, len(recording) - 1) if progress else contextlib.nullcontext()
        with bar as b:
            scorers = evaluate_recording(
                recording,
                methods,
                grid,
                warmup,
                getattr(b, "update", None),
                collector,
                None if collector is None else collector.add_moving,
            )
        results.append((name, scorers))
        if report_dir is not None and collector is not None:
            # two recordings of one file name (a/run.bag, b/run.bag) must not share pictures
            stem, n = safe_stem(name), 1
            while stem in stems:
                n += 1
                stem = f"{safe_stem(name)}_{n}"
            stems.add(stem)
            title = f"{Path(name).name}: PR curves"
            pr = pr_figure(scorers, report_dir / f"{stem}_pr.png", title)
            gifs = collector.write(report_dir, stem, fps=recording.frame_rate or 10.0)
            reliability = plot_reliability(
                {m: sc.calibration.summary() for m, sc in scorers.items()},
                report_dir / f"{stem}_reliability.png",
                f"{Path(name).name}: reliability",
            )
            figures[name] = [("precision-recall", pr), ("reliability diagram", reliability), *gifs]
            epe = {m: s.epe_per_frame for m, s in scorers.items() if s.epe_per_frame}
            if epe:
                plot = plot_epe_per_frame(epe, report_dir / f"{stem}_epe.png", f"{Path(name).name}")
                figures[name].append(("flow end-point error per frame", plot))
    report = build_report(results, config)
    for entry, (_, recording) in zip(report["recordings"], named_recordings, strict=True):
        gaps = find_gaps(recording)
        if gaps:  # steps not scored: the frame after a gap is not the next scan
            entry["gaps_not_scored"] = [
                {"before_frame": i, "seconds": round(s, 3)} for i, s in gaps
            ]
        recorded = other_recorded_grid(recording, grid)
        # a real recording is rasterized on any grid alike; a simulated one's ground truth
        # was made on its own grid and is not scored on another
        if recorded is not None and has_ground_truth(recording):
            entry["recorded_grid"] = recorded
            entry["ground_truth_not_scored"] = True
    if report_dir is not None:
        report_dir.mkdir(parents=True, exist_ok=True)
        write_text(report_dir / "report.json", json.dumps(report, indent=2))
        write_html_report(report, report_dir / "index.html", figures)
    return report
