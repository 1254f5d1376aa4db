"""Cleaning a scan topic as it was read, in arrival order: unset (zero) header stamps filled,
copies of one message dropped, stamps that never advance replaced by the log times.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from lidarflow.scan import BeamGeometry, Scan

__all__ = ["SIM_CLOCK_NS", "Cleaned", "clean_scans", "without_copies", "zero_stamps_filled"]

#: Header stamps all below a day after the epoch are a simulator's clock (ROS ``/clock``).
SIM_CLOCK_NS = 86_400 * 1_000_000_000

_COPIES_WITHIN_NS = 1_000_000_000  # log times of one message recorded twice: well within 1 s


@dataclass(frozen=True)
class Cleaned:
    """A scan topic after :func:`clean_scans`: the scans kept (arrival order), their log times
    (int64 ns), how many were dropped as copies, and what the stamps are (``meta["stamps"]``)."""

    scans: list[Scan]
    arrivals: np.ndarray
    duplicates: int
    stamps: str


def clean_scans(scans: list[Scan], log_times: Sequence[int]) -> Cleaned:
    """``scans`` (arrival order, logged at ``log_times`` ns) cleaned; where the header stamps
    do not advance (between fewer than half of the scans) but the log times do, the scans are
    stamped with their log times."""
    header = np.array([s.stamp_ns for s in scans], dtype=np.int64)
    filled = zero_stamps_filled(header, np.array(log_times, dtype=np.int64))
    if not np.array_equal(filled, header):
        scans = _stamped(scans, filled)
    unique, arrivals = without_copies(scans, log_times)
    stamps = "header"
    if _stuck(np.array([s.stamp_ns for s in unique])) and not _stuck(arrivals):
        # A driver that never advances its header stamps (all one value) would leave every scan
        # at one instant: no frame rate, every frame a gap, every scan at one odometry pose.
        unique = _stamped(unique, arrivals)
        stamps = "log time (the header stamps do not advance)"
    return Cleaned(unique, arrivals, len(scans) - len(unique), stamps)


def zero_stamps_filled(header_ns: np.ndarray, log_ns: np.ndarray) -> np.ndarray:
    """Header stamps with each zero (unset) replaced by its log time. On a simulator's clock,
    which starts at 0, leading zeros stay and a later zero gets the stamps around it,
    interpolated by position (the log time, a wall clock, is no stand-in there)."""
    zero = header_ns <= 0
    if not zero.any():
        return header_ns
    rest = np.flatnonzero(~zero)
    if rest.size == 0 or header_ns[rest].max() >= SIM_CLOCK_NS:
        return np.where(zero, log_ns, header_ns)
    out = np.maximum(header_ns, 0)
    later = np.flatnonzero(zero)
    later = later[later > rest[0]]
    out[later] = np.rint(np.interp(later, rest, header_ns[rest])).astype(np.int64)
    return out


def without_copies(scans: list[Scan], log_times: Sequence[int]) -> tuple[list[Scan], np.ndarray]:
    """``scans`` less the copies of one message, and the log times (int64 ns) of those kept.

    A copy has the same stamp, geometry and ranges and is logged within 1 s of the one kept:
    kept twice, it would make a copy of the last map a perfect prediction. The same scan a
    session later (a simulator replaying itself after a clock reset) is kept.
    """
    # a digest of the ranges: their bytes as keys held a second copy of every scan
    seen: dict[tuple[int, BeamGeometry, bytes], int] = {}
    unique: list[tuple[Scan, int]] = []
    for scan, log_time in zip(scans, log_times, strict=True):
        digest = hashlib.blake2b(np.ascontiguousarray(scan.ranges), digest_size=16).digest()
        key = (scan.stamp_ns, scan.geometry, digest)
        if key not in seen or abs(int(log_time) - seen[key]) > _COPIES_WITHIN_NS:
            unique.append((scan, log_time))
            seen[key] = int(log_time)
    arrivals = np.array([log_time for _, log_time in unique], dtype=np.int64)
    return [scan for scan, _ in unique], arrivals


def _stuck(stamps_ns: np.ndarray) -> bool:
    """Whether stamps in arrival order advance between fewer than half of the messages."""
    advancing = np.count_nonzero(np.diff(stamps_ns) > 0)
    return len(stamps_ns) > 1 and advancing < (len(stamps_ns) - 1) / 2


def _stamped(scans: list[Scan], stamps_ns: np.ndarray) -> list[Scan]:
    return [Scan(s.ranges, s.geometry, int(t)) for s, t in zip(scans, stamps_ns, strict=True)]
