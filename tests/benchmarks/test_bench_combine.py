"""The combination's cost benchmark still runs on the bundled model. Smoke only: no timing is
judged, but the memory it reports must be what the combination holds."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def bench(tmp_path: Path, *args: str) -> dict:
    """``bench_combine.py`` on 14 scans, one round, ``args`` beside: its JSON."""
    out = tmp_path / "combine.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"}
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_combine.py"), "--scans", "14",
         "--rounds", "1", "-o", str(out), *args],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(out.read_text())


def test_bench_combine_runs_and_reports_every_predictor(tmp_path):
    result = bench(tmp_path, "--horizons", "1", "3")
    horizons = result["horizons"]
    assert set(horizons) == {"1", "3"} and result["poses"] is None
    for entry in horizons.values():
        assert entry["median_ms"]["plain"] > 0 and entry["ratio"] > 0 and entry["learn_ratio"] > 0
    # K = 3 keeps 1 + 2 + 3 frames of five experts' maps waiting: more than K = 1's one
    assert horizons["3"]["combination_bytes"] > horizons["1"]["combination_bytes"] > 0


def test_bench_combine_with_poses_says_so(tmp_path):
    result = bench(tmp_path, "--horizons", "2", "--poses")
    assert result["poses"] and result["horizons"]["2"]["ratio"] > 0
