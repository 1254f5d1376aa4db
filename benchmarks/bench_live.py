"""What serving predictions live to Foxglove costs per scan, beside the Predictor's own update
(issue 37: the live paths may add little to the model's latency).

Runs the Predictor over the bundled sample's scans as fast as it goes, handing each prediction
to a :class:`~lidarflow.live.foxglove.LiveServer` on a free localhost port: a first pass with
no client connected (publishing then only checks who listens), a second with a WebSocket client
subscribed to every topic and reading every message (the server builds, encodes and queues
each one). The client is a process of its own, as Foxglove is: in this one it would take the
interpreter's lock from the loop it measures. Per scan it times ``Predictor.update`` and
``LiveServer.publish`` apart. The judged number is the ratio of the medians within one run,
publish over update, with a client watching. Writes JSON (default
``benchmarks/results/live.json``).

    python benchmarks/bench_live.py [--scans 243] [--model M] [--horizon K] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
from _output import machine, write_json

from lidarflow.data import read_bag, sample_bag_path
from lidarflow.live.foxglove import LiveServer
from lidarflow.predict import Predictor

HERE = Path(__file__).resolve().parent


def drain(url: str, ready: Any, stop: Any, got: Any) -> None:
    """A Foxglove client: subscribe to every advertised channel, read until ``stop``, then put
    ``(messages, bytes)`` received on the queue ``got``."""
    from websockets.exceptions import ConnectionClosed
    from websockets.sync.client import connect

    messages = size = 0
    with connect(url, subprotocols=["foxglove.sdk.v1"]) as ws:
        channels: list[int] = []
        while not channels:
            message = json.loads(ws.recv(timeout=10))
            if message["op"] == "advertise":
                channels = [c["id"] for c in message["channels"]]
        subscriptions = [{"id": i, "channelId": c} for i, c in enumerate(channels)]
        ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))
        time.sleep(0.5)  # the subscription reaches the server before scans go out
        ready.set()
        while not stop.is_set():
            try:
                frame = ws.recv(timeout=0.2)
            except TimeoutError:
                continue
            except ConnectionClosed:
                break
            if isinstance(frame, bytes):
                messages, size = messages + 1, size + len(frame)
    got.put((messages, size))


def stats(seconds: list[float]) -> dict[str, float]:
    ms = 1e3 * np.asarray(seconds)
    return {"median_ms": float(np.median(ms)), "p99_ms": float(np.percentile(ms, 99))}


def one_pass(recording: Any, predictor: Predictor, server: LiveServer) -> dict[str, Any]:
    """Every scan updated and published, each timed apart."""
    predictor.reset()
    update, publish = [], []
    for scan in recording:
        t0 = time.perf_counter()
        prediction = predictor.update(scan)
        t1 = time.perf_counter()
        server.publish(scan, prediction)
        update.append(t1 - t0)
        publish.append(time.perf_counter() - t1)
    result: dict[str, Any] = {"update": stats(update), "publish": stats(publish)}
    result["publish_over_update"] = result["publish"]["median_ms"] / result["update"]["median_ms"]
    return result


def watched_pass(recording: Any, predictor: Predictor, server: LiveServer) -> dict[str, Any]:
    """:func:`one_pass` with a client in another process subscribed to every topic."""
    spawn = multiprocessing.get_context("spawn")  # no fork of a process running threads
    ready, stop, got = spawn.Event(), spawn.Event(), spawn.Queue()
    client = spawn.Process(target=drain, args=(server.url, ready, stop, got))
    client.start()
    if not ready.wait(60):
        raise SystemExit("the client did not subscribe within 60 s")
    result = one_pass(recording, predictor, server)
    time.sleep(1.0)  # the last messages arrive
    stop.set()
    messages, size = got.get(timeout=30)
    client.join(10)
    result["client_received"] = {
        "messages": messages,
        "kbytes_per_scan": size / 1e3 / len(recording),
    }
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=0, help="scans of the sample (0: all)")
    parser.add_argument("--model", default=None, help="model (default: the bundled one)")
    parser.add_argument("--horizon", type=int, default=1)
    parser.add_argument("--json", type=Path, default=HERE / "results" / "live.json")
    args = parser.parse_args()

    recording = read_bag(sample_bag_path())
    if args.scans:
        recording = recording.slice(0, args.scans)
    predictor = Predictor(args.model, horizon=args.horizon)
    frame_id = recording.meta.get("frame_id") or "laser"
    flow = predictor.backend.capabilities.flow
    load_before = os.getloadavg()[0]
    with LiveServer(predictor.grid, frame_id, port=0, horizon=args.horizon, flow=flow) as server:
        idle = one_pass(recording, predictor, server)
        watched = watched_pass(recording, predictor, server)
    options = [f"--{k} {v}" for k, v in vars(args).items() if k != "json" and v]
    result = {
        "command": " ".join(["python benchmarks/bench_live.py", *options]),
        "machine": {**machine(), "loadavg_1min_before": load_before},
        "model": args.model or "bundled",
        "scans": len(recording),
        "horizon": args.horizon,
        "no_client": idle,
        "client_subscribed_to_all": watched,
    }
    print(json.dumps(result, indent=2))
    write_json(args.json, result)


if __name__ == "__main__":
    main()
