"""The README's test command and CI are one script, scripts/test.sh. Run here against stand-ins
for everything it calls (apt-get, npm, python3 and the venvs' tools, each writing its command
line to a log): it installs what is missing, lints, runs pytest with the ROS tests required,
and stops with the failing step's status."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: A stand-in: logs its name and arguments; exits with $FAIL_<name> (0 by default). `python3 -m
#: venv DIR` also makes DIR/bin with stand-ins for pip, ruff and python.
STANDIN = r"""#!/bin/bash
name=$(basename "$0")
echo "$name $* REQUIRE_ROS=${LIDARFLOW_REQUIRE_ROS:-}" >> "$LOG"
if [ "$name" = python3 ] && [ "$1" = -m ] && [ "$2" = venv ]; then
    mkdir -p "$3/bin"
    for tool in pip ruff python; do cp "$0" "$3/bin/$tool"; done
fi
failing=FAIL_${name//-/_}
exit "${!failing:-0}"
"""
#: What the script runs of the machine's own (linked into the stand-ins' PATH as they are).
REAL = ("bash", "sh", "dirname", "basename", "mkdir", "cp", "id", "cat")
#: What the script looks for before installing it.
LOOKED_FOR = ("chromium", "roscore", "rosbag", "node", "npm")


@pytest.fixture
def checkout(tmp_path):
    """A checkout holding the real scripts/test.sh and .ci/run, with an npm client installed."""
    repo = tmp_path / "repo"
    for name in ("scripts/test.sh", ".ci/run"):
        (repo / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(ROOT / name, repo / name)
    client = repo / "tests/live/npm_client"
    (client / "node_modules").mkdir(parents=True)
    (client / "package-lock.json").write_text("{}")
    (client / "node_modules/.package-lock.json").write_text("{}")
    os.utime(client / "package-lock.json", (1, 1))  # older than what is installed
    return repo


def run_script(repo: Path, argv: list[str], present=LOOKED_FOR, **fail: int):
    """Run ``argv`` in ``repo`` with only the stand-ins on PATH (those of ``present`` among what
    the script looks for); returns (exit status, the logged command lines)."""
    bin_dir = repo.parent / "bin"
    bin_dir.mkdir(exist_ok=True)
    for tool in ("apt-get", "sudo", "python3", *present):
        (bin_dir / tool).write_text(STANDIN)
        (bin_dir / tool).chmod(0o755)
    for tool in REAL:
        if not (bin_dir / tool).exists():
            (bin_dir / tool).symlink_to(shutil.which(tool))
    log = repo.parent / "log"
    log.write_text("")
    env = {"PATH": str(bin_dir), "LOG": str(log), **{f"FAIL_{k}": str(v) for k, v in fail.items()}}
    done = subprocess.run(["bash", *argv], cwd=repo, env=env, capture_output=True, text=True)
    return done.returncode, log.read_text().splitlines()


def test_the_readme_runs_the_script_ci_runs(checkout):
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", readme, flags=re.S)
    assert "bash scripts/test.sh" in [line.strip() for b in blocks for line in b.splitlines()]
    code, log = run_script(checkout, [".ci/run"], python=3)
    assert code == 3  # the suite's failure is CI's
    assert any(line.startswith("python -m pytest") for line in log)


def test_lint_then_the_whole_suite_with_the_ros_tests_required(checkout):
    code, log = run_script(checkout, ["scripts/test.sh", "-k", "x"])
    assert code == 0, log
    ruff = next(i for i, line in enumerate(log) if line.startswith("ruff check ."))
    pytest_line = log[-1]
    # on two workers (pytest-xdist), the ROS tests required
    assert pytest_line.startswith("python -m pytest -n 2 -k x ") and "REQUIRE_ROS=1" in pytest_line
    assert ruff < len(log) - 1
    assert any(line.startswith('pip install -q -e .[dev]') for line in log)
    assert any(line.startswith("pip install -q -e .[ros2]") for line in log)  # .venv-ros2


def test_the_fast_tier_leaves_out_the_slow_tests(checkout):
    code, log = run_script(checkout, ["scripts/test.sh", "--fast", "-x"])
    assert code == 0, log
    assert log[-1].startswith("python -m pytest -n 2 -m not slow -x ")


@pytest.mark.parametrize(("failing", "status"), [("ruff", 1), ("pip", 2), ("python", 5)])
def test_any_failing_step_stops_it_with_its_status(checkout, failing, status):
    # pytest's 5 is "no tests collected": a suite that ran nothing has not passed
    code, log = run_script(checkout, ["scripts/test.sh"], **{failing: status})
    assert code == status
    if failing != "python":
        assert not any(line.startswith("python -m pytest") for line in log)


def test_what_the_tests_need_is_installed_where_missing(checkout):
    from lidarflow.live.ros1 import DEBIAN_PACKAGES
    from tests.viz.test_html_render import BROWSERS

    code, log = run_script(checkout, ["scripts/test.sh"], present=())
    assert code == 0, log
    installs = [line for line in log if " install " in line and line.startswith(("apt", "sudo"))]
    assert len(installs) == 1
    wanted = installs[0].split()
    assert "chromium-headless-shell" in wanted and "chromium-headless-shell" in BROWSERS
    assert set(DEBIAN_PACKAGES.split()) <= set(wanted)
    assert {"nodejs", "npm"} <= set(wanted)
    assert installs[0].startswith("sudo" if os.getuid() != 0 else "apt-get")


def test_the_npm_client_is_installed_when_its_lock_is_newer(checkout):
    client = checkout / "tests/live/npm_client"
    os.utime(client / "node_modules/.package-lock.json", (1, 1))
    os.utime(client / "package-lock.json", None)
    code, log = run_script(checkout, ["scripts/test.sh"])
    assert code == 0, log
    assert "npm ci --prefix tests/live/npm_client --no-audit --no-fund" in " ".join(log)
