"""Does adapting the occupancy head to the stream it predicts pay? (issue 11, positive_4)

Causal test-time adaptation: a fold model is streamed once over a held-out recording as
`lidarflow evaluate` streams it (offset 0, no online decision); each frame's head input (the
per-cell features the head's hidden layer takes) and the rest of its logit (``g W(O^t, B^t)``)
are kept. The head (hidden layer and output) is then replayed over the stream: frame ``t`` is
predicted with the head as it stands, and once ``O^{t+1}`` has arrived the head takes ``steps``
Adam steps of the training cross-entropy on the last ``window`` frames (``lr`` 0: the fold model
itself, which must reproduce the stream's logits). Every fixed pair of decision offsets of
``pair_frontier``'s wide grid is scored on each replay (hindsight: an upper bound for the online
choice) against the best baselines.

Only for models whose head has a hidden layer (the ``head`` recipe's).

    python experiments/adapt_head.py -m runs/loo/subcell_p4/head_subcell/positive_4/run \\
        ../shared/data/positive_4.bag --runs 0:1:1 1e-4:1:1 1e-3:1:1 3e-3:1:30 1e-2:1:30 \\
        --json docs/results/accuracy/positive_4/adaptation/adapt_head.json
"""

from __future__ import annotations

import argparse
import copy
import json
from pathlib import Path

import numpy as np
import torch
from online_rules import LOGIT, f1, logit_of, pair_frame, stream_beside_baselines, threshold_counts
from pair_frontier import FREE, OCCUPIED, frontier
from study import BASELINES

from lidarflow.data import load_any
from lidarflow.models.presets import resolve_model
from lidarflow.predict.decision import moved_last_map
from lidarflow.scan import GridSpec


def stream(net: torch.nn.Module, path: Path) -> dict[str, np.ndarray]:
    """Per scored frame: the head's ``features`` (T, F, H, W), its output ``residual``, the
    ``logit``, the ``moved`` last map, ``current`` and ``target`` maps, and the ``baselines``'
    counts (T, 3, 2 masks, tp/predicted/positives)."""
    head = getattr(net, "inner", net)
    features: list[np.ndarray] = []
    residuals: list[np.ndarray] = []
    hooks = [
        head.occupancy_hidden.register_forward_pre_hook(
            lambda _m, args: features.append(args[0].detach().numpy()[0].copy())
        ),
        head.conv_occupancy.register_forward_hook(
            lambda _m, _a, out: residuals.append(out.detach().numpy()[0, 0].copy())
        ),
    ]
    recording = load_any(path)
    occupancy, visibility = recording.maps(GridSpec())
    rows: dict[str, list] = {k: [] for k in ("features", "residual", "logit", "moved", "current")}
    rows["target"], baselines = [], {}

    def add(name: str, t: int, probability: np.ndarray, flow: np.ndarray | None) -> None:
        current, target = occupancy[t].astype(bool), occupancy[t + 1].astype(bool)
        if name != "model":
            baselines.setdefault(name, []).append(threshold_counts(probability, current, target))
            return
        rows["logit"].append(logit_of(probability).astype(np.float32))
        rows["moved"].append(moved_last_map(current, None if flow is None else flow[:2]))
        rows["current"].append(current)
        rows["target"].append(target)
        rows["features"].append(features[-1])  # the step that made this prediction
        rows["residual"].append(residuals[-1])

    stream_beside_baselines(net, recording, (occupancy, visibility), add)
    for hook in hooks:  # else the replay's copies of the head would keep recording
        hook.remove()
    data = {k: np.array(v) for k, v in rows.items()}
    data["baselines"] = np.array([baselines[b] for b in BASELINES], float).transpose(1, 0, 2, 3)
    return data


def replay(
    net: torch.nn.Module, data: dict[str, np.ndarray], lr: float, steps: int, window: int
) -> np.ndarray:
    """The logits ``(T, H, W)`` of the head adapted causally (see above)."""
    head = getattr(net, "inner", net)
    hidden, output = copy.deepcopy(head.occupancy_hidden), copy.deepcopy(head.conv_occupancy)
    optimizer = torch.optim.Adam([*hidden.parameters(), *output.parameters()], lr=lr)
    rest = torch.from_numpy(data["logit"] - data["residual"])  # g W(O^t, B^t)
    features = torch.from_numpy(data["features"])
    targets = torch.from_numpy(data["target"].astype(np.float32))
    logits = []
    for t in range(len(features)):
        with torch.no_grad():
            logits.append((rest[t] + output(torch.relu(hidden(features[t : t + 1])))[0, 0]).numpy())
        for _ in range(steps if lr > 0 else 0):
            start = max(0, t - window + 1)
            logit = rest[start : t + 1] + output(torch.relu(hidden(features[start : t + 1])))[:, 0]
            loss = torch.nn.functional.binary_cross_entropy_with_logits(
                logit, targets[start : t + 1]
            )
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    return np.array(logits)


def pair_scores(data: dict[str, np.ndarray], logits: np.ndarray) -> np.ndarray:
    """Every pair's counts per frame ``(T, A, B, 2 masks, 3)`` (``pair_frontier``'s layout)."""
    return np.array([
        pair_frame(
            LOGIT - logit, data["moved"][t], data["current"][t], data["target"][t], OCCUPIED, FREE
        )
        for t, logit in enumerate(logits)
    ])  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("-m", "--model", type=Path, required=True)
    parser.add_argument(
        "--runs", nargs="+", default=["0:1:1", "1e-3:1:1"], help="lr:steps:window per replay"
    )
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    torch.set_num_threads(1)
    net, _ = resolve_model(args.model)
    head = getattr(net, "inner", net)
    if not getattr(head, "head_hidden_channels", 0):
        parser.error("the model's occupancy head has no hidden layer to adapt")
    head.decision_offset, head.decision_offset_free, head.online_decision = 0.0, None, False
    data = stream(net, args.recording)
    best = f1(data["baselines"].sum(axis=0)).max(axis=0)
    result: dict = {"model": str(args.model), "recording": str(args.recording)}
    result["best_baselines"], result["replays"] = best.tolist(), {}
    for spec in args.runs:
        lr, steps, window = spec.split(":")
        logits = replay(net, data, float(lr), int(steps), int(window))
        if float(lr) == 0:  # the replay must be the stream itself
            assert np.allclose(logits, data["logit"], atol=1e-3), "replay does not match stream"
        summary = frontier(pair_scores(data, logits), best)
        result["replays"][spec] = summary
        print(spec, json.dumps(summary), flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
