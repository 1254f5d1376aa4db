"""The per-scan step of a live node: one scan through the Predictor and out to every sink, timed.

A source (a ROS node's scan callback, or any other) calls :class:`LiveStep` with each scan; the
step predicts and hands a :class:`LiveFrame` to each sink in turn. A scan's latency runs from
its arrival to the last sink returning; it is logged per scan at debug level and summarised
(median, p99) every ``summary_every`` scans at info level.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from lidarflow.predict.predictor import Prediction, Predictor
    from lidarflow.scan import Scan

__all__ = ["LatencyLog", "LiveFrame", "LiveStep", "Sink", "clock_ns"]

log = logging.getLogger("lidarflow.live")

#: The clock arrival and completion are read on: monotonic, so a clock step cannot make a
#: latency negative.
clock_ns = time.monotonic_ns


@dataclass(frozen=True)
class LiveFrame:
    """What a sink receives for one scan: the prediction, the scan it was made from, the scan's
    frame (grids go out in it) and when the scan arrived (:data:`clock_ns`)."""

    prediction: Prediction
    scan: Scan
    frame_id: str
    received_ns: int


#: A sink takes each frame once; it runs on the source's thread, so it should hand slow work on.
Sink = Callable[[LiveFrame], Any]


class LatencyLog:
    """Per-scan latencies in milliseconds, summarised every ``summary_every`` scans."""

    def __init__(self, summary_every: int = 100) -> None:
        if summary_every < 1:
            raise ValueError(f"summary_every must be >= 1, got {summary_every}")
        self.summary_every = summary_every
        self.all_ms: list[float] = []
        self._window: list[float] = []

    def add(self, ms: float, stamp_ns: int, predict_ms: float | None = None) -> None:
        """One scan's latency; ``predict_ms``, where given, the part of it the Predictor took
        (logged beside it, so that what a node adds is read off one process at one moment)."""
        self.all_ms.append(ms)
        self._window.append(ms)
        of_it = "" if predict_ms is None else f", {predict_ms:.2f} ms of it predicting"
        log.debug("scan %d (stamp %d ns): %.2f ms from arrival to published%s", len(self.all_ms),
                  stamp_ns, ms, of_it)  # fmt: skip
        if len(self._window) >= self.summary_every:
            log.info("latency over the last %s", self.describe(self._window))
            self._window = []

    @staticmethod
    def summary(values: list[float]) -> dict[str, float]:
        """``scans``, ``median_ms`` and ``p99_ms`` of ``values`` (0 scans: NaN)."""
        if not values:
            return {"scans": 0, "median_ms": float("nan"), "p99_ms": float("nan")}
        ms = np.asarray(values)
        return {"scans": len(ms), "median_ms": float(np.median(ms)),
                "p99_ms": float(np.percentile(ms, 99))}  # fmt: skip

    def describe(self, values: list[float] | None = None) -> str:
        s = self.summary(self.all_ms if values is None else values)
        if not s["scans"]:
            return "0 scans"
        return f"{s['scans']} scans: median {s['median_ms']:.2f} ms, p99 {s['p99_ms']:.2f} ms"


class LiveStep:
    """Predict each arriving scan and pass the result to every sink, in order (``sinks`` may
    be appended to later).

    Thread-safe: a source may call it from several threads (rospy runs a callback per
    publisher connection); scans then go through the recurrent model one after another.
    """

    def __init__(
        self, predictor: Predictor, sinks: list[Sink] | None = None, summary_every: int = 100
    ) -> None:
        self.predictor = predictor
        self.sinks: list[Sink] = list(sinks or [])
        self.latency = LatencyLog(summary_every)
        self._lock = threading.Lock()

    def __call__(self, scan: Scan, frame_id: str, received_ns: int, pose: Any = None) -> LiveFrame:
        """Predict ``scan`` (arrived at ``received_ns`` on :data:`clock_ns`; ``pose``
        ``(x, y, yaw)`` of the sensor or ``None``), hand it to the sinks, log its latency."""
        with self._lock:
            started = clock_ns()
            frame = LiveFrame(self.predictor.update(scan, pose), scan, frame_id, received_ns)
            predicted = clock_ns()
            for sink in self.sinks:
                sink(frame)
            done = clock_ns()
            self.latency.add((done - received_ns) / 1e6, scan.stamp_ns, (predicted - started) / 1e6)
        return frame
