"""The thread benchmark runs (smoke only: no timing is judged here; the recorded run is
benchmarks/results/threads.json)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def test_bench_threads_runs_every_setting(tmp_path):
    out = tmp_path / "threads.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_threads.py"), "--scans", "2",
         "--chunk", "1", "--json", str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(out.read_text())
    for case in ("busy", "idle"):
        rows = result["results"][case]
        assert set(rows) == {"default", "threads=1", "threads=2", "library"}
        assert rows["default"]["torch_threads"] == 1 and rows["threads=2"]["torch_threads"] == 2
        assert all(r["scans"] == 2 and r["median_ms"] > 0 for r in rows.values())
