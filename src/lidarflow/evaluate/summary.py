"""The text ``evaluate`` prints: per recording its tables and notes, then the overall ones.
Each function returns the text without a trailing newline; a section a report lacks is left out.
"""

from __future__ import annotations

from typing import Any

from lidarflow.evaluate.horizon import horizon_note
from lidarflow.evaluate.labels import CEILING, RADIUS
from lidarflow.evaluate.report import (
    format_comparison,
    format_peer_table,
    format_table,
    format_uncertainty_table,
    gaps_note,
    grid_note,
    undefined_note,
)

__all__ = [
    "HORIZON_TABLES",
    "format_horizon",
    "format_labels",
    "format_overall",
    "format_recording",
]

_PEER_TITLE = "peers' metrics (mean per frame; WMSE lower is better, SSIM higher)"
#: The horizon tables, report key and title, in the order printed.
HORIZON_TABLES = (
    ("horizon_f1", "F1"),
    ("horizon_changed_f1", "changed F1"),
    ("horizon_wmse", "WMSE"),
    ("horizon_ssim", "SSIM"),
    ("horizon_mover_f1", "mover F1"),
    ("horizon_mover_f1_tolerant", "tolerant mover F1"),
    ("horizon_mover_auc", "mover AUC"),
    ("horizon_mover_soft_iou", "mover soft IoU"),
)


def format_horizon(scores: dict[str, list[float | None]], what: str = "F1") -> str:
    """A table of ``scores`` per method at k = 1..K (``-`` where a score is undefined)."""
    k = len(next(iter(scores.values())))
    title = f"{what} per horizon step"
    width = max(24, len(title) + 2, *(len(name) + 2 for name in scores))
    lines = [f"{title:<{width}}" + "".join(f"{f'k={i + 1}':>10}" for i in range(k))]
    for name, values in scores.items():
        cells = "".join(f"{'-':>10}" if v is None else f"{v:>10.4f}" for v in values)
        lines.append(f"{name:<{width}}{cells}")
    return "\n".join(lines)


def format_labels(legs: dict[str, dict[str, list[Any]]], kind: str = "legs") -> str:
    """The labelled movers' table: recall and precision per method at ``k = 1`` and the last
    ``k``, the best of each column marked *; the scan's own row, recall's ceiling, last."""
    k = len(next(iter(legs.values()))["recall"])
    columns = [(key, i) for key in ("recall", "precision") for i in ([0] if k == 1 else [0, k - 1])]
    rows = {name: [one[key][i] for key, i in columns] for name, one in legs.items()}
    best = [max((r[j] for n, r in rows.items() if n != CEILING and r[j] is not None), default=None)
            for j in range(len(columns))]  # fmt: skip
    counts = legs.get(CEILING, next(iter(legs.values())))
    title = (
        f"labelled {kind} within {RADIUS:g} m ({counts['labelled'][0]} {kind} on "
        f"{counts['frames'][0]} frames at k=1; precision in the dynamic region)"
    )
    width = max(24, *(len(name) + 12 for name in rows))
    header = "".join(f"{f'{key} k={i + 1}':>15}" for key, i in columns)
    lines = [title, f"{'method':<{width}}{header}"]
    for name in [*(n for n in rows if n != CEILING), *([CEILING] if CEILING in rows else [])]:
        cells = ""
        for j, v in enumerate(rows[name]):
            mark = "*" if name != CEILING and v == best[j] else " "
            cells += f"{'-':>15}" if v is None else f"{v:>14.4f}{mark}"
        label = f"{name} (ceiling)" if name == CEILING else name
        lines.append(f"{label:<{width}}{cells}")
    return "\n".join(lines)


def format_recording(entry: dict[str, Any], grid: dict[str, Any]) -> str:
    """A recording's report ``entry`` as printed: its tables, notes (a grid other than
    ``grid`` among them) and verdicts."""
    title = f"{entry['path']} ({entry['frames_evaluated']} frames{gaps_note(entry)})"
    parts = [format_table(entry["methods"], title)]
    parts += [n for n in (undefined_note(entry.get("undefined", [])), grid_note(entry, grid)) if n]
    comparison = format_comparison(entry["against_baselines"])
    parts.append(comparison + "\n" if comparison else "")
    if "horizon_f1" in entry:
        parts.append(horizon_note(entry) + "\n")
        parts += [format_horizon(entry[k], what) + "\n" for k, what in HORIZON_TABLES if k in entry]
    if "legs" in entry:
        parts.append(format_labels(entry["legs"], entry.get("legs_kind", "legs")) + "\n")
    for extra in (
        format_uncertainty_table(entry["methods"]),
        format_peer_table(entry["methods"], _PEER_TITLE),
    ):
        if extra:
            parts.append(extra + "\n")
    return "\n".join(parts)


def format_overall(report: dict[str, Any]) -> str:
    """The overall (micro-averaged) tables of a report of several recordings."""
    parts = [format_table(report["overall"], "overall (micro-averaged)")]
    note = undefined_note(report.get("undefined", []))
    if note:
        parts.append(note)
    if report["against_baselines"]:
        parts.append(format_comparison(report["against_baselines"]))
    for extra in (
        format_uncertainty_table(report["overall"], "overall "),
        format_peer_table(report["overall"], f"overall {_PEER_TITLE}"),
    ):
        if extra:
            parts.append(extra)
    return "\n".join(parts)
