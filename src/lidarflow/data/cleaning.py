"""Cleaning a scan topic as it was read: unset stamps filled, copies dropped, stuck stamps replaced.

Drivers leave header stamps unset (zero), never advance them, or a bag holds one message twice
(two connections on one topic, merged bags). :func:`clean_scans` undoes each in arrival order,
before :func:`lidarflow.data.sessions.in_sessions` orders the scans and handles a header
clock that jumps back.
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
    """A scan topic after :func:`clean_scans`.

    Attributes:
        scans: the scans kept, in arrival order, with the stamps they are read at.
        arrivals: their log times (int64 nanoseconds).
        duplicates: how many scans were dropped as another's copy.
        stamps: what the stamps are (``meta["stamps"]``): ``"header"``, or
            ``"log time (the header stamps do not advance)"``.
    """

    scans: list[Scan]
    arrivals: np.ndarray
    duplicates: int
    stamps: str


def clean_scans(scans: list[Scan], log_times: Sequence[int]) -> Cleaned:
    """``scans`` (in arrival order, logged at ``log_times`` ns) with zero header stamps filled
    (:func:`zero_stamps_filled`), copies of one message dropped (:func:`without_copies`), and
    where the header stamps do not advance (between fewer than half of the scans) but the log
    times do, stamped with their log times instead."""
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
    """Header stamps with each zero (a driver that left the stamp unset) replaced by its log
    time. On a simulator's clock, which starts at 0, zeros before its first other stamp are its
    first instants and stay; a later zero is unset, and the log time (a wall clock) no stand-in
    there: it gets the stamps around it, interpolated by position."""
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

    A copy is a scan of the same stamp, geometry and ranges logged within 1 s of the one kept:
    the same message recorded twice (two connections on one topic, merged bags) is one
    measurement, and kept twice it would make a copy of the last map a perfect prediction. The
    same scan at the same stamp a session later is a simulator replaying itself after its clock
    was reset (:mod:`lidarflow.data.sessions`), and is kept.
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
    """``scans`` with these stamps instead of their own."""
    return [Scan(s.ranges, s.geometry, int(t)) for s, t in zip(scans, stamps_ns, strict=True)]
