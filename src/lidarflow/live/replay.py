"""A recording played as if it came live into a :class:`~lidarflow.live.foxglove.LiveServer`
(``lidarflow live``): each scan predicted when the recording's clock says (``speed`` times
faster; 0: as fast as the Predictor goes).

Played over again (``loop``), each pass restarts the Predictor (the jump back to the first scan
is no motion) and moves the stamps on by :func:`loop_shift_ns`, so that they keep running
forward: Foxglove's timeline does not go back.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from lidarflow.outputs.job import check_poses

if TYPE_CHECKING:
    from lidarflow.data.recording import Recording
    from lidarflow.live.foxglove import LiveServer
    from lidarflow.predict.predictor import Predictor

__all__ = ["Served", "loop_shift_ns", "replay"]

#: The pace of a recording without stamps (all zero): a common scanner's 10 Hz.
UNSTAMPED_STEP_NS = 100_000_000
#: Scans whose timings :class:`Served` keeps (the latest): enough for a median and a p99, and
#: bounded, as a looped replay may run for days.
KEPT_TIMINGS = 10_000


def _timings() -> deque[float]:
    return deque(maxlen=KEPT_TIMINGS)


@dataclass
class Served:
    """What a replay served: scans and passes, the seconds the Predictor's update and the
    publishing took per scan (the latest :data:`KEPT_TIMINGS`: what serving costs beside
    predicting), and how far behind the recording's pace it fell at worst."""

    scans: int = 0
    passes: int = 0
    update_s: deque[float] = field(default_factory=_timings)
    publish_s: deque[float] = field(default_factory=_timings)
    worst_lag_s: float = 0.0


def _offsets_ns(recording: Recording) -> np.ndarray:
    """Each scan's time after the first, on the recording's clock."""
    stamps = np.asarray(recording.stamps_ns, np.int64)
    if recording.frame_rate > 0:
        return stamps - stamps[0]
    return np.arange(len(stamps), dtype=np.int64) * UNSTAMPED_STEP_NS


def loop_shift_ns(recording: Recording) -> int:
    """How far each pass of a looped replay moves the stamps on: the recording's span plus one
    typical step, as if it were recorded again right after it ended."""
    rate = recording.frame_rate
    step_ns = round(1e9 / rate) if rate > 0 else UNSTAMPED_STEP_NS
    return int(_offsets_ns(recording)[-1]) + step_ns


def replay(
    recording: Recording,
    predictor: Predictor,
    server: LiveServer,
    speed: float = 1.0,
    loop: bool = False,
    progress: Callable[[int], None] | None = None,
    served: Served | None = None,
) -> Served:
    """Play ``recording`` through ``predictor`` into ``server``, counting into ``served`` (a new
    one by default) and returning it. With ``loop`` it ends only on Ctrl-C (or SIGTERM made
    one); the caller's ``served`` still says what went out."""
    if speed < 0:
        raise ValueError(f"speed must be >= 0, got {speed}")
    check_poses(recording, predictor)
    offsets = _offsets_ns(recording)
    shift = loop_shift_ns(recording)
    poses = recording.poses if predictor.uses_motion else None
    served = Served() if served is None else served
    start = time.monotonic()
    for n in itertools.count():
        predictor.reset()
        moved = n * shift
        for i, scan in enumerate(recording):
            if speed > 0:
                due = start + (moved + int(offsets[i])) / 1e9 / speed
                wait = due - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                else:
                    served.worst_lag_s = max(served.worst_lag_s, -wait)
            if moved:
                scan = dataclasses.replace(scan, stamp_ns=int(scan.stamp_ns) + moved)
            t0 = time.perf_counter()
            prediction = predictor.update(scan, None if poses is None else poses[i])
            t1 = time.perf_counter()
            server.publish(scan, prediction)
            served.update_s.append(t1 - t0)
            served.publish_s.append(time.perf_counter() - t1)
            served.scans += 1
            if progress is not None:
                progress(1)
        served.passes += 1
        if not loop:
            break
    return served
