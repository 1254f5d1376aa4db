"""A recording served once to the clients of a test, in a process of its own that ends as
``lidarflow live`` does: right after :meth:`LiveServer.close` (what is still queued then is
what a process that exits would lose).

``python -m tests.live.serve_recording RECORDING MODEL HORIZON`` prints the server's ws://
address, waits (a minute at most) until every topic has a subscriber, replays the recording as
fast as the model goes, prints ``published N``, closes the server and exits at once
(``os._exit``): what ``close()`` promises must hold when it returns, not thanks to the second
or so an interpreter's teardown would otherwise give the SDK's threads.
"""

from __future__ import annotations

import os
import sys
import time

from lidarflow.data.recording import load_recording
from lidarflow.live.foxglove import LiveServer
from lidarflow.live.replay import replay
from lidarflow.predict import Predictor

WAIT_S = 60.0


def main(recording_path: str, model: str, horizon: str) -> int:
    recording = load_recording(recording_path)
    predictor = Predictor(model, horizon=int(horizon))
    server = LiveServer(
        predictor.grid, recording.meta.get("frame_id") or "laser", port=0,
        horizon=predictor.horizon, flow=predictor.backend.capabilities.flow,
        scan_topic="/" + (recording.meta.get("topic") or "scan").lstrip("/"),
    )  # fmt: skip
    print(server.url, flush=True)
    deadline = time.monotonic() + WAIT_S
    while len(server.subscribed) < len(server.topics):
        if time.monotonic() > deadline:
            print(f"no client subscribed to every topic within {WAIT_S:g} s", file=sys.stderr)
            return 1
        time.sleep(0.01)
    served = replay(recording, predictor, server, speed=0)
    print(f"published {served.scans}", flush=True)
    server.close()
    return 0


if __name__ == "__main__":
    code = main(*sys.argv[1:])
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
