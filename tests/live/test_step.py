"""The per-scan step of the live nodes: every sink gets every frame, in order, timed."""

from __future__ import annotations

import logging
import threading
import time

import numpy as np
import pytest

from lidarflow.live.step import LatencyLog, LiveStep, clock_ns
from lidarflow.scan import BeamGeometry, Scan


class SlowPredictor:
    """Takes ``seconds`` per update and notes whether two updates ever overlapped."""

    def __init__(self, seconds: float) -> None:
        self.seconds, self.busy, self.overlapped, self.poses = seconds, False, False, []

    def update(self, scan, pose=None):
        self.overlapped |= self.busy
        self.busy = True
        time.sleep(self.seconds)
        self.poses.append(pose)
        self.busy = False
        return f"prediction of {scan.stamp_ns}"


def scan(stamp_ns: int) -> Scan:
    return Scan(np.ones(3, np.float32), BeamGeometry(3, -0.1, 0.1, 0.05, 5.0), stamp_ns)


def test_sinks_get_each_frame_in_order_and_the_latency_counts_from_arrival():
    seen = []
    sinks = [lambda f: seen.append(("a", f)), lambda f: seen.append(("b", f))]
    step = LiveStep(SlowPredictor(0.01), sinks)
    arrived = clock_ns() - 50_000_000  # the scan waited 50 ms before the step began
    frame = step(scan(7), "laser", arrived, pose=(1.0, 2.0, 0.5))
    assert [name for name, _ in seen] == ["a", "b"] and seen[0][1] is frame
    assert (frame.prediction, frame.frame_id) == ("prediction of 7", "laser")
    assert frame.received_ns == arrived
    assert step.predictor.poses == [(1.0, 2.0, 0.5)]
    assert 60 <= step.latency.all_ms[0] < 1000


def test_scans_from_several_threads_go_through_one_at_a_time():
    predictor = SlowPredictor(0.005)
    step = LiveStep(predictor)
    threads = [threading.Thread(target=step, args=(scan(i), "l", clock_ns())) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert len(predictor.poses) == 8 and not predictor.overlapped


def test_latency_is_logged_per_scan_and_summarised(caplog):
    log = LatencyLog(summary_every=3)
    with caplog.at_level(logging.DEBUG, logger="lidarflow.live"):
        for i, ms in enumerate([10.0, 30.0, 20.0, 5.0]):
            log.add(ms, i)
    debug = [r.getMessage() for r in caplog.records if r.levelno == logging.DEBUG]
    info = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    assert len(debug) == 4 and debug[1] == "scan 2 (stamp 1 ns): 30.00 ms from arrival to published"
    assert info == ["latency over the last 3 scans: median 20.00 ms, p99 29.80 ms"]
    assert log.summary(log.all_ms)["median_ms"] == pytest.approx(15.0)
    assert LatencyLog().describe() == "0 scans"
    with caplog.at_level(logging.DEBUG, logger="lidarflow.live"):
        log.add(12.0, 9, predict_ms=10.5)
    assert caplog.records[-1].getMessage() == (
        "scan 5 (stamp 9 ns): 12.00 ms from arrival to published, 10.50 ms of it predicting"
    )
