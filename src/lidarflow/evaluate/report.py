"""Evaluation reports: the JSON every script reads, and the table people read."""

from __future__ import annotations

import functools
import operator
from collections.abc import Collection, Mapping, Sequence
from typing import Any

from lidarflow.evaluate.resampling import (
    LEVEL,
    MARGINS,
    add_intervals,
    lost_within_noise,
    within_noise,
)
from lidarflow.evaluate.scoring import Scorer

__all__ = [
    "BASELINES",
    "MOVER_KEY",
    "ORACLE_SUFFIX",
    "PEER_COLUMNS",
    "UNCERTAINTY_COLUMNS",
    "add_horizon_verdict",
    "against_baselines",
    "build_report",
    "count_recordings_won",
    "format_comparison",
    "format_peer_table",
    "format_table",
    "format_uncertainty_table",
    "gaps_note",
    "grid_note",
    "uncertainty_row",
    "uncertainty_rows",
    "undefined_metrics",
    "undefined_note",
]

#: The baselines a model must beat.
BASELINES = ("copy_last", "temporal_average", "constant_velocity", "tracker")
#: Names ending so are variants that know the true next pose: no deployable method, no verdict.
ORACLE_SUFFIX = "_oracle"
#: The verdict's mover metric (:mod:`lidarflow.evaluate.movers`), against copy-last's.
MOVER_KEY = "mover_f1_tolerant"
_COLUMNS = ("f1", "precision", "recall", "ap", "changed_f1", "mover_f1", MOVER_KEY, "epe")
#: Columns of the second table: calibration of the probabilities (lower is better) and
#: moving-object segmentation of the moving class (flow models on simulated data).
_CALIBRATION = ("ece", "ece_active", "brier")
UNCERTAINTY_COLUMNS = (*_CALIBRATION, "moving_iou", "moving_precision", "moving_recall")
_LOWER_IS_BETTER = (*_CALIBRATION, "wmse")
#: The peers' metrics (:mod:`lidarflow.evaluate.peer_metrics`): WMSE lower is better, SSIM higher.
PEER_COLUMNS = ("wmse", "ssim")


def build_report(
    per_recording: list[tuple[str, dict[str, Scorer]]], config: dict[str, Any] | None = None
) -> dict[str, Any]:
    """``{"recordings": [{"path", "frames_evaluated", "methods": {name: metrics},
    "against_baselines"}], "overall": {name: metrics}, "against_baselines"}``, overall summed
    over recordings (micro-averaged); ``"undefined"`` (:func:`undefined_metrics`) where a
    recording, or all of them, left a metric nothing to find."""
    recordings = []
    names: list[str] = []
    no_verdict = (config or {}).get("no_verdict")
    for path, scorers in per_recording:
        names.extend(n for n in scorers if n not in names)
        frames = max((s.frames for s in scorers.values()), default=0)
        entry: dict[str, Any] = {
            "path": path,
            "frames_evaluated": frames,
            "methods": {name: s.summary() for name, s in scorers.items()},
        }
        undefined = undefined_metrics(scorers)
        if undefined:
            entry["undefined"] = undefined
        entry["against_baselines"] = against_baselines(entry["methods"], undefined, no_verdict)
        add_intervals(entry["against_baselines"], scorers)
        recordings.append(entry)
    overall_scorers = {
        name: functools.reduce(operator.add, (sc[name] for _, sc in per_recording if name in sc))
        for name in names
    }
    overall = {name: s.summary() for name, s in overall_scorers.items()}
    overall_undefined = undefined_metrics(overall_scorers)
    compared = against_baselines(overall, overall_undefined, no_verdict)
    report: dict[str, Any] = {
        "recordings": recordings,
        "overall": overall,
        "against_baselines": compared,
    }
    count_recordings_won(report)
    if overall_undefined:
        report["undefined"] = overall_undefined
    if config:
        report["config"] = config
    return report


def undefined_metrics(scorers: Mapping[str, Scorer]) -> list[str]:
    """The metrics that had nothing to find in the frames ``scorers`` scored: ``f1``,
    ``recall`` and ``ap`` where no target cell was occupied, ``changed_f1`` where no changed
    cell became occupied, ``mover_f1`` where nothing moved. Their 0/0 values say nothing about
    a method, so the report flags them rather than let a blind recording read as perfect."""
    if not scorers:
        return []
    out = []
    if all(s.counts.tp + s.counts.fn == 0 for s in scorers.values()):
        out += ["f1", "recall", "ap"]
    if all(s.changed.tp + s.changed.fn == 0 for s in scorers.values()):
        out.append("changed_f1")
    movers = [s.movers for s in scorers.values() if s.movers.frames]
    if movers and not any(m.defined for m in movers):
        out.append("mover_f1")
    return out


def undefined_note(undefined: Sequence[str]) -> str:
    """The note under a table with ``undefined`` metrics, ``""`` without any."""
    if "f1" in undefined:
        return (
            "note: no occupied cell in any scored target frame (`lidarflow info` counts invalid "
            "beams): F1, recall, AP and changed-cell F1 have nothing to find (F1 is 1.0 for "
            "predicting nothing, 0 for predicting anything)"
        )
    notes = []
    if "changed_f1" in undefined:
        notes.append(
            "note: no cell becomes occupied in any scored frame: changed-cell F1 has nothing to "
            "find (1.0 for predicting no vanished cell occupied, else 0)"
        )
    if "mover_f1" in undefined:
        notes.append(
            "note: no occupied cell in the dynamic region of any scored target (nothing moved): "
            "the mover metric has nothing to find and does not decide the verdict"
        )
    return "\n".join(notes)


def against_baselines(
    methods: Mapping[str, Mapping[str, Any]],
    undefined: Collection[str] = (),
    no_verdict: Collection[str] | None = None,
) -> dict[str, dict[str, Any]]:
    """Each model among ``methods`` against the baselines: it wins when its F1 is above the
    best baseline's, its changed-cell F1 above every baseline's and its :data:`MOVER_KEY`
    above copy-last's. ``{name: {"wins", "f1_margin", "f1_baseline", "changed_f1_margin",
    "changed_f1_baseline", "mover_f1_margin"}}`` (the mover margin ``None`` where it cannot
    decide; ``"wins"`` ``None`` where F1 or changed-cell F1 is ``undefined``); ``{}`` without
    baselines. ``no_verdict``: the methods that get none, ``None`` to tell them by name
    (``copy_last_ego*``, ``*_oracle``)."""
    present = [b for b in BASELINES if b in methods]
    if not present:
        return {}
    best_f1 = max(present, key=lambda b: methods[b]["f1"])
    best_changed = max(present, key=lambda b: methods[b]["changed_f1"])
    out = {}
    for name, metrics in methods.items():
        if no_verdict is None:
            skip = name.startswith("copy_last_ego") or name.endswith(ORACLE_SUFFIX)
        else:
            skip = name in no_verdict
        if name in BASELINES or skip:
            continue
        f1_margin = metrics["f1"] - methods[best_f1]["f1"]
        changed_margin = metrics["changed_f1"] - methods[best_changed]["changed_f1"]
        mover_margin = _mover_margin(metrics, methods.get("copy_last"), undefined)
        # a margin on a metric with nothing to find is no win and no loss
        decided = not {"f1", "changed_f1"} & set(undefined)
        wins = f1_margin > 0 and changed_margin > 0 and (mover_margin is None or mover_margin > 0)
        out[name] = {
            "wins": bool(wins) if decided else None,
            "f1_margin": f1_margin,
            "f1_baseline": best_f1,
            "changed_f1_margin": changed_margin,
            "changed_f1_baseline": best_changed,
            "mover_f1_margin": mover_margin,
        }
    return out


def _mover_margin(
    metrics: Mapping[str, Any], copy_last: Mapping[str, Any] | None, undefined: Collection[str]
) -> float | None:
    if copy_last is None or "mover_f1" in undefined:
        return None
    if MOVER_KEY not in metrics or MOVER_KEY not in copy_last:
        return None
    return float(metrics[MOVER_KEY] - copy_last[MOVER_KEY])


def add_horizon_verdict(entry: dict[str, Any]) -> None:
    """Extend a recording's verdicts by the mover condition at its horizon: the tolerant
    mover F1 ``K`` ahead must be above copy-last's too. Adds ``mover_f1_horizon_margin``
    (``None`` where nothing moved); a no-op without horizon mover scores."""
    scores = entry.get("horizon_mover_f1_tolerant")
    if not scores or "copy_last" not in scores:
        return
    nothing = "mover_f1" in entry.get("horizon_undefined", [])
    for name, verdict in entry.get("against_baselines", {}).items():
        if name not in scores:
            continue
        margin = None if nothing else float(scores[name][-1] - scores["copy_last"][-1])
        verdict["mover_f1_horizon_margin"] = margin
        if margin is not None and "intervals" in verdict:
            interval = entry.get("horizon_mover_f1_tolerant_interval", {}).get(name)
            verdict["intervals"]["mover_f1_horizon"] = interval
        if margin is not None and margin <= 0 and verdict["wins"] is not None:
            verdict["wins"] = False


def count_recordings_won(report: dict[str, Any]) -> None:
    """Set the overall verdicts' ``recordings_won``, ``recordings_lost_within_noise``
    (:func:`~lidarflow.evaluate.resampling.lost_within_noise`), ``recordings`` and
    ``recordings_undecided`` from the recordings' verdicts."""
    for name, verdict in report.get("against_baselines", {}).items():
        verdicts = [
            e["against_baselines"][name]
            for e in report["recordings"]
            if name in e.get("against_baselines", {})
        ]
        verdict["recordings_won"] = sum(v["wins"] is True for v in verdicts)
        verdict["recordings_lost_within_noise"] = sum(lost_within_noise(v) for v in verdicts)
        verdict["recordings"] = len(verdicts)
        undecided = sum(v["wins"] is None for v in verdicts)
        verdict.pop("recordings_undecided", None)
        if undecided:
            verdict["recordings_undecided"] = undecided


def format_comparison(compared: Mapping[str, Mapping[str, Any]]) -> str:
    """One line per model of :func:`against_baselines`: its margins and whether it wins."""
    lines = []
    for name, v in compared.items():
        won = ""
        if "recordings_won" in v:
            won = f"; won {v['recordings_won']} of {v['recordings']} recordings"
            if v.get("recordings_lost_within_noise"):
                won += f" ({v['recordings_lost_within_noise']} more lost only within the noise)"
            if v.get("recordings_undecided"):
                won += f" ({v['recordings_undecided']} undecided)"
        verdict = {True: "wins", False: "loses", None: "undecided (nothing to find)"}[v["wins"]]
        movers = ""
        if v.get("mover_f1_margin") is not None:
            movers = f", tolerant mover F1 {v['mover_f1_margin']:+.4f} (copy_last"
            if v.get("mover_f1_horizon_margin") is not None:
                movers += f"; {v['mover_f1_horizon_margin']:+.4f} at the horizon"
            movers += ")"
        lines.append(
            f"{name} against the best baseline: F1 {v['f1_margin']:+.4f} ({v['f1_baseline']}), "
            f"changed-cell F1 {v['changed_f1_margin']:+.4f} ({v['changed_f1_baseline']})"
            f"{movers}: {verdict}{won}{_noise_note(v)}"
        )
    return "\n".join(lines)


def _noise_note(verdict: Mapping[str, Any]) -> str:
    """``"; within the noise ...: F1 -0.0012..+0.0034, ..."`` for the margins whose interval
    over the frames holds 0, else ``""``."""
    ties = within_noise(verdict) if verdict.get("wins") is not None else []
    if not ties:
        return ""
    spans = ", ".join(f"{MARGINS[n][1]} {low:+.4f}..{high:+.4f}" for n, low, high in ties)
    return f"; within the noise ({LEVEL:.0%} interval over the frames holds 0): {spans}"


def gaps_note(entry: Mapping[str, Any]) -> str:
    """``"; N gaps in time, not scored across"`` for an entry with gaps, else ``""``."""
    gaps = len(entry.get("gaps_not_scored", []))
    return f"; {gaps} gap{'s' * (gaps > 1)} in time, not scored across" if gaps else ""


def grid_note(entry: Mapping[str, Any], scored: Mapping[str, Any]) -> str:
    """The note for an entry recorded on another grid than the one it was ``scored`` on,
    ``""`` otherwise."""
    recorded = entry.get("recorded_grid")
    if not recorded:
        return ""
    note = (
        f"note: recorded on {_grid_text(recorded)}; scored on {_grid_text(scored)} "
        "(--grid/--res to change)"
    )
    if entry.get("ground_truth_not_scored"):
        note += "; ground-truth flow and moving cells not scored"
    return note


def _grid_text(grid: Mapping[str, Any]) -> str:
    return f"{grid['height']} x {grid['width']} x {grid['res']:g} m"


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
    """A plain-text table, one row per method; the best F1s marked with *."""
    present = [c for c in _COLUMNS if any(c in m for m in methods.values())]
    best = {
        c: max((m[c] for m in methods.values() if c in m), default=None)
        for c in ("f1", "changed_f1", "mover_f1", MOVER_KEY)
    }
    widths = {c: max(10, len(c) + 1) for c in present}
    return _text_table(methods, present, best, widths, title)


def uncertainty_row(metrics: dict[str, Any]) -> dict[str, float]:
    """The :data:`UNCERTAINTY_COLUMNS` present in one method's report metrics."""
    calibration = metrics.get("calibration") or {}
    row = {key: calibration[key] for key in _CALIBRATION if key in calibration}
    segmentation = metrics.get("segmentation")
    if segmentation:
        row.update({f"moving_{key}": segmentation[key] for key in ("iou", "precision", "recall")})
    return row


def uncertainty_rows(
    methods: dict[str, dict[str, Any]],
) -> tuple[list[str], dict[str, dict[str, float]], dict[str, float]]:
    """``(columns present, {method: row}, {column: best value})`` of the uncertainty table;
    a column that only one method has gets no best."""
    rows = {name: uncertainty_row(m) for name, m in methods.items()}
    present = [c for c in UNCERTAINTY_COLUMNS if any(c in r for r in rows.values())]
    return present, rows, _best(rows, present, least=2)


def format_uncertainty_table(methods: dict[str, dict[str, Any]], whose: str = "") -> str:
    """The calibration and moving segmentation table, best marked *, its title after
    ``whose`` ("overall "); "" when no method has any of them."""
    present, rows, best = uncertainty_rows(methods)
    if not present:
        return ""
    moving = any(c.startswith("moving_") for c in present)
    title = whose + ("calibration and moving segmentation" if moving else "calibration")
    widths = {c: max(len(c), 9) + 1 for c in present}
    return _text_table(rows, present, best, widths, title)


def format_peer_table(methods: Mapping[str, Mapping[str, Any]], title: str = "") -> str:
    """The peers' WMSE and SSIM, one row per method, best marked *; "" without them."""
    rows = {n: {c: m[c] for c in PEER_COLUMNS if c in m} for n, m in methods.items()}
    present = [c for c in PEER_COLUMNS if any(c in r for r in rows.values())]
    if not present:
        return ""
    return _text_table(rows, present, _best(rows, present), dict.fromkeys(present, 10), title)


def _best(rows: Mapping[str, Mapping[str, float]], columns: list[str], least: int = 1) -> dict:
    """Each column's best value (the lowest where lower is better), where ``least`` rows
    have one."""
    best = {}
    for c in columns:
        values = [r[c] for r in rows.values() if c in r]
        if len(values) >= least:
            best[c] = min(values) if c in _LOWER_IS_BETTER else max(values)
    return best
