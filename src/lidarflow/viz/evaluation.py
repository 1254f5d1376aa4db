"""Figures of an evaluation run (:class:`ReportFigures`, what ``lidarflow.evaluate.evaluation``
is handed to draw): overlay GIFs, PR curves, reliability diagrams and the HTML report."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.atomic import write_text
from lidarflow.data.blocks import Frames
from lidarflow.data.recording import Recording
from lidarflow.evaluate.metrics import THRESHOLD
from lidarflow.evaluate.scoring import Scorer
from lidarflow.evaluate.stream import RecordingInputs
from lidarflow.flowcolor import flow_to_rgb
from lidarflow.viz.html import write_html_report
from lidarflow.viz.overlay import moving_rgb, overlay_rgb, write_gif
from lidarflow.viz.plots import plot_epe_per_frame, plot_pr_curves, plot_reliability

__all__ = ["OverlayCollector", "RecordingDrawing", "ReportFigures", "pr_figure"]


class OverlayCollector:
    """Collects the first ``max_frames`` scored predictions of each method as overlay frames
    (the runner's ``on_prediction``) and writes them as GIFs."""

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
        """Draw one frame's moving cells on ``O^t`` (the runner's ``on_moving``)."""
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
        """Write the GIFs as ``folder/{stem}_{method}[_flow|_moving].gif``; (caption, path)."""
        if self.moving_has_truth:
            legend = "found red, missed green, both yellow"
        else:
            legend = "moving red, static grey"
        kinds = (
            (self.frames, "", "prediction vs next map"),
            (self.flow_frames, "_flow", "backward flow (colour wheel, 3 cells = full colour)"),
            (self.moving_frames, "_moving", f"moving cells ({legend})"),
        )
        out = []
        for kept, suffix, caption in kinds:
            for method, frames in kept.items():
                if frames:
                    path = write_gif(frames, folder / f"{stem}_{method}{suffix}.gif", fps=fps)
                    out.append((f"{method}: {caption}", path))
        return out


def pr_figure(scorers: Mapping[str, Scorer], path: Path, title: str) -> Path:
    curves = {}
    for name, scorer in scorers.items():
        _, precision, recall = scorer.pr_curve()
        curves[name] = (precision, recall, scorer.average_precision())
    return plot_pr_curves(curves, path, title)


@dataclass(frozen=True)
class ReportFigures:
    """Draws an evaluation's pictures into ``folder`` (overlay GIFs of the first ``gif_frames``
    scored predictions), then writes ``report.json`` and a self-contained ``index.html``.
    Picklable: ``evaluate --jobs`` hands it to its workers."""

    folder: Path
    gif_frames: int = 100

    def recording(
        self, name: str, stem: str, recording: Recording, inputs: RecordingInputs
    ) -> RecordingDrawing:
        rate = recording.frame_rate or 10.0
        return RecordingDrawing(self.folder, name, stem, inputs, self.gif_frames, rate)

    def write(self, report: dict[str, Any], figures: Mapping[str, list[tuple[str, Path]]]) -> None:
        self.folder.mkdir(parents=True, exist_ok=True)
        write_text(self.folder / "report.json", json.dumps(report, indent=2))
        write_html_report(report, self.folder / "index.html", figures)


class RecordingDrawing:
    """One recording's share of :class:`ReportFigures`: overlays collected while it streams,
    the rest drawn by :meth:`finish`."""

    def __init__(
        self,
        folder: Path,
        name: str,
        stem: str,
        inputs: RecordingInputs,
        gif_frames: int,
        frame_rate: float,
    ) -> None:
        self.folder, self.name, self.stem, self.frame_rate = folder, name, stem, frame_rate
        self.collector = OverlayCollector(inputs.occupancy, inputs.visibility, gif_frames)
        self.on_prediction = self.collector
        self.on_moving = self.collector.add_moving

    def finish(self, scorers: Mapping[str, Scorer]) -> list[tuple[str, Path]]:
        """Draw the PR curves, reliability diagram, overlays and any end-point error per frame;
        returns them (caption, path)."""
        folder, stem, title = self.folder, self.stem, Path(self.name).name
        pr = pr_figure(scorers, folder / f"{stem}_pr.png", f"{title}: PR curves")
        gifs = self.collector.write(folder, stem, fps=self.frame_rate)
        reliability = plot_reliability(
            {m: sc.calibration.summary() for m, sc in scorers.items()},
            folder / f"{stem}_reliability.png",
            f"{title}: reliability",
        )
        figures = [("precision-recall", pr), ("reliability diagram", reliability), *gifs]
        epe = {m: s.epe_per_frame for m, s in scorers.items() if s.epe_per_frame}
        if epe:
            plot = plot_epe_per_frame(epe, folder / f"{stem}_epe.png", title)
            figures.append(("flow end-point error per frame", plot))
        return figures
