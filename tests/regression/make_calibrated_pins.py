"""Write the pins of a model's calibrated probability: the bundled model's (run at v9's install),
and v8's (``--model flownet_v8``, run once at main ``9f9eedb``, when v8 was the bundled model).

Until issue 35 the Predictor's ``probability`` was the decided one (the head's logit shifted by
the decision offsets); since, it is the calibrated ``sigmoid(logit)`` and the decision is only in
``occupied``. ``9f9eedb`` predicts exactly what ``a4a22da`` did (``bundled_pins.npz`` holds it to
that), and this script records there the calibrated probability of every one-step prediction:
the head's own logit of the same step, without offsets.

    PYTHONPATH=src:. OMP_NUM_THREADS=1 python tests/regression/make_calibrated_pins.py \\
        [--model flownet_v8]
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from tests.regression.make_bundled_pins import FULL_EVERY, MODELS, STREAMS, stream_recording

OUT = Path(__file__).resolve().parent / "calibrated_pins.npz"
PINS = {"bundled": OUT, "flownet_v8": OUT.with_name("flownet_v8_calibrated_pins.npz")}


def main(argv: list[str]) -> None:
    import torch

    from lidarflow.predict import Predictor

    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=OUT.parent
    ).stdout.strip()
    arrays: dict[str, np.ndarray] = {"commit": np.asarray(commit)}
    model_name = argv[argv.index("--model") + 1] if "--model" in argv else "bundled"
    out_path = PINS[model_name]
    predictor = Predictor(MODELS[model_name], threads=1)
    model, run = predictor.backend.model, predictor.backend.run
    calibrated: list[np.ndarray] = []

    def run_and_keep(maps, state, motion=None, next_motion=None):
        probability, out, state = run(maps, state, motion, next_motion)
        with torch.inference_mode():
            logit = model.next_logit(torch.from_numpy(maps), torch.from_numpy(out))
        calibrated.append(torch.sigmoid(logit)[0, 0].float().numpy())
        return probability, out, state

    predictor.backend.run = run_and_keep
    for name, source, frames in STREAMS:
        recording = stream_recording(source, frames)
        poses = recording.poses
        calibrated.clear()
        predictor.reset()
        for i, scan in enumerate(recording):
            predictor.update(scan, None if poses is None else poses[i])
        stack = np.stack(calibrated).astype(np.float64)
        arrays[f"{name}/calibrated_sum"] = stack.sum(axis=(1, 2))
        arrays[f"{name}/calibrated_full"] = np.stack(calibrated[::FULL_EVERY]).astype(np.float32)
        print(name, len(stack), "frames", file=sys.stderr)
    np.savez_compressed(out_path, **arrays)
    print(out_path, out_path.stat().st_size, "bytes", file=sys.stderr)


if __name__ == "__main__":
    main(sys.argv[1:])
