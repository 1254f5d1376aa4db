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
from lidarflow.motion.odometry import pose_jumps
from lidarflow.predict.baselines import Method
from lidarflow.scan import GridSpec
from lidarflow.viz.html import write_html_report
from lidarflow.viz.overlay import moving_rgb, overlay_rgb, write_gif
from lidarflow.viz.plots import plot_epe_per_frame, plot_pr_curves, plot_reliability

__all__ = [
    "OverlayCollector",
    "evaluate_and_report",
    "finish_report",
    "pr_figure",
    "recording_notes",
    "safe_stem",
    "score_and_draw",
    "unique_stems",
]


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


def unique_stems(names: Sequence[str]) -> list[str]:
    """A file-name stem per recording name (:func:`safe_stem`), numbered where two share one
    (``a/run.bag``, ``b/run.bag`` -> ``run``, ``run_2``): the pictures of two recordings must
    not share a file."""
    stems: list[str] = []
    for name in names:
        stem, n = safe_stem(name), 1
        while stem in stems:
            n += 1
            stem = f"{safe_stem(name)}_{n}"
        stems.append(stem)
    return stems


def score_and_draw(
    name: str,
    recording: Recording,
    methods: Sequence[Method],
    grid: GridSpec,
    warmup: int,
    report_dir: Path | None = None,
    stem: str | None = None,
    gif_frames: int = 100,
    progress: Callable[[int], None] | None = None,
) -> tuple[dict[str, Scorer], list[tuple[str, Path]]]:
    """Score ``methods`` on one recording; with ``report_dir``, draw its PR curves, reliability
    diagram and overlay GIFs there (files named by ``stem``). Returns the scorers and the
    figures (caption, path). One recording's share of :func:`evaluate_and_report`, which
    ``evaluate --jobs`` runs in a worker process per recording."""
    collector = None
    if report_dir is not None:
        collector = OverlayCollector(*streamed_maps(recording, grid), max_frames=gif_frames)
    scorers = evaluate_recording(
        recording,
        methods,
        grid,
        warmup,
        progress,
        collector,
        None if collector is None else collector.add_moving,
    )
    if report_dir is None or collector is None:
        return scorers, []
    stem = stem or safe_stem(name)
    title = f"{Path(name).name}: PR curves"
    pr = pr_figure(scorers, report_dir / f"{stem}_pr.png", title)
    gifs = collector.write(report_dir, stem, fps=recording.frame_rate or 10.0)
    reliability = plot_reliability(
        {m: sc.calibration.summary() for m, sc in scorers.items()},
        report_dir / f"{stem}_reliability.png",
        f"{Path(name).name}: reliability",
    )
    figures = [("precision-recall", pr), ("reliability diagram", reliability), *gifs]
    epe = {m: s.epe_per_frame for m, s in scorers.items() if s.epe_per_frame}
    if epe:
        plot = plot_epe_per_frame(epe, report_dir / f"{stem}_epe.png", f"{Path(name).name}")
        figures.append(("flow end-point error per frame", plot))
    return scorers, figures


def recording_notes(recording: Recording, grid: GridSpec) -> dict[str, Any]:
    """What a recording's report entry says beside its scores: the gaps not scored across,
    and a grid it was recorded on other than ``grid``."""
    notes: dict[str, Any] = {}
    gaps = find_gaps(recording)
    if gaps:  # steps not scored: the frame after a gap is not the next scan
        notes["gaps_not_scored"] = [{"before_frame": i, "seconds": round(s, 3)} for i, s in gaps]
    jumps = pose_jumps(recording.poses, recording.stamps_ns)
    if jumps:  # odometry glitches: the mover region is counted in the world by these poses
        notes["pose_jumps"] = len(jumps)
        notes["first_pose_jumps"] = [{"before_frame": t, "metres": d} for t, d in jumps[:10]]
    recorded = other_recorded_grid(recording, grid)
    # a real recording is rasterized on any grid alike; a simulated one's ground truth
    # was made on its own grid and is not scored on another
    if recorded is not None and has_ground_truth(recording):
        notes["recorded_grid"] = recorded
        notes["ground_truth_not_scored"] = True
    return notes


def finish_report(
    scored: Sequence[tuple[str, dict[str, Scorer]]],
    notes: Sequence[Mapping[str, Any]],
    config: dict[str, Any],
    report_dir: Path | None = None,
    figures: Mapping[str, list[tuple[str, Path]]] | None = None,
) -> dict[str, Any]:
    """The report of the recordings ``scored`` (name, scorers), in order, each entry with its
    :func:`recording_notes`; with ``report_dir``, ``report.json`` and ``index.html`` written
    there too, showing ``figures`` (per recording name)."""
    report = build_report(list(scored), config)
    for entry, extra in zip(report["recordings"], notes, strict=True):
        entry.update(extra)
    if report_dir is not None:
        report_dir.mkdir(parents=True, exist_ok=True)
        write_text(report_dir / "report.json", json.dumps(report, indent=2))
        write_html_report(report, report_dir / "index.html", figures or {})
    return report


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
    names = [name for name, _ in named_recordings]
    for (name, recording), stem in zip(named_recordings, unique_stems(names), strict=True):
        bar = progress(name, len(recording) - 1) if progress else contextlib.nullcontext()
        with bar as b:
            scorers, drawn = score_and_draw(
                name, recording, methods, grid, warmup, report_dir, stem, gif_frames,
                getattr(b, "update", None),
            )  # fmt: skip
        results.append((name, scorers))
        if report_dir is not None:
            figures[name] = drawn
    notes = [recording_notes(recording, grid) for _, recording in named_recordings]
    return finish_report(results, notes, config, report_dir, figures)
