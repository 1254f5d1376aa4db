"""The navigation benchmark runs end to end on one episode per source and writes its keys.
Smoke only: no rate is judged."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
KEYS = ("episodes", "success_rate", "collision_rate", "min_distance_m", "time_s")


@pytest.mark.slow
def test_bench_navigation_writes_every_source_and_crowd(tmp_path):
    out = tmp_path / "navigation.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"}
    args = ["--episodes", "1", "--crowds", "0", "2", "--json", str(out)]
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_navigation.py"), *args],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(out.read_text())
    for source in ("last_scan", "lidarflow", "tracker", "true_future"):
        for crowd in ("0", "2"):
            row = result[source][crowd]
            assert row["episodes"] == 1
            for key in KEYS[1:]:
                assert key in row and f"{key}_ci" in row
        assert result[source]["0"]["min_distance_m"] is None  # nobody to keep away from
    assert result["setup"]["crowds"] == [0, 2]
