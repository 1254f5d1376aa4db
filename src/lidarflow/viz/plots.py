"""Plots of evaluation results: precision-recall curves of every method on one figure."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from lidarflow.viz.figures import pyplot, save_figure

__all__ = ["plot_epe_per_frame", "plot_pr_curves"]


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
