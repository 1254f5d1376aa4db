#!/usr/bin/env bash
# The test suite on any machine, from a fresh clone: the README's test command and what `.ci/run`
# runs, so the two cannot differ. In order:
#   1. from Debian, what the tests need where it is missing: headless Chromium (the HTML report's
#      browser test, tests/viz/test_html_render.py) and ROS 1 (the live node's end-to-end tests,
#      tests/live/test_ros1_node.py) and Node.js with npm, with sudo when not root;
#   2. the npm Foxglove client of tests/live/test_foxglove_npm.py (`npm ci` in
#      tests/live/npm_client, where its node_modules is missing or older than its lock file);
#   3. the venv (.venv) with the project and its dev extra, and beside it .venv-ros2: the core
#      install with the ros2 extra (ROS 2 Jazzy's wheels from PyPI), which the ROS 2 node's tests
#      (tests/live/test_ros2_node.py) run the node and its peers with; a venv of its own, as its
#      message packages would shadow ROS 1's in .venv;
#   4. ruff, then the whole suite on two workers (pytest-xdist). LIDARFLOW_REQUIRE_ROS=1 makes
#      the ROS tests (ROS 1 and ROS 2) and the npm client's fail rather than skip, so the suite
#      never passes by skipping them.
# Any failure stops it with a non-zero exit, pytest's 5 ("no tests collected") included.
# `--fast` (first argument): the fast tier, for a developer's loop: the tests not marked `slow`
# (under 2 minutes); CI runs everything. Other arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")/.."
tier=()
if [ "${1:-}" = "--fast" ]; then
    shift
    tier=(-m "not slow")
fi

missing=()
if ! command -v chromium-headless-shell >/dev/null && ! command -v chromium >/dev/null \
    && ! command -v chromium-browser >/dev/null; then
    missing+=(chromium-headless-shell)
fi
# keep in step with lidarflow.live.ros1.DEBIAN_PACKAGES
if ! command -v roscore >/dev/null || ! command -v rosbag >/dev/null \
    || ! /usr/bin/python3 -c "import rospy, rosbag, sensor_msgs.msg, nav_msgs.msg, tf2_msgs.msg" \
        2>/dev/null; then
    missing+=(ros-core python3-rospy python3-rosbag python3-sensor-msgs python3-nav-msgs
        python3-tf2-msgs)
fi
# the npm Foxglove client of tests/live/test_foxglove_npm.py runs on Node.js
if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
    missing+=(nodejs npm)
fi
if [ "${#missing[@]}" -gt 0 ]; then
    echo "scripts/test.sh: installing from Debian: ${missing[*]}" >&2
    sudo=()
    if [ "$(id -u)" -ne 0 ]; then sudo=(sudo); fi
    "${sudo[@]}" apt-get update -q
    DEBIAN_FRONTEND=noninteractive "${sudo[@]}" apt-get install -y -q --no-install-recommends \
        "${missing[@]}"
fi

npm_client=tests/live/npm_client
if [ ! -d "$npm_client/node_modules" ] \
    || [ "$npm_client/package-lock.json" -nt "$npm_client/node_modules/.package-lock.json" ]; then
    echo "scripts/test.sh: installing the npm Foxglove client ($npm_client)" >&2
    npm ci --prefix "$npm_client" --no-audit --no-fund
fi

python3 -m venv .venv
.venv/bin/pip install -q -e ".[dev]"
python3 -m venv .venv-ros2
.venv-ros2/bin/pip install -q -e ".[ros2]"
.venv/bin/ruff check .
export LIDARFLOW_REQUIRE_ROS=1
# Two workers, one a core of the 2-core machines CI runs on, each at one thread (PyTorch's and
# NumPy's own threads beside a second worker only wait on each other).
export OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}"
exec .venv/bin/python -m pytest -n 2 ${tier[@]+"${tier[@]}"} "$@"
