"""How far can a cell's own history go? A reference point for issue 11's ablation.

Fit ``P(O^{t+1} = 1 | the cell's last K values)`` (a table of 2^K counts, no network, no
neighbours, no flow) on training recordings, then predict held-out recordings with it at the
design's threshold 0.4 and score F1 and changed-cell F1 exactly as `lidarflow evaluate` does
(frames t >= 10 predicted, every cell of the 100 x 100 grid). It shows what calibrated,
history-only decisions give: where they beat copy-last in F1, and how low their changed-cell
F1 stays beside the temporal average's.

    python experiments/history_rule.py --train ../shared/data/positive_{1,3,4}.bag \\
        --eval ../shared/data/positive_2.bag --k 3 5 8 --json history_rule.json

``--oracle`` asks a different question: can any decision made from a cell's own past win a
recording at all? It fits the table on each ``--eval`` recording *itself* (in-sample, so an
upper bound for history-only rules of that length, not a method) and sweeps the decision
threshold, reporting each point's F1 / changed-cell F1 beside the best baselines' and whether
any threshold beats them on both (the issue's "wins").

    python experiments/history_rule.py --oracle --eval ../shared/data/positive_4.bag \\
        --k 5 8 10 --json history_oracle_positive_4.json

``--causal S ...`` is a method again, leave-one-out: each ``--eval`` recording is predicted
with the table of the *other* ``--eval`` recordings as a prior (its counts weighted by ``S``)
that every frame of the held-out stream updates once its next map has arrived (causal), with
two thresholds (cells occupied now / free now). It reports the pair of thresholds with the
best margin over the best baselines, chosen in hindsight (an upper bound for the choice):

    python experiments/history_rule.py --causal 0 0.003 0.03 0.3 --k 8 10 12 \\
        --eval ../shared/data/{positive_1,positive_2,positive_3,positive_4}.bag \\
        ../shared/data/demo_stationary_simple_environment.bag --json history_causal.json

With ``--subcell`` (``--causal``) the table is also keyed by where the returns
lie inside their cells (:func:`lidarflow.scan.subcell_batch`: the cell's returns all at its
border; a neighbour's return against its edge), 4x the keys: how much a cell's next value
depends on that, beyond its history (docs/results/accuracy/positive_4/subcell/).

With ``--model RUN`` the table is also keyed by the bin of that model's probability
(:data:`PROBABILITY_BINS`): the model's output calibrated on each cell's history, the prior from
the model run on the other recordings. ``RUN`` must not have trained on the held-out recordings
(``--held-out``, a leave-one-out fold model), which it reports beside the model alone:

    python experiments/history_rule.py --causal 0.03 0.3 1 3 --k 8 \\
        --model runs/loo/cell/head_cell/positive_4/run --held-out positive_4.bag \\
        --eval ../shared/data/{positive_1,positive_2,positive_3,positive_4}.bag \\
        ../shared/data/demo_stationary_simple_environment.bag --json model_history_causal.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from lidarflow.data import Recording, load_any
from lidarflow.evaluate.metrics import f1_score
from lidarflow.evaluate.stream import evaluate_maps
from lidarflow.predict.baselines import ConstantVelocity, CopyLast, TemporalAverage
from lidarflow.scan import GridSpec

WARMUP = 10
THRESHOLD = 0.4
ORACLE_THRESHOLDS = (0.2, 0.25, 0.3, 0.35, 0.4, 0.45, 0.5, 0.55, 0.6)


def history_codes(occupancy: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Per cell and frame ``t >= k - 1``: the code of ``O^{t-k+1} .. O^t`` (bits, oldest
    first) and the target ``O^{t+1}``; frames ``k - 1 .. N - 2``."""
    o = occupancy.astype(np.int64)
    code = np.zeros_like(o[k - 1 : -1])
    for j in range(k):
        code = code * 2 + o[j : len(o) - k + j]
    return code, occupancy[k:].astype(bool)


def fit(recordings: list[np.ndarray], k: int) -> np.ndarray:
    """``P(next occupied | code)`` for the ``2^k`` codes (0 where a code was never seen)."""
    ones, total = np.zeros(2**k), np.zeros(2**k)
    for occupancy in recordings:
        code, target = history_codes(occupancy, k)
        np.add.at(total, code.ravel(), 1)
        np.add.at(ones, code.ravel(), target.ravel())
    return ones / np.maximum(total, 1)


def scored_frames(occupancy: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Codes, targets and current maps of the frames `lidarflow evaluate` scores (t >= 10)."""
    code, target = history_codes(occupancy, k)
    skip = max(0, WARMUP - (k - 1))  # code index i predicts frame k + i from frame k - 1 + i
    return code[skip:], target[skip:], occupancy[k - 1 : -1][skip:].astype(bool)


def score(
    table: np.ndarray, occupancy: np.ndarray, k: int, threshold: float = THRESHOLD
) -> dict[str, float]:
    code, target, current = scored_frames(occupancy, k)
    predicted = table[code] >= threshold
    changed = current != target
    return {
        "f1": f1_score(predicted, target),
        "changed_f1": f1_score(predicted[changed], target[changed]),
        "copy_last_f1": f1_score(current, target),
        "frames": len(target),
    }


def best_baselines(occupancy: np.ndarray, visibility: np.ndarray) -> dict[str, float]:
    """The best baseline F1 and changed-cell F1, scored as `lidarflow evaluate` scores them."""
    scorers = evaluate_maps(
        occupancy, visibility, [CopyLast(), TemporalAverage(), ConstantVelocity()]
    )
    summaries = [s.summary() for s in scorers.values()]
    return {m: max(s[m] for s in summaries) for m in ("f1", "changed_f1")}


def oracle(paths: list[Path], ks: list[int]) -> dict[str, dict]:
    """Per recording: the in-sample history table's F1 / changed-cell F1 at each threshold."""
    results: dict[str, dict] = {}
    for path in paths:
        occupancy, visibility = load_any(path).maps(GridSpec())
        best = best_baselines(occupancy, visibility)
        row: dict = {"best_baselines": best}
        for k in ks:
            table = fit([occupancy], k)
            points = {str(t): score(table, occupancy, k, t) for t in ORACLE_THRESHOLDS}
            wins = [t for t, r in points.items() if all(r[m] > best[m] for m in best)]
            row[f"K={k}"] = {"thresholds": points, "winning_thresholds": wins}
            print(
                f"{path.name} K={k}: "
                + " ".join(f"{t}: {r['f1']:.4f}/{r['changed_f1']:.3f}" for t, r in points.items())
                + f" | best baselines {best['f1']:.4f}/{best['changed_f1']:.3f}; "
                + f"wins at {wins or 'no threshold'}"
            )
        results[path.name] = row
    return results


PAIR_THRESHOLDS = np.round(np.arange(0.05, 0.96, 0.05), 2)


def _counts_by_class(
    probability: np.ndarray, current: np.ndarray, target: np.ndarray
) -> np.ndarray:
    """``(2, T, 2, 3)``: per class (occupied now, free now), threshold of
    :data:`PAIR_THRESHOLDS` and cell set (all, changed) the (tp, fp, fn) of ``probability >= t``."""
    out = np.zeros((2, len(PAIR_THRESHOLDS), 2, 3))
    for c, cls in enumerate((current, ~current)):
        p, y = probability[cls], target[cls]
        changed = (current != target)[cls]
        for i, threshold in enumerate(PAIR_THRESHOLDS):
            hit = p >= threshold
            for j, cells in enumerate((np.ones_like(changed), changed)):
                out[c, i, j] = [(hit & y & cells).sum(), (hit & ~y & cells).sum(),
                                (~hit & y & cells).sum()]  # fmt: skip
    return out


#: Bins of a model's probability, the extra table key of ``--causal --model``.
PROBABILITY_BINS = np.array([0, 0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95])


def model_probabilities(
    model: Path, recording: Recording, maps: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """``(N, H, W)``: the model's probability after frame ``t`` (predicting ``t + 1``),
    streamed as `lidarflow evaluate` streams it over ``maps`` (the recording's occupancy and
    visibility on the default grid), at its fixed decision offset (a model with
    ``subcell_input`` fed the recording's sub-cell maps, as evaluate feeds them)."""

    from lidarflow.evaluate.model_method import ModelMethod
    from lidarflow.models.presets import resolve_model

    net, _ = resolve_model(str(model))
    occupancy, visibility = maps
    out = np.zeros(occupancy.shape, np.float32)

    def keep(name: str, t: int, probability: np.ndarray, flow: object) -> None:
        out[t] = probability

    method = ModelMethod("model", net, online=False)
    subcell = recording.subcell_maps(GridSpec()) if method.takes_subcell else None
    evaluate_maps(occupancy, visibility, [method], warmup=0, on_prediction=keep, subcell=subcell)
    return out


def table_codes(
    occupancy: np.ndarray,
    k: int,
    probability: np.ndarray | None = None,
    subcell: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`history_codes`, with ``probability`` (:func:`model_probabilities`) also keyed
    by the bin of :data:`PROBABILITY_BINS` the model's probability for the target falls in, and
    with ``subcell`` (``Recording.subcell_maps``) by the frame's two sub-cell bits."""
    code, target = history_codes(occupancy, k)
    if probability is not None:
        bins = np.digitize(probability[k - 1 : -1], PROBABILITY_BINS) - 1
        code = code * len(PROBABILITY_BINS) + bins
    if subcell is not None:
        code = code * 4 + 2 * subcell[k - 1 : -1, 0] + subcell[k - 1 : -1, 1]
    return code, target


def table_size(k: int, model: bool, subcell: bool) -> int:
    """Keys of :func:`table_codes`."""
    return 2**k * (len(PROBABILITY_BINS) if model else 1) * (4 if subcell else 1)


def causal_counts(
    occupancy: np.ndarray,
    k: int,
    prior_ones: np.ndarray,
    prior_total: np.ndarray,
    weight: float,
    probability: np.ndarray | None = None,
    subcell: np.ndarray | None = None,
) -> np.ndarray:
    """:func:`_counts_by_class` summed over the scored frames of ``occupancy``, each predicted
    by the prior table (counts times ``weight``) plus this stream's counts so far (a key never
    seen: 0, or the model's own probability)."""
    code, target = table_codes(occupancy, k, probability, subcell)  # i: i .. i+k-1 -> i+k
    ones, total = weight * prior_ones, weight * prior_total
    counts = np.zeros((2, len(PAIR_THRESHOLDS), 2, 3))
    for i in range(len(code)):
        if i + k - 1 >= WARMUP:
            seen = total[code[i]]
            unseen = 0.0 if probability is None else probability[i + k - 1]
            p = np.where(seen > 0, ones[code[i]] / np.maximum(seen, 1e-12), unseen)
            counts += _counts_by_class(p.ravel(), occupancy[i + k - 1].ravel() > 0,
                                       target[i].ravel())  # fmt: skip
        np.add.at(total, code[i].ravel(), 1)  # its next map has arrived: learn from it
        np.add.at(ones, code[i].ravel(), target[i].ravel())
    return counts


def _best_pair(counts: np.ndarray, best: dict[str, float]) -> dict[str, object]:
    """The threshold pair of ``counts`` (:func:`_counts_by_class`) with the best margin."""
    pairs = counts[0][:, None] + counts[1][None, :]  # [occupied now, free now, set, 3]
    tp, fp, fn = np.moveaxis(pairs, -1, 0)
    f1s = 2 * tp / np.maximum(2 * tp + fp + fn, 1)
    margin = np.minimum(f1s[..., 0] - best["f1"], f1s[..., 1] - best["changed_f1"])
    a, b = np.unravel_index(int(np.argmax(margin)), margin.shape)
    return {
        "thresholds": [float(PAIR_THRESHOLDS[a]), float(PAIR_THRESHOLDS[b])],
        "f1": float(f1s[a, b, 0]),
        "changed_f1": float(f1s[a, b, 1]),
        "margin": float(margin[a, b]),
    }


def causal(
    paths: list[Path],
    ks: list[int],
    weights: list[float],
    model: Path | None = None,
    held_out: list[str] | None = None,
    with_subcell: bool = False,
) -> dict[str, dict]:
    """Per held-out recording (``held_out`` names, default every one), K and prior weight:
    the best threshold pair's scores; with ``model`` keyed by its probability too, with
    ``with_subcell`` by the sub-cell bits."""
    grid = GridSpec()
    recordings = {p.name: load_any(p) for p in paths}
    maps = {n: r.maps(grid) for n, r in recordings.items()}
    subcells = {n: r.subcell_maps(grid) if with_subcell else None for n, r in recordings.items()}
    probabilities = {
        n: None if model is None else model_probabilities(model, r, maps[n])
        for n, r in recordings.items()
    }
    results: dict[str, dict] = {}
    for name, (occupancy, visibility) in maps.items():
        if held_out and name not in held_out:
            continue
        best = best_baselines(occupancy, visibility)
        row: dict = {"best_baselines": best}
        points: dict[str, dict] = {}
        own = probabilities[name]
        if own is not None:  # the model alone, its probability with the same two thresholds
            alone = sum(
                _counts_by_class(
                    own[t].ravel(), occupancy[t].ravel() > 0, occupancy[t + 1].ravel() > 0
                )
                for t in range(WARMUP, len(occupancy) - 1)
            )
            points["model alone"] = _best_pair(np.asarray(alone), best)
        for k in ks:
            size = table_size(k, model is not None, with_subcell)
            ones, total = np.zeros(size), np.zeros(size)
            for other, (other_occupancy, _) in maps.items():
                if other != name:
                    code, target = table_codes(
                        other_occupancy, k, probabilities[other], subcells[other]
                    )
                    np.add.at(total, code.ravel(), 1)
                    np.add.at(ones, code.ravel(), target.ravel())
            for weight in weights:
                counts = causal_counts(occupancy, k, ones, total, weight, own, subcells[name])
                points[f"K={k} prior={weight}"] = _best_pair(counts, best)
        for label, point in points.items():
            print(
                f"{name} {label}: thresholds {point['thresholds']} F1 {point['f1']:.4f} / "
                f"{point['changed_f1']:.3f}, margin {point['margin']:+.4f} "
                f"(best baselines {best['f1']:.4f} / {best['changed_f1']:.3f})",
                flush=True,
            )
        results[name] = row | points
    return results


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--train", type=Path, nargs="+")
    parser.add_argument("--eval", type=Path, nargs="+", required=True)
    parser.add_argument("--k", type=int, nargs="+", default=[3, 5, 8])
    parser.add_argument("--json", type=Path)
    parser.add_argument(
        "--oracle", action="store_true", help="fit on each --eval recording itself (upper bound)"
    )
    parser.add_argument(
        "--causal", type=float, nargs="+", metavar="S",
        help="leave-one-out over --eval: prior weights of the other recordings' table",
    )  # fmt: skip
    parser.add_argument("--model", type=Path, help="with --causal: key the table by its output")
    parser.add_argument("--held-out", nargs="+", help="with --causal: only these --eval names")
    parser.add_argument(
        "--subcell", action="store_true", help="with --causal: key by the sub-cell bits too"
    )
    args = parser.parse_args()
    if args.causal:
        results = causal(args.eval, args.k, args.causal, args.model, args.held_out, args.subcell)
        if args.json:
            payload = {"causal": "prior from the other --eval recordings, updated online",
                       "model": None if args.model is None else str(args.model),
                       "subcell": args.subcell,
                       "warmup": WARMUP, "results": results}  # fmt: skip
            args.json.write_text(json.dumps(payload, indent=2) + "\n")
        return
    if args.oracle:
        results = oracle(args.eval, args.k)
        if args.json:
            payload = {"oracle": "in-sample", "warmup": WARMUP, "results": results}
            args.json.write_text(json.dumps(payload, indent=2) + "\n")
        return
    if not args.train:
        parser.error("--train is needed (or --oracle)")
    if set(args.train) & set(args.eval):
        parser.error("evaluate on recordings that were not fitted on")
    grid = GridSpec()
    train = [load_any(p).maps(grid)[0] for p in args.train]
    held = {p.name: load_any(p).maps(grid)[0] for p in args.eval}
    results: dict[str, dict] = {}
    for k in args.k:
        table = fit(train, k)
        for name, occupancy in held.items():
            r = score(table, occupancy, k)
            results.setdefault(f"K={k}", {})[name] = r
            print(
                f"K={k} {name:42s} F1 {r['f1']:.4f}  changed F1 {r['changed_f1']:.4f}  "
                f"(copy-last F1 {r['copy_last_f1']:.4f})"
            )
    if args.json:
        payload = {"train": [str(p) for p in args.train], "threshold": THRESHOLD,
                   "warmup": WARMUP, "results": results}  # fmt: skip
        args.json.write_text(json.dumps(payload, indent=2))


if __name__ == "__main__":
    main()
