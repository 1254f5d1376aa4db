"""SOGMP's cost benchmark still runs, PyTorch and onnxruntime, beside the bundled model. Smoke
only: no timing is judged, but the parameters it reports are."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from tests.conftest import make_model_dir

ROOT = Path(__file__).resolve().parents[2]


def test_bench_sogmp_runs_and_reports_both_backends(tmp_path):
    run = make_model_dir(tmp_path / "sogmp", name="sogmp", ego_motion=True)
    out = tmp_path / "sogmp.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"}
    args = [str(run), "--rounds", "1", "--steps", "5", "--json", str(out)]
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_sogmp.py"), *args],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(out.read_text())
    assert result["parameters"] == {"bundled": 194, str(run): 730_245}  # v9: the head alone
    assert all(result["ratio_over_bundled"][b] > 0 for b in ("torch", "onnxruntime"))
