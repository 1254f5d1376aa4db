"""Latency of the live ROS 1 node (`lidarflow ros1`) beside the Predictor's own, machine loaded.

In one run, with one busy process (a Python loop) beside everything (unless ``--no-load``):
the Predictor's own latency per scan (``update`` on the bundled sample's scans in this process,
no poses, as the node gets them; timed before and after the ROS run, the two pooled), and the
ROS loop's:

- ``node``: the node's own timestamps, scan callback entered (the message deserialised) to its
  last grid published (handed to rospy), from its per-scan debug log: what the target is about,
  the time the node adds to the Predictor's;
- ``end_to_end``: a rospy peer's (tests/live/ros1_peer.py, Debian's python3) wall clock from
  sending a scan to receiving that scan's last grid: adds the transport both ways
  (serialisation, TCP on localhost) and any wait of a scan queued while the node was busy.

The peer publishes the sample's scans at their recorded pace (7.5 Hz); the node runs the
bundled model exported to ONNX (no PyTorch at run time), one thread. The first ``--warmup``
scans are left out of every figure. Target (issue 37): node <= 1.5x the Predictor, median and
p99. Writes JSON (default ``benchmarks/results/ros1.json``).

    python benchmarks/bench_ros1.py [--scans 243] [--horizon 1] [--moving] [--no-load]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
import xmlrpc.client
from pathlib import Path

import numpy as np
from _output import machine, write_json

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.outputs.grids import grid_topics
from lidarflow.predict import Predictor

ROOT = Path(__file__).resolve().parents[1]
PEER = ROOT / "tests" / "live" / "ros1_peer.py"
TOPIC = "/right_scan"  # the sample's `right_scan`


def stats(ms: list[float]) -> dict[str, float]:
    a = np.asarray(ms)
    return {"median_ms": float(np.median(a)), "p99_ms": float(np.percentile(a, 99)),
            "scans": len(a)}  # fmt: skip


def own_latency(model: Path, scans: list, horizon: int, moving: bool, warmup: int) -> list[float]:
    """Milliseconds per ``Predictor.update`` (and the moving cells, where the node makes them)."""
    predictor = Predictor(model, horizon=horizon)
    times = []
    for scan in scans:
        t0 = time.perf_counter()
        p = predictor.update(scan)
        if moving:
            _ = p.moving
        times.append((time.perf_counter() - t0) * 1e3)
    return times[warmup:]


def start(argv: list[str], env: dict, log: Path) -> subprocess.Popen:
    return subprocess.Popen(argv, env=env, stdout=log.open("w"), stderr=subprocess.STDOUT,
                            start_new_session=True)  # fmt: skip


def stop(process: subprocess.Popen, sig: int = signal.SIGTERM) -> int:
    if process.poll() is None:
        os.killpg(process.pid, sig)
    try:
        return process.wait(30)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        return process.wait()


def wait_for(text: str, log: Path, process: subprocess.Popen, timeout_s: float = 120) -> None:
    deadline = time.monotonic() + timeout_s
    while text not in log.read_text():
        if process.poll() is not None or time.monotonic() > deadline:
            sys.exit(f"{log.name}: {log.read_text()[-2000:]}")
        time.sleep(0.1)


def ros_loop(model: Path, n: int, horizon: int, moving: bool, tmp: Path) -> tuple[list, list]:
    """Per-scan milliseconds: the node's own, and the peer's scan sent -> last grid received."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    uri = f"http://127.0.0.1:{port}"
    env = {**os.environ, "ROS_MASTER_URI": uri, "ROS_HOME": str(tmp), "ROS_IP": "127.0.0.1",
           "ROS_LOG_DIR": str(tmp / "log"), "OMP_NUM_THREADS": "1"}  # fmt: skip
    core = start(["roscore", "-p", str(port)], env, tmp / "roscore.log")
    node = peer = None
    try:
        while True:
            try:
                xmlrpc.client.ServerProxy(uri).getPid("/bench")
                break
            except OSError:
                time.sleep(0.2)
        topics = grid_topics(horizon, moving, occupancy=False)
        node_argv = [sys.executable, "-m", "lidarflow", "ros1", "-m", str(model), "--topic", TOPIC,
                     "--horizon", str(horizon), "-v", "--queue", "1000",
                     *(["--moving"] if moving else [])]  # fmt: skip
        node = start(node_argv, env, tmp / "node.log")
        wait_for("publishing", tmp / "node.log", node)
        out = tmp / "peer.json"
        peer = start(["/usr/bin/python3", str(PEER), "--out", str(out), "--scan-topic", TOPIC,
                      "--grids", *topics, "--publish", str(sample_bag_path()), "--limit", str(n),
                      "--count", str(n), "--timeout", "600"], env, tmp / "peer.log")  # fmt: skip
        if peer.wait(700) != 0:
            sys.exit((tmp / "peer.log").read_text()[-2000:])
        stop(node)
    finally:
        for p in (peer, node, core):
            if p is not None:
                stop(p, signal.SIGINT if p is core else signal.SIGTERM)
    log = (tmp / "node.log").read_text()
    node_ms = [float(ms) for ms in re.findall(r"scan \d+ \(stamp \d+ ns\): ([\d.]+) ms", log)]
    got = json.loads(out.read_text())
    sent = {s["stamp_ns"]: s["sent_ns"] for s in got["sent"]}
    last = {g["scan_stamp_ns"]: g["received_ns"] for g in got["grids"][topics[-1]]}
    end_to_end = [(last[t] - sent[t]) / 1e6 for t in sent if t in last]
    if len(node_ms) != n or len(end_to_end) != n:
        sys.exit(f"the node answered {len(node_ms)} and the peer saw {len(end_to_end)} of {n}")
    return node_ms, end_to_end


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=243, help="of the sample (243 in all)")
    parser.add_argument("--horizon", type=int, default=1)
    parser.add_argument("--moving", action="store_true")
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument(
        "--no-load", dest="load", action="store_false",
        help="no busy process beside the node (a quiet machine; the figures are then not "
             "those of the recorded run)",
    )  # fmt: skip
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/ros1.json"))
    args = parser.parse_args()
    from lidarflow.models.presets import resolve_model
    from lidarflow.outputs.export import export_onnx
    from lidarflow.predict.decision import DecisionPolicy

    recording = read_bag(sample_bag_path())
    scans = [recording.scan(i) for i in range(min(args.scans, len(recording)))]
    busy = None
    if args.load:
        loop = [sys.executable, "-c", "while True: pass"]
        busy = subprocess.Popen(loop, start_new_session=True)
    try:
        with tempfile.TemporaryDirectory() as folder:
            tmp = Path(folder)
            net, card = resolve_model(None)
            policy = DecisionPolicy.from_record(card["decision"])
            model = export_onnx(net.eval(), tmp / "bundled.onnx", decision=policy)
            before = own_latency(model, scans, args.horizon, args.moving, args.warmup)
            node_ms, e2e_ms = ros_loop(model, len(scans), args.horizon, args.moving, tmp)
            after = own_latency(model, scans, args.horizon, args.moving, args.warmup)
    finally:
        if busy is not None:
            stop(busy, signal.SIGKILL)
    own = stats(before + after)
    node, e2e = stats(node_ms[args.warmup :]), stats(e2e_ms[args.warmup :])
    ratios = {f"{name}_vs_predictor_{q}": figures[f"{q}_ms"] / own[f"{q}_ms"]
              for name, figures in (("node", node), ("end_to_end", e2e))
              for q in ("median", "p99")}  # fmt: skip
    print(f"Predictor {own['median_ms']:.1f} ms (p99 {own['p99_ms']:.1f}); node "
          f"{node['median_ms']:.1f} ms (p99 {node['p99_ms']:.1f}); end to end "
          f"{e2e['median_ms']:.1f} ms (p99 {e2e['p99_ms']:.1f}); ratios "
          + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items()))  # fmt: skip
    write_json(args.json, {
        "benchmark": "ros1",
        "scans": len(scans),
        "warmup_left_out": args.warmup,
        "model": "bundled, exported to ONNX (onnxruntime, 1 thread)",
        "horizon": args.horizon,
        "moving": args.moving,
        "load": "one busy process (a Python loop) beside the node, roscore and the peer"
        if args.load else "none added (--no-load)",
        "machine": machine(),
        "measures": {
            "predictor": "Predictor.update per scan in one process (before and after the ROS "
                         "run, pooled)",
            "node": "the node's own clock: scan callback entered -> last grid published",
            "end_to_end": "a rospy peer's wall clock: scan sent -> that scan's last grid "
                          "received (transport both ways and queueing included)",
        },
        "target": "node <= 1.5x the predictor, median and p99 (issue 37)",
        "results": {"predictor": own, "node": node, "end_to_end": e2e, **ratios},
    })  # fmt: skip


if __name__ == "__main__":
    main()
