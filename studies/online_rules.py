"""Compare rules for choosing the decision offsets online, from per-frame counts (issue 11).

For each held-out recording its fold model (``FOLDS/<recording>/run``) is streamed once, as
`lidarflow evaluate` does; every frame's true-positive / false-positive / false-negative counts
are kept for every pair of offsets of a wide grid (cells occupied / free in the last map moved
by the model's flow), over all cells and over the changed ones, and for the three baselines.
Any rule that picks a pair per frame from past frames only can then be replayed in
milliseconds. Two rules are replayed over the grid's sub-ranges and their constants:

- ``recent``: the pair with the largest win margin of its own recent (decayed) counts;
- ``lookahead`` (what :mod:`lidarflow.predict.decision` does): the pair that would leave the
  stream's margin largest if ``h`` more frames went as its recent ones did, after the decisions
  made so far.

Each rule is replayed with the pairs on the moved map only (``maps: moved``) and with every pair
also tried on the last map unmoved (``maps: both``, the head's ``g * O^t + r``; what the shipped
decision does).

The replay counts from the first scored frame; `lidarflow evaluate --online-decision` (whose
numbers the docs report) also counts the warm-up frames, so it differs in the last digits.

    python -m studies.online_rules --folds runs/studies/leave_one_out/head \\
        -o runs/studies/online_rules --recordings ../shared/data/{positive_1,positive_2}.bag

With ``--model M`` instead of ``--folds``, M runs on every recording: replayed on a fold's own
training recordings, the rules can be chosen there, fold-clean (see the docs' table).

Writes OUT/<recording>.npz (the counts) and OUT/rules.json (every rule's F1 / changed F1 and
margin per recording).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from lidarflow.baselines import ConstantVelocity, CopyLast, TemporalAverage
from lidarflow.data import Recording, load_any
from lidarflow.evaluate.ego import recording_motions
from lidarflow.evaluate.metrics import THRESHOLD, confusion
from lidarflow.evaluate.model_method import ModelMethod
from lidarflow.evaluate.runner import evaluate_maps
from lidarflow.models.presets import resolve_model
from lidarflow.predict.lookahead import f1_from_counts, lookahead_terms
from lidarflow.predict.offsets import moved_last_map, pair_counts_within
from lidarflow.scan import GridSpec
from studies.harness import parse, parser, read_json, stem, write_json, write_summary

OCCUPIED = np.round(np.arange(-4.8, 4.21, 0.3), 2)
FREE = np.round(np.arange(-0.6, 3.01, 0.3), 2)
LOGIT = float(np.log(THRESHOLD / (1.0 - THRESHOLD)))
#: The baselines the online decision weighs itself against (predict/decision.py): the three it
#: was built on, not every baseline evaluate reports (the tracker is not among them).
ONLINE_BASELINES = ("copy_last", "temporal_average", "constant_velocity")


def collect(
    model: Path, path: Path, occupied: np.ndarray = OCCUPIED, free: np.ndarray = FREE
) -> dict[str, np.ndarray]:
    """Per scored frame: ``pairs`` (T, A, B, 2 masks, tp/predicted/positives) on the moved map,
    ``unmoved`` (the same on the last map unmoved) and ``baselines`` (T, 3, 2, tp/...); the
    pairs of the ``occupied`` x ``free`` offsets."""
    net, _ = resolve_model(model)  # streamed with no decision: its calibrated probability
    gain = net.warp_gain()
    recording = load_any(path)
    occupancy, visibility = recording.maps(GridSpec())
    pairs, unmoved, baselines = [], [], {}

    def add(name: str, t: int, probability: np.ndarray, flow: np.ndarray | None) -> None:
        current, target = occupancy[t].astype(bool), occupancy[t + 1].astype(bool)
        if name == "model":
            logit = logit_of(probability)
            moved = moved_last_map(current, None if flow is None else flow[:2])
            last = current.astype(np.float64)
            for split, need, out in (
                (moved, LOGIT - logit, pairs),
                (last, LOGIT - (logit + gain * (last - moved)), unmoved),
            ):
                out.append(pair_frame(need, split, current, target, occupied, free))
        else:
            baselines.setdefault(name, []).append(threshold_counts(probability, current, target))

    stream_beside_baselines(net, recording, (occupancy, visibility), add)
    return {
        "pairs": np.array(pairs),
        "unmoved": np.array(unmoved),
        "baselines": np.array([baselines[b] for b in ONLINE_BASELINES], float).transpose(
            1, 0, 2, 3
        ),
    }


def stream_beside_baselines(
    net: torch.nn.Module,
    recording: Recording,
    maps: tuple[np.ndarray, np.ndarray],
    add: Callable[..., None],
) -> None:
    """Stream ``net`` (as "model", fixed offsets) and the three baselines over ``recording``
    (``maps``: its occupancy and visibility on the default grid) as `lidarflow evaluate` does
    (motions, sub-cell maps where the model takes them), calling ``add(name, t, probability,
    flow)`` for every prediction."""
    occupancy, visibility = maps
    methods = [ModelMethod("model", net, online=False)]
    methods += [CopyLast(), TemporalAverage(), ConstantVelocity()]
    motions = recording_motions(recording, GridSpec(), methods, occupancy)
    subcell = recording.subcell_maps(GridSpec()) if methods[0].takes.subcell else None
    evaluate_maps(
        occupancy, visibility, methods, on_prediction=add, motions=motions, subcell=subcell
    )


def logit_of(probability: np.ndarray) -> np.ndarray:
    """The logit of a probability map (float64, clipped away from 0 and 1)."""
    p = np.clip(probability.astype(np.float64), 1e-12, 1 - 1e-12)
    return np.log(p) - np.log1p(-p)


def pair_frame(
    need: np.ndarray,
    split: np.ndarray,
    current: np.ndarray,
    target: np.ndarray,
    occupied: np.ndarray,
    free: np.ndarray,
) -> np.ndarray:
    """One frame's counts ``(A, B, 2 masks, tp/predicted/positives)`` of every offset pair
    (:func:`pair_counts_within`), over all cells and over the cells that change."""
    frame = np.zeros((len(occupied), len(free), 2, 3))
    both = pair_counts_within(need, split, target, [None, current != target], occupied, free)
    for k, (tp, predicted, positives) in enumerate(both):
        frame[:, :, k] = np.stack([tp, predicted, np.full_like(tp, positives)], -1)
    return frame


def threshold_counts(
    probability: np.ndarray, current: np.ndarray, target: np.ndarray
) -> list[tuple[int, int, int]]:
    """``(tp, predicted, positives)`` at the metric's threshold, over all cells and over the
    cells that change (a baseline's frame)."""
    masks = (np.ones_like(target), current != target)
    both = [confusion(probability >= THRESHOLD, target, m) for m in masks]
    return [(c.tp, c.tp + c.fp, c.tp + c.fn) for c in both]


def f1(counts: np.ndarray) -> np.ndarray:
    """F1 of counts ``(..., tp / predicted / positives)``."""
    return f1_from_counts(counts[..., 0], counts[..., 1], counts[..., 2])


def replay(
    pairs: np.ndarray,
    baselines: np.ndarray,
    rule: str,
    decay: float,
    h: float,
    history: float = 1.0,
) -> np.ndarray:
    """The pair index chosen each frame (flattened over the grid) by ``rule``; ``history``:
    the decisions made and the baselines' counts weigh the past by it per frame
    (``OnlineDecisionConfig.history_decay``)."""
    frames, k = len(pairs), pairs.shape[1]
    # The library's layout: [mask, ..., (tp, predicted, positives)].
    pairs, baselines = pairs.transpose(0, 2, 1, 3), baselines.transpose(0, 2, 1, 3)
    made, base = np.zeros((2, 3)), np.zeros((2, 3, 3))  # since the start (x history)
    recent, recent_base, weight = np.zeros((2, k, 3)), np.zeros((2, 3, 3)), 0.0  # decayed
    chosen = np.zeros(frames, int)
    for t in range(frames):
        if t:
            if rule == "recent":  # each pair's own recent margin
                terms = lookahead_terms(np.zeros((2, 3)), recent, weight, recent_base, 1.0)
            else:
                terms = lookahead_terms(made, recent, weight, base, h)
            chosen[t] = int(np.argmax(terms.min(axis=0) + 1e-3 * terms.sum(axis=0)))
        made = history * made + pairs[t, :, chosen[t]]
        base = history * base + baselines[t]
        recent = decay * recent + pairs[t]
        recent_base = decay * recent_base + baselines[t]
        weight = decay * weight + 1.0
    return chosen


def margin(pairs: np.ndarray, baselines: np.ndarray, chosen: np.ndarray) -> tuple[float, ...]:
    total = pairs[np.arange(len(chosen)), chosen].sum(axis=0)
    best = f1(baselines.sum(axis=0)).max(axis=0)
    scores = f1(total)
    return float(scores[0]), float(scores[1]), float(min(scores - best))


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    p = parser("online_rules", __doc__)
    which = p.add_mutually_exclusive_group(required=True)
    which.add_argument("--folds", type=Path, help="each recording's model: FOLDS/<recording>/run")
    which.add_argument(
        "--model", type=Path, help="one model for every recording (e.g. a fold's own training set)"
    )
    p.add_argument("--recordings", type=Path, nargs="+", required=True)
    p.add_argument(
        "--choose-from", type=Path,
        help="with --folds: a folder of per-fold runs with --model on each fold's training "
        "recordings (TRAIN/<held-out recording>/rules.json); choose each fold's rule there",
    )  # fmt: skip
    args = parse(p, argv)
    args.output.mkdir(parents=True, exist_ok=True)
    data = {}
    for path in args.recordings:
        # the counts take one streaming pass of the model; every replay after it is cheap
        cache = args.output / f"{stem(path)}.npz"
        if not cache.exists() or "unmoved" not in np.load(cache).files:
            model = args.model or args.folds / stem(path) / "run"
            np.savez(cache, **collect(model, path))
        data[stem(path)] = dict(np.load(cache))
    results = replayed(data)
    write_summary(args, "rules", results, markdown(results))
    if args.choose_from:
        choose_fold_clean(results, args.choose_from, args.output / "chosen.json")
    return results


def replayed(data: dict[str, dict[str, np.ndarray]]) -> list[dict[str, Any]]:
    """Every rule (grid range, maps, rule and its constants) replayed on every recording's
    counts: its F1, changed-cell F1 and margin there, and the recordings it wins."""
    ranges = {"a -0.6..3.0": (-0.6, 3.0), "a -2.4..3.0": (-2.4, 3.0), "a -4.8..4.2": (-4.8, 4.2)}
    constants = [("recent", 0.98, 0), ("lookahead", 0.95, 5), ("lookahead", 0.98, 20)]
    constants += [("lookahead", 0.99, 100)]
    results = []
    for (label, (low, high)), maps, (rule, decay, h) in itertools.product(
        ranges.items(), ("moved", "both"), constants
    ):
        keep = np.abs(OCCUPIED - (low + high) / 2) <= (high - low) / 2 + 1e-9
        row: dict[str, Any] = {
            "grid": label, "maps": maps, "rule": rule, "decay": decay, "lookahead": h,
            "recordings": {},
        }  # fmt: skip
        for name, d in data.items():
            tried = [d["pairs"]] + ([d["unmoved"]] if maps == "both" else [])
            pairs = np.stack([t[:, keep] for t in tried], 1).reshape(len(d["pairs"]), -1, 2, 3)
            chosen = replay(pairs, d["baselines"], rule, decay, h)
            f, changed, m = margin(pairs, d["baselines"], chosen)
            row["recordings"][name] = {"f1": f, "changed_f1": changed, "margin": m}
        row["wins"] = sum(r["margin"] > 0 for r in row["recordings"].values())
        results.append(row)
    return results


def markdown(results: list[dict[str, Any]]) -> str:
    names = list(results[0]["recordings"])
    lines = [
        "| grid | maps | rule | decay | look-ahead | wins | " + " | ".join(names) + " |",
        "|---" * (6 + len(names)) + "|",
    ]
    for row in results:
        margins = [f"{row['recordings'][n]['margin']:+.4f}" for n in names]
        lines.append(
            f"| {row['grid']} | {row['maps']} | {row['rule']} | {row['decay']} | "
            f"{row['lookahead']} | {row['wins']} of {len(names)} | " + " | ".join(margins) + " |"
        )
    return "\n".join(lines) + "\n"


def choose_fold_clean(held_out: list[dict], train_dir: Path, out: Path) -> dict[str, Any]:
    """Per held-out recording: the rule (grid, rule, constants) with the largest summed margin
    on that fold's own training recordings (``train_dir/<recording>/rules.json``, written with
    ``--model``), and what it scores on the held-out recording."""
    key = ("grid", "maps", "rule", "decay", "lookahead")
    chosen = {}
    for name in held_out[0]["recordings"]:
        trained = read_json(train_dir / name / "rules.json")["results"]
        sums = [sum(r["margin"] for r in row["recordings"].values()) for row in trained]
        best = trained[int(np.argmax(sums))]
        rule = {k: best[k] for k in key}
        (row,) = [r for r in held_out if all(r[k] == rule[k] for k in key)]
        chosen[name] = {**rule, "training_margin": max(sums), **row["recordings"][name]}
    write_json(out, chosen)
    return chosen


if __name__ == "__main__":
    main()
