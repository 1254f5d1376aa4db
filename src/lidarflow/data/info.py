"""Summaries of a recording: what `lidarflow info` prints."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from lidarflow.beams import NO_RETURN, RETURN, UNKNOWN, at_range_max, beam_status, ring_scans
from lidarflow.data.gaps import MAX_GAP_PERIODS, frames_after_gaps
from lidarflow.data.recording import Recording

__all__ = [
    "MAX_FRAME_RATE_HZ",
    "describe_recording",
    "find_gaps",
    "return_share",
    "stamps_problem",
    "unknown_share",
]

#: Faster than any 2-D LiDAR scans (50 to 100 Hz at most): stamps that step faster are a
#: counter, not a clock.
MAX_FRAME_RATE_HZ = 1000.0


def find_gaps(
    recording: Recording, max_gap_periods: float = MAX_GAP_PERIODS
) -> list[tuple[int, float]]:
    """``(frame index after the gap, gap in seconds)`` for every gap
    (:func:`lidarflow.data.gaps.frames_after_gaps`)."""
    stamps = recording.stamps_ns
    return [
        (i, float(stamps[i] - stamps[i - 1]) / 1e9)
        for i in frames_after_gaps(stamps, max_gap_periods)
    ]


def stamps_problem(recording: Recording) -> str | None:
    """Why ``recording``'s stamps cannot tell its frame rate (every scan at one instant, or
    steps faster than :data:`MAX_FRAME_RATE_HZ`); ``None`` where they can or it has no rate."""
    stamps = recording.stamps_ns
    if len(stamps) < 2:
        return None
    if np.all(stamps == stamps[0]):
        return f"all {len(stamps)} scans bear one stamp ({int(stamps[0])} ns)"
    rate = recording.frame_rate
    if rate > MAX_FRAME_RATE_HZ:
        return (
            f"they step {1e9 / rate:.3g} ns apart ({rate:.3g} Hz), faster than any scanner: a "
            "counter, not a clock"
        )
    return None


def describe_recording(recording: Recording) -> dict[str, Any]:
    """Scan count, duration, rate, field of view, range limits, beam statistics and gaps."""
    n = len(recording)
    status, at_max, rings = _beam_census(recording)
    raw = recording.ranges
    unknown = int(np.sum(status == UNKNOWN))
    nan, neg_inf, zero = (int(np.sum(m)) for m in (np.isnan(raw), np.isneginf(raw), raw == 0))
    counts = np.diff(recording.offsets)
    fov = np.abs(recording.angle_increment) * np.maximum(counts - 1, 0)
    duration = float(recording.stamps_ns[-1] - recording.stamps_ns[0]) / 1e9 if n > 1 else 0.0
    gaps = find_gaps(recording)
    problem = stamps_problem(recording)
    unusable = {"stamps_unusable": f"{problem}; the frame rate is unknown"} if problem else {}
    return {
        "scans": n,
        "duration_s": round(duration, 3),
        # unknown (None) where the stamps cannot tell it: 1e9 Hz is no scanner's rate
        "frame_rate_hz": None if problem else round(recording.frame_rate, 3),
        "beams_per_scan": sorted({int(c) for c in counts}),
        "field_of_view_deg": sorted({round(math.degrees(float(f)), 2) for f in np.unique(fov)}),
        "angle_min_deg": sorted(
            {round(math.degrees(float(a)), 2) for a in np.unique(recording.angle_min)}
        ),
        "range_min_m": sorted({round(float(r), 3) for r in np.unique(recording.range_min)}),
        "range_max_m": sorted({round(float(r), 3) for r in np.unique(recording.range_max)}),
        "beams": {
            "total": int(raw.size),
            "returns": int(np.sum(status == RETURN)),
            "no_return": int(np.sum(status == NO_RETURN)),
            "at_range_max": at_max,
            "scans_no_return_as_range_max": rings,
            "unknown": unknown,
            "nan": nan,
            "neg_inf": neg_inf,
            "zero": zero,
            "below_range_min": unknown - nan - neg_inf - zero,
        },
        "gaps": [{"before_frame": i, "seconds": round(s, 3)} for i, s in gaps],
        "geometry_changes": len(recording.geometry_runs()) - 1 if n else 0,
        "has_poses": recording.has_poses,
        # Odometry moved to the scanner by the bag's TF ((x, y, yaw) of the mount), or None:
        # the poses are the odometry's own frame's (the base's), which ego-motion models check.
        **({"sensor_mount": recording.meta.get("sensor_mount")} if recording.has_poses else {}),
        **({"sensor_upside_down": True} if recording.meta.get("sensor_upside_down") else {}),
        **_read_notes(recording.meta),
        **unusable,
    }


def unknown_share(recording: Recording) -> float:
    """The share of ``recording``'s beams that say nothing, as the rasterizer reads them."""
    return _share(recording, UNKNOWN)


def return_share(recording: Recording) -> float:
    """The share of ``recording``'s beams that are returns, as the rasterizer reads them."""
    return _share(recording, RETURN)


def _share(recording: Recording, code: int) -> float:
    status = _beam_census(recording)[0]
    return float(np.mean(status == code)) if status.size else 0.0


def _beam_census(recording: Recording) -> tuple[np.ndarray, int, int]:
    """Every beam's status as the rasterizer reads it, how many readings are exactly
    ``range_max`` and how many scans write no return so."""
    statuses, at_max, rings = [np.zeros(0, np.uint8)], 0, 0
    for a, b in recording.geometry_runs() if len(recording) else ():
        rows = recording.ranges[recording.offsets[a] : recording.offsets[b]].reshape(b - a, -1)
        low, high = float(recording.range_min[a]), float(recording.range_max[a])
        statuses.append(beam_status(rows, low, high).ravel())
        at_max += int(at_range_max(rows, high).sum())
        rings += int(np.count_nonzero(ring_scans(rows, high)))
    return np.concatenate(statuses), at_max, rings


def _read_notes(meta: dict[str, Any]) -> dict[str, Any]:
    """What reading the bag left out or replaced (read_bag's meta), so that it is never silent."""
    notes: dict[str, Any] = {}
    dropped = {kind: int(meta.get(f"{kind}_scans_dropped") or 0)
               for kind in ("empty", "duplicate", "malformed")}  # fmt: skip
    if any(dropped.values()):
        notes["scans_dropped"] = dropped
    if meta.get("stamps", "header") != "header":
        notes["stamps"] = meta["stamps"]
    keys = ("scan_type", "topic_choice", "pose_topic_choice", "clock_jumps", "recovered")
    notes.update({key: meta[key] for key in keys if meta.get(key)})
    return notes
