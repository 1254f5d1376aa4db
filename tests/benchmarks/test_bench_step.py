"""The step benchmark runs the reference, this checkout without and with its compiled kernels
and the reference workload (smoke only: no timing is judged here; the recorded run is
benchmarks/results/step.json)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
VARIANTS = ("reference", "current_numpy", "current")
SETTINGS = ("fixed", "online", "online_h8", "noposes")


@pytest.mark.slow
def test_bench_step_times_every_variant_and_setting_against_the_workload(tmp_path):
    out = tmp_path / "step.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    done = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_step.py"), "--scans", "2",
         "--chunk", "1", "--threads", "1", "--backends", "default", "--no-batch",
         "--json", str(out)],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(out.read_text())
    assert result["reference"] == "d4a70f5" and result["batched_scans_per_s"] == {}
    assert result["variants"]["current_numpy"]["env"] == {"LIDARFLOW_COMPILED": "0"}
    workload = result["reference_workload"]["median_ms"]
    assert workload > 0 and result["reference_workload"]["samples"] == 2 * len(VARIANTS)
    assert "estimate" in result["derived"]["one_second_at_40hz_ms"]
    row = result["results"]["threads=1"]
    assert row["current_numpy"]["compiled_kernels"] is not True  # turned off (or not there)
    for variant in VARIANTS:
        got = row[variant]
        for setting in SETTINGS:
            ms = got[f"default/{setting}_median_ms"]
            assert ms > 0 and got[f"default/{setting}_median_per_reference"] == ms / workload
        step = got["default_rollout_step_ms"]
        assert step == (got["default/online_h8_median_ms"] - got["default/online_median_ms"]) / 7
        assert got["default_one_second_at_40hz_ms"] == got["default/online_median_ms"] + 40 * step
    for variant in VARIANTS[1:]:
        ratios = row[f"ratio_{variant}_to_reference"]
        key = "default/noposes_median_ms"
        assert ratios[key] == row[variant][key] / row["reference"][key]
