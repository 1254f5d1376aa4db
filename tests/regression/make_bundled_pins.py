"""Write the pins of a model's predictions: the bundled model's (run at v10's install), and
v8's (``--model flownet_v8``, run once at main ``a4a22da``, when v8 was the bundled model).

The house issue (35) restructures the per-frame pipeline and the model without changing what the
bundled model predicts; ``test_bundled_pins.py`` holds every later commit to what this script
recorded before the restructuring (v8, a flow model: ``flownet_v8_pins.npz``, which also pins
the flow path) and to what the bundled model predicted when it was installed
(``bundled_pins.npz``: v10, issue 44, v9's head with the tracked movers laid over it). Do not
re-run it to make a failing pin pass: a pin that moves is a behaviour change, to be explained
and pinned on its own (installing a new bundled model is one: re-run it for ``bundled`` then).

    PYTHONPATH=src:. OMP_NUM_THREADS=1 python tests/regression/make_bundled_pins.py \\
        [--model flownet_v8]

What is pinned, per stream (the bundled sample and the first frames of two development
recordings, a static one and a driving one, through ``Predictor.update`` with the recording's
poses, ``horizon=2``): every frame's decided map (``Prediction.occupied``, packed bits; since
v9 the one two steps ahead too), the probability's sum and sum of squares, the backward flow's
sum, whether the step was ego compensated, and every ``FULL_EVERY``-th frame's probability in
full (float32).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
OUT = HERE / "bundled_pins.npz"
SHARED = HERE.parents[2] / "shared" / "data"
#: The pinned models: the pins' files, and the model each streams (``None``: the bundled one).
PINS = {"bundled": OUT, "flownet_v8": HERE / "flownet_v8_pins.npz"}
MODELS = {"bundled": None, "flownet_v8": HERE.parent / "fixtures" / "flownet_v8"}
#: (name, source, frames): the sample whole, two development recordings' first frames.
STREAMS = (
    ("sample", None, None),
    ("positive_1", SHARED / "positive_1.bag", 150),
    ("datmo_overtakes", SHARED / "datmo_overtakes.bag", 150),
)
HORIZON = 2
FULL_EVERY = 25


def stream_recording(source: Path | None, frames: int | None):
    from lidarflow.data.samples import sample_bag_path
    from lidarflow.data.sources import load_any

    recording = load_any(sample_bag_path() if source is None else source)
    if frames is not None:
        recording = recording.slice(0, min(frames, len(recording)))
    return recording


def run_stream(recording, predictor) -> dict[str, np.ndarray]:
    poses = recording.poses
    occupied, ahead, sums, squares, flows, ego, full, full_k2 = [], [], [], [], [], [], [], []
    predictor.reset()
    for i, scan in enumerate(recording):
        p = predictor.update(scan, None if poses is None else poses[i])
        probability = np.asarray(p.probability, np.float64)
        occupied.append(np.packbits(np.asarray(p.occupied, bool)))
        ahead.append(np.packbits(np.asarray(p.horizon_occupied[1], bool)))
        sums.append(probability.sum())
        squares.append((probability**2).sum())
        flows.append(0.0 if p.backward_flow is None else float(np.sum(p.backward_flow)))
        ego.append(p.ego_compensated)
        if i % FULL_EVERY == 0:
            full.append(np.asarray(p.probability, np.float32))
            full_k2.append(np.asarray(p.horizon[1], np.float32))
    return {
        "occupied": np.stack(occupied),
        # since v9 (a4a22da's pins have none): the decided map two steps ahead, every frame
        "ahead_occupied": np.stack(ahead),
        "probability_sum": np.asarray(sums),
        "probability_square_sum": np.asarray(squares),
        "backward_flow_sum": np.asarray(flows),
        "ego_compensated": np.asarray(ego),
        "probability_full": np.stack(full),
        "horizon2_full": np.stack(full_k2),
    }


def main(argv: list[str]) -> None:
    from lidarflow.predict import Predictor

    model = argv[argv.index("--model") + 1] if "--model" in argv else "bundled"
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=HERE
    ).stdout.strip()
    arrays: dict[str, np.ndarray] = {"commit": np.asarray(commit)}
    predictor = Predictor(MODELS[model], horizon=HORIZON, threads=1, combine=False)
    for name, source, frames in STREAMS:
        pinned = run_stream(stream_recording(source, frames), predictor)
        for key, value in pinned.items():
            arrays[f"{name}/{key}"] = value
        print(name, len(pinned["occupied"]), "frames", file=sys.stderr)
    np.savez_compressed(PINS[model], **arrays)
    print(PINS[model], PINS[model].stat().st_size, "bytes", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv[1:])
