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
    args = ["--episodes", "1", "--crowds", "0", "2", "--workers", "2", "--json", str(out)]
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


@pytest.mark.slow
def test_bench_navigation_resumes_from_its_log(tmp_path):
    """A rerun with the same log runs nothing again and reports the same numbers; a torn last
    line (a run killed while writing it) is run again, not misread."""
    log = tmp_path / "episodes.jsonl"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"}

    def run(out: Path, *more: str) -> subprocess.CompletedProcess:
        args = ["--episodes", "2", "--crowds", "2", "--sources", "last_scan", "tracker",
                "--json", str(out), "--log", str(log), *more]  # fmt: skip
        return subprocess.run(
            [sys.executable, str(ROOT / "benchmarks" / "bench_navigation.py"), *args],
            cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
        )  # fmt: skip

    first = run(tmp_path / "a.json")
    assert first.returncode == 0, first.stderr[-2000:]
    assert len(log.read_text().splitlines()) == 4
    log.write_text(log.read_text()[:-20])  # the last episode torn
    second = run(tmp_path / "b.json")
    assert second.returncode == 0, second.stderr[-2000:]
    assert "3 of 4 episodes already in" in second.stdout
    a, b = (json.loads((tmp_path / n).read_text()) for n in ("a.json", "b.json"))
    for source in ("last_scan", "tracker"):
        assert a[source] == b[source]
    rows = [json.loads(line) for line in log.read_text().splitlines()[-1:]]
    assert rows[0]["source"] in ("last_scan", "tracker")  # the rerun's line stands on its own
    kept = log.read_bytes()
    third = run(tmp_path / "c.json", "--from-log", "--episodes", "3")  # one more asked: not run
    assert third.returncode == 0, third.stderr[-2000:]
    assert log.read_bytes() == kept
    c = json.loads((tmp_path / "c.json").read_text())
    assert c["setup"]["from_log"] and c["last_scan"] == b["last_scan"]


def test_wilson_interval_holds_the_rate_at_every_count():
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        from bench_navigation import wilson
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    for n in (1, 7, 100, 1000):
        for k in range(n + 1):
            low, high = wilson(k, n)
            assert 0.0 <= low <= k / n <= high <= 1.0
    assert wilson(0, 0) is None


@pytest.mark.slow
def test_the_combined_source_plans_on_a_combining_predictor_of_its_own():
    """``lidarflow_combined`` runs the bundled model with the online combination, in a
    Predictor apart from the plain source's (sharing one would mix the two)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import bench_navigation as bench
    finally:
        sys.path.remove(str(ROOT / "benchmarks"))
    bench._PREDICTORS.clear()
    name, walkers, seed, outcome = bench.episode(("lidarflow_combined", 2, 0))
    assert (name, walkers, seed) == ("lidarflow_combined", 2, 0)
    assert outcome.success or outcome.collision or outcome.time_s > 0
    (combined,) = bench._PREDICTORS.values()
    assert combined.combination is not None and combined.combination.horizon == combined.horizon
    bench.episode(("lidarflow", 2, 0))
    plain = [p for p in bench._PREDICTORS.values() if p is not combined]
    assert len(plain) == 1 and plain[0].combination is None
