"""The scan odometry benchmark runs the reference code beside this one (smoke only: no timing
is judged here; the recorded run is benchmarks/results/scan_odometry.json)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from lidarflow.data.samples import sample_bag_path

ROOT = Path(__file__).resolve().parents[2]


def test_bench_scan_odometry_times_both_codes_and_they_find_the_same_motions(tmp_path):
    out = tmp_path / "scan_odometry.json"
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}:{ROOT}"}
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_scan_odometry.py"), "--frames", "15",
         "--rounds", "1", "--json", str(out), str(sample_bag_path())],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(out.read_text())
    assert result["reference"] == "d4a7e7a" and len(result["load"]) == 2
    (row,) = result["results"].values()
    for timing in ("scan_matching", "scan_matching_cpu", "update_without_poses"):
        assert row[f"{timing}_reference_ms"] > 0 and row[f"{timing}_now_ms"] > 0
        assert row[f"{timing}_ratio"] == row[f"{timing}_now_ms"] / row[f"{timing}_reference_ms"]
    assert row["accuracy_now"] == row["accuracy_reference"]
