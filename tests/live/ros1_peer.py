"""A real rospy peer of ``lidarflow ros1``, run with Debian's ``/usr/bin/python3``.

It subscribes to the scan topic and to the node's grid topics and records, per message, what a
test checks (stamps, frame, layout, value range) and when it arrived (``time.time_ns()``, the
wall clock every process on the machine shares); the data of the first ``--keep`` grids of
each topic are kept whole. With ``--publish BAG`` it also plays the bag's scans itself, at
``--rate`` times their recorded pace, noting when each went out, so that a benchmark gets the
latency from the scan sent to its grids received. It prints ``ready`` once every grid topic is
connected, and writes its JSON when ``--count`` grids came on every grid topic, or every scan
seen has its grids and none came for ``--settle`` seconds, or nothing came for ``--idle``
seconds, or after ``--timeout`` seconds.

    /usr/bin/python3 ros1_peer.py --out OUT.json --scan-topic /scan --grids /lidarflow/predicted
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time

import rospy
from nav_msgs.msg import OccupancyGrid
from sensor_msgs.msg import LaserScan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--scan-topic", required=True)
    parser.add_argument("--grids", nargs="+", required=True)
    parser.add_argument("--count", type=int, default=0, help="grids per topic to wait for")
    parser.add_argument("--keep", type=int, default=0, help="grids per topic kept whole")
    parser.add_argument("--publish", default=None, help="a bag whose scans to publish")
    parser.add_argument("--rate", type=float, default=1.0)
    parser.add_argument("--limit", type=int, default=0, help="publish only the first N scans")
    parser.add_argument("--idle", type=float, default=10.0)
    parser.add_argument(
        "--settle", type=float, default=2.0,
        help="seconds without grids after which a peer whose every scan has its grids ends",
    )  # fmt: skip
    parser.add_argument("--timeout", type=float, default=120.0)
    args = parser.parse_args()

    rospy.init_node("lidarflow_peer", anonymous=True, disable_signals=True)
    lock = threading.Lock()
    last = [time.monotonic()]
    scans: list[dict] = []
    sent: list[dict] = []
    grids: dict[str, list[dict]] = {t: [] for t in args.grids}
    kept: dict[str, list[list[int]]] = {t: [] for t in args.grids}

    def on_scan(msg: LaserScan) -> None:
        with lock:
            scans.append({"stamp_ns": msg.header.stamp.to_nsec(), "frame_id": msg.header.frame_id,
                          "received_ns": time.time_ns()})  # fmt: skip

    def on_grid(msg: OccupancyGrid, topic: str) -> None:
        received = time.time_ns()
        info, o = msg.info, msg.info.origin
        record = {
            "stamp_ns": msg.header.stamp.to_nsec(),
            "scan_stamp_ns": info.map_load_time.to_nsec(),
            "frame_id": msg.header.frame_id,
            "width": info.width,
            "height": info.height,
            "resolution": info.resolution,
            "origin": [o.position.x, o.position.y, o.position.z,
                       o.orientation.x, o.orientation.y, o.orientation.z, o.orientation.w],
            "cells": len(msg.data),
            "min": min(msg.data),
            "max": max(msg.data),
            "values": sorted(set(msg.data)) if len(set(msg.data)) <= 3 else None,
            "received_ns": received,
        }  # fmt: skip
        with lock:
            grids[topic].append(record)
            if len(kept[topic]) < args.keep:
                kept[topic].append(list(msg.data))
            last[0] = time.monotonic()

    subs = [rospy.Subscriber(t, OccupancyGrid, on_grid, callback_args=t, queue_size=1000,
                             tcp_nodelay=True) for t in args.grids]  # fmt: skip
    rospy.Subscriber(args.scan_topic, LaserScan, on_scan, queue_size=1000, tcp_nodelay=True)
    start = time.monotonic()
    while any(s.get_num_connections() == 0 for s in subs):
        if time.monotonic() - start > args.timeout:
            sys.exit("ros1_peer: the node's grid topics never connected")
        time.sleep(0.05)
    print("ready", flush=True)
    if args.publish:
        publish(args.publish, args.scan_topic, args.rate, sent, args.timeout, args.limit)
    last[0] = time.monotonic()
    while time.monotonic() - start < args.timeout and time.monotonic() - last[0] < args.idle:
        with lock:
            if args.count and all(len(g) >= args.count for g in grids.values()):
                break
            # every scan seen has its grids and none came for a while: the scans have ended
            answered = scans and all(len(g) >= len(scans) for g in grids.values())
            if answered and time.monotonic() - last[0] >= args.settle:
                break
        time.sleep(0.05)
    with lock:
        out = {"scans": scans, "sent": sent, "grids": grids, "kept": kept}
    with open(args.out, "w") as f:
        json.dump(out, f)
    rospy.signal_shutdown("done")


def publish(
    bag_path: str, topic: str, rate: float, sent: list[dict], timeout: float, limit: int = 0
) -> None:
    """The bag's scans (the first ``limit``, where given) on ``topic`` at ``rate`` times their
    recorded pace, once the node (a subscriber other than this peer) listens; each send time
    noted."""
    import rosbag

    pub = rospy.Publisher(topic, LaserScan, queue_size=1000, tcp_nodelay=True)
    start = time.monotonic()
    while pub.get_num_connections() < 2:  # this peer's own subscriber and the node's
        if time.monotonic() - start > timeout:
            sys.exit(f"ros1_peer: nobody subscribed to {topic}")
        time.sleep(0.05)
    time.sleep(1.0)  # the connections' handshakes finish
    with rosbag.Bag(bag_path) as bag:
        messages = [m for _, m, _ in bag.read_messages()][: limit or None]
    first_stamp, t0 = messages[0].header.stamp.to_nsec(), time.monotonic()
    for msg in messages:
        due = t0 + (msg.header.stamp.to_nsec() - first_stamp) / 1e9 / rate
        time.sleep(max(0.0, due - time.monotonic()))
        sent.append({"stamp_ns": msg.header.stamp.to_nsec(), "sent_ns": time.time_ns()})
        pub.publish(msg)


if __name__ == "__main__":
    main()
