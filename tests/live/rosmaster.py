"""A real ROS 1 master for tests: ``roscore`` on a free port, its logs in a temporary folder.

ROS 1 comes from Debian's packages (``lidarflow.live.ros1.DEBIAN_PACKAGES``). Where they are
missing the tests using it skip, unless ROS is required: under ``scripts/test.sh`` (the README's
test command, which ``.ci/run`` runs; it installs the packages and sets
``LIDARFLOW_REQUIRE_ROS=1``) or where ``CI`` is set they fail instead, so that CI never passes by
skipping them.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
import xmlrpc.client
from collections.abc import Iterator
from pathlib import Path

import pytest

SYSTEM_PYTHON = "/usr/bin/python3"


def ros_missing() -> str | None:
    """Why ROS 1 cannot be used here, or ``None`` where it can."""
    for tool in ("roscore", "rosbag", "rostopic"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed"
    probe = "import rospy, rosbag, sensor_msgs.msg, nav_msgs.msg, tf2_msgs.msg"
    done = subprocess.run([SYSTEM_PYTHON, "-c", probe], capture_output=True, text=True)
    if done.returncode != 0:
        return f"Debian's python3 lacks ROS 1: {done.stderr.strip().splitlines()[-1]}"
    return None


def require_ros() -> None:
    """Skip where ROS 1 is missing, or fail where it is required."""
    why = ros_missing()
    if why is None:
        return
    from lidarflow.live.ros1 import DEBIAN_PACKAGES

    message = f"{why}: apt-get install {DEBIAN_PACKAGES}"
    if os.environ.get("LIDARFLOW_REQUIRE_ROS") or os.environ.get("CI"):
        pytest.fail(f"ROS 1 is required here (CI): {message}")
    pytest.skip(message)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def stop(process: subprocess.Popen, sig: int = signal.SIGTERM, wait_s: float = 15.0) -> int:
    """Stop ``process`` and what it started (its own process group) and reap it."""
    if process.poll() is None:
        try:
            os.killpg(process.pid, sig)
            return process.wait(wait_s)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return process.wait()


@pytest.fixture(scope="module")
def ros_env(tmp_path_factory) -> Iterator[dict[str, str]]:
    """The environment of processes talking to a fresh ``roscore`` (started here)."""
    require_ros()
    home = tmp_path_factory.mktemp("ros_home")
    uri = f"http://127.0.0.1:{free_port()}"
    env = {**os.environ, "ROS_MASTER_URI": uri, "ROS_HOME": str(home),
           "ROS_LOG_DIR": str(home / "log"), "ROS_IP": "127.0.0.1"}  # fmt: skip
    env.pop("ROS_HOSTNAME", None)
    log = open(home / "roscore.log", "w")  # noqa: SIM115 (closed below, after roscore)
    core = subprocess.Popen(["roscore", "-p", uri.rsplit(":", 1)[1]], env=env, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                xmlrpc.client.ServerProxy(uri).getPid("/test")
                break
            except OSError:
                if core.poll() is not None or time.monotonic() > deadline:
                    pytest.fail(f"roscore did not start: {Path(log.name).read_text()[-500:]}")
                time.sleep(0.2)
        yield env
    finally:
        stop(core, signal.SIGINT)
        log.close()
