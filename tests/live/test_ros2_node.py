"""``lidarflow ros2`` end to end, against real rclpy over DDS: the node as its own process (the
core install, PyTorch blocked, an ONNX model), a peer process publishing the bundled sample's
scans at their recorded pace and a subscriber process receiving the grids
(tests/live/ros2_peer.py), each in a ROS domain of this run's own, discovery kept on localhost.

Checked as the ROS 1 node's test checks it (tests/live/test_ros1_node.py): one grid per scan on
every topic, stamps (a grid k frames ahead: the scan's stamp plus k steps, ``map_load_time`` the
scan's), the scan's frame, the layout the bag output writes, values in -1..100, the first grids
cell for cell against the Predictor offline, and a clean shutdown.

ROS 2 comes from the ``ros2`` extra, which ``scripts/test.sh`` installs in a venv of its own
(:data:`ROS2_PYTHON`: the core install and ROS 2's wheels, no PyTorch; ROS 2's message packages
would shadow ROS 1's in the test venv); the node and the peers run with that Python
(``LIDARFLOW_ROS2_PYTHON`` names another; without either, this one). Where rclpy is missing
these tests skip, unless ROS is required (``LIDARFLOW_REQUIRE_ROS=1``, as scripts/test.sh sets,
or ``CI``): then they fail, so that CI never passes by skipping them.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.outputs.grids import grid_topics, prediction_grids
from lidarflow.predict import Predictor
from tests.live.rosmaster import stop
from tests.live.test_ros1_node import bag_output_layout
from tests.without_torch import MAIN, PRELUDE

PEER = Path(__file__).with_name("ros2_peer.py")
ROOT = Path(__file__).resolve().parents[2]
#: The Python with the ``ros2`` extra that scripts/test.sh sets up.
ROS2_PYTHON = ROOT / ".venv-ros2" / "bin" / "python"


def ros2_python() -> str:
    """The Python the node and its peers run with."""
    named = os.environ.get("LIDARFLOW_ROS2_PYTHON")
    if named:
        return named
    return str(ROS2_PYTHON) if ROS2_PYTHON.exists() else sys.executable
SCAN_TOPIC = "/right_scan"
HORIZON = 2
GRIDS = grid_topics(HORIZON, moving=True, occupancy=False)
SCANS = 60  # of the sample, at its recorded pace (7.5 Hz): 8 s
KEEP = 12  # grids per topic compared with the Predictor's own


def ros2_missing() -> str | None:
    """Why rclpy cannot be used by this Python, or ``None`` where it can."""
    probe = "import rclpy, sensor_msgs.msg, nav_msgs.msg, std_msgs.msg"
    done = subprocess.run([ros2_python(), "-c", probe], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    if done.returncode != 0:
        return f"{ros2_python()} lacks ROS 2: {done.stderr.strip().splitlines()[-1]}"
    return None


@pytest.fixture(scope="module")
def ros2_env() -> dict[str, str]:
    """The environment of the node and its peers: a ROS domain of this run's own (parallel runs
    on one machine do not hear each other), discovery on localhost only."""
    why = ros2_missing()
    if why is not None:
        from lidarflow.live.ros2 import ROS2_EXTRA

        message = f"{why}: {ROS2_EXTRA}"
        if os.environ.get("LIDARFLOW_REQUIRE_ROS") or os.environ.get("CI"):
            pytest.fail(f"ROS 2 is required here (CI): {message}")
        pytest.skip(message)
    # 1..100: domains above 101 collide with Linux's ephemeral ports
    domain = 1 + (os.getpid() + time.time_ns() // 1_000_000) % 100
    return {**os.environ, "ROS_DOMAIN_ID": str(domain), "OMP_NUM_THREADS": "1",
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}  # fmt: skip


def start_node(env: dict, log: Path, *args: str) -> subprocess.Popen:
    """``lidarflow ros2 ARGS`` as the core install runs it (no PyTorch), in its own process
    group, logging to ``log``; returns once it published its topics (or ended)."""
    node = subprocess.Popen([ros2_python(), "-c", MAIN, "ros2", *args], env=env,
                            stdout=subprocess.DEVNULL, stderr=log.open("w"),
                            start_new_session=True)  # fmt: skip
    wait_for(lambda: "publishing" in log.read_text() or node.poll() is not None, 90, log)
    return node


def peer(env: dict, log: Path, *args: str) -> subprocess.Popen:
    return subprocess.Popen([ros2_python(), str(PEER), *args], env=env, stdout=log.open("w"),
                            stderr=subprocess.STDOUT, start_new_session=True)  # fmt: skip


def wait_for(ready, timeout_s: float, log: Path) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out; {log.name}: {log.read_text()[-1500:]}")
        time.sleep(0.1)


def test_the_node_publishes_one_grid_per_scan_stamped_laid_out_and_valued_as_offline(
    ros2_env, flow_onnx, tmp_path
):
    recording = read_bag(sample_bag_path())
    node_log, sub_log, pub_log = (tmp_path / f"{name}.log" for name in ("node", "sub", "pub"))
    # a queue that drops nothing, should the loaded machine fall behind the scans
    node = start_node(ros2_env, node_log, "-m", str(flow_onnx), "--topic", SCAN_TOPIC,
                      "--horizon", str(HORIZON), "--moving", "-v", "--queue", "1000")  # fmt: skip
    listener = publisher = None
    try:
        assert node.poll() is None, node_log.read_text()
        out = tmp_path / "grids.json"
        listener = peer(ros2_env, sub_log, "--out", str(out), "--scan-topic", SCAN_TOPIC,
                        "--grids", *GRIDS, "--keep", str(KEEP), "--count", str(SCANS),
                        "--idle", "15", "--timeout", "150")  # fmt: skip
        wait_for(lambda: "ready" in sub_log.read_text() or listener.poll() is not None, 60,
                 sub_log)  # fmt: skip
        publisher = peer(ros2_env, pub_log, "--out", str(tmp_path / "sent.json"),
                         "--scan-topic", SCAN_TOPIC, "--publish", "--limit", str(SCANS),
                         "--subscribers", "2", "--timeout", "60")  # fmt: skip
        assert publisher.wait(120) == 0, pub_log.read_text()
        assert listener.wait(180) == 0, sub_log.read_text()
        assert stop(node) == 0, node_log.read_text()[-2000:]  # SIGTERM: a clean stop
    finally:
        for process in (publisher, listener, node):
            if process is not None:
                stop(process, signal.SIGKILL)
    got = json.loads(out.read_text())
    log = node_log.read_text()
    assert "Traceback" not in log, log[-2000:]
    last = log.strip().splitlines()[-1]
    assert last.startswith(f"lidarflow ros2: latency over {SCANS} scans: median"), log[-500:]

    # every scan sent reached the listener, and one grid per scan came on every topic
    scan_stamps = [s["stamp_ns"] for s in got["scans"]]
    assert scan_stamps == [recording.scan(i).stamp_ns for i in range(SCANS)]
    frame = recording.meta["frame_id"]
    assert {s["frame_id"] for s in got["scans"]} == {frame}
    expected_layout = bag_output_layout(tmp_path)
    step = float(np.median(np.diff(scan_stamps)))
    for topic in GRIDS:
        grids = got["grids"][topic]
        assert [g["scan_stamp_ns"] for g in grids] == scan_stamps, topic
        k = int(topic.rsplit("_k", 1)[1]) if "_k" in topic else 1
        for i, g in enumerate(grids):
            assert g["frame_id"] == frame, topic
            layout = (g["width"], g["height"], g["resolution"], *g["origin"])
            assert layout == pytest.approx(expected_layout), topic
            assert g["cells"] == g["width"] * g["height"]
            assert -1 <= g["min"] <= g["max"] <= 100, topic
            ahead = g["stamp_ns"] - g["scan_stamp_ns"]
            if topic.endswith("/moving"):  # the current map: the scan's own stamp
                assert ahead == 0 and set(g["values"]) <= {-1, 0, 100}
            elif i == 0:  # no step known yet
                assert ahead == 0, topic
            elif i >= 5:  # k typical steps ahead
                assert ahead == pytest.approx(k * step, rel=0.05), (topic, i)
            if "/decided" in topic:
                assert set(g["values"]) <= {-1, 0, 100}, topic
        if "/predicted" in topic:  # probabilities, not only the decided values
            assert any(g["values"] is None for g in grids), topic

    # the same grids as the Predictor gives offline, cell for cell
    predictor = Predictor(flow_onnx, horizon=HORIZON)
    for i in range(KEEP):
        offline = {g.topic: g.data for g in prediction_grids(predictor.update(recording.scan(i)))}
        for topic in GRIDS:
            np.testing.assert_array_equal(got["kept"][topic][i], offline[topic], err_msg=topic)


def test_a_topic_of_another_type_stops_the_node_in_one_line(ros2_env, flow_onnx, tmp_path):
    talker = peer(ros2_env, tmp_path / "talker.log", "--out", str(tmp_path / "t.json"),
                  "--scan-topic", "/words", "--words", "--timeout", "60")  # fmt: skip
    try:
        log = tmp_path / "node.log"
        node = start_node(ros2_env, log, "-m", str(flow_onnx), "--topic", "/words")
        assert node.wait(60) == 1
    finally:
        stop(talker, signal.SIGKILL)
    lines = log.read_text().strip().splitlines()
    assert lines[-1] == (
        "lidarflow: error: /words carries std_msgs/msg/String, not sensor_msgs/msg/LaserScan: "
        "name the right topic with --topic"
    ), lines
    assert "Traceback" not in log.read_text()


def test_ctrl_c_stops_a_waiting_node_cleanly(ros2_env, flow_onnx, tmp_path):
    log = tmp_path / "node.log"
    node = start_node(ros2_env, log, "-m", str(flow_onnx))
    assert node.poll() is None, log.read_text()
    domain = ros2_env["ROS_DOMAIN_ID"]
    assert f"in ROS domain {domain}:" in log.read_text()  # ROS_DOMAIN_ID's domain
    assert stop(node, signal.SIGINT) == 0, log.read_text()
    assert log.read_text().strip().splitlines()[-1] == "lidarflow ros2: no scan arrived on /scan"


def test_ros_2_not_installed_is_one_line_naming_the_extra():
    # runs everywhere: rclpy blocked as where it is not installed
    code = PRELUDE + "sys.modules['rclpy'] = None\n" + MAIN.removeprefix(PRELUDE)
    done = subprocess.run([sys.executable, "-c", code, "ros2"], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().splitlines() == [
        "lidarflow: error: ROS 2 is not installed for this Python (import of rclpy halted; None "
        'in sys.modules): pip install "lidarflow[ros2]" (ROS 2 Jazzy\'s wheels), or source a ROS '
        "2 installation built for this Python version"
    ]


def test_poses_and_messages_with_ros_2s_own_classes(ros2_env):
    # rclpy's message classes, as the node receives and sends them; no peers needed
    code = PRELUDE + (
        "import math, numpy as np\n"
        "from lidarflow.live.ros2 import Ros2Node\n"
        "from lidarflow.live.step import LiveStep\n"
        "from lidarflow.scan import GridSpec\n"
        "class GridOnly:\n    grid = GridSpec()\n    horizon = 1\n"
        "node = Ros2Node(LiveStep(GridOnly()), '/scan', '/odom')\n"
        "assert node._pose('laser') is None\n"
        "odom = node.ros.Odometry(child_frame_id='base_link')\n"
        "odom.pose.pose.position.x, odom.pose.pose.position.y = 2.0, 3.0\n"
        "odom.pose.pose.orientation.z = math.sin(0.25)\n"
        "odom.pose.pose.orientation.w = math.cos(0.25)\n"
        "node._on_odom(odom)\n"
        "data = (np.arange(10000) % 102 - 1).astype(np.int8)\n"
        "msg = node._message(data, 3_000_000_001, 2_999_999_999, 'laser')\n"
        "print(node._pose('laser'), list(msg.data) == data.tolist(), msg.header.stamp.sec,\n"
        "      msg.header.stamp.nanosec, msg.info.map_load_time.nanosec, msg.header.frame_id,\n"
        "      msg.info.width, msg.info.origin.position.y)\n"
    )
    done = subprocess.run([ros2_python(), "-c", code], env=ros2_env, capture_output=True,
                          text=True, timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr[-1500:]
    pose, rest = done.stdout.strip().rsplit(")", 1)
    assert [float(v) for v in pose.strip("(").split(",")] == pytest.approx([2.0, 3.0, 0.5])
    assert rest.split() == ["True", "3", "1", "999999999", "laser", "100", "-5.0"]


@pytest.mark.parametrize("given", ["abc", "233"])
def test_a_bad_ros_domain_id_is_one_line_with_what_was_given_and_the_range(given):
    # runs everywhere: checked before rclpy is imported
    env = {**os.environ, "ROS_DOMAIN_ID": given}
    done = subprocess.run([sys.executable, "-c", MAIN, "ros2"], capture_output=True, text=True,
                          env=env, timeout=120)  # fmt: skip
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().splitlines() == [
        f"lidarflow: error: ROS_DOMAIN_ID={given!r} is no ROS 2 domain: set it to an integer "
        "from 0 to 232, or unset it for domain 0"
    ]


def test_domain_id_reads_ros_domain_id_without_rclpy():
    from lidarflow.errors import PredictError
    from lidarflow.live.ros2 import domain_id

    assert domain_id({}) is None and domain_id({"ROS_DOMAIN_ID": ""}) is None
    assert domain_id({"ROS_DOMAIN_ID": "0"}) == 0 and domain_id({"ROS_DOMAIN_ID": "232"}) == 232
    for given in ("abc", "233", "-1", "1.5", "+7", "٣"):
        expected = re.escape(f"ROS_DOMAIN_ID={given!r} is no ROS 2 domain")
        with pytest.raises(PredictError, match=expected):
            domain_id({"ROS_DOMAIN_ID": given})
