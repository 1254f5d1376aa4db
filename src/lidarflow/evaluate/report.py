"""Evaluation reports: the JSON every script reads, and the table people read."""

from __future__ import annotations

import functools
import operator
from typing import Any

from lidarflow.evaluate.scoring import Scorer

__all__ = ["BASELINES", "build_report", "format_table"]

BASELINES = ("copy_last", "temporal_average", "constant_velocity")
_COLUMNS = ("f1", "precision", "recall", "ap", "changed_f1", "epe")


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


def format_table(methods: dict[str, dict[str, float]], title: str = "") -> str:
    """A plain-text table, one row per method; the best F1 / changed-cell F1 marked with *."""
    present = [c for c in _COLUMNS if any(c in m for m in methods.values())]
    best = {
        c: max((m[c] for m in methods.values() if c in m), default=None)
        for c in ("f1", "changed_f1")
    }
    width = max([len(n) for n in methods] + [6])
    lines = [title] if title else []
    lines.append(f"{'method':<{width}}  " + "  ".join(f"{c:>10}" for c in present))
    for name, metrics in methods.items():
        cells = []
        for c in present:
            if c not in metrics:
                cells.append(f"{'-':>10}")
                continue
            mark = "*" if best.get(c) is not None and metrics[c] == best[c] else " "
            cells.append(f"{metrics[c]:>9.4f}{mark}")
        lines.append(f"{name:<{width}}  " + "  ".join(cells))
    return "\n".join(lines)
