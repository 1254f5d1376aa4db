"""Where a bag's header clock goes back: the sessions one after the other, not interleaved.

Scans are read in header-stamp order, which undoes arrival jitter. Where the header clock goes
back (a driver restart, a simulator's ``/clock`` reset), the sessions keep their arrival order,
each in header order and re-stamped to follow the one before after a gap, and each gets the
poses of the odometry's own session.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from lidarflow.scan import Scan

__all__ = ["in_sessions", "interpolate_poses", "recorded_stamps", "sliced_clock_jumps"]

# A header stamp this far behind the latest one of its session is a clock that went back, not
# transport jitter: multi-connection bags reorder a frame or a few (some tens of ms), a clock
# that restarts goes back seconds. The floor keeps a fast scanner's jitter jitter.
_JUMP_PERIODS = 5
_JUMP_MIN_NS = 500_000_000


def _jump_tolerance_ns(stamps_ns: np.ndarray) -> int:
    """How far a stamp may fall behind the latest before it and still be jitter."""
    steps = np.diff(stamps_ns)
    steps = steps[steps > 0]
    period = int(np.median(steps)) if steps.size else 0
    return max(_JUMP_PERIODS * period, _JUMP_MIN_NS)


def _session_starts(stamps_ns: np.ndarray, tolerance_ns: int) -> list[int]:
    """The index of each stamp (arrival order) that starts a session: 0, and each one more than
    ``tolerance_ns`` behind the latest of its session so far."""
    starts, latest = [0], None
    for i, stamp in enumerate(stamps_ns.tolist()):
        if latest is not None and stamp < latest - tolerance_ns:
            starts.append(i)
            latest = stamp
        else:
            latest = stamp if latest is None else max(latest, stamp)
    return starts


def _order_sessions(
    stamps_ns: np.ndarray, starts: list[int], seam_ns: int
) -> tuple[np.ndarray, np.ndarray]:
    """The reading order of the stamps, split into sessions at ``starts``: the sessions one
    after the other, each in stamp order, and the shift (ns) for each stamp so that each
    session begins ``seam_ns`` after the one before ends.

    >>> _order_sessions(np.array([10, 12, 11, 2, 3]), [0, 3], 5)
    (array([0, 2, 1, 3, 4]), array([ 0,  0,  0, 15, 15]))
    """
    order, shifts, end = [], [], None
    for a, b in itertools.pairwise([*starts, len(stamps_ns)]):
        session = a + np.argsort(stamps_ns[a:b], kind="stable")
        shift = 0 if end is None else end + seam_ns - int(stamps_ns[session[0]])
        end = int(stamps_ns[session[-1]]) + shift
        order.append(session)
        shifts.append(np.full(b - a, shift, dtype=np.int64))
    return np.concatenate(order), np.concatenate(shifts)


def _restamped(scan: Scan, shift_ns: int) -> Scan:
    return scan if shift_ns == 0 else Scan(scan.ranges, scan.geometry, scan.stamp_ns + shift_ns)


def interpolate_poses(
    stamps_ns: np.ndarray, pose_stamps_ns: np.ndarray, poses: np.ndarray
) -> np.ndarray:
    """Poses ``(x, y, yaw)`` at ``stamps_ns`` by linear interpolation (yaw unwrapped first);
    NaN outside the span of the pose messages."""
    out = np.full((len(stamps_ns), 3), np.nan)
    if len(pose_stamps_ns) == 0:
        return out
    order = np.argsort(pose_stamps_ns, kind="stable")
    t, p = pose_stamps_ns[order].astype(np.float64), poses[order]
    inside = (stamps_ns >= t[0]) & (stamps_ns <= t[-1])
    q = stamps_ns[inside].astype(np.float64)
    yaw = np.unwrap(p[:, 2])
    out[inside, 0] = np.interp(q, t, p[:, 0])
    out[inside, 1] = np.interp(q, t, p[:, 1])
    out[inside, 2] = (np.interp(q, t, yaw) + math.pi) % (2 * math.pi) - math.pi
    return out


def _session_poses(
    scan_stamps: list[np.ndarray],
    scan_jumps_ns: np.ndarray,
    odometry: tuple[np.ndarray, np.ndarray, np.ndarray],
    window_ns: int,
) -> tuple[np.ndarray, int]:
    """Poses at the stamps of each scan session from the odometry's own session, and how many
    of the scans' clock jumps (at log times ``scan_jumps_ns``) the odometry made too, within
    ``window_ns``. A scan session after the first unpaired jump gets NaN: its clock is one the
    odometry's does not follow."""
    stamps, log_times, values = odometry
    if len(scan_stamps) == 1:  # no jump in the scans: all the odometry, as it always was
        return interpolate_poses(scan_stamps[0], stamps, values), 0
    starts = _session_starts(stamps, _jump_tolerance_ns(stamps))
    paired = 0
    for scan_jump, pose_jump in zip(scan_jumps_ns, log_times[starts[1:]], strict=False):
        if abs(int(scan_jump) - int(pose_jump)) > window_ns:
            break
        paired += 1
    bounds = [*starts, len(stamps)]
    poses = [
        interpolate_poses(at, stamps[bounds[k] : bounds[k + 1]], values[bounds[k] : bounds[k + 1]])
        if k <= paired
        else np.full((len(at), 3), np.nan)
        for k, at in enumerate(scan_stamps)
    ]
    return np.concatenate(poses), paired


def _clock_jumps(
    stamps_ns: np.ndarray, starts: list[int], shifts: np.ndarray, poses_paired: int | None
) -> list[dict[str, Any]]:
    """``meta["clock_jumps"]``: for each session after the first, the frame it begins at, how
    far its clock went back and the shift added to its stamps, and with odometry whether the
    odometry's clock jumped with it."""
    jumps = []
    for k, (a, b) in enumerate(itertools.pairwise(starts), start=1):
        jump: dict[str, Any] = {
            "before_frame": b,
            "back_s": round(int(stamps_ns[a:b].max() - stamps_ns[b]) / 1e9, 3),
            "shift_s": round(int(shifts[b]) / 1e9, 3),
            "shift_ns": int(shifts[b]),
        }
        if poses_paired is not None:
            jump["poses_matched"] = k <= poses_paired
        jumps.append(jump)
    return jumps


def in_sessions(
    scans: list[Scan],
    arrivals: np.ndarray,
    odometry: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
) -> tuple[list[Scan], np.ndarray | None, list[dict[str, Any]]]:
    """``scans`` (in arrival order, log times ``arrivals``) in reading order, their poses from
    ``odometry`` (stamps, log times, ``(x, y, yaw)``; None without), and ``meta["clock_jumps"]``.
    Each later session is re-stamped to follow the one before after twice the jitter tolerance
    (at least 1 s), a gap that find_gaps and training cut at."""
    stamps_ns = np.array([s.stamp_ns for s in scans], dtype=np.int64)
    tolerance = _jump_tolerance_ns(stamps_ns)
    starts = _session_starts(stamps_ns, tolerance)
    order, shifts = _order_sessions(stamps_ns, starts, seam_ns=2 * tolerance)
    ordered = [_restamped(scans[i], int(d)) for i, d in zip(order, shifts, strict=True)]
    poses, paired = None, None
    if odometry is not None:
        bounds = [*starts, len(scans)]
        at = [stamps_ns[order[a:b]] for a, b in itertools.pairwise(bounds)]
        poses, paired = _session_poses(at, arrivals[starts[1:]], odometry, tolerance)
    return ordered, poses, _clock_jumps(stamps_ns, starts, shifts, paired)


def recorded_stamps(stamps_ns: np.ndarray, clock_jumps: list[dict[str, Any]]) -> np.ndarray:
    """The stamps as the bag had them: each session after a clock jump (``meta["clock_jumps"]``)
    un-shifted."""
    out = np.array(stamps_ns, dtype=np.int64)
    for jump in sorted(clock_jumps, key=lambda j: j["before_frame"]):
        # each session's shift is its own (not added to the one before's): later ones override
        shift = jump.get("shift_ns", round(float(jump["shift_s"]) * 1e9))
        out[jump["before_frame"] :] = np.asarray(stamps_ns[jump["before_frame"] :]) - shift
    return out


def sliced_clock_jumps(
    clock_jumps: list[dict[str, Any]], start: int, stop: int
) -> list[dict[str, Any]]:
    """``meta["clock_jumps"]`` for frames ``[start, stop)`` of a recording: the jumps inside,
    renumbered, and the one in effect at ``start`` (its session's shift) as if at frame 0."""
    ordered = sorted(clock_jumps, key=lambda j: j["before_frame"])
    before = [j for j in ordered if j["before_frame"] <= start]
    inside = [j for j in ordered if start < j["before_frame"] < stop]
    out = [{**before[-1], "before_frame": 0}] if before else []
    return out + [{**j, "before_frame": j["before_frame"] - start} for j in inside]
