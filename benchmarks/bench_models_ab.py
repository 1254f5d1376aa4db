"""Does one model cost more per scan than another? Alternating rounds in one run.

On a shared machine absolute times drift by 2-3x between runs (the bundled model's PyTorch step
measured 10.7 ms one day and 19-23 ms another), so two models are compared in the same run,
round by round: each round streams the same scans of the sample through a fresh ``Predictor``
of each model in turn (PyTorch eager, no poses, so the motion from the scans is included), and
the result is the median over rounds of the per-round ratio of median step times: of the whole
``update`` (what a user pays), and of the model's own step inside it (the backend's ``run``).

    python benchmarks/bench_models_ab.py RUN_A bundled [--rounds 6] [--scans 120] [--threads 1]

A model named ``head_only:SOURCE`` (e.g. ``head_only:bundled``) is SOURCE's occupancy head in a
LiDAR-FlowNet without the flow network (issue 36), its weights copied as ``--init`` copies them
(:func:`lidarflow.train.model_setup.load_init`): the same decisions as SOURCE with its flow set to
zero, without the ConvGRUs' cost. ``benchmarks/results/head_only_ab.json``:
``bundled head_only:bundled --note "..."``.

(the v6 / v8 comparison in ``benchmarks/results/models_ab_v8.json`` took v6's weights, since
left the tree: ``git show a4a22da:docs/results/accuracy/bundled_v6/model.safetensors``).

Writes JSON (default ``benchmarks/results/models_ab.json``).
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from _output import machine, write_json

from lidarflow.data import load_any, sample_bag_path
from lidarflow.predict import Predictor

WARMUP_SCANS = 20  # the first steps allocate and fill the memories
HEAD_ONLY = "head_only:"


def head_only_folder(source: str, folder: Path) -> str:
    """A run folder holding ``source``'s head in a model without the flow network."""
    from safetensors.torch import save_file

    from lidarflow.models import ModelSpec, build
    from lidarflow.models.presets import resolve_model
    from lidarflow.train.model_setup import load_init

    net, card = resolve_model(source)
    ego = net.capabilities.ego_motion
    head = (net.inner if ego else net).head.config  # type: ignore[union-attr]
    spec = ModelSpec("flownet", None, head, ego, net.capabilities.poses_optional)
    model = build(spec)
    load_init(model, source)
    folder.mkdir(parents=True, exist_ok=True)
    weights = {k: v.contiguous() for k, v in model.state_dict().items()}
    save_file(weights, folder / "model.safetensors")
    record = {"model": "flownet", "model_kwargs": spec.to_kwargs(), "decision": card["decision"]}
    (folder / "model.json").write_text(json.dumps(record))
    return str(folder)


def step_times_ms(model: str, scans: list) -> tuple[np.ndarray, np.ndarray]:
    """Milliseconds of each ``Predictor.update`` of a fresh predictor of ``model``, and of the
    model's own step inside it (the backend's ``run``: the network, the ego-motion warp of its
    state; not rasterising, matching the motion from the scans or deciding)."""
    predictor = Predictor(model)  # "bundled" resolves like any other name
    backend, inner = predictor.backend, []
    run = backend.run

    def timed(*args, **kwargs):  # type: ignore[no-untyped-def]
        start = time.perf_counter()
        out = run(*args, **kwargs)
        inner.append(time.perf_counter() - start)
        return out

    backend.run = timed  # type: ignore[method-assign]
    times = []
    for scan in scans:
        start = time.perf_counter()
        predictor.update(scan)
        times.append(time.perf_counter() - start)
    # horizon 1: one run per update
    return np.array(times[WARMUP_SCANS:]) * 1e3, np.array(inner[WARMUP_SCANS:]) * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", help="run folder, ONNX file or 'bundled'")
    parser.add_argument("model", help="the model compared with it")
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--scans", type=int, default=120)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/models_ab.json"))
    parser.add_argument("--note", default="", help="how the machine was (e.g. its load)")
    args = parser.parse_args()
    if args.scans <= WARMUP_SCANS:
        parser.error(f"--scans must be above the {WARMUP_SCANS} warm-up scans")
    torch.set_num_threads(args.threads)
    recording = load_any(sample_bag_path())
    scans = [recording.scan(i) for i in range(min(args.scans, len(recording)))]
    medians: dict[str, list[float]] = {args.reference: [], args.model: []}
    steps: dict[str, list[float]] = {args.reference: [], args.model: []}
    with tempfile.TemporaryDirectory() as tmp:
        paths = {
            name: head_only_folder(name.removeprefix(HEAD_ONLY), Path(tmp) / str(i))
            if name.startswith(HEAD_ONLY)
            else name
            for i, name in enumerate(medians)
        }
        for _ in range(args.rounds):
            for name in medians:
                update, step = step_times_ms(paths[name], scans)
                medians[name].append(float(np.median(update)))
                steps[name].append(float(np.median(step)))
    ratios = np.array(medians[args.model]) / np.array(medians[args.reference])
    ratio = float(np.median(ratios))
    step_ratio = float(np.median(np.array(steps[args.model]) / np.array(steps[args.reference])))
    print(f"{args.model} / {args.reference}: {ratio:.3f} (per round {np.round(ratios, 3)})")
    print(f"the model's step alone: {step_ratio:.3f}")
    write_json(
        args.json,
        {
            "benchmark": "models_ab",
            "reference": args.reference,
            "model": args.model,
            "threads": args.threads,
            "scans": len(scans),
            "warmup_scans": WARMUP_SCANS,
            "machine": machine(),
            "median_step_ms_per_round": medians,
            "ratio_model_over_reference": ratio,
            "median_model_step_ms_per_round": steps,
            "ratio_model_step_over_reference": step_ratio,
            "note": " ".join(
                ["absolute times are indicative only; compare the ratio.", args.note]
            ).strip(),
        },
    )


if __name__ == "__main__":
    main()
