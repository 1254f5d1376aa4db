"""A recording as another sensor would have seen it: a narrower field of view, a shorter
range, fewer beams, a lower rate.

lidarflow is judged on recordings from other robots (86 to 360 degrees, 3.5 to 12 m, 5 to
15 Hz). Cutting a real recording down keeps its real noise, dropouts and people, which the
simulated sensors only imitate. A view is named by a spec of ``+``-joined parts, each a kind
and a number:

- ``fov86``: only the beams within 43 degrees of straight ahead (the sensor's x axis);
- ``range3.5``: no return beyond 3.5 m (``range_max`` becomes 3.5 m);
- ``beams4``: every fourth beam;
- ``rate2``: every second scan (:meth:`~lidarflow.data.Recording.every`).

``range3.5+beams2+rate2`` is a hobby scanner. Scans are dropped first, then each kept scan is
narrowed, shortened and thinned, in that order. Scored by ``python -m studies.other_sensors``;
training on such copies (``data.sensor_copies``, ``docs/research/sensor_copies/``) was removed
without gain.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from lidarflow.data.recording import Recording
from lidarflow.errors import RecordingError
from lidarflow.scan import BeamGeometry, Scan

__all__ = ["SensorView", "coarser", "narrower", "shorter"]

_PART = re.compile(r"(fov|range|beams|rate)(\d+(?:\.\d+)?)")


def narrower(scan: Scan, fov_deg: float) -> Scan:
    """The beams of ``scan`` within ``fov_deg / 2`` of straight ahead (the sensor's x axis),
    bearings taken modulo a turn (a scan from 0 to 2 pi keeps both its ends, joined; a beam
    that repeats the bearing of one a turn before it is left out); a scan with no beam there
    becomes one unknown beam straight ahead."""
    g = scan.geometry
    count = g.count
    if g.angle_increment != 0:
        # beams a whole turn after an earlier one point the same way: keep the first turn
        count = min(count, max(1, round(2.0 * np.pi / abs(g.angle_increment))))
    angles = g.angle_min + g.angle_increment * np.arange(count)
    bearings = (angles + np.pi) % (2.0 * np.pi) - np.pi
    # a beam exactly at the edge stays whichever way the increment runs (float rounding)
    keep = np.flatnonzero(np.abs(bearings) <= np.radians(fov_deg) / 2.0 + 1e-9)
    if keep.size == 0:
        ahead = BeamGeometry(1, 0.0, g.angle_increment, g.range_min, g.range_max)
        return Scan(np.array([np.nan], np.float32), ahead, scan.stamp_ns)
    gaps = np.flatnonzero(np.diff(keep) > 1)
    if gaps.size:  # the kept beams run over the end of the scan into its start
        keep = np.concatenate([keep[gaps[0] + 1 :], keep[: gaps[0] + 1]])
    geometry = BeamGeometry(
        count=int(keep.size),
        angle_min=float(bearings[keep[0]]),
        angle_increment=g.angle_increment,
        range_min=g.range_min,
        range_max=g.range_max,
    )
    return Scan(np.asarray(scan.ranges, np.float32)[keep], geometry, scan.stamp_ns)


def shorter(scan: Scan, range_max: float) -> Scan:
    """``scan`` as a sensor that sees no further than ``range_max`` metres (or its own
    ``range_max``, if nearer): every return beyond it becomes no return (``+inf``), as do the
    readings at or past the scanner's own limit (no return already, by the beam rule)."""
    g = scan.geometry
    limit = min(range_max, g.range_max)
    if limit <= g.range_min:
        raise RecordingError(
            f"a range limit of {range_max:g} m leaves nothing: the scanner's range_min is "
            f"{g.range_min:g} m"
        )
    ranges = np.asarray(scan.ranges, np.float32).copy()
    with np.errstate(invalid="ignore"):
        beyond = np.isfinite(ranges) & ((ranges >= g.range_max) | (ranges > limit))
    ranges[beyond] = np.inf
    geometry = BeamGeometry(g.count, g.angle_min, g.angle_increment, g.range_min, limit)
    return Scan(ranges, geometry, scan.stamp_ns)


def coarser(scan: Scan, every: int) -> Scan:
    """Every ``every``-th beam of ``scan``, from its first."""
    g = scan.geometry
    ranges = np.asarray(scan.ranges[::every], np.float32)
    geometry = BeamGeometry(
        ranges.size, g.angle_min, g.angle_increment * every, g.range_min, g.range_max
    )
    return Scan(ranges, geometry, scan.stamp_ns)


def _decimal(value: float) -> str:
    """``value`` as the shortest plain decimal that reads back to it (no exponent)."""
    return np.format_float_positional(value, trim="-")


@dataclass(frozen=True)
class SensorView:
    """Another sensor's view: ``fov_deg`` and ``range_max`` (``None``: the recording's own),
    every ``every_beam``-th beam of every ``every_scan``-th scan.

    >>> view = SensorView.parse("range3.5+beams2+rate2")
    >>> view.range_max, view.every_beam, view.every_scan, view.name
    (3.5, 2, 2, 'range3.5+beams2+rate2')
    """

    fov_deg: float | None = None
    range_max: float | None = None
    every_beam: int = 1
    every_scan: int = 1

    def __post_init__(self) -> None:
        if self.fov_deg is not None and not 0.0 < self.fov_deg <= 360.0:
            raise RecordingError(f"a field of view is in (0, 360] degrees, got {self.fov_deg}")
        if self.range_max is not None and not (
            math.isfinite(self.range_max) and self.range_max > 0
        ):
            raise RecordingError(f"a range limit is a positive distance, got {self.range_max}")
        for every in (self.every_beam, self.every_scan):
            if not isinstance(every, int) or isinstance(every, bool) or every < 1:
                raise RecordingError("every_beam and every_scan are whole numbers >= 1")

    @classmethod
    def parse(cls, spec: str) -> SensorView:
        """The view named ``spec`` (module docstring), e.g. ``"fov180"``,
        ``"range4+beams3"``; a :class:`~lidarflow.errors.RecordingError` naming the part it
        cannot read. ``"recorded"`` is the view that changes nothing."""
        if spec.strip() == "recorded":
            return cls()
        found: dict[str, float] = {}
        for part in spec.split("+"):
            match = _PART.fullmatch(part.strip())
            if match is None:
                raise RecordingError(
                    f"sensor view {spec!r}: cannot read {part!r}; parts are fovDEG, rangeM, "
                    "beamsK or rateK joined by '+' (e.g. range3.5+beams2)"
                )
            kind, number = match.group(1), float(match.group(2))
            if kind in found:
                raise RecordingError(f"sensor view {spec!r} names {kind} twice")
            if kind in ("beams", "rate") and (number != int(number) or number < 1):
                raise RecordingError(f"sensor view {spec!r}: {kind} takes a whole number >= 1")
            found[kind] = number
        return cls(
            fov_deg=found.get("fov"),
            range_max=found.get("range"),
            every_beam=int(found.get("beams", 1)),
            every_scan=int(found.get("rate", 1)),
        )

    @property
    def name(self) -> str:
        """The spec that :meth:`parse` reads back as this view (``"recorded"``: no change)."""
        parts = []
        if self.fov_deg is not None:
            parts.append(f"fov{_decimal(self.fov_deg)}")
        if self.range_max is not None:
            parts.append(f"range{_decimal(self.range_max)}")
        if self.every_beam > 1:
            parts.append(f"beams{self.every_beam}")
        if self.every_scan > 1:
            parts.append(f"rate{self.every_scan}")
        return "+".join(parts) or "recorded"

    def scan(self, scan: Scan) -> Scan:
        """One scan as this sensor would have returned it."""
        if self.fov_deg is not None:
            scan = narrower(scan, self.fov_deg)
        if self.range_max is not None:
            scan = shorter(scan, self.range_max)
        if self.every_beam > 1:
            scan = coarser(scan, self.every_beam)
        return scan

    def recording(self, recording: Recording) -> Recording:
        """``recording`` as this sensor would have recorded it, poses kept. A view that
        changes the scans drops the per-frame extras (the simulator's ground truth, made for
        the scans as they were), keeping those the scans do not bear on."""
        if self.every_scan > 1:
            recording = recording.every(self.every_scan)
        if (self.fov_deg, self.range_max, self.every_beam) == (None, None, 1):
            return recording
        extras = {k: v for k, v in recording.extras.items() if not recording.is_per_frame(v)}
        scans = [self.scan(recording.scan(i)) for i in range(len(recording))]
        meta = dict(recording.meta)
        meta["sensor_view"] = self.name
        return Recording.from_scans(scans, recording.poses, meta, extras)
