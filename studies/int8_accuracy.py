"""What int8 quantization (`lidarflow export --int8`) costs in accuracy.

Exports a model twice (float32 and int8, the latter calibrated on --calibration, which should
not be one of the evaluated recordings), streams each evaluated recording through both ONNX
graphs with onnxruntime, and writes F1 / changed-cell F1 / AP per recording and the largest
probability difference.

    python experiments/int8_accuracy.py --calibration ../shared/data/positive_1.bag \\
        --recordings ../shared/data/positive_2.bag ../shared/data/datmo_overtakes.bag \\
        --json docs/results/speed/int8_accuracy.json
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

from lidarflow.data import load_any
from lidarflow.evaluate.stream import evaluate_maps
from lidarflow.models.presets import resolve_model
from lidarflow.predict import Predictor
from lidarflow.predict.export import export_onnx
from lidarflow.predict.quantize import quantize_onnx
from lidarflow.scan import GridSpec, Scan, takes_subcell


class OnnxMethod:
    """An evaluate method around a Predictor fed the recording's scans (what a robot gives
    it; a ``subcell_input`` model needs them); remembers every probability it gave."""

    def __init__(self, name: str, path: Path, scans: list[Scan]) -> None:
        self.name, self.predictor = name, Predictor(path, threads=2)
        self.scans = scans
        self.probabilities: list[np.ndarray] = []

    def reset(self) -> None:
        self.predictor.reset()
        self.probabilities = []

    def update(self, occupancy: np.ndarray, visibility: np.ndarray) -> np.ndarray:
        prediction = self.predictor.update(self.scans[len(self.probabilities)])
        assert (prediction.occupancy == occupancy).all()  # the frame evaluate scores
        self.probabilities.append(prediction.probability)
        return prediction.probability


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=None, help="run folder (default: bundled model)")
    parser.add_argument("--calibration", type=Path, required=True)
    parser.add_argument("--recordings", type=Path, nargs="+", required=True)
    parser.add_argument("--json", type=Path, required=True)
    args = parser.parse_args()
    grid = GridSpec()
    net, _ = resolve_model(args.model)
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        float_path = export_onnx(net, Path(tmp) / "float.onnx")
        calibration = load_any(args.calibration)
        maps = calibration.stacked_maps(grid, subcell=takes_subcell(net.input_channels))
        int8_path = quantize_onnx(float_path, Path(tmp) / "int8.onnx", maps)
        for path in args.recordings:
            recording = load_any(path)
            occupancy, visibility = recording.maps(grid)
            scans = list(recording)
            methods = [
                OnnxMethod("float32", float_path, scans),
                OnnxMethod("int8", int8_path, scans),
            ]
            scores = evaluate_maps(occupancy, visibility, methods)
            summary = {name: s.summary() for name, s in scores.items()}
            difference = max(
                float(np.abs(a - b).max())
                for a, b in zip(methods[0].probabilities, methods[1].probabilities, strict=True)
            )
            results[path.name] = {
                name: {k: summary[name][k] for k in ("f1", "changed_f1", "ap")} for name in summary
            } | {"max_probability_difference": difference}
            f, q = summary["float32"], summary["int8"]
            print(
                f"{path.name}: F1 {f['f1']:.4f} -> {q['f1']:.4f}, changed F1 "
                f"{f['changed_f1']:.4f} -> {q['changed_f1']:.4f}, AP {f['ap']:.4f} -> "
                f"{q['ap']:.4f}, max |dp| {difference:.3f}",
                flush=True,
            )
    report = {
        "model": args.model or "bundled",
        "calibration": args.calibration.name,
        "recordings": results,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")


if __name__ == "__main__":
    main()
