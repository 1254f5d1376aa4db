"""Issue 44's mover tables for the flow model and the peers: the fold models of a
:mod:`studies.peer_comparison` study (its ``evaluate`` reports: `lidarflow evaluate --horizon K`,
which scores movers too) set beside a :mod:`studies.movers` study's summary (the default
recipe's fold models over their seeds, the baselines, the tracker, the ego-moved map)::

    python -m studies.peer_movers -o OUT --peers runs/peers \\
        --movers docs/research/carry_movers/summary.json

Both score every k over the same frames of the same recordings, so their baselines must agree:
copy-last's numbers are compared fold by fold (to the summary's four decimals) and a fold whose
do not is refused. Writes OUT/peer_movers.{md,json}: per fold and over the static, moving and
all folds, each method's F1, exact and tolerant mover F1 at k = 1 and K.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from studies.harness import parse, parser, read_json, write_summary
from studies.mover_tables import KEYS
from studies.peer_comparison import _model_of

#: the peer study's methods shown, with the names the table gives them
PEERS = {
    "flownet": "flow model (v8's recipe + carried movers)",
    "flownet_noflow": "the same, its flow set to zero",
    "deeptracking": "DeepTracking",
    "sogmp": "SOGMP",
}
#: the movers study's rows shown beside them
MOVERS = {
    "model": "default recipe (v10's)",
    "copy_last": "copy-last",
    "temporal_average": "temporal average",
    "tracker": "tracker",
    "copy_last_ego": "ego-moved last map",
}
COLUMNS = tuple(f"{key}_{k}" for k in ("1", "K") for key in KEYS)
#: the summary keeps four decimals
AGREE = 1e-4


def peer_rows(report: dict[str, Any], out: Path) -> dict[str, dict[str, float]]:
    """``{method: {f1_1, mover_f1_1, ..., mover_f1_tolerant_K}}`` of one held-out evaluation
    report, the models named as the peer study names them."""
    entry = report["recordings"][0]
    rows = {}
    for method in entry["horizon_f1"]:
        values = {key: entry[f"horizon_{key}"][method] for key in KEYS}
        rows[_model_of(method, report, out)] = {
            f"{key}_{k}": float(v[0] if k == "1" else v[-1])
            for key, v in values.items()
            for k in ("1", "K")
        }
    return rows


def merged(peers: Path, movers: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """Per fold: ``{"moving", "K", "rows": {name: {column: [mean, half-spread]}}}``, the movers
    summary's rows and the peer study's models, where both scored the fold."""
    folds = {}
    for path in sorted((peers / "evaluation").glob("*.json")):
        fold = movers["folds"].get(path.stem)
        if fold is None:
            continue
        theirs = peer_rows(read_json(path), peers)
        mine, copy_last = fold["scores"], theirs["copy_last"]
        off = [c for c in COLUMNS if abs(mine["copy_last"][c][0] - copy_last[c]) > AGREE]
        if off:
            raise SystemExit(f"{path.stem}: copy-last differs between the studies in {off}")
        rows = {MOVERS[m]: mine[m] for m in MOVERS if m in mine}
        rows.update(
            {PEERS[m]: {c: [v, 0.0] for c, v in theirs[m].items()} for m in PEERS if m in theirs}
        )
        folds[path.stem] = {"moving": fold["moving"], "K": fold["K"], "rows": rows}
    return folds


def means(folds: dict[str, dict[str, Any]]) -> dict[str, dict[str, dict[str, float]]]:
    """Over the static, moving and all folds: each method's mean where it scored every one."""
    groups = {
        "static": [f for f in folds.values() if not f["moving"]],
        "moving": [f for f in folds.values() if f["moving"]],
        "all": list(folds.values()),
    }
    out: dict[str, dict[str, dict[str, float]]] = {}
    for group, members in groups.items():
        if not members:
            continue
        names = [n for n in members[0]["rows"] if all(n in f["rows"] for f in members)]
        out[f"{group} ({len(members)})"] = {
            n: {c: float(np.mean([f["rows"][n][c][0] for f in members])) for c in COLUMNS}
            for n in names
        }
    return out


def table(folds: dict[str, dict[str, Any]], mean: dict[str, dict[str, dict[str, float]]]) -> str:
    head = (
        "| held-out (K) | method | F1 k=1 | mover F1 k=1 | tolerant k=1 | F1 ~1 s | "
        "mover F1 ~1 s | tolerant ~1 s |\n|---|---|---|---|---|---|---|---|\n"
    )
    lines = []
    for name, fold in folds.items():
        for method, row in fold["rows"].items():
            cells = [
                f"{row[c][0]:.3f}" + (f" ± {row[c][1]:.3f}" if row[c][1] else "")
                for c in COLUMNS
            ]
            lines.append(f"| {name} ({fold['K']}) | {method} | " + " | ".join(cells) + " |")
    for group, rows in mean.items():
        for method, row in rows.items():
            cells = [f"{row[c]:.3f}" for c in COLUMNS]
            lines.append(f"| **{group}** | {method} | " + " | ".join(cells) + " |")
    return head + "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("peer_movers", __doc__)
    p.add_argument("--peers", type=Path, required=True, help="a peer_comparison study's folder")
    p.add_argument("--movers", type=Path, required=True, help="a movers study's summary.json")
    args = parse(p, argv)
    if not args.movers.is_file():
        raise SystemExit(f"{args.movers}: no such movers summary")
    if not (args.peers / "evaluation").is_dir():
        raise SystemExit(f"{args.peers}: no evaluation/ folder (run peer_comparison evaluate)")
    folds = merged(args.peers, read_json(args.movers))
    if not folds:
        raise SystemExit(f"no fold scored by both {args.peers} and {args.movers}")
    mean = means(folds)
    results = {"folds": folds, "mean": mean}
    write_summary(args, "peer_movers", results, table(folds, mean))
    return results


if __name__ == "__main__":
    main()
