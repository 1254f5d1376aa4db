"""The online decision on one long stream through several places (issue 11).

A robot's Predictor runs for hours without a reset, through places that want other decisions.
The online decision's counts of the decisions made and of the baselines are kept since the
stream began by default (``OnlineDecisionConfig.history_decay`` 1), as a recording is scored.
This replays the shipped look-ahead rule (grid -4.8..4.2, moved and unmoved map, decay 0.98,
look-ahead 20) over the development recordings played back to back, in several orders, from
the per-frame counts that ``studies.online_rules`` caches (the model streamed on each recording from
a fresh state), and scores each recording's own stretch against its own baselines, for several
``history_decay`` values; and each recording played alone for comparison.

    python -m studies.long_stream --counts runs/studies/online_rules -o runs/studies/long_stream

(``--counts``: the output of ``python -m studies.online_rules --model bundled``, or of
``--folds`` for the fold models, each recording's counts from its own fold.) Writes
OUT/long_stream.json and OUT/long_stream.md.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from studies.harness import parse, parser, write_summary
from studies.online_rules import f1, replay

HISTORIES = (1.0, 0.999, 0.995, 0.99, 0.98, 0.95)
ORDERS = 4  # the files' order, then three shuffles (seed 0)


def stretch_margins(
    data: dict[str, tuple[np.ndarray, np.ndarray]], order: list[str], history: float
) -> dict[str, float]:
    """Each recording's win margin over its own stretch of the stream played in ``order``."""
    pairs = np.concatenate([data[n][0] for n in order])
    baselines = np.concatenate([data[n][1] for n in order])
    chosen = replay(pairs, baselines, "lookahead", 0.98, 20.0, history)
    margins, start = {}, 0
    for name in order:
        frames = len(data[name][0])
        part = slice(start, start + frames)
        start += frames
        got = pairs[part][np.arange(frames), chosen[part]].sum(axis=0)
        best = f1(baselines[part].sum(axis=0)).max(axis=0)
        margins[name] = float((f1(got) - best).min())
    return margins


def markdown(results: dict[str, Any], recordings: int) -> str:
    lines = [
        "| history_decay | alone: wins | alone: summed margin | back to back: wins | "
        "back to back: summed margin |",
        "|---|---|---|---|---|",
    ]
    streams = recordings * len(results["orders"])
    for history, row in results["histories"].items():
        lines.append(
            f"| {history} | {row['alone_wins']} of {recordings} | {row['alone_summed']:+.4f} | "
            f"{row['stream_wins']} of {streams} | {row['stream_summed']:+.4f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = parser("long_stream", __doc__)
    p.add_argument("--counts", type=Path, required=True, help="studies.online_rules' output")
    p.add_argument("--histories", type=float, nargs="+", default=list(HISTORIES))
    args = parse(p, argv)
    data = {}
    for cache in sorted(args.counts.glob("*.npz")):
        d = np.load(cache)
        both = np.stack([d["pairs"], d["unmoved"]], axis=1)  # (T, maps, A, B, 2, 3)
        data[cache.stem] = (both.reshape(len(both), -1, 2, 3), d["baselines"])
    if not data:
        p.error(f"no counts (*.npz) in {args.counts}: run studies.online_rules first")
    names = list(data)
    rng = np.random.default_rng(0)
    orders = [names] + [list(rng.permutation(names)) for _ in range(ORDERS - 1)]
    results: dict[str, Any] = {"orders": orders, "histories": {}}
    for history in args.histories:
        alone = {n: stretch_margins(data, [n], history)[n] for n in names}
        streamed = [stretch_margins(data, order, history) for order in orders]
        results["histories"][str(history)] = {
            "alone": alone,
            "alone_wins": sum(m > 0 for m in alone.values()),
            "alone_summed": sum(alone.values()),
            "stream": streamed,
            "stream_wins": sum(m > 0 for s in streamed for m in s.values()),
            "stream_summed": sum(sum(s.values()) for s in streamed),
        }
    write_summary(args, "long_stream", results, markdown(results, len(names)))
    return results


if __name__ == "__main__":
    main()
