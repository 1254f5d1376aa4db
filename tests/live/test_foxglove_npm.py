"""A Foxglove client nobody here wrote: ``@foxglove/ws-protocol``'s ``FoxgloveClient`` (Node,
``tests/live/npm_client``, installed by ``scripts/test.sh`` with ``npm ci``), decoding with
protobufjs from the schemas the server advertises, connecting with each name of the protocol.

A recording is served once (``tests.live.serve_recording``: every scan after the client has
subscribed, then the server closes and its process ends): every scan's messages must arrive,
the last included, the grids whole and their values in -1..100, and the close say 1001.
Where Node or the client is missing these tests skip, unless required (``scripts/test.sh``
sets ``LIDARFLOW_REQUIRE_ROS``; CI sets ``CI``): there they fail.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess

import pytest

from lidarflow.live.front import LEGACY_SUBPROTOCOL, SDK_SUBPROTOCOL
from tests.live.serve_recording import HORIZON, ROOT, SCANS, serve_once

CLIENT = ROOT / "tests" / "live" / "npm_client"
TOPICS = 8  # the scan, six grids, the flow image


def require_client() -> None:
    """Skip where Node or the npm client is missing, or fail where the tests require it."""
    why = None
    if shutil.which("node") is None:
        why = "node is not installed (Debian: apt-get install nodejs npm)"
    elif not (CLIENT / "node_modules" / "@foxglove" / "ws-protocol").is_dir():
        why = f"the npm client is not installed: cd {CLIENT} && npm ci"
    if why is None:
        return
    if os.environ.get("LIDARFLOW_REQUIRE_ROS") or os.environ.get("CI"):
        pytest.fail(f"the npm Foxglove client is required here (CI): {why}")
    pytest.skip(why)


@pytest.mark.parametrize("subprotocol", [SDK_SUBPROTOCOL, LEGACY_SUBPROTOCOL])
def test_the_npm_foxglove_client_gets_every_scan_with_either_subprotocol(
    short_flow, subprotocol
):
    require_client()
    server, url = serve_once(*short_flow)
    try:
        node = subprocess.run(["node", str(CLIENT / "client.mjs"), url, subprotocol, "60"],
                              capture_output=True, text=True, timeout=90)  # fmt: skip
    finally:
        _, err = server.communicate(timeout=60)
    assert server.returncode == 0, err
    assert node.returncode == 0, node.stdout + node.stderr
    summary = json.loads(node.stdout)
    assert summary["subprotocol"] == subprotocol and summary["server"] == "lidarflow"
    assert summary["errors"] == [] and summary["closeCode"] == 1001, summary["errors"]
    topics = summary["topics"]
    assert len(topics) == TOPICS
    times = {topic: [int(t) for t in got["logTimes"]] for topic, got in topics.items()}
    scan_times = times["/right_scan"]
    assert len(scan_times) == SCANS and scan_times == sorted(scan_times)
    for topic, logged in times.items():
        assert logged == scan_times, topic  # every scan on every topic, the last included
    grids = [topic for topic, got in topics.items() if got["schema"] == "foxglove.Grid"]
    assert len(grids) == 2 * HORIZON + 2
    for topic in grids:
        for grid in topics[topic]["grids"]:
            assert (grid["columns"], grid["rows"], grid["cells"]) == (100, 100, 100 * 100), topic
            assert -1 <= grid["min"] <= grid["max"] <= 100, topic
