"""The tables of :mod:`studies.movers` (issue 44): per fold and aggregated, each method's F1,
exact and tolerant mover F1 at k = 1 and K, the verdicts against the issue's targets, the people
shares and the simulated recordings, from a movers study's folder (its evaluation/ and sim/
reports). `python -m studies.movers` writes them itself; this rebuilds them alone::

    python -m studies.mover_tables -o runs/movers_tables --study runs/movers

Writes OUT/movers.{md,json} and OUT/summary.json (k = 1 and K only: what the page keeps).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from studies.harness import BASELINES, RUNS, parse, parser, read_json, write_json, write_summary

EGO = "copy_last_ego"
#: scored beside the fold models, in-sample (trained on every development recording)
REFERENCES = {"flownet_v8": "tests/fixtures/flownet_v8", "bundled_v9": "bundled"}
KEYS = ("f1", "mover_f1", "mover_f1_tolerant")


def ego_moved(scores: dict[str, Any]) -> bool:
    """Whether the ego-moved map (the motion matched from the scans where a recording has no
    poses: datmo_overtakes) differs from copy-last one step ahead by more than 0.01 F1: the
    platform moved. On a standing platform the matched motion is about zero and the two agree."""
    if EGO not in scores:
        return False
    return abs(at(scores[EGO], "f1", "1") - at(scores["copy_last"], "f1", "1")) > 0.01


def at(row: dict[str, list[float]], key: str, k: str) -> float:
    values = row[key]
    return float(values[0] if k == "1" else values[-1])


def model_stats(scores: dict, seeds: Sequence[str], key: str, k: str) -> tuple[float, float]:
    """Mean and half-spread (half of max - min) of the fold models' ``key`` at ``k``."""
    values = [at(scores[s], key, k) for s in seeds]
    return float(np.mean(values)), (max(values) - min(values)) / 2


def baselines_of(fold: dict) -> list[str]:
    """The baselines a fold is judged against: the four, and the ego-moved map where the
    platform moved."""
    return [b for b in (*BASELINES, *([EGO] if fold["moving"] else [])) if b in fold["scores"]]


def targets(fold: dict) -> dict[str, dict[str, Any]]:
    """Issue 44's targets for one held-out recording: each ``{"model", "bar", "margin",
    "spread", "said"}``; ``said`` is ``met``, ``missed``, or ``tie`` where the margin is
    within the spread over training seeds (max - min; ``None`` with one seed, said so)."""
    s, seeds = fold["scores"], fold["fold_models"]
    cl = s["copy_last"]
    best = {k: max(at(s[b], "f1", k) for b in baselines_of(fold)) for k in ("1", "K")}
    bars: dict[str, tuple[str, str, float]] = {
        "exact mover F1 k=1 > copy-last": ("mover_f1", "1", at(cl, "mover_f1", "1")),
        "exact mover F1 ~1 s > copy-last": ("mover_f1", "K", at(cl, "mover_f1", "K")),
        "F1 k=1 > best baseline": ("f1", "1", best["1"]),
        "F1 ~1 s > best baseline": ("f1", "K", best["K"]),
    }
    tol = "mover_f1_tolerant"
    if fold["moving"]:
        if EGO in s:
            bars["tolerant mover F1 ~1 s > ego-moved map"] = (tol, "K", at(s[EGO], tol, "K"))
        bars["tolerant mover F1 ~1 s > tracker"] = (tol, "K", at(s["tracker"], tol, "K"))
    else:
        bars["tolerant mover F1 k=1 >= copy-last + 0.02"] = (tol, "1", at(cl, tol, "1") + 0.02)
        bars["tolerant mover F1 ~1 s >= 1.5 x copy-last"] = (tol, "K", 1.5 * at(cl, tol, "K"))
        bars["tolerant mover F1 ~1 s > tracker"] = (tol, "K", at(s["tracker"], tol, "K"))
    out = {}
    for name, (key, k, bar) in bars.items():
        values = [at(s[m], key, k) for m in seeds]
        mean = float(np.mean(values))
        # with one seed there is no spread to call a tie by: said so
        spread = max(values) - min(values) if len(values) > 1 else None
        margin = mean - bar
        above = margin >= 0 if ">=" in name else margin > 0
        said = "met" if above else "missed"
        if spread is None:
            said += " (1 seed)"
        elif abs(margin) < spread:
            said = "tie"
        out[name] = {"model": mean, "bar": bar, "margin": margin, "spread": spread, "said": said}
    return out


def collect(out: Path) -> dict[str, Any]:
    folds = {p.stem: read_json(p) for p in sorted((out / "evaluation").glob("*.json"))}
    for fold in folds.values():
        fold["moving"] = fold["moving"] or ego_moved(fold["scores"])
        fold["targets"] = targets(fold) if fold["fold_models"] else {}
    sims = {p.stem: read_json(p) for p in sorted((out / "sim").glob("*.json"))}
    return {"folds": folds, "aggregate": aggregate(folds), "sims": sims}


def method_order(fold: dict) -> list[str]:
    order = ["model", *BASELINES, EGO, *REFERENCES]
    return [m for m in order if m == "model" or m in fold["scores"]]


def summary_rows(fold: dict) -> dict[str, dict[str, tuple[float, float]]]:
    """``{method: {"f1_1": (value, half-spread), ...}}`` of a fold, the fold models as one
    ``model`` (mean and half-spread), everything else with a half-spread of 0."""
    rows: dict[str, dict[str, tuple[float, float]]] = {}
    for method in method_order(fold):
        row = {}
        for key in KEYS:
            for k in ("1", "K"):
                if method == "model":
                    row[f"{key}_{k}"] = model_stats(fold["scores"], fold["fold_models"], key, k)
                else:
                    row[f"{key}_{k}"] = (at(fold["scores"][method], key, k), 0.0)
        rows[method] = row
    return rows


def aggregate(folds: dict[str, dict]) -> dict[str, dict[str, dict[str, float]]]:
    """Mean over the folds of each group (all, static, moving) of each method's scores (the
    fold model: the mean over its seeds), with the methods every fold of the group has."""
    groups = {
        "all": list(folds),
        "static": [f for f in folds if not folds[f]["moving"]],
        "moving": [f for f in folds if folds[f]["moving"]],
    }
    out: dict[str, dict[str, dict[str, float]]] = {}
    for group, names in groups.items():
        if not names:
            continue
        rows = [summary_rows(folds[n]) for n in names if folds[n]["fold_models"]]
        if not rows:
            continue
        common = [m for m in rows[0] if all(m in r for r in rows)]
        out[group] = {
            m: {c: float(np.mean([r[m][c][0] for r in rows])) for c in rows[0][m]} for m in common
        }
        out[group]["folds"] = {"n": float(len(rows))}
    return out


def table(study: dict[str, Any]) -> str:
    """Markdown: per held-out recording every method at k = 1 and ~1 s, the aggregates, the
    targets, the people shares and the simulated recordings."""
    cols = [f"{key}_{k}" for k in ("1", "K") for key in KEYS]
    head = (
        "| held-out (K) | method | F1 k=1 | mover F1 k=1 | tolerant k=1 | F1 ~1 s | "
        "mover F1 ~1 s | tolerant ~1 s |\n|---|---|---|---|---|---|---|---|"
    )
    lines = ["## Per fold (fold model: mean ± half-spread over its seeds)", "", head]
    for rec, fold in study["folds"].items():
        if not fold["fold_models"]:
            continue
        seeds = "+".join(fold["fold_models"])
        for method, row in summary_rows(fold).items():
            name = f"head_only ({seeds})" if method == "model" else method
            if method in REFERENCES:
                name += " (in-sample)"
            spread = method == "model" and len(fold["fold_models"]) > 1
            cells = [
                f"{v:.3f} ± {h:.3f}" if spread else f"{v:.3f}" for v, h in (row[c] for c in cols)
            ]
            lines.append(f"| {rec} ({fold['K']}) | {name} | " + " | ".join(cells) + " |")
    lines += ["", "## Mean over folds", "", head.replace("held-out (K)", "folds")]
    for group, rows in study["aggregate"].items():
        n = int(rows["folds"]["n"])
        for method, row in rows.items():
            if method == "folds":
                continue
            cells = [f"{row[c]:.3f}" for c in cols]
            lines.append(f"| {group} ({n}) | {method} | " + " | ".join(cells) + " |")
    lines += ["", "## Issue 44's targets (tie: margin within the seeds' spread)", ""]
    lines += ["| held-out | target | model | bar | margin | spread | said |", "|" + "---|" * 7]
    for rec, fold in study["folds"].items():
        for name, t in fold["targets"].items():
            spread = "–" if t["spread"] is None else f"{t['spread']:.3f}"
            lines.append(
                f"| {rec} | {name} | {t['model']:.3f} | {t['bar']:.3f} | {t['margin']:+.3f} | "
                f"{spread} | {t['said']} |"
            )
    for rec, fold in study["folds"].items():
        if "people" not in fold:
            continue
        k = fold["K"]
        lines += ["", f"## People covered at t+k on {rec} (within 0.3 m)", ""]
        lines += ["| method | " + " | ".join(f"k={i}" for i in range(1, k + 1)) + " |"]
        lines += ["|---|" + "---|" * k]
        for method, got in fold["people"].items():
            shares = ["" if v is None else f"{v:.3f}" for v in got["share"]]
            lines.append(f"| {method} | " + " | ".join(shares) + " |")
        counted = fold["people"]["copy_last"]["counted"]
        lines.append("| people counted | " + " | ".join(str(c) for c in counted) + " |")
        check = ", ".join(f"{lag}: {v:.3f}" for lag, v in fold["people_stamp_check"].items())
        lines += ["", f"On their own scan, by the lag of the stamp (scan periods): {check}"]
    if study["sims"]:
        lines += ["", "## Simulated recordings (region: the true movers' cells)", ""]
        lines += [head.replace("held-out (K)", "recording (K)")]
        for name, sim in study["sims"].items():
            s = sim["scores"]
            for method in s:
                cells = [f"{at(s[method], key, k):.3f}" for k in ("1", "K") for key in KEYS]
                lines.append(f"| {name} ({sim['K']}) | {method} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def summary(study: dict[str, Any]) -> dict[str, Any]:
    """The study at k = 1 and K only (what the research page keeps): per fold each method's
    F1, exact and tolerant mover F1 (the fold models' mean and half-spread), the targets, the
    people shares; the aggregates; the simulated recordings."""
    folds = {}
    for rec, fold in study["folds"].items():
        if not fold["fold_models"]:
            continue
        rows = {
            m: {c: [round(v, 4), round(h, 4)] for c, (v, h) in r.items()}
            for m, r in summary_rows(fold).items()
        }
        folds[rec] = {
            "K": fold["K"],
            "moving": fold["moving"],
            "fold_models": fold["fold_models"],
            "scores": rows,
            "targets": {
                n: {k: (round(v, 4) if isinstance(v, float) else v) for k, v in t.items()}
                for n, t in fold["targets"].items()
            },
        }
        for key in ("people", "people_stamp_check"):
            if key in fold:
                folds[rec][key] = fold[key]
    sims = {
        name: {
            "K": sim["K"],
            "scores": {
                m: {f"{key}_{k}": round(at(row, key, k), 4) for k in ("1", "K") for key in KEYS}
                for m, row in sim["scores"].items()
            },
        }
        for name, sim in study["sims"].items()
    }
    for sim in sims.values():  # the fold models together: mean, min and max
        models = [r for m, r in sim["scores"].items() if m not in (*BASELINES, EGO)]
        if models:
            values = {c: [r[c] for r in models] for c in models[0]}
            sim["fold_models"] = {
                c: [round(float(f(v)), 4) for f in (np.mean, min, max)] for c, v in values.items()
            }
    return {"folds": folds, "aggregate": study["aggregate"], "sims": sims}


def write_tables(out: Path, command: str, study: dict[str, Any], args: Any) -> None:
    """OUT/movers.{md,json} and OUT/summary.json of ``study``."""
    write_summary(args, "movers", study, table(study))
    write_json(out / "summary.json", {"command": command, **summary(study)})


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("mover_tables", __doc__)
    p.add_argument("--study", type=Path, default=RUNS / "movers", help="the movers study's -o")
    args = parse(p, argv)
    study = collect(args.study)
    write_tables(args.output, args.command, study, args)
    return study


if __name__ == "__main__":
    main()
