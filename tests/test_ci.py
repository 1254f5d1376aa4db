"""CI runs what the README says, after installing what the tests need."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_ci_runs_the_readmes_test_command_last():
    readme = (ROOT / "README.md").read_text()
    command = next(line for line in readme.splitlines() if "-m pytest" in line).strip()
    script = (ROOT / ".ci" / "run").read_text()
    lines = [line.strip() for line in script.splitlines() if line.strip()]
    assert lines[-1] == command
    assert "set -euo pipefail" in script  # any failure stops it, non-zero


def test_ci_installs_the_browser_the_html_test_looks_for():
    from tests.viz.test_html_render import BROWSERS

    script = (ROOT / ".ci" / "run").read_text()
    assert "apt-get install" in script and "chromium-headless-shell" in script
    checked = set(re.findall(r"command -v ([\w-]+)", script))
    assert checked - {"roscore", "rosbag"} == set(BROWSERS)


def test_ci_installs_ros_1_and_makes_its_tests_fail_rather_than_skip():
    from lidarflow.live.ros1 import DEBIAN_PACKAGES

    script = (ROOT / ".ci" / "run").read_text()
    assert all(package in script for package in DEBIAN_PACKAGES.split())
    assert "export LIDARFLOW_REQUIRE_ROS=1" in script
