"""Run the ``lidarflow`` command in a child process under an address-space limit (issue 51): a
small input that would take gigabytes must end in lidarflow's one-line error there, as on a
robot whose node would otherwise be killed by the kernel without a word."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GIB = 1 << 30


def run_limited(
    argv: list[str], cwd: Path, limit_bytes: int = 2 * GIB, timeout: float = 300
) -> subprocess.CompletedProcess[str]:
    """``lidarflow *argv`` in ``cwd`` with ``RLIMIT_AS`` at ``limit_bytes`` (the interpreter and
    lidarflow's imports take under 200 MB of it)."""

    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))

    env = {**os.environ, "PYTHONPATH": f"{ROOT / 'src'}:{ROOT}", "OMP_NUM_THREADS": "1"}
    env.pop("LIDARFLOW_DEBUG", None)
    return subprocess.run(
        [sys.executable, "-m", "lidarflow", *argv], cwd=cwd, env=env, capture_output=True,
        text=True, timeout=timeout, preexec_fn=limit,
    )  # fmt: skip


def one_line_error(done: subprocess.CompletedProcess[str]) -> str:
    """The one line ``done`` ended with on stderr, checked to be lidarflow's error for bad
    input (not an internal error, not a traceback)."""
    lines = [line for line in done.stderr.splitlines() if line.startswith("lidarflow:")]
    assert done.returncode == 1, done.stderr[-2000:]
    assert "Traceback" not in done.stderr, done.stderr[-2000:]
    assert len(lines) == 1 and lines[0].startswith("lidarflow: error: "), done.stderr[-2000:]
    return lines[0]
