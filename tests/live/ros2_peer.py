"""A real rclpy peer of ``lidarflow ros2``, run as its own process (the venv's Python, with the
``ros2`` extra).

With ``--publish`` it publishes the bundled sample's scans (``sensor_msgs/LaserScan``, reliable,
in the recording's frame) at ``--rate`` times their recorded pace once the node subscribes,
noting when each went out. With ``--grids`` it subscribes to the node's grid topics (reliable)
and to the scan topic and records, per message, what a test checks (stamps, frame, layout,
value range) and when it arrived (``time.time_ns()``, the wall clock every process on the
machine shares); the data of the first ``--keep`` grids of each topic are kept whole. It prints
``ready`` once the node's grid publishers are matched, and writes its JSON when ``--count``
grids came on every grid topic, or nothing came for ``--idle`` seconds, or after ``--timeout``.
``--words`` publishes ``std_msgs/String`` on the scan topic instead (a topic of another type).

    python ros2_peer.py --out OUT.json --scan-topic /scan --grids /lidarflow/predicted
"""

from __future__ import annotations

import argparse
import array
import contextlib
import json
import sys
import threading
import time
from typing import Any

import numpy as np
import rclpy
from builtin_interfaces.msg import Time
from nav_msgs.msg import OccupancyGrid
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def ns(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--scan-topic", required=True)
    parser.add_argument("--grids", nargs="*", default=[])
    parser.add_argument("--count", type=int, default=0, help="grids per topic to wait for")
    parser.add_argument("--keep", type=int, default=0, help="grids per topic kept whole")
    parser.add_argument("--publish", action="store_true", help="publish the sample's scans")
    parser.add_argument("--words", action="store_true", help="publish std_msgs/String")
    parser.add_argument("--rate", type=float, default=1.0)
    parser.add_argument("--limit", type=int, default=0, help="publish only the first N scans")
    parser.add_argument("--subscribers", type=int, default=1,
                        help="scan readers to wait for before publishing")  # fmt: skip
    parser.add_argument("--idle", type=float, default=10.0)
    parser.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args()

    rclpy.init(args=[])
    node = rclpy.create_node("lidarflow_peer")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    spinner = threading.Thread(target=spin, args=(executor,), daemon=True)
    spinner.start()
    lock = threading.Lock()
    last = [time.monotonic()]
    scans: list[dict] = []
    sent: list[dict] = []
    grids: dict[str, list[dict]] = {t: [] for t in args.grids}
    kept: dict[str, list[list[int]]] = {t: [] for t in args.grids}

    def on_scan(msg: LaserScan) -> None:
        with lock:
            scans.append({"stamp_ns": ns(msg.header.stamp), "frame_id": msg.header.frame_id,
                          "received_ns": time.time_ns()})  # fmt: skip

    def on_grid(msg: OccupancyGrid, topic: str) -> None:
        received = time.time_ns()
        info, o = msg.info, msg.info.origin
        data = np.asarray(msg.data, dtype=np.int8)  # an int8 array.array: no copy, no loop
        values = np.unique(data)
        record = {
            "stamp_ns": ns(msg.header.stamp),
            "scan_stamp_ns": ns(info.map_load_time),
            "frame_id": msg.header.frame_id,
            "width": info.width,
            "height": info.height,
            "resolution": info.resolution,
            "origin": [o.position.x, o.position.y, o.position.z,
                       o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w],
            "cells": int(data.size),
            "min": int(values[0]),
            "max": int(values[-1]),
            "values": values.tolist() if len(values) <= 3 else None,
            "received_ns": received,
        }  # fmt: skip
        with lock:
            grids[topic].append(record)
            if len(kept[topic]) < args.keep:
                kept[topic].append(data.tolist())
            last[0] = time.monotonic()

    start = time.monotonic()
    if args.grids:
        for topic in args.grids:
            node.create_subscription(OccupancyGrid, topic,
                                     lambda m, t=topic: on_grid(m, t), RELIABLE)  # fmt: skip
        node.create_subscription(LaserScan, args.scan_topic, on_scan, RELIABLE)
        while any(node.count_publishers(t) == 0 for t in args.grids):
            if time.monotonic() - start > args.timeout:
                sys.exit("ros2_peer: the node's grid topics never came up")
            time.sleep(0.05)
        time.sleep(0.5)  # the matched endpoints finish their handshakes
    print("ready", flush=True)
    if args.words:
        words(node, args.scan_topic, args.timeout)
    if args.publish:
        publish(node, args.scan_topic, args.rate, sent, args.timeout, args.limit,
                args.subscribers)  # fmt: skip
    last[0] = time.monotonic()
    while args.grids and time.monotonic() - start < args.timeout:
        with lock:
            if args.count and all(len(g) >= args.count for g in grids.values()):
                break
            if time.monotonic() - last[0] > args.idle:
                break
        time.sleep(0.05)
    with lock:
        out = {"scans": scans, "sent": sent, "grids": grids, "kept": kept}
    with open(args.out, "w") as f:
        json.dump(out, f)
    # the context first: it wakes the executor, whose thread must end before the process does
    rclpy.try_shutdown()
    spinner.join(5)
    node.destroy_node()


def spin(executor: SingleThreadedExecutor) -> None:
    from rclpy.executors import ExternalShutdownException

    with contextlib.suppress(ExternalShutdownException):
        executor.spin()


def wait_for_subscriber(pub: Any, topic: str, timeout: float, subscribers: int) -> None:
    """Until ``subscribers`` readers (the node's among them) are matched with ``pub``: a
    best-effort reader drops what comes before it has matched the writer in turn, so a little
    more time is given for that."""
    start = time.monotonic()
    while pub.get_subscription_count() < subscribers:
        if time.monotonic() - start > timeout:
            sys.exit(f"ros2_peer: nobody subscribed to {topic}")
        time.sleep(0.05)
    time.sleep(2.0)


def publish(node: rclpy.node.Node, topic: str, rate: float, sent: list[dict], timeout: float,
            limit: int = 0, subscribers: int = 1) -> None:  # fmt: skip
    """The sample's scans (the first ``limit``, where given) on ``topic`` at ``rate`` times
    their recorded pace, once the node listens; each send time noted."""
    from lidarflow.data import read_bag, sample_bag_path

    recording = read_bag(sample_bag_path())
    frame_id = recording.meta["frame_id"]
    pub = node.create_publisher(LaserScan, topic, RELIABLE)
    wait_for_subscriber(pub, topic, timeout, subscribers)
    count = min(limit or len(recording), len(recording))
    first_stamp, t0 = recording.scan(0).stamp_ns, time.monotonic()
    for i in range(count):
        scan = recording.scan(i)
        g = scan.geometry
        msg = LaserScan()
        msg.header.frame_id = frame_id
        msg.header.stamp = Time(sec=scan.stamp_ns // 1_000_000_000,
                                nanosec=scan.stamp_ns % 1_000_000_000)  # fmt: skip
        msg.angle_min, msg.angle_increment = float(g.angle_min), float(g.angle_increment)
        msg.angle_max = float(g.angle_min + (g.count - 1) * g.angle_increment)
        msg.range_min, msg.range_max = float(g.range_min), float(g.range_max)
        # an array.array: taken as it is (a list has each value range-checked, and NaN fails)
        msg.ranges = array.array("f", scan.ranges.astype("float32").tobytes())
        due = t0 + (scan.stamp_ns - first_stamp) / 1e9 / rate
        time.sleep(max(0.0, due - time.monotonic()))
        sent.append({"stamp_ns": scan.stamp_ns, "sent_ns": time.time_ns()})
        pub.publish(msg)
    time.sleep(0.5)  # the last messages leave before the process does


def words(node: rclpy.node.Node, topic: str, timeout: float) -> None:
    """``std_msgs/String`` on ``topic`` at 5 Hz for ``timeout`` seconds (a topic whose type is
    not the node's)."""
    from std_msgs.msg import String

    pub = node.create_publisher(String, topic, 10)
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        pub.publish(String(data="hi"))
        time.sleep(0.2)


if __name__ == "__main__":
    main()
