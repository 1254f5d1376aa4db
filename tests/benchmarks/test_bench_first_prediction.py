"""The first-prediction benchmark runs every way the kernels can start and writes its JSON
(smoke only: no timing is judged here; the recorded run is
benchmarks/results/first_prediction.json)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from lidarflow import compiled

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
@pytest.mark.skipif(not compiled.available(), reason="numba is not installed")
def test_bench_first_prediction_times_each_way_the_kernels_start(tmp_path):
    out = tmp_path / "first.json"
    done = subprocess.run(
        # the way that compiles in its callers is left out: it compiles everything once more
        [sys.executable, str(ROOT / "benchmarks" / "bench_first_prediction.py"), "--rounds",
         "1", "--scans", "3", "--ways", "first_run", "later_run", "numpy", "--json", str(out)],
        cwd=ROOT, env={**os.environ}, capture_output=True, text=True, timeout=900,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    ways = json.loads(out.read_text())["ways"]
    assert set(ways) == {"first_run", "later_run", "numpy"}
    for row in ways.values():
        assert 0 < row["first_s"] <= row["second_s"] <= row["compiled_s"]
        assert row["failed"] == []
    assert ways["numpy"]["pending_at_first"] == [0]  # nothing compiles without numba
    assert ways["first_run"]["pending_at_first"][0] > 0  # it predicted while compiling
    # the cache the first run left: loaded, not compiled again, so done far sooner
    assert ways["later_run"]["compiled_s"] < ways["first_run"]["compiled_s"] / 2
