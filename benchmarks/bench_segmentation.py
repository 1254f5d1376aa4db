"""Per-scan cost of moving-object segmentation (when ``Prediction.moving`` is read) and of the
calibration sums (in every evaluated frame), as ratios to a reference measured in the same run.

Segmentation: :func:`lidarflow.predict.moving.moving_mask` on a flow model's forward flow
(``--model``; default v8, ``tests/fixtures/flownet_v8``: the bundled model has none since v9) of
the bundled sample's scans, against ``Predictor.update`` (rasterize + model step; segmentation
is computed on first access to ``Prediction.moving``, so it is no longer in the update) on the
same scans. Calibration: ``Calibration.add`` against ``Scorer.add`` (which
includes it). Medians over ``--scans`` scans, one thread. Writes JSON (default
``benchmarks/results/segmentation.json``).

    python benchmarks/bench_segmentation.py [--scans 200]
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from _output import machine, write_json

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.evaluate.calibration import Calibration
from lidarflow.evaluate.scoring import Scorer
from lidarflow.predict import Predictor
from lidarflow.predict.moving import moving_mask

#: v8, the bundled model until v9 (which has no flow network), kept as a test fixture.
FLOW_MODEL = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "flownet_v8"


def median_ms(call: Callable[[int], object], n: int) -> float:
    times = []
    for i in range(n):
        t0 = time.perf_counter()
        call(i)
        times.append(time.perf_counter() - t0)
    return float(np.median(times) * 1e3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=200)
    parser.add_argument("--model", default=str(FLOW_MODEL), help="a model with a flow network")
    parser.add_argument(
        "--json", type=Path, default=Path("benchmarks/results/segmentation.json")
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    recording = read_bag(sample_bag_path())
    scans = [recording.scan(i % len(recording)) for i in range(args.scans)]
    predictor = Predictor(args.model, threads=1)
    predictions = [predictor.update(s) for s in scans]  # also warms up
    predictor.reset()
    update = median_ms(lambda i: predictor.update(scans[i]), args.scans)
    segment = median_ms(
        lambda i: moving_mask(predictions[i].occupancy, predictions[i].forward_flow), args.scans
    )
    plain = median_ms(
        lambda i: moving_mask(predictions[i].occupancy, predictions[i].forward_flow,
                              compensate=False),
        args.scans,
    )
    scorer, calibration = Scorer(), Calibration()

    def score(i: int) -> None:
        p = predictions[i]
        scorer.add(p.probability, p.occupancy, predictions[(i + 1) % args.scans].occupancy)

    scorer_ms = median_ms(score, args.scans)
    calibration_ms = median_ms(
        lambda i: calibration.add(predictions[i].probability, predictions[i].occupancy),
        args.scans,
    )
    results = {
        "predictor_update_ms": update,
        "moving_mask_ms": segment,
        "moving_mask_no_compensation_ms": plain,
        "moving_mask_share_of_update": segment / update,
        "scorer_add_ms": scorer_ms,
        "calibration_add_ms": calibration_ms,
        "calibration_share_of_scorer_add": calibration_ms / scorer_ms,
    }
    for key, value in results.items():
        print(f"{key}: {value:.3f}")
    out = {
        "benchmark": "segmentation",
        "scans": args.scans,
        "command": "python benchmarks/bench_segmentation.py --scans " + str(args.scans),
        "machine": machine(),
        "note": "medians, one thread, on a 2-core CPU shared with other work: read the ratios, "
        "which are measured in the same run; absolute times are indicative",
        "results": results,
    }
    write_json(args.json, out)


if __name__ == "__main__":
    main()
