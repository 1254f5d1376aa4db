"""A recording served once to the clients of a test, in a process of its own that ends as
``lidarflow live`` does: right after :meth:`LiveServer.close` (what is still queued then is
what a process that exits would lose).

``python -m tests.live.serve_recording RECORDING MODEL HORIZON`` prints the server's ws://
address, waits (a minute at most) until every topic has a subscriber, replays the recording as
fast as the model goes, prints ``published N``, closes the server and exits at once
(``os._exit``): what ``close()`` promises must hold when it returns, not thanks to the second
or so an interpreter's teardown would otherwise give the SDK's threads.
Tests start it with :func:`serve_once`, on :data:`SCANS` scans (the ``short_flow`` fixture).
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from lidarflow.data.recordfile import load_recording
from lidarflow.live.foxglove import LiveServer
from lidarflow.live.replay import replay
from lidarflow.predict import Predictor

WAIT_S = 60.0
ROOT = Path(__file__).resolve().parents[2]
#: Scans served (of the bundled sample) and frames predicted ahead: every topic, 80 kB a scan.
SCANS = 8
HORIZON = 2


def serve_once(recording: Path, model: Path) -> tuple[subprocess.Popen, str]:
    """This module in a process of its own, and the ws:// address it serves on."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "tests.live.serve_recording", str(recording), str(model),
         str(HORIZON)],
        cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"},
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    url = proc.stdout.readline().strip()
    assert url.startswith("ws://"), proc.communicate(timeout=60)
    return proc, url


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
