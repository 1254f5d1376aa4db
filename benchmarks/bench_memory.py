"""Peak memory of ``lidarflow predict`` on the bundled sample (issue 46: at most 137 MiB in the
core install, without PyTorch).

Each run is a fresh ``python -m lidarflow predict SAMPLE -o OUT.mcap`` (the bundled model) whose
own peak resident set size (``VmHWM`` of ``/proc/self/status``, read as it exits; not
``ru_maxrss``, which a forked child inherits from its parent's peak before ``exec``) is
reported: in the core install (``torch``, ``safetensors`` and ``onnx`` blocked as
tests/without_torch.py blocks them: the bundled model's ONNX export on ONNX Runtime) and with
PyTorch. Memory does not depend on the machine's load; the median of ``--repeats`` runs is
reported beside each. Writes JSON (default ``benchmarks/results/memory.json``).

    python benchmarks/bench_memory.py [--repeats 3] [--json PATH]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from _output import machine, write_json

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
from tests.without_torch import PRELUDE  # noqa: E402

#: The issue's bound on the core install's peak, MiB.
CORE_BOUND_MIB = 137
# The command, its peak RSS written to stderr as its last line when it exits (Linux: KiB).
_REPORT_PEAK = (
    "import atexit, sys\n"
    "def _hwm():\n"
    "    with open('/proc/self/status') as f:\n"
    "        return next(int(v.split()[1]) for v in f if v.startswith('VmHWM:'))\n"
    "atexit.register(lambda: sys.stderr.write(f'\\npeak_rss_kib={_hwm()}\\n'))\n"
    "import runpy\nrunpy.run_module('lidarflow', run_name='__main__')\n"
)


def peak_rss_mib(argv: list[str], core: bool, cwd: Path) -> float:
    """The peak RSS (MiB) of ``lidarflow ARGV`` in a fresh process, in the core install where
    ``core``."""
    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}:{ROOT}", "OMP_NUM_THREADS": "1"}
    code = (PRELUDE if core else "") + _REPORT_PEAK
    done = subprocess.run(
        [sys.executable, "-c", code, *argv], cwd=cwd, env=env, capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    if done.returncode != 0:
        raise RuntimeError(f"lidarflow {' '.join(argv)} failed: {done.stderr[-2000:]}")
    last = done.stderr.strip().splitlines()[-1]
    return int(last.removeprefix("peak_rss_kib=")) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--json", type=Path, default=HERE / "results" / "memory.json")
    args = parser.parse_args()
    sys.path.insert(0, str(ROOT / "src"))
    from lidarflow.data import sample_bag_path

    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, core in (("core_install", True), ("with_torch", False)):
            peaks = [
                peak_rss_mib(
                    ["predict", str(sample_bag_path()), "-o", f"{name}_{i}.mcap"], core, Path(tmp)
                )
                for i in range(args.repeats)
            ]
            results[name] = {
                "peak_rss_mib": [round(p, 1) for p in peaks],
                "median_mib": round(statistics.median(peaks), 1),
            }
            print(f"{name}: peak RSS {results[name]['median_mib']} MiB (median of {args.repeats})")
    core = results["core_install"]
    core.update(bound_mib=CORE_BOUND_MIB, within_bound=core["median_mib"] <= CORE_BOUND_MIB)
    write_json(
        args.json,
        {
            "machine": machine(),
            "command": f"lidarflow predict {sample_bag_path().name} -o OUT.mcap (bundled model)",
            "measure": "VmHWM (/proc/self/status) of the command's process, at exit",
            "results": results,
        },
    )


if __name__ == "__main__":
    main()
