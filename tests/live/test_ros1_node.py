"""``lidarflow ros1`` end to end, against a real ROS 1: ``roscore``, ``rosbag play`` of the
bundled sample, the node as its own process (an ONNX model, the machine loaded by a busy
process beside it) and a rospy peer run with Debian's python3 (tests/live/ros1_peer.py).

Checked as the bag output's tests check it (tests/outputs/test_rosout.py): one grid per scan on
every topic (the planner grid's too, at the scan's stamp), stamps (a grid k frames ahead: the
scan's stamp plus k steps, ``map_load_time`` the scan's), the scan's frame, the layout the bag
output writes, values in -1..100 and the same values the Predictor gives offline; and the
node's latency under load, within a generous bound
(benchmarks/bench_ros1.py measures it).
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
from lidarflow.outputs.grids import GridLayout, grid_topics, prediction_grids
from lidarflow.predict import Predictor
from tests.live.rosmaster import SYSTEM_PYTHON, stop
from tests.without_torch import MAIN

PEER = Path(__file__).with_name("ros1_peer.py")
SCAN_TOPIC = "/right_scan"  # the sample bag's topic, `right_scan`, as rosbag play names it
HORIZON = 2
GRIDS = grid_topics(HORIZON, moving=True, occupancy=False, planner=True)
SECONDS = "10"  # of the sample played, at its recorded pace: 75 scans at 7.5 Hz
KEEP = 12  # grids per topic compared with the Predictor's own


@pytest.fixture(scope="module")
def onnx_model(flow_onnx) -> Path:
    """A flow model as ONNX (what a robot without PyTorch runs), for the moving cells: the
    bundled model, the head alone since v9, has none."""
    return flow_onnx


def start_node(env: dict, log: Path, *args: str) -> subprocess.Popen:
    """``lidarflow ros1 ARGS`` as the core install runs it (no PyTorch), in its own process
    group, logging to ``log``; returns once it published its topics (or ended)."""
    node = subprocess.Popen(
        [sys.executable, "-c", MAIN, "ros1", *args], env={**env, "OMP_NUM_THREADS": "1"},
        stdout=subprocess.DEVNULL, stderr=log.open("w"), start_new_session=True,
    )  # fmt: skip
    wait_for(lambda: "publishing" in log.read_text() or node.poll() is not None, 90, log)
    return node


def wait_for(ready, timeout_s: float, log: Path) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out; {log.name}: {log.read_text()[-1500:]}")
        time.sleep(0.1)


def test_the_node_publishes_one_grid_per_scan_stamped_laid_out_and_valued_as_offline(
    ros_env, onnx_model, tmp_path
):
    recording = read_bag(sample_bag_path())
    busy = subprocess.Popen([sys.executable, "-c", "while True: pass"], start_new_session=True)
    try:
        node_log = tmp_path / "node.log"
        # a queue that drops nothing, should the loaded machine fall behind the scans
        node = start_node(ros_env, node_log, "-m", str(onnx_model), "--topic", SCAN_TOPIC,
                          "--horizon", str(HORIZON), "--moving", "--planner-grid", "-v",
                          "--queue", "1000")  # fmt: skip
        assert node.poll() is None, node_log.read_text()
        out, peer_log = tmp_path / "peer.json", tmp_path / "peer.log"
        peer = subprocess.Popen(
            [SYSTEM_PYTHON, str(PEER), "--out", str(out), "--scan-topic", SCAN_TOPIC,
             "--grids", *GRIDS, "--keep", str(KEEP), "--idle", "8", "--timeout", "100"],
            env=ros_env, stdout=peer_log.open("w"), stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
        wait_for(lambda: "ready" in peer_log.read_text() or peer.poll() is not None, 30, peer_log)
        subprocess.run(["rosbag", "play", "-q", "-d", "1", "-u", SECONDS, "--wait-for-subscribers",
                        str(sample_bag_path())], env=ros_env, check=True, timeout=90,
                       stdout=subprocess.DEVNULL)  # fmt: skip
        assert peer.wait(60) == 0, peer_log.read_text()
        assert stop(node) == 0, node_log.read_text()[-2000:]  # SIGTERM: a clean stop
    finally:
        stop(busy, signal.SIGKILL)
    got = json.loads(out.read_text())
    log = node_log.read_text()
    assert "Traceback" not in log, log[-2000:]

    # every scan played reached the peer, and one grid per scan came on every topic
    scan_stamps = [s["stamp_ns"] for s in got["scans"]]
    n = len(scan_stamps)
    assert n >= 60 and scan_stamps == [recording.scan(i).stamp_ns for i in range(n)], n
    frame = got["scans"][0]["frame_id"].lstrip("/")
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
            elif topic.endswith("/planner_grid") or i == 0:  # the scan's frame; no step yet
                assert ahead == 0, topic
            elif i >= 5:  # k typical steps ahead
                assert ahead == pytest.approx(k * step, rel=0.05), (topic, i)
            if "/decided" in topic:
                assert set(g["values"]) <= {-1, 0, 100}, topic
        if "/predicted" in topic:  # probabilities, not only the decided values
            assert any(g["values"] is None for g in grids), topic

    # the same grids as the Predictor gives offline, cell for cell
    predictor = Predictor(onnx_model, horizon=HORIZON)
    for i in range(KEEP):
        p = predictor.update(recording.scan(i))
        offline = {g.topic: g.data for g in prediction_grids(p, GRIDS)}
        for topic in GRIDS:
            np.testing.assert_array_equal(got["kept"][topic][i], offline[topic], err_msg=topic)

    # latency under load: the node's (scan callback entered -> last grid published), within a
    # generous bound; the peer's (scan received -> its last grid received, on the peer's clock;
    # it adds the transport both ways, and the wait of a scan queued while the node was busy)
    # cannot be shorter, or the node's own figure leaves out part of its work
    per_scan = [float(ms) for ms in re.findall(r"scan \d+ \(stamp \d+ ns\): ([\d.]+) ms", log)]
    assert len(per_scan) == n
    summary = re.search(rf"latency over {n} scans: median ([\d.]+) ms, p99 ([\d.]+) ms", log)
    assert summary, log[-1000:]
    assert float(summary[1]) == pytest.approx(np.median(per_scan), abs=0.01)
    assert float(summary[1]) < 1000 and float(summary[2]) < 3000, summary[0]
    last_grid = {g["scan_stamp_ns"]: g["received_ns"] for g in got["grids"][GRIDS[-1]]}
    seen = [(last_grid[s["stamp_ns"]] - s["received_ns"]) / 1e6 for s in got["scans"]]
    assert np.median(seen) >= 0.9 * np.median(per_scan), (np.median(seen), summary[0])


def bag_output_layout(tmp_path: Path) -> tuple:
    """What the bag output writes for the bundled model's grid: width, height, resolution and
    origin (position, orientation), read back from a bag it wrote."""
    from lidarflow.outputs.rosout import BagOutput
    from lidarflow.scan import GridSpec
    from tests.outputs.test_rosout import read_all, write_grid

    grid = GridSpec()
    assert GridLayout.of(grid) == GridLayout(100, 100, 0.1, 0.0, -5.0)
    with BagOutput(tmp_path / "layout.bag") as out:
        write_grid(out, "/g", np.zeros(grid.shape), grid, 1, "laser")
    info = read_all(tmp_path / "layout.bag")["/g"][0].info
    p, q = info.origin.position, info.origin.orientation
    return (info.width, info.height, info.resolution, p.x, p.y, p.z, q.x, q.y, q.z, q.w)


def test_a_topic_of_another_type_stops_the_node_in_one_line(ros_env, onnx_model, tmp_path):
    talker = subprocess.Popen(["rostopic", "pub", "-r", "5", "/words", "std_msgs/String", "hi"],
                              env=ros_env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                              start_new_session=True)  # fmt: skip
    try:
        log = tmp_path / "node.log"
        node = start_node(ros_env, log, "-m", str(onnx_model), "--topic", "/words")
        assert node.wait(30) == 1
    finally:
        stop(talker, signal.SIGINT)
    lines = log.read_text().strip().splitlines()
    assert lines[-1] == (
        "lidarflow: error: /words carries std_msgs/String, not sensor_msgs/LaserScan: name the "
        "right topic with --topic"
    ), lines
    assert "Traceback" not in log.read_text()


def test_ctrl_c_stops_a_waiting_node_cleanly(ros_env, onnx_model, tmp_path):
    log = tmp_path / "node.log"
    node = start_node(ros_env, log, "-m", str(onnx_model))
    assert node.poll() is None, log.read_text()
    assert stop(node, signal.SIGINT) == 0, log.read_text()
    assert log.read_text().strip().splitlines()[-1] == "lidarflow ros1: no scan arrived on /scan"


def test_no_master_is_one_line(ros_env, tmp_path):
    from tests.live.rosmaster import free_port

    env = {**ros_env, "ROS_MASTER_URI": f"http://127.0.0.1:{free_port()}"}
    done = subprocess.run([sys.executable, "-m", "lidarflow", "ros1"], env=env,
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert done.returncode == 1
    assert done.stderr.strip() == (
        f"lidarflow: error: no ROS master at {env['ROS_MASTER_URI']}: start roscore, or set "
        "ROS_MASTER_URI"
    )


def test_ros_not_installed_names_the_debian_packages():
    # runs everywhere: Debian's folder swapped for one that does not exist
    code = (
        "import lidarflow.live.ros1 as r\n"
        "r.DIST_PACKAGES = '/nonexistent'\n"
        "try:\n    r.import_ros()\nexcept r.PredictError as e:\n    print(e)\n"
    )
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}  # no ROS setup.bash
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("ROS 1 is not installed for this Python (No module named")
    assert "apt-get install ros-core python3-rospy" in done.stdout
