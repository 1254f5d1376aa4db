"""The core install's ``predict`` on the bundled sample peaks at or below 137 MiB (issue 46;
benchmarks/bench_memory.py reports it: 112 MiB when this was written). A peak is the process's
own resident set, not a timing, so the bound holds on a busy machine alike. It is read as
``VmHWM``, the peak of the process's own address space: ``ru_maxrss`` of a child forked by a
pytest near 1 GiB late in the suite read as ~950 MiB, the parent's peak before ``exec``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from lidarflow.data import sample_bag_path
from tests.without_torch import PRELUDE

ROOT = Path(__file__).resolve().parents[1]
BOUND_MIB = 137


@pytest.mark.slow
def test_predict_in_the_core_install_stays_within_its_memory(tmp_path):
    code = PRELUDE + (
        "import atexit, sys\n"
        "def _hwm():\n"
        "    with open('/proc/self/status') as f:\n"
        "        return next(int(v.split()[1]) for v in f if v.startswith('VmHWM:'))\n"
        "atexit.register(lambda: sys.stderr.write(f'\\npeak_rss_kib={_hwm()}\\n'))\n"
        "import runpy\nrunpy.run_module('lidarflow', run_name='__main__')\n"
    )
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}:{ROOT}", "OMP_NUM_THREADS": "1"}
    argv = ["predict", str(sample_bag_path()), "-o", "p.mcap"]
    done = subprocess.run(
        [sys.executable, "-c", code, *argv], cwd=tmp_path, env=env, capture_output=True,
        text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "/lidarflow/predicted x243" in done.stdout  # the whole sample was predicted
    peak_mib = int(done.stderr.strip().splitlines()[-1].removeprefix("peak_rss_kib=")) / 1024
    assert peak_mib <= BOUND_MIB, f"predict peaked at {peak_mib:.1f} MiB"
