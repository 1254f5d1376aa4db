"""A self-contained HTML page of an evaluation: tables, PR curves, overlay animations, the
images embedded as data URIs so that the one file can be mailed or attached to an issue."""

from __future__ import annotations

import base64
import html
import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from lidarflow.atomic import write_text
from lidarflow.evaluate.report import (
    format_comparison,
    gaps_note,
    grid_note,
    uncertainty_rows,
    undefined_note,
)

__all__ = ["write_html_report"]

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
.table { overflow-x: auto; margin: 0.5em 0 1.5em; }
table { border-collapse: collapse; }
th, td { padding: 0.3em 0.6em; border-bottom: 1px solid #ddd; text-align: right; }
th { vertical-align: bottom; }
th:first-child, td:first-child { text-align: left; }
td.best { font-weight: bold; background: #eef7ee; }
figure { display: inline-block; margin: 0.5em; text-align: center; }
figcaption { font-size: 0.85em; color: #555; }
.legend span { padding: 0 0.5em; margin-right: 0.5em; }
"""
_MOVER = ("mover_f1", "mover_f1_tolerant", "mover_auc", "mover_soft_iou")
_COLUMNS = ("f1", "precision", "recall", "ap", "changed_f1", *_MOVER, "epe")
_BEST = ("f1", "changed_f1", *_MOVER)


def _data_uri(path: Path) -> str:
    mime = {".png": "image/png", ".gif": "image/gif"}[path.suffix.lower()]
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode()


def _breakable(name: str) -> str:
    """``name`` escaped, free to break after its underscores and slashes so that long names
    let a table fit the page."""
    return re.sub(r"([_/])", r"\1<wbr>", html.escape(name))


def _html_table(
    rows: Mapping[str, Mapping[str, float]], columns: Sequence[str], best: Mapping[str, float]
) -> str:
    """One row per method; a value equal to its column's ``best`` is bold."""
    head = "".join(f"<th>{_breakable(c)}</th>" for c in columns)
    body = []
    for name, row in rows.items():
        cells = []
        for c in columns:
            if c not in row:
                cells.append("<td>-</td>")
                continue
            cls = ' class="best"' if c in best and row[c] == best[c] else ""
            cells.append(f"<td{cls}>{row[c]:.4f}</td>")
        body.append(f"<tr><td>{_breakable(name)}</td>{''.join(cells)}</tr>")
    table = f"<table><tr><th>method</th>{head}</tr>{''.join(body)}</table>"
    return f"<div class='table'>{table}</div>"  # scrolls on its own where it cannot fit


def _table(methods: Mapping[str, Mapping[str, Any]]) -> str:
    rows = {name: {**m, **_mover_cells(m)} for name, m in methods.items()}
    present = [c for c in _COLUMNS if any(c in m for m in rows.values())]
    best = {c: max(m.get(c, float("-inf")) for m in rows.values()) for c in _BEST}
    return _html_table(rows, present, best)


def _mover_cells(metrics: Mapping[str, Any]) -> dict[str, float]:
    """The mover metric's AUC and soft IoU as flat columns (the F1s are flat already)."""
    movers = metrics.get("movers") or {}
    return {f"mover_{k}": movers[k] for k in ("auc", "soft_iou") if movers.get(k) is not None}


def _uncertainty_table(methods: Mapping[str, Mapping[str, Any]]) -> str:
    present, rows, best = uncertainty_rows({name: dict(m) for name, m in methods.items()})
    return _html_table(rows, present, best) if present else ""


def _comparison(compared: Mapping[str, Mapping[str, Any]]) -> str:
    lines = format_comparison(compared).splitlines()
    return "".join(f"<p><b>{html.escape(line)}</b></p>" for line in lines)


def _note(text: str) -> str:
    return f"<p>{html.escape(text)}</p>" if text else ""


def write_html_report(
    report: Mapping[str, Any],
    path: str | Path,
    figures: Mapping[str, Sequence[tuple[str, Path]]] | None = None,
    title: str = "lidarflow evaluation",
) -> Path:
    """Write ``report`` (the evaluate JSON) as one HTML page, under each recording's table
    its ``figures`` (path -> ``(caption, PNG or GIF file)`` pairs)."""
    figures = figures or {}
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>{html.escape(title)}</title><style>{_STYLE}</style></head><body>",
        f"<h1>{html.escape(title)}</h1>",
        "<p>F1 at threshold 0.4, micro-averaged over all cells of all frames after the warm-up; "
        "changed-cell F1 counts only cells that differ between the current and the next map "
        "(copying the last map scores 0 there). Mover F1 counts only the dynamic region: the "
        "cells occupied in under 5 % of the frames that saw them over the whole recording "
        "(world frame where the platform moves; the true moving objects' cells on simulated "
        "data), exactly and within 0.2 m (mover_f1_tolerant); mover_auc and mover_soft_iou "
        "score the probability there. A model wins only when it also beats copy-last's "
        "tolerant mover F1. Best values in bold.</p>",
        "<p>Second table: calibration of the predicted probabilities (expected calibration "
        "error over bins of 0.1 on all cells, the same on the cells predicted at least 0.1 "
        "(ece_active), and the Brier score; lower is better; see the reliability diagram) and, "
        "for flow models on simulated data, moving-object "
        "segmentation (IoU, precision and recall of the moving cells of the current map "
        "against the simulator's truth).</p>",
        "<p class='legend'>Overlays: <span style='background:#28b428'>truth only</span>"
        "<span style='background:#dc2828;color:white'>prediction only</span>"
        "<span style='background:#f0c800'>both</span>"
        "<span style='background:#e1e1e1'>not visible</span></p>",
    ]
    if len(report.get("recordings", [])) > 1:
        parts += ["<h2>Overall (micro-averaged)</h2>", _table(report["overall"])]
        parts.append(_note(undefined_note(report.get("undefined", []))))
        parts.append(_comparison(report.get("against_baselines", {})))
        parts.append(_uncertainty_table(report["overall"]))
    names = [Path(entry["path"]).name for entry in report.get("recordings", [])]
    for entry in report.get("recordings", []):
        name = Path(entry["path"]).name
        name = html.escape(entry["path"] if names.count(name) > 1 else name)
        evaluated = f"{entry['frames_evaluated']} frames evaluated{gaps_note(entry)}"
        parts.append(f"<h2>{name}</h2><p>{html.escape(evaluated)}</p>")
        parts.append(_table(entry["methods"]))
        parts.append(_note(undefined_note(entry.get("undefined", []))))
        if "grid" in report.get("config", {}):
            parts.append(_note(grid_note(entry, report["config"]["grid"])))
        parts.append(_comparison(entry.get("against_baselines", {})))
        parts.append(_uncertainty_table(entry["methods"]))
        for caption, image in figures.get(entry["path"], []):
            parts.append(
                f"<figure><img src='{_data_uri(Path(image))}' alt='{html.escape(caption)}'>"
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
            )
    if "config" in report:
        parts.append("<h2>Configuration</h2><pre>")
        parts.append(html.escape(json.dumps(report["config"], indent=2)))
        parts.append("</pre>")
    parts.append("</body></html>")
    return write_text(Path(path), "\n".join(parts))
