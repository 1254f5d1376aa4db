"""The README's test command and CI are one script, scripts/test.sh, which installs what the tests
need before it runs them."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "test.sh"


def _lines(path: Path) -> list[str]:
    return [line.strip() for line in path.read_text().splitlines() if line.strip()]


def test_the_readme_and_ci_run_the_same_script():
    readme = (ROOT / "README.md").read_text()
    blocks = re.findall(r"```bash\n(.*?)```", readme, flags=re.S)
    commands = [line.strip() for block in blocks for line in block.splitlines()]
    assert "bash scripts/test.sh" in commands
    ci = _lines(ROOT / ".ci" / "run")
    assert ci[-1] == "bash scripts/test.sh"
    assert "set -euo pipefail" in ci


def test_the_script_stops_on_any_failure_and_ends_in_pytest():
    lines = _lines(SCRIPT)
    assert "set -euo pipefail" in lines
    assert lines[-1].startswith("exec .venv/bin/python -m pytest")
    assert ".venv/bin/ruff check ." in lines
    assert 'python3 -m venv .venv' in lines


def test_the_script_installs_the_browser_the_html_test_looks_for():
    from tests.viz.test_html_render import BROWSERS

    script = SCRIPT.read_text()
    assert "apt-get install" in script and "chromium-headless-shell" in script
    checked = set(re.findall(r"command -v ([\w-]+)", script))
    assert checked - {"roscore", "rosbag", "node", "npm"} == set(BROWSERS)
    assert '(sudo)' in script and "id -u" in script  # sudo when not root


def test_the_script_installs_ros_1_and_makes_its_tests_fail_rather_than_skip():
    from lidarflow.live.ros1 import DEBIAN_PACKAGES

    script = SCRIPT.read_text()
    assert all(package in script for package in DEBIAN_PACKAGES.split())
    assert "export LIDARFLOW_REQUIRE_ROS=1" in script


def test_the_script_installs_node_and_the_npm_foxglove_client():
    from tests.live.test_foxglove_npm import CLIENT

    script = SCRIPT.read_text()
    folder = CLIENT.relative_to(ROOT).as_posix()
    assert f"npm_client={folder}" in script
    assert 'npm ci --prefix "$npm_client"' in script
    assert (CLIENT / "package-lock.json").is_file()  # what `npm ci` installs, pinned
    assert "command -v node" in script and "command -v npm" in script
    assert "missing+=(nodejs npm)" in script  # from Debian where missing, as the rest


def test_the_script_installs_the_ros_2_extra_its_test_runs_the_node_with():
    import tomllib

    from tests.live.test_ros2_node import ROS2_PYTHON

    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    assert any(package.startswith("ros-jazzy-rclpy") for package in extras["ros2"])
    # apart from ROS 1: ROS 2's message packages would shadow Debian's ROS 1 ones in one venv
    assert not any("ros2" in package or "ros-" in package for package in extras["dev"])
    lines = _lines(SCRIPT)
    assert "python3 -m venv .venv-ros2" in lines
    assert '.venv-ros2/bin/pip install -q -e ".[ros2]"' in lines
    assert ROS2_PYTHON == ROOT / ".venv-ros2" / "bin" / "python"
    assert "export LIDARFLOW_REQUIRE_ROS=1" in SCRIPT.read_text()
