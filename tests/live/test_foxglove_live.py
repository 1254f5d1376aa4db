"""``lidarflow live`` end to end: a Foxglove WebSocket client on localhost connects to the
command, subscribes to every topic it advertises, and decodes what comes (protobuf, from the
FileDescriptorSets the server advertises) against what the Predictor makes of the same scans.

The client speaks the protocol itself (https://github.com/foxglove/ws-protocol): the
subprotocol the SDK accepts, ``serverInfo`` and ``advertise`` as JSON text, ``subscribe``
sent, message data as binary frames (opcode 1, uint32 subscription id, uint64 log time, the
message), so a change in what the server sends or how shows here as it would in Foxglove.
"""

from __future__ import annotations

import base64
import json
import os
import queue
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from websockets.sync.client import connect

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.errors import PredictError
from lidarflow.flowcolor import flow_to_rgb
from lidarflow.live.foxglove import LiveServer
from lidarflow.live.replay import loop_shift_ns
from lidarflow.outputs.grids import FLOW_RGB_FULL_CELLS
from lidarflow.outputs.rosout import map_from_grid_data
from lidarflow.predict import Predictor
from tests.test_cli import run
from tests.without_torch import MAIN

ROOT = Path(__file__).resolve().parents[2]
SUBPROTOCOL = "foxglove.sdk.v1"  # the one foxglove-sdk's server accepts
MESSAGE_DATA = 0x01
SCANS = 8  # scans in the short recording played over and over
HORIZON = 2
GRIDS = [
    "/lidarflow/occupancy",
    "/lidarflow/predicted",
    "/lidarflow/decided",
    "/lidarflow/predicted_k2",
    "/lidarflow/decided_k2",
    "/lidarflow/moving",
]
SCAN_TOPIC = "/right_scan"  # the sample bag's scans, `right_scan` as recorded
FLOW_IMAGE = "/lidarflow/flow_forward_rgb"


@pytest.fixture(scope="module")
def short_and_model(tmp_path_factory, flow_onnx):
    """Eight scans of the bundled sample, and a flow model as ONNX (what a robot without
    PyTorch runs; onnxruntime on one thread gives the same numbers in every process): v8, as
    the bundled model (the head alone since v9) serves neither moving cells nor flow."""
    folder = tmp_path_factory.mktemp("live")
    short = read_bag(sample_bag_path()).slice(0, SCANS).save(folder / "short.npz")
    return short, flow_onnx


def start_live(short: Path, model: Path, *extra: str) -> tuple[subprocess.Popen, str]:
    """``lidarflow live`` on a free port, as the core install runs it (no PyTorch), and the
    ws:// address it printed."""
    proc = subprocess.Popen(
        [sys.executable, "-c", MAIN, "live", str(short), "-m", str(model),
         "--port", "0", "--horizon", str(HORIZON), *extra],
        env={**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    lines: queue.Queue[str] = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(x) for x in proc.stdout], daemon=True)
    reader.start()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            assert proc.poll() is None, proc.stderr.read()
            continue
        if " on ws://" in line:
            proc.lines, proc.reader = lines, reader  # the rest of stdout, for the end
            return proc, line.split(" on ")[-1].strip()
    proc.kill()
    raise AssertionError("lidarflow live printed no ws:// address within a minute")


def decoder(channel: dict):
    """The protobuf class of an advertised channel, built from its FileDescriptorSet."""
    assert channel["encoding"] == "protobuf" and channel["schemaEncoding"] == "protobuf"
    files = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(channel["schema"]))
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(channel["schemaName"]))


def ns(stamp) -> int:
    return stamp.seconds * 1_000_000_000 + stamp.nanos


def receive(url: str, enough, within_s: float = 30.0):
    """Connect, check the advertisement, subscribe to everything, and collect decoded
    messages by log time until ``enough`` (the log times of the scans that came complete,
    every topic) says so."""
    topics = [SCAN_TOPIC, *GRIDS, FLOW_IMAGE]
    by_time: dict[int, dict[str, object]] = {}
    with connect(url, subprotocols=[SUBPROTOCOL], open_timeout=10) as ws:
        assert ws.subprotocol == SUBPROTOCOL
        info = json.loads(ws.recv(timeout=10))
        assert info["op"] == "serverInfo" and info["name"] == "lidarflow"
        channels: dict[int, dict] = {}
        while {c["topic"] for c in channels.values()} != set(topics):
            advert = json.loads(ws.recv(timeout=10))
            assert advert["op"] == "advertise", advert
            channels.update({c["id"]: c for c in advert["channels"]})
        schemas = {c["topic"]: c["schemaName"] for c in channels.values()}
        assert schemas == {
            SCAN_TOPIC: "foxglove.LaserScan",
            **dict.fromkeys(GRIDS, "foxglove.Grid"),
            FLOW_IMAGE: "foxglove.RawImage",
        }
        classes = {cid: decoder(c) for cid, c in channels.items()}
        # subscription ids of our own choosing, distinct from the channel ids
        subs = {100 + cid: cid for cid in channels}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": sid, "channelId": cid} for sid, cid in subs.items()]}))  # fmt: skip
        deadline = time.monotonic() + within_s
        complete: set[int] = set()
        while not enough(complete):
            assert time.monotonic() < deadline, f"complete scans after {within_s} s: {complete}"
            frame = ws.recv(timeout=10)
            if isinstance(frame, str):  # a later advertise/status: not data
                continue
            op, sid, log_time = struct.unpack_from("<BIQ", frame)
            assert op == MESSAGE_DATA and sid in subs
            channel = channels[subs[sid]]
            message = classes[subs[sid]].FromString(frame[13:])
            by_time.setdefault(log_time, {})[channel["topic"]] = message
            if set(by_time[log_time]) == set(topics):
                complete.add(log_time)
    return by_time, complete


@pytest.mark.slow
def test_live_serves_what_the_predictor_makes_of_each_scan(short_and_model):
    short, model = short_and_model
    recording = read_bag(sample_bag_path()).slice(0, SCANS)
    predictor = Predictor(model, horizon=HORIZON)
    expected = [predictor.update(scan) for scan in recording]
    stamps = recording.stamps_ns
    shift = loop_shift_ns(recording)
    assert shift > stamps[-1] - stamps[0]  # a pass's stamps follow the last pass's

    def which(log_time: int) -> tuple[int, int]:
        """The scan and the pass of a message: its log time is the scan's stamp moved on by
        whole passes."""
        (i,) = [i for i in range(SCANS) if (log_time - int(stamps[i])) % shift == 0]
        return i, (log_time - int(stamps[i])) // shift

    def enough(complete: set[int]) -> bool:  # scans past the first two, of two passes
        return len({which(t)[1] for t in complete if which(t)[0] >= 2}) >= 2

    proc, url = start_live(short, model, "--loop")
    try:
        assert url.startswith("ws://127.0.0.1:")
        by_time, complete = receive(url, enough)
    finally:
        proc.send_signal(signal.SIGTERM)  # a server's Ctrl-C: ends it, not an error
        proc.wait(timeout=60)
        proc.reader.join(timeout=10)  # stdout read to its end
    assert proc.returncode == 0, proc.stderr.read()
    summary = list(proc.lines.queue)[-1]
    assert summary.startswith("stopped; served ") and "publish" in summary, summary

    passes = set()
    checked = 0
    for log_time in sorted(complete):
        i, n = which(log_time)
        passes.add(n)
        moved = n * shift
        if i < 2:  # the first scans of a pass know no step yet: checked below for i >= 2
            continue
        check_scan_messages(by_time[log_time], recording.scan(i), expected[i], moved)
        checked += 1
    assert len(passes) >= 2 and checked, (passes, checked)  # --loop went round, stamps moved on


def check_scan_messages(messages, scan, p, moved):
    """Every message of one scan, decoded, against the Predictor's own prediction ``p``."""
    scan_stamp = int(scan.stamp_ns) + moved
    laser = messages[SCAN_TOPIC]
    assert ns(laser.timestamp) == scan_stamp and laser.frame_id == "right_laser"
    g = scan.geometry
    assert laser.start_angle == pytest.approx(g.angle_min)
    assert laser.end_angle == pytest.approx(g.angle_min + g.angle_increment * (g.count - 1))
    np.testing.assert_array_equal(np.array(laser.ranges), scan.ranges.astype(np.float64))

    seen = p.visibility
    ahead = {1: p.stamp_ahead_ns(1) + moved, 2: p.stamp_ahead_ns(2) + moved}
    assert scan_stamp < ahead[1] < ahead[2]  # predicted grids carry the time they predict
    for topic in GRIDS:
        grid = messages[topic]
        assert grid.frame_id == "right_laser"
        assert (grid.column_count, grid.row_stride, grid.cell_stride) == (100, 100, 1)
        assert (grid.cell_size.x, grid.cell_size.y) == (pytest.approx(0.1), pytest.approx(0.1))
        assert (grid.pose.position.x, grid.pose.position.y) == (0, pytest.approx(-5.0))
        assert grid.pose.orientation.w == 1
        (field,) = grid.fields
        assert field.name == "occupancy" and field.offset == 0 and field.type == 2  # INT8
        assert len(grid.data) == 100 * 100
        cells = map_from_grid_data(np.frombuffer(grid.data, np.int8), 100, 100).astype(int)
        k = 2 if topic.endswith("_k2") else 1
        if "predicted" in topic or "decided" in topic:
            assert ns(grid.timestamp) == ahead[k], topic
            occupied = p.horizon_occupied[k - 1]
            known = seen | occupied
            if "predicted" in topic:
                want = np.rint(100 * p.horizon[k - 1]).astype(int)
            else:
                want = np.where(occupied, 100, 0)
        else:  # the current map and its moving cells: the scan's stamp
            assert ns(grid.timestamp) == scan_stamp, topic
            known = seen
            want = np.where(p.occupancy if topic.endswith("occupancy") else p.moving, 100, 0)
        np.testing.assert_array_equal(cells, np.where(known, want, -1), err_msg=topic)

    image = messages[FLOW_IMAGE]
    assert (image.width, image.height, image.encoding, image.step) == (100, 100, "rgb8", 300)
    assert ns(image.timestamp) == scan_stamp and image.frame_id == "right_laser"
    pixels = np.frombuffer(image.data, np.uint8).reshape(100, 100, 3)
    np.testing.assert_array_equal(pixels, flow_to_rgb(p.forward_flow, FLOW_RGB_FULL_CELLS))


def test_a_taken_port_and_an_unreadable_source_are_one_line_errors(
    tmp_path, capsys, short_and_model
):
    short, model = short_and_model
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, _, err = run(["live", str(short), "-m", str(model), "--port", str(port)], capsys)
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert err.startswith(f"lidarflow: error: cannot serve on 127.0.0.1:{port}: "), err
    assert "in use" in err and "--port" in err, err
    bad = tmp_path / "cut.bag"
    bad.write_bytes(sample_bag_path().read_bytes()[:100])
    code, _, err = run(["live", str(bad), "-m", str(model), "--port", "0"], capsys)
    assert code == 1 and err.startswith(f"lidarflow: error: {bad}") and len(err.splitlines()) == 1


def test_the_server_refuses_predictions_it_was_not_made_for(short_and_model):
    _, model = short_and_model
    scan = read_bag(sample_bag_path()).scan(0)
    predictor = Predictor(model, horizon=2)
    p = predictor.update(scan)
    server = LiveServer(predictor.grid, "laser", port=0)  # horizon 1
    with pytest.raises(PredictError, match="2 frames ahead, but the server was made for 1"):
        server.publish(scan, p)
    server.close()
    server.close()  # twice: harmless
    with pytest.raises(PredictError, match="closed"):
        server.publish(scan, p)


@pytest.mark.slow
def test_a_live_step_feeds_the_server_as_the_ros_node_does(short_and_model):
    """``lidarflow ros1 --foxglove``: the server is one more sink of the node's
    :class:`~lidarflow.live.step.LiveStep`, each scan served in its own frame."""
    from lidarflow.live.step import LiveStep, clock_ns

    _, model = short_and_model
    recording = read_bag(sample_bag_path()).slice(0, SCANS)
    expected_predictor = Predictor(model, horizon=HORIZON)
    expected = [expected_predictor.update(scan) for scan in recording]
    stamps = [int(s) for s in recording.stamps_ns]
    predictor = Predictor(model, horizon=HORIZON)
    done = threading.Event()
    with LiveServer(predictor.grid, port=0, horizon=HORIZON, scan_topic=SCAN_TOPIC) as server:
        step = LiveStep(predictor, [server.publish_frame])

        def feed() -> None:  # the node's callbacks, pass after pass until the client has seen
            while not done.is_set():
                predictor.reset()
                for scan in recording:
                    step(scan, "right_laser", clock_ns())
                    time.sleep(0.01)

        feeder = threading.Thread(target=feed, daemon=True)
        feeder.start()
        try:
            by_time, complete = receive(
                server.url, lambda c: any(stamps.index(t) >= 2 for t in c)
            )
        finally:
            done.set()
            feeder.join(timeout=30)
    checked = [t for t in complete if stamps.index(t) >= 2]
    for t in checked:
        i = stamps.index(t)
        check_scan_messages(by_time[t], recording.scan(i), expected[i], 0)
    assert checked
