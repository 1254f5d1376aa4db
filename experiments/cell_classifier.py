"""What a classifier of each cell's own memories can do on the static recordings (issue 11).

A reference point, no network of the project's: per cell and frame, the features are the current
map ``O^t`` and the occupancy head's five memories (exponential averages with decays 0.5 / 0.8 /
0.95 / 0.98 / 0.995), streamed over the whole recording as at test time, or, with ``--reset N``,
restarted from zero every N frames in training as the head's 16-frame training windows used to
start them. With ``--visibility`` it also sees the visibility map ``V^t`` and five memories of
it (how often each cell has been seen at all: a cell behind a wall's edge is seldom seen, one in
the open nearly always). A two-layer perceptron (32 + 32 units) is fitted by cross-entropy on
the cells near recent occupancy (some occupied cell within 2 cells in the last 16 frames; every
other cell is predicted free) of the training recordings, leave-one-recording-out. Two
thresholds (one for the cells occupied now, one for the free ones) are chosen on the training
recordings by the largest summed win margin, then the held-out recording is scored with them.

Baselines here: copy-last and the temporal average (5 frames, 0.4), scored on the same frames
(t >= 15, not 10 as in `lidarflow evaluate`); on static recordings the constant-velocity
baseline equals copy-last within 0.001.

    python experiments/cell_classifier.py --recordings ../shared/data/positive_{1,2,3,4}.bag \\
        ../shared/data/demo_stationary_simple_environment.bag --seeds 0 1 --json out.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from lidarflow.data import load_any

DECAYS = (0.5, 0.8, 0.95, 0.98, 0.995)
HISTORY = 16  # frames of the candidate neighbourhood, and the first frame scored - 1
WINDOW_WARMUP = 6  # with --reset: the first frames of each window are not trained on
THRESHOLDS = np.linspace(0.1, 0.7, 25)

# features, next map, current map, temporal average's prediction (candidate cells), appearing
# cells outside the candidates
Data = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]


def _memories(maps: np.ndarray, reset: int) -> np.ndarray:
    """``(len(DECAYS), N, H, W)`` exponential averages of ``maps`` ``(N, H, W)``."""
    memories = np.zeros((len(DECAYS), *maps.shape), np.float32)
    m = np.zeros((len(DECAYS), *maps.shape[1:]), np.float32)
    d = np.asarray(DECAYS, np.float32)[:, None, None]
    for t in range(len(maps)):
        if reset and t % reset == 0:
            m = np.zeros_like(m)
        m = d * m + (1 - d) * maps[t]
        memories[:, t] = m
    return memories


def features(occupancy: np.ndarray, reset: int = 0, visibility: np.ndarray | None = None) -> Data:
    """``(X (n, 6), next (n,), current (n,), temporal average (n,), appearing cells outside
    the candidates)``; with ``visibility`` ``X`` also holds ``V^t`` and its five memories
    ``(n, 12)``."""
    o = occupancy.astype(np.float32)
    n = len(o)
    memories = _memories(o, reset)
    if visibility is not None:
        v = visibility.astype(np.float32)
        memories = np.concatenate([memories, v[None], _memories(v, reset)])
    pad = np.pad(o, ((0, 0), (2, 2), (2, 2)))
    near = np.zeros_like(o)
    for dy in range(5):
        for dx in range(5):
            near = np.maximum(near, pad[:, dy : dy + o.shape[1], dx : dx + o.shape[2]])
    xs, ys, cur, average = [], [], [], []
    unseen = 0
    for t in range(HISTORY - 1, n - 1):
        if reset and t % reset < WINDOW_WARMUP:
            continue
        mask = near[t - HISTORY + 1 : t + 1].max(0) > 0
        xs.append(np.concatenate([o[t][mask][:, None], memories[:, t][:, mask].T], axis=1))
        ys.append(o[t + 1][mask])
        cur.append(o[t][mask])
        average.append(o[t - 4 : t + 1].mean(0)[mask] >= 0.4)
        unseen += int(((o[t + 1] > 0) & ~mask).sum())
    return (
        np.concatenate(xs),
        np.concatenate(ys),
        np.concatenate(cur),
        np.concatenate(average),
        unseen,
    )


def f1(tp: int, fp: int, fn: int) -> float:
    return 2 * tp / max(2 * tp + fp + fn, 1)


def scores(predicted: np.ndarray, data: Data) -> tuple[float, float]:
    """F1 and changed-cell F1 (appearing cells outside the candidates count as missed)."""
    _, y, cur, _, unseen = data
    y, cur = y > 0, cur > 0
    changed = y != cur
    whole = f1((predicted & y).sum(), (predicted & ~y).sum(), (~predicted & y).sum() + unseen)
    ch = f1(
        (predicted & y & changed).sum(),
        (predicted & ~y & changed).sum(),
        (~predicted & y & changed).sum() + unseen,
    )
    return whole, ch


def margin(p: np.ndarray, data: Data, occupied: float, free: float) -> tuple[float, float, float]:
    _, _, cur, temporal_average, _ = data
    copy, average = scores(cur > 0, data), scores(temporal_average, data)
    model = scores(np.where(cur > 0, p >= occupied, p >= free), data)
    best = (max(copy[0], average[0]), max(copy[1], average[1]))
    return min(model[0] - best[0], model[1] - best[1]), *model


def fit(train: list[Data], seed: int, epochs: int = 30, hidden: int = 32) -> torch.nn.Module:
    torch.manual_seed(seed)
    x = torch.from_numpy(np.concatenate([d[0] for d in train]))
    y = torch.from_numpy(np.concatenate([d[1] for d in train]))
    net = torch.nn.Sequential(
        torch.nn.Linear(x.shape[1], hidden),
        torch.nn.ReLU(),
        torch.nn.Linear(hidden, hidden),
        torch.nn.ReLU(),
        torch.nn.Linear(hidden, 1),
    )
    opt = torch.optim.Adam(net.parameters(), 3e-3)
    for _ in range(epochs):
        order = torch.randperm(len(x))
        for i in range(0, len(x), 8192):
            b = order[i : i + 8192]
            loss = torch.nn.functional.binary_cross_entropy_with_logits(net(x[b])[:, 0], y[b])
            opt.zero_grad()
            loss.backward()
            opt.step()
    return net


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=Path, nargs="+", required=True)
    parser.add_argument("--held-out", type=Path, nargs="*", default=[])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--reset", type=int, default=0, help="restart training memories every N")
    parser.add_argument("--epochs", type=int, default=30)
    parser.add_argument("--hidden", type=int, default=32, help="units in each of two layers")
    parser.add_argument(
        "--visibility",
        action="store_true",
        help="also V^t and five memories of it (how often each cell is seen at all)",
    )
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(2)
    maps = {p.name: load_any(p).maps() for p in args.recordings}
    streamed = {
        name: features(o, 0, v if args.visibility else None) for name, (o, v) in maps.items()
    }
    train_view = (
        {
            name: features(o, args.reset, v if args.visibility else None)
            for name, (o, v) in maps.items()
        }
        if args.reset
        else streamed
    )
    results: dict[str, list[dict]] = {}
    for held in [p.name for p in args.held_out] or list(maps):
        others = [name for name in maps if name != held]
        for seed in args.seeds:
            net = fit([train_view[name] for name in others], seed, args.epochs, args.hidden)
            with torch.no_grad():
                p = {
                    name: torch.sigmoid(net(torch.from_numpy(d[0]))[:, 0]).numpy()
                    for name, d in streamed.items()
                }
            pairs = [(a, b) for a in THRESHOLDS for b in THRESHOLDS]
            occupied, free = max(
                pairs, key=lambda ab: sum(margin(p[n], streamed[n], *ab)[0] for n in others)
            )
            won, f1_all, f1_changed = margin(p[held], streamed[held], occupied, free)
            row = {
                "seed": seed,
                "thresholds": [float(occupied), float(free)],
                "margin": won,
                "f1": f1_all,
                "changed_f1": f1_changed,
            }
            results.setdefault(held, []).append(row)
            print(
                f"{held}: seed {seed}, thresholds {occupied:.3f} / {free:.3f} -> "
                f"{f1_all:.4f} / {f1_changed:.4f}, margin {won:+.4f}",
                flush=True,
            )
    if args.json:
        settings = {
            "reset": args.reset,
            "epochs": args.epochs,
            "hidden": args.hidden,
            "visibility": args.visibility,
        }
        args.json.write_text(json.dumps({**settings, "results": results}, indent=2))


if __name__ == "__main__":
    main()
