"""DDP under torchrun: 2 CPU processes (gloo) train a few steps and stay identical."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from lidarflow.train.distributed import Dist, all_reduce_sum, any_flag, setup

ROOT = Path(__file__).resolve().parents[2]


def test_single_process_needs_no_process_group(monkeypatch):
    for var in ("WORLD_SIZE", "RANK", "LOCAL_RANK"):
        monkeypatch.delenv(var, raising=False)
    ctx = setup("cpu")
    assert ctx == Dist() and ctx.is_main and not ctx.enabled
    assert all_reduce_sum(ctx, [1.0, 2.5]) == [1.0, 2.5] and any_flag(ctx, True)


@pytest.mark.slow
def test_two_processes_under_torchrun_keep_identical_weights(blob_files, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), str(ROOT)]),
        "OMP_NUM_THREADS": "1",
    }
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--standalone",
        "--nproc_per_node",
        "2",
        str(ROOT / "tests" / "train" / "ddp_worker.py"),
        str(blob_files[0]),
        str(tmp_path / "run"),
        str(out),
    ]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    w0, w1 = load_file(out / "rank0.safetensors"), load_file(out / "rank1.safetensors")
    assert all(torch.equal(w0[k], w1[k]) for k in w0)
    assert any(not torch.equal(v, torch.zeros_like(v)) for k, v in w0.items() if "conv_flow" in k)
    # both ranks agree on the loss (summed over ranks), and only rank 0 wrote the run
    assert (out / "rank0.rows").read_text() == (out / "rank1.rows").read_text() != "[]"
    saved = load_file(tmp_path / "run" / "model.safetensors")
    assert all(torch.equal(saved[k], w0[k]) for k in w0)
    rows = [json.loads(x) for x in (tmp_path / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["epoch"] for r in rows] == [0, 1, 2]
    assert "world_size" in (tmp_path / "run" / "run.json").read_text()
    assert json.loads((tmp_path / "run" / "run.json").read_text())["world_size"] == 2
