"""Evaluation reports: the JSON every script reads, and the table people read."""

from __future__ import annotations

import functools
import operator
from typing import Any

from lidarflow.evaluate.scoring import Scorer

__all__ = [
    "BASELINES",
    "UNCERTAINTY_COLUMNS",
    "build_report",
    "format_table",
    "format_uncertainty_table",
    "uncertainty_row",
    "uncertainty_rows",
]

BASELINES = ("copy_last", "temporal_average", "constant_velocity")
_COLUMNS = ("f1", "precision", "recall", "ap", "changed_f1", "epe")
#: Columns of the second table: calibration of the probabilities (lower is better) and
#: moving-object segmentation of the moving class (flow models on simulated data).
UNCERTAINTY_COLUMNS = (
    "ece", "ece_active", "brier", "moving_iou", "moving_precision", "moving_recall"
)
_LOWER_IS_BETTER = ("ece", "ece_active", "brier")


def build_report(
    per_recording: list[tuple[str, dict[str, Scorer]]], config: dict[str, Any] | None = None
) -> dict[str, Any]:
    """``{"recordings": [{"path", "frames_evaluated", "methods": {name: metrics}}],
    "overall": {name: metrics}}``; overall micro-averages (sums counts) over recordings."""
    recordings = []
    names: list[str] = []
    for path, scorers in per_recording:
        names.extend(n for n in scorers if n not in names)
        frames = max((s.frames for s in scorers.values()), default=0)
        recordings.append(
            {
                "path": path,
                "frames_evaluated": frames,
                "methods": {name: s.summary() for name, s in scorers.items()},
            }
        )
    overall = {
        name: functools.reduce(
            operator.add, (sc[name] for _, sc in per_recording if name in sc)
        ).summary()
        for name in names
    }
    report: dict[str, Any] = {"recordings": recordings, "overall": overall}
    if config:
        report["config"] = config
    return report


def _text_table(
    rows: dict[str, dict[str, Any]],
    columns: list[str],
    best: dict[str, Any],
    widths: dict[str, int],
    title: str,
) -> str:
    """One line per method; a value equal to its column's ``best`` (when not None) gets *."""
    width = max([len(n) for n in rows] + [6])
    lines = [title] if title else []
    lines.append(f"{'method':<{width}}  " + "  ".join(f"{c:>{widths[c]}}" for c in columns))
    for name, row in rows.items():
        cells = []
        for c in columns:
            if c not in row:
                cells.append(f"{'-':>{widths[c]}}")
                continue
            mark = "*" if best.get(c) is not None and row[c] == best[c] else " "
            cells.append(f"{row[c]:>{widths[c] - 1}.4f}{mark}")
        lines.append(f"{name:<{width}}  " + "  ".join(cells))
    return "\n".join(lines)


def format_table(methods: dict[str, dict[str, float]], title: str = "") -> str:
    """A plain-text table, one row per method; the best F1 / changed-cell F1 marked with *."""
    present = [c for c in _COLUMNS if any(c in m for m in methods.values())]
    best = {
        c: max((m[c] for m in methods.values() if c in m), default=None)
        for c in ("f1", "changed_f1")
    }
    return _text_table(methods, present, best, dict.fromkeys(present, 10), title)


def uncertainty_row(metrics: dict[str, Any]) -> dict[str, float]:
    """The :data:`UNCERTAINTY_COLUMNS` present in one method's metrics (from the nested
    ``calibration`` and ``segmentation`` entries of the report)."""
    row: dict[str, float] = {}
    calibration = metrics.get("calibration")
    if calibration:
        for key in ("ece", "ece_active", "brier"):
            if key in calibration:
                row[key] = calibration[key]
    segmentation = metrics.get("segmentation")
    if segmentation:
        row["moving_iou"] = segmentation["iou"]
        row["moving_precision"] = segmentation["precision"]
        row["moving_recall"] = segmentation["recall"]
    return row


def uncertainty_rows(
    methods: dict[str, dict[str, Any]],
) -> tuple[list[str], dict[str, dict[str, float]], dict[str, float]]:
    """``(columns present, {method: row}, {column: best value})`` of the uncertainty table:
    the best ECE and Brier are the lowest, the best segmentation scores the highest; a column
    that only one method has gets no best."""
    rows = {name: uncertainty_row(m) for name, m in methods.items()}
    present = [c for c in UNCERTAINTY_COLUMNS if any(c in r for r in rows.values())]
    best = {}
    for c in present:
        values = [r[c] for r in rows.values() if c in r]
        if len(values) > 1:
            best[c] = min(values) if c in _LOWER_IS_BETTER else max(values)
    return present, rows, best


def format_uncertainty_table(methods: dict[str, dict[str, Any]], title: str = "") -> str:
    """Calibration (ECE, active ECE, Brier: lower is better, best marked *) and moving-object
    segmentation (IoU, precision, recall of the moving class: higher is better); "" when no
    method has any of them."""
    present, rows, best = uncertainty_rows(methods)
    if not present:
        return ""
    widths = {c: max(len(c), 9) + 1 for c in present}
    return _text_table(rows, present, best, widths, title)
