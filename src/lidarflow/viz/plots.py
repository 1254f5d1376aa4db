"""Plots of evaluation results: precision-recall curves, flow error per frame and reliability
diagrams, every method on one figure."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.viz.figures import pyplot, save_figure

__all__ = ["plot_epe_per_frame", "plot_pr_curves", "plot_reliability"]


def plot_pr_curves(
    curves: Mapping[str, tuple[np.ndarray, np.ndarray, float]], path: str | Path, title: str = ""
) -> Path:
    """``curves`` maps a method name to ``(precision, recall, average_precision)``."""
    plt = pyplot()

    fig, ax = plt.subplots(figsize=(5.5, 5), constrained_layout=True)
    for name, (precision, recall, ap) in curves.items():
        ax.plot(recall, precision, label=f"{name} (AP {ap:.3f})", drawstyle="steps-post")
    ax.set_xlabel("recall")
    ax.set_ylabel("precision")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left")
    if title:
        ax.set_title(title)
    return save_figure(fig, path)


def plot_epe_per_frame(
    series: Mapping[str, Sequence[float]], path: str | Path, title: str = ""
) -> Path:
    """Flow end-point error (cells) per evaluated frame, one line per method."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 3.5), constrained_layout=True)
    for name, values in series.items():
        ax.plot(np.arange(len(values)), values, label=f"{name} (mean {np.nanmean(values):.3f})")
    ax.set_xlabel("evaluated frame")
    ax.set_ylabel("EPE on occupied cells (cells)")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right")
    if title:
        ax.set_title(title)
    return save_figure(fig, path)


def plot_reliability(
    calibrations: Mapping[str, Mapping[str, Any]], path: str | Path, title: str = ""
) -> Path:
    """Reliability diagram: per method (``calibrations`` maps its name to the report's
    ``calibration`` entry, :meth:`lidarflow.evaluate.calibration.Calibration.summary`) the
    observed frequency of occupancy against the mean predicted probability of each bin, with
    the diagonal of perfect calibration; below, the cells per bin (log scale)."""
    plt = pyplot()
    fig, (ax, counts) = plt.subplots(
        2, 1, figsize=(5.5, 6.5), sharex=True, height_ratios=(3, 1), constrained_layout=True
    )
    ax.plot([0, 1], [0, 1], color="grey", linestyle="--", linewidth=1, label="calibrated")
    for i, (name, cal) in enumerate(calibrations.items()):
        bins = [b for b in cal["bins"] if b["count"]]
        mean = [b["mean_probability"] for b in bins]
        active = f", active {cal['ece_active']:.3f}" if "ece_active" in cal else ""
        ax.plot(
            mean,
            [b["frequency"] for b in bins],
            marker="o",
            label=f"{name} (ECE {cal['ece']:.4f}{active}, Brier {cal['brier']:.4f})",
        )
        width = 1.0 / (len(cal["bins"]) * (len(calibrations) + 1))
        centres = [(b["low"] + b["high"]) / 2 + (i - len(calibrations) / 2) * width for b in bins]
        counts.bar(centres, [b["count"] for b in bins], width=width, label=name)
    ax.set_ylabel("observed frequency of occupancy")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize="small")
    counts.set_yscale("log")
    counts.set_xlabel("predicted probability (bin)")
    counts.set_ylabel("cells")
    counts.grid(alpha=0.3)
    if title:
        ax.set_title(title)
    return save_figure(fig, path)
