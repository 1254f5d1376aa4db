"""The latency benchmark still runs on the bundled model (it once fed v8 two channels where
v8 takes four, and nothing noticed until it was next run). Smoke only: no timing is judged."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_bench_predict_runs_on_the_bundled_model(tmp_path):
    out = tmp_path / "predict.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"}
    args = ["--scans", "12", "--threads", "1", "--batch", "2", "--json", str(out)]
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_predict.py"), *args],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    results = json.loads(out.read_text())["results"]
    backends = ("torch_eager_fp32", "onnxruntime_fp32", "onnxruntime_int8")
    backends += ("onnxruntime_fp32_online",)
    assert all(results["threads=1"][b]["median_ms"] > 0 for b in backends)
    assert results["batched"]["torch_scans_per_s"] > 0
