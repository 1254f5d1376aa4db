"""Decoding a bag's scan messages: ``LaserScan`` and ``MultiEchoLaserScan`` into :class:`Scan`.

A ``MultiEchoLaserScan`` gives each beam's nearest valid echo, the first surface it met. A
message's beam count is read from its raw bytes, so that one claiming millions of beams is
refused before anything is allocated for them.
"""

from __future__ import annotations

import struct
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.data.topics import MULTI_ECHO
from lidarflow.errors import BagError
from lidarflow.scan import MAX_BEAMS, BeamGeometry, Scan

__all__ = ["check_beams", "declared_beams", "nearest_echoes", "scan_of", "stamp_ns"]


def nearest_echoes(echoes: Iterable[Any], range_min: float) -> np.ndarray:
    """A ``MultiEchoLaserScan``'s ``ranges`` (one ``LaserEcho`` per beam) as one float32 range
    per beam: the nearest echo at or beyond ``range_min``; where none, ``+inf`` if an echo said
    no return, else NaN (unknown)."""
    per_beam = [np.asarray(beam.echoes, dtype=np.float32).ravel() for beam in echoes]
    out = np.full(len(per_beam), np.nan, np.float32)
    if not per_beam:
        return out
    # one flat array of every echo and the beam it belongs to (a loop over the beams is slow)
    values = np.concatenate(per_beam)
    beam = np.repeat(np.arange(len(per_beam)), [len(v) for v in per_beam])
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(values) & (values >= range_min) & (values > 0)
    out[beam[np.isposinf(values)]] = np.inf
    nearest = np.full(len(per_beam), np.inf, np.float32)
    np.minimum.at(nearest, beam[valid], values[valid])
    found = np.bincount(beam[valid], minlength=len(per_beam)) > 0
    out[found] = nearest[found]
    return out


def declared_beams(raw: bytes | memoryview, ros1: bool) -> int | None:
    """The length of ``ranges`` a serialised ``LaserScan`` or ``MultiEchoLaserScan`` declares;
    ``None`` where the bytes are too short to say (deserialising them fails on its own).

    Both types begin alike: a header (ROS 1: ``seq``, stamp, ``frame_id``; ROS 2's CDR: a
    4-byte encapsulation, stamp, ``frame_id``), seven float32 fields, then ``ranges``' length.

    >>> import struct
    >>> raw = struct.pack("<III", 0, 0, 0) + struct.pack("<I", 5) + b"laser"
    >>> declared_beams(raw + bytes(28) + struct.pack("<I", 1081), ros1=True)
    1081
    """
    u32 = struct.Struct("<I")
    try:
        if ros1:
            at = 12  # seq, stamp
            at += 4 + u32.unpack_from(raw, at)[0]  # frame_id
        else:
            big = bytes(raw[:2]) in (b"\x00\x00", b"\x00\x02")  # CDR_BE, PL_CDR_BE
            u32 = struct.Struct(">I" if big else "<I")
            at = 8  # stamp, after the encapsulation; CDR aligns from there
            at += 4 + u32.unpack_from(raw, 4 + at)[0]  # frame_id (with its NUL)
            at = 4 + (at + 3) // 4 * 4
        return int(u32.unpack_from(raw, at + 7 * 4)[0])
    except struct.error:
        return None


def check_beams(path: Path, topic: str, raw: bytes, conn: Any) -> None:
    """Raise :class:`BagError` for a raw scan message that declares more than
    :data:`MAX_BEAMS` beams, before anything is allocated for them."""
    from rosbags.interfaces import ConnectionExtRosbag1

    count = declared_beams(raw, isinstance(conn.ext, ConnectionExtRosbag1))
    if count is not None and count > MAX_BEAMS:
        raise BagError(
            f"{path}: topic {topic}: a scan of {count:,} beams; real scanners give at most a "
            f"few thousand (lidarflow takes up to {MAX_BEAMS:,}): the bag is damaged or not "
            "a 2-D laser scan"
        )


def stamp_ns(msg: Any) -> int:
    """The header stamp of a message, in integer nanoseconds."""
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def scan_of(msg: Any, msgtype: str) -> Scan | None:
    """The :class:`Scan` of a deserialised ``LaserScan`` or ``MultiEchoLaserScan`` (by
    ``msgtype``) at its header stamp, ranges copied as float32; ``None`` for a scan of no beams.
    Raises :class:`ScanError` for a beam geometry no scanner has."""
    if msgtype == MULTI_ECHO:
        ranges = nearest_echoes(msg.ranges, float(msg.range_min))
    else:
        ranges = np.array(msg.ranges, dtype=np.float32)  # not a view of the message
    if ranges.size == 0:
        return None
    geometry = BeamGeometry(
        count=int(ranges.size),
        angle_min=float(msg.angle_min),
        angle_increment=float(msg.angle_increment),
        range_min=float(msg.range_min),
        range_max=float(msg.range_max),
    )
    return Scan(ranges, geometry, stamp_ns(msg))
