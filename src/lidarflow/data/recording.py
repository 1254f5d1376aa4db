"""The recording: raw scans with their beam geometry, stamps, optional poses, and metadata.

It keeps the raw ranges rather than maps, so the grid can change without re-reading the bag;
they are stored ragged (one flat array plus offsets), since the beam count may change. On disk:
:mod:`lidarflow.data.recordfile`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from lidarflow.data.sessions import sliced_clock_jumps
from lidarflow.errors import RecordingError, ScanError
from lidarflow.scan import BeamGeometry, GridSpec, Scan, rasterize_batch, subcell_batch

T = TypeVar("T")

__all__ = ["GEOMETRY_FIELDS", "Recording"]

#: The per-scan beam geometry arrays of a :class:`Recording`, as :class:`BeamGeometry` names them.
GEOMETRY_FIELDS = ("angle_min", "angle_increment", "range_min", "range_max")

_BATCH_FRAMES = 256  # frames rasterized at once


@dataclass
class Recording:
    """A sequence of 2-D LiDAR scans.

    Attributes:
        ranges: all ranges of all scans, concatenated (float32, metres).
        offsets: ``(N + 1,)`` scan ``i`` is ``ranges[offsets[i]:offsets[i + 1]]``.
        angle_min, angle_increment, range_min, range_max: ``(N,)`` per-scan beam geometry.
        stamps_ns: ``(N,)`` integer nanoseconds.
        poses: ``(N, 3)`` sensor pose ``(x, y, yaw)`` in a fixed frame, NaN where unknown,
            or ``None`` when the recording has no odometry.
        meta: JSON-serialisable metadata (source, topic, frame_id, ...).
        extras: per-recording arrays carried along unchanged (e.g. ground truth).
    """

    ranges: np.ndarray
    offsets: np.ndarray
    angle_min: np.ndarray
    angle_increment: np.ndarray
    range_min: np.ndarray
    range_max: np.ndarray
    stamps_ns: np.ndarray
    poses: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n = len(self.stamps_ns)
        if self.offsets.shape != (n + 1,):
            raise RecordingError(f"offsets must be ({n + 1},), got {self.offsets.shape}")
        for name in GEOMETRY_FIELDS:
            if getattr(self, name).shape != (n,):
                raise RecordingError(f"{name} must be ({n},), got {getattr(self, name).shape}")
        if self.poses is not None and self.poses.shape != (n, 3):
            raise RecordingError(f"poses must be ({n}, 3), got {self.poses.shape}")
        if n and (self.offsets[0] != 0 or self.offsets[-1] != len(self.ranges)):
            raise RecordingError("offsets do not match the ranges array")
        if np.any(np.diff(self.offsets) <= 0):
            raise RecordingError("every scan must have at least one beam")

    @classmethod
    def from_scans(
        cls,
        scans: Sequence[Scan],
        poses: np.ndarray | None = None,
        meta: dict[str, Any] | None = None,
        extras: dict[str, np.ndarray] | None = None,
    ) -> Recording:
        """Build a recording from scans (in time order)."""
        counts = np.array([s.geometry.count for s in scans], dtype=np.int64)
        offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        ranges = (
            np.concatenate([np.asarray(s.ranges, dtype=np.float32) for s in scans])
            if scans
            else np.zeros(0, np.float32)
        )

        geometry = {
            name: np.array([getattr(s.geometry, name) for s in scans], dtype=np.float64)
            for name in GEOMETRY_FIELDS
        }
        return cls(
            ranges=ranges,
            offsets=offsets,
            **geometry,
            stamps_ns=np.array([s.stamp_ns for s in scans], dtype=np.int64),
            poses=None if poses is None else np.asarray(poses, dtype=np.float64),
            meta=dict(meta or {}),
            extras=dict(extras or {}),
        )

    def __len__(self) -> int:
        return len(self.stamps_ns)

    def geometry(self, i: int) -> BeamGeometry:
        return BeamGeometry(
            count=int(self.offsets[i + 1] - self.offsets[i]),
            angle_min=float(self.angle_min[i]),
            angle_increment=float(self.angle_increment[i]),
            range_min=float(self.range_min[i]),
            range_max=float(self.range_max[i]),
        )

    def scan(self, i: int) -> Scan:
        if not -len(self) <= i < len(self):
            raise RecordingError(f"frame {i} is out of range: the recording has {len(self)}")
        i %= len(self)
        return Scan(
            self.ranges[self.offsets[i] : self.offsets[i + 1]],
            self.geometry(i),
            int(self.stamps_ns[i]),
        )

    def __iter__(self) -> Iterator[Scan]:
        for i in range(len(self)):
            yield self.scan(i)

    def geometry_runs(self) -> list[tuple[int, int]]:
        """Half-open ``(start, stop)`` frame ranges over which the beam geometry is constant."""
        n = len(self)
        if n == 0:
            return []
        counts = np.diff(self.offsets)
        keys = np.stack(
            [counts, self.angle_min, self.angle_increment, self.range_min, self.range_max], 1
        )
        change = np.any(keys[1:] != keys[:-1], axis=1)
        starts = np.concatenate([[0], np.nonzero(change)[0] + 1])
        stops = np.concatenate([starts[1:], [n]])
        return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]

    @property
    def frame_rate(self) -> float:
        """Median frame rate in Hz (0 when it cannot be told)."""
        if len(self) < 2:
            return 0.0
        dt = np.diff(self.stamps_ns)
        dt = dt[dt > 0]
        return float(1e9 / np.median(dt)) if dt.size else 0.0

    @property
    def has_poses(self) -> bool:
        return self.poses is not None and bool(np.isfinite(self.poses).all(axis=1).any())

    def maps(
        self, grid: GridSpec | None = None, start: int = 0, stop: int | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Rasterize frames ``[start, stop)`` into boolean ``(occupancy, visibility)``, each
        ``(n, H, W)``; frames sharing a geometry are rasterized as one batch."""
        grid = grid or GridSpec()
        n = max(self._stop(stop) - start, 0)
        occ = np.zeros((n, *grid.shape), dtype=bool)
        vis = np.zeros((n, *grid.shape), dtype=bool)
        for at, (o, v) in self._per_geometry(lambda r, g: rasterize_batch(r, g, grid), start, stop):
            occ[at], vis[at] = o, v
        return occ, vis

    def check_maps(self, grid: GridSpec | None = None) -> None:
        """Rasterize every frame on ``grid`` and keep nothing: a scan that cannot be rasterized
        is a :class:`RecordingError` now, in the memory of one batch of frames."""
        grid = grid or GridSpec()
        for _ in self._per_geometry(lambda r, g: rasterize_batch(r, g, grid), 0, len(self)):
            pass

    def subcell_maps(
        self, grid: GridSpec | None = None, start: int = 0, stop: int | None = None
    ) -> np.ndarray:
        """Where the returns of frames ``[start, stop)`` lie inside their cells: boolean
        ``(n, 2, H, W)`` (:func:`lidarflow.scan.subcell_batch`)."""
        grid = grid or GridSpec()
        out = np.zeros((max(self._stop(stop) - start, 0), 2, *grid.shape), dtype=bool)
        for at, features in self._per_geometry(lambda r, g: subcell_batch(r, g, grid), start, stop):
            out[at] = features
        return out

    def stacked_maps(
        self,
        grid: GridSpec | None = None,
        start: int = 0,
        stop: int | None = None,
        subcell: bool = False,
    ) -> np.ndarray:
        """Frames ``[start, stop)`` as a model's ``step`` takes them: boolean ``(n, C, H, W)``,
        channels ``(O, V)`` (:meth:`maps`) and with ``subcell`` ``(edge, near)`` after them
        (:meth:`subcell_maps`, for models built with ``subcell_input``)."""
        maps = np.stack(self.maps(grid, start, stop), axis=1)
        if subcell:
            maps = np.concatenate([maps, self.subcell_maps(grid, start, stop)], axis=1)
        return maps

    def _stop(self, stop: int | None) -> int:
        return len(self) if stop is None else min(stop, len(self))

    def _per_geometry(
        self, batch: Callable[[np.ndarray, BeamGeometry], T], start: int, stop: int | None
    ) -> Iterator[tuple[slice, T]]:
        """``batch(ranges (b - a, count), geometry)`` for each run of frames ``[a, b)`` of
        ``[start, stop)`` that share one geometry, at most ``_BATCH_FRAMES`` at a time, with the
        frames' place in an output starting at ``start``. Raises :class:`RecordingError`."""
        stop = self._stop(stop)
        for run_start, run_stop in self.geometry_runs():
            for a in range(max(run_start, start), min(run_stop, stop), _BATCH_FRAMES):
                b = min(a + _BATCH_FRAMES, run_stop, stop)
                geom = self.geometry(a)
                block = self.ranges[self.offsets[a] : self.offsets[b]].reshape(b - a, geom.count)
                try:
                    result = batch(block, geom)
                except ScanError as err:
                    raise RecordingError(f"frames {a}..{b - 1}: {err}") from err
                yield slice(a - start, b - start), result

    def is_per_frame(self, extra: np.ndarray) -> bool:
        """Whether ``extra`` holds one entry per frame (its first axis is the frame count)."""
        return bool(extra.ndim) and extra.shape[0] == len(self)

    def slice(self, start: int, stop: int) -> Recording:
        """Frames ``[start, stop)`` as a new recording (per-frame extras are sliced too)."""
        a, b = int(self.offsets[start]), int(self.offsets[stop])
        extras = {k: (v[start:stop] if self.is_per_frame(v) else v) for k, v in self.extras.items()}
        return Recording(
            ranges=self.ranges[a:b],
            offsets=self.offsets[start : stop + 1] - a,
            **{name: getattr(self, name)[start:stop] for name in GEOMETRY_FIELDS},
            stamps_ns=self.stamps_ns[start:stop],
            poses=None if self.poses is None else self.poses[start:stop],
            meta=self._sliced_meta(start, stop),
            extras=extras,
        )

    def every(self, step: int) -> Recording:
        """Every ``step``-th frame from the first, with its pose and per-frame extras: what a
        sensor ``step`` times slower would have given. Ground-truth flow (``flow_*``) and the
        metadata that number frames (``clock_jumps``, ``episodes``) no longer hold: left out."""
        if step < 1:
            raise RecordingError(f"step must be >= 1, got {step}")
        kept = np.arange(0, len(self), step)
        extras = {}
        for key, value in self.extras.items():
            if not self.is_per_frame(value):
                extras[key] = value
            elif not key.startswith("flow_"):
                extras[key] = value[kept]
        dropped = {"clock_jumps", "episodes", "flow_storage"}
        meta = {k: v for k, v in self.meta.items() if k not in dropped}
        meta["every"] = step * int(self.meta.get("every", 1))
        poses = None if self.poses is None else self.poses[kept]
        slower = Recording.from_scans([self.scan(int(i)) for i in kept], poses, meta, extras)
        if "frame_rate_hz" in meta:
            slower.meta["frame_rate_hz"] = round(slower.frame_rate, 3)
        return slower

    def _sliced_meta(self, start: int, stop: int) -> dict[str, Any]:
        meta = {**self.meta, "sliced_from": [start, stop]}
        if meta.get("clock_jumps"):  # frame numbers (and the shift in effect) of the slice
            meta["clock_jumps"] = sliced_clock_jumps(meta["clock_jumps"], start, stop)
        return meta

    def save(self, path: str | Path) -> Path:
        """:func:`lidarflow.data.recordfile.save_recording` of this recording."""
        from lidarflow.data.recordfile import save_recording  # it imports this module

        return save_recording(self, path)
