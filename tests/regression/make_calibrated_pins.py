"""Write the pins of the bundled model's calibrated probability (run once, at main ``9f9eedb``).

Until issue 35 the Predictor's ``probability`` was the decided one (the head's logit shifted by
the decision offsets); since, it is the calibrated ``sigmoid(logit)`` and the decision is only in
``occupied``. ``9f9eedb`` predicts exactly what ``a4a22da`` did (``bundled_pins.npz`` holds it to
that), and this script records there the calibrated probability of every one-step prediction:
the head's own logit of the same step, without offsets.

    PYTHONPATH=src:. OMP_NUM_THREADS=1 python tests/regression/make_calibrated_pins.py
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from tests.regression.make_bundled_pins import FULL_EVERY, STREAMS, stream_recording

OUT = Path(__file__).resolve().parent / "calibrated_pins.npz"


def main() -> None:
    import torch

    from lidarflow.predict import Predictor

    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=OUT.parent
    ).stdout.strip()
    arrays: dict[str, np.ndarray] = {"commit": np.asarray(commit)}
    predictor = Predictor(threads=1)
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
    np.savez_compressed(OUT, **arrays)
    print(OUT, OUT.stat().st_size, "bytes", file=sys.stderr)


if __name__ == "__main__":
    main()
