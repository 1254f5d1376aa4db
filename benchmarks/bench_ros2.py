"""Latency of the live ROS 2 node (`lidarflow ros2`) beside the Predictor's own, in one run.

As benchmarks/bench_ros1.py does for ROS 1: the Predictor's own latency per scan (``update`` on
the bundled sample's scans in this process, no poses, as the node gets them; timed before and
after the ROS run, the two pooled), back to back (``predictor``) and at the recording's pace
(``predictor_paced``, the reference the target is judged against: the node gets a scan every
133 ms and idles between them, and a Predictor that idles between scans is 10-40 % slower
on this machine than one stepped back to back), and the ROS loop's, over rclpy and Fast DDS on
localhost:

- ``node``: the node's own timestamps, scan callback entered (the message deserialised) to its
  last grid published (handed to rclpy), from its per-scan debug log: what the target is about,
  the time the node adds to the Predictor's;
- ``predictor_in_node``: the part of each of those the Predictor's ``update`` took, from the
  same log line: the Predictor timed in the node's process at the same moments, which a machine
  shared with other work (its load changing from one minute to the next, the peer's process
  beside the node) makes the fairer reference;
- ``end_to_end``: an rclpy peer's (tests/live/ros2_peer.py) wall clock from publishing a scan to
  receiving that scan's last grid: adds the transport both ways and any wait of a scan queued
  while the node was busy.

The peer publishes the sample's scans at their recorded pace (7.5 Hz); the node runs the bundled
model as the Predictor's default does (its head step in NumPy, no PyTorch; ``--onnx``: its ONNX
export on onnxruntime) on one thread (``--threads 1``, ``OMP_NUM_THREADS=1``), the
Predictor here too. No busy process is added: the machine's load (``os.getloadavg``) before and
after is recorded instead. The first ``--warmup`` scans are left out of every figure. Target
(issue 45): node median <= 1.1x the Predictor's. Writes JSON (default
``benchmarks/results/ros2.json``). Needs rclpy (``pip install ".[ros2]"``).

    python benchmarks/bench_ros2.py [--scans 243] [--horizon 1] [--moving]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from _output import machine, write_json
from bench_ros1 import start, stats, stop, wait_for

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.models.presets import bundled_onnx
from lidarflow.outputs.grids import grid_topics
from lidarflow.predict import Predictor

ROOT = Path(__file__).resolve().parents[1]
PEER = ROOT / "tests" / "live" / "ros2_peer.py"
TOPIC = "/right_scan"  # the sample's `right_scan`


def own_latency(
    model: Path | None, scans: list, horizon: int, moving: bool, warmup: int, period_s: float = 0.0
) -> list[float]:
    """Milliseconds per ``Predictor.update`` (and the moving cells, where the node makes them),
    on one thread: back to back, or with ``period_s`` a scan started every ``period_s`` seconds
    (the pace the node gets them at: between scans the core idles, and caches and clock cool
    down; on this machine that alone costs the Predictor 10-40 %)."""
    predictor = Predictor(model, horizon=horizon, threads=1)
    times = []
    due = time.perf_counter()
    for scan in scans:
        t0 = time.perf_counter()
        p = predictor.update(scan)
        if moving:
            _ = p.moving
        times.append((time.perf_counter() - t0) * 1e3)
        if period_s:  # back to back: no sleep call between scans at all
            due += period_s
            time.sleep(max(0.0, due - time.perf_counter()))
    return times[warmup:]


def ros_loop(
    model: Path | None, n: int, horizon: int, moving: bool, tmp: Path
) -> tuple[list, list, list]:
    """Per-scan milliseconds: the node's own, the Predictor's part of it, and the peer's scan
    sent -> last grid received."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
           "ROS_DOMAIN_ID": str(1 + os.getpid() % 100)}  # fmt: skip
    topics = grid_topics(horizon, moving, occupancy=False)
    node = peer = None
    try:
        node = start([sys.executable, "-m", "lidarflow", "ros2",
                      *([] if model is None else ["-m", str(model)]), "--topic", TOPIC,
                      "--horizon", str(horizon), "-v", "--queue", "1000", "--threads", "1",
                      *(["--moving"] if moving else [])], env, tmp / "node.log")  # fmt: skip
        wait_for("publishing", tmp / "node.log", node)
        out = tmp / "peer.json"
        # two scan readers to wait for: the node's and the peer's own
        peer = start([sys.executable, str(PEER), "--out", str(out), "--scan-topic", TOPIC,
                      "--grids", *topics, "--publish", "--limit", str(n), "--subscribers", "2",
                      "--count", str(n), "--timeout", "600"], env, tmp / "peer.log")  # fmt: skip
        if peer.wait(700) != 0:
            sys.exit((tmp / "peer.log").read_text()[-2000:])
        stop(node)
    finally:
        for p in (peer, node):
            if p is not None:
                stop(p)
    log = (tmp / "node.log").read_text()
    per_scan = re.findall(r"scan \d+ \(stamp \d+ ns\): ([\d.]+) ms from arrival to "
                          r"published, ([\d.]+) ms of it predicting", log)  # fmt: skip
    node_ms = [float(total) for total, _ in per_scan]
    predict_ms = [float(predicting) for _, predicting in per_scan]
    got = json.loads(out.read_text())
    sent = {s["stamp_ns"]: s["sent_ns"] for s in got["sent"]}
    last = {g["scan_stamp_ns"]: g["received_ns"] for g in got["grids"][topics[-1]]}
    end_to_end = [(last[t] - sent[t]) / 1e6 for t in sent if t in last]
    if len(node_ms) != n or len(end_to_end) != n:
        sys.exit(f"the node answered {len(node_ms)} and the peer saw {len(end_to_end)} of {n}")
    return node_ms, predict_ms, end_to_end


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=243, help="of the sample (243 in all)")
    parser.add_argument("--horizon", type=int, default=1)
    parser.add_argument("--moving", action="store_true")
    parser.add_argument("--warmup", type=int, default=10)
    parser.add_argument("--onnx", action="store_true", help="the bundled model's ONNX export")
    parser.add_argument("--json", type=Path, default=Path("benchmarks/results/ros2.json"))
    args = parser.parse_args()

    recording = read_bag(sample_bag_path())
    scans = [recording.scan(i) for i in range(min(args.scans, len(recording)))]
    model = bundled_onnx()[0] if args.onnx else None
    load_before = os.getloadavg()
    period = float(np.median(np.diff(recording.stamps_ns))) / 1e9  # the peer's pace
    own_args = (model, scans, args.horizon, args.moving, args.warmup)
    with tempfile.TemporaryDirectory() as folder:
        before, before_paced = own_latency(*own_args), own_latency(*own_args, period_s=period)
        node_ms, in_node_ms, e2e_ms = ros_loop(model, len(scans), args.horizon, args.moving,
                                               Path(folder))  # fmt: skip
        after_paced, after = own_latency(*own_args, period_s=period), own_latency(*own_args)
    load_after = os.getloadavg()
    own, paced = stats(before + after), stats(before_paced + after_paced)
    node, e2e = stats(node_ms[args.warmup :]), stats(e2e_ms[args.warmup :])
    in_node = stats(in_node_ms[args.warmup :])
    ratios = {f"{name}_vs_{ref}_{q}": figures[f"{q}_ms"] / reference[f"{q}_ms"]
              for ref, reference in (("predictor", own), ("predictor_paced", paced),
                                     ("predictor_in_node", in_node))
              for name, figures in (("node", node), ("end_to_end", e2e))
              for q in ("median", "p99")}  # fmt: skip
    print(f"Predictor {own['median_ms']:.1f} ms (p99 {own['p99_ms']:.1f}), at the scans' pace "
          f"{paced['median_ms']:.1f} ms (p99 {paced['p99_ms']:.1f}), in the node "
          f"{in_node['median_ms']:.1f} ms (p99 {in_node['p99_ms']:.1f}); node "
          f"{node['median_ms']:.1f} ms (p99 {node['p99_ms']:.1f}); end to end "
          f"{e2e['median_ms']:.1f} ms (p99 {e2e['p99_ms']:.1f}); ratios "
          + ", ".join(f"{k} {v:.2f}" for k, v in ratios.items())
          + f"; load {load_before[0]:.2f} -> {load_after[0]:.2f}")  # fmt: skip
    write_json(args.json, {
        "benchmark": "ros2",
        "scans": len(scans),
        "warmup_left_out": args.warmup,
        "model": "bundled, " + ("ONNX (onnxruntime, " if args.onnx else "NumPy head step (")
                 + "1 thread)",
        "ros": "ROS 2 Jazzy wheels (rclpy, rmw_fastrtps_cpp), localhost",
        "horizon": args.horizon,
        "moving": args.moving,
        "load": {"loadavg_1_5_15_before": load_before, "loadavg_1_5_15_after": load_after,
                 "note": "a machine shared with other work; no busy process added"},
        "machine": machine(),
        "measures": {
            "predictor": "Predictor.update per scan in one process, back to back (before and "
                         "after the ROS run, pooled)",
            "predictor_paced": "the same at the recording's pace, a scan every "
                               f"{period * 1e3:.0f} ms as the peer publishes them (before and "
                               "after, pooled): the Predictor's own time under the node's "
                               "conditions but for ROS",
            "node": "the node's own clock: scan callback entered -> last grid published",
            "predictor_in_node": "the Predictor's update within each of the node's scans "
                                 "(same process, same moments)",
            "end_to_end": "an rclpy peer's wall clock: scan published -> that scan's last grid "
                          "received (transport both ways and queueing included)",
        },
        "target": "node median <= 1.1x the predictor's at the same pace (issue 45)",
        "results": {"predictor": own, "predictor_paced": paced, "predictor_in_node": in_node,
                    "node": node,
                    "end_to_end": e2e, **ratios},
    })  # fmt: skip


if __name__ == "__main__":
    main()
