"""What int8 quantization (`lidarflow export --int8`) costs in accuracy.

Exports a model twice (float32 and int8, the latter calibrated on --calibration, which should
not be one of the evaluated recordings), streams each evaluated recording through both ONNX
graphs with onnxruntime, and writes F1 / changed-cell F1 / AP per recording and the largest
probability difference.

    python -m studies.int8_accuracy --calibration ../shared/data/positive_1.bag \\
        --recordings ../shared/data/positive_2.bag ../shared/data/datmo_overtakes.bag

Writes OUT/int8_accuracy.json (per recording: each graph's F1 / changed-cell F1 / AP and the
largest probability difference) and OUT/int8_accuracy.md.
"""

from __future__ import annotations

import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.data import load_any
from lidarflow.evaluate.runner import evaluate_maps
from lidarflow.models.presets import resolve_model
from lidarflow.outputs.export import export_onnx
from lidarflow.outputs.quantize import quantize_onnx
from lidarflow.predict import Predictor
from lidarflow.scan import GridSpec, Scan, takes_subcell
from studies.harness import parse, parser, write_summary


class OnnxMethod:
    """An evaluate method around a Predictor fed the recording's scans (what a robot gives
    it; a ``subcell_input`` model needs them); remembers every probability it gave."""

    def __init__(self, name: str, path: Path, scans: list[Scan], threads: int = 1) -> None:
        self.name, self.predictor = name, Predictor(path, threads=threads)
        self.scans = scans
        self.probabilities: list[np.ndarray] = []

    def reset(self) -> None:
        self.predictor.reset()
        self.probabilities = []

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: object = None
    ) -> np.ndarray:
        prediction = self.predictor.update(self.scans[len(self.probabilities)])
        assert (prediction.occupancy == occupancy).all()  # the frame evaluate scores
        self.probabilities.append(prediction.probability)
        return prediction.probability


def markdown(results: dict[str, dict[str, Any]]) -> str:
    lines = [
        "| recording | F1 float32 / int8 | changed F1 float32 / int8 | AP float32 / int8 | "
        "max probability difference |",
        "|---|---|---|---|---|",
    ]
    for name, r in results.items():
        f, q = r["float32"], r["int8"]
        cells = [f"{f[k]:.4f} / {q[k]:.4f}" for k in ("f1", "changed_f1", "ap")]
        lines.append(
            f"| {name} | " + " | ".join(cells) + f" | {r['max_probability_difference']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, dict[str, Any]]:
    p = parser("int8_accuracy", __doc__)
    p.add_argument("--model", default=None, help="run folder (default: the bundled model)")
    p.add_argument(
        "--calibration",
        type=Path,
        required=True,
        help="recording to calibrate int8 on (not one of --recordings)",
    )
    p.add_argument("--recordings", type=Path, nargs="+", required=True)
    p.add_argument("--threads", type=int, default=1, help="threads of each ONNX session")
    args = parse(p, argv)  # fmt: skip
    grid = GridSpec()
    net, _ = resolve_model(args.model)
    results: dict[str, dict[str, Any]] = {}
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
                OnnxMethod("float32", float_path, scans, args.threads),
                OnnxMethod("int8", int8_path, scans, args.threads),
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
    write_summary(args, "int8_accuracy", results, markdown(results))
    return results


if __name__ == "__main__":
    main()
