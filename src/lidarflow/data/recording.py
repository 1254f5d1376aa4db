"""The recording: raw scans with their beam geometry, stamps, optional poses, and metadata.

A recording keeps the raw ranges rather than maps, so the grid can change later without
re-reading the bag. Scans may change beam count mid-recording, so ranges are stored ragged (one
flat array plus offsets). On disk it is a single ``.npz`` (NumPy, no pickle) with the metadata as
JSON; extra per-frame arrays (the simulator's ground truth, for instance) travel in ``extras``.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from lidarflow.data.inputs import check_regular
from lidarflow.data.sessions import sliced_clock_jumps
from lidarflow.errors import RecordingError, ScanError
from lidarflow.scan import MAX_BEAMS, BeamGeometry, GridSpec, Scan, rasterize_batch, subcell_batch

T = TypeVar("T")

__all__ = ["FORMAT_VERSION", "Recording", "load_recording"]

FORMAT_VERSION = 1
_EXTRA_PREFIX = "extra__"
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
        for name in ("angle_min", "angle_increment", "range_min", "range_max"):
            if getattr(self, name).shape != (n,):
                raise RecordingError(f"{name} must be ({n},), got {getattr(self, name).shape}")
        if self.poses is not None and self.poses.shape != (n, 3):
            raise RecordingError(f"poses must be ({n}, 3), got {self.poses.shape}")
        if n and (self.offsets[0] != 0 or self.offsets[-1] != len(self.ranges)):
            raise RecordingError("offsets do not match the ranges array")
        if np.any(np.diff(self.offsets) <= 0):
            raise RecordingError("every scan must have at least one beam")

    # ----------------------------------------------------------------- construction
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

        def column(attr: str) -> np.ndarray:
            return np.array([getattr(s.geometry, attr) for s in scans], dtype=np.float64)

        return cls(
            ranges=ranges,
            offsets=offsets,
            angle_min=column("angle_min"),
            angle_increment=column("angle_increment"),
            range_min=column("range_min"),
            range_max=column("range_max"),
            stamps_ns=np.array([s.stamp_ns for s in scans], dtype=np.int64),
            poses=None if poses is None else np.asarray(poses, dtype=np.float64),
            meta=dict(meta or {}),
            extras=dict(extras or {}),
        )

    # ----------------------------------------------------------------- access
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
        stop = len(self) if stop is None else min(stop, len(self))
        n = max(stop - start, 0)
        occ = np.zeros((n, *grid.shape), dtype=bool)
        vis = np.zeros((n, *grid.shape), dtype=bool)
        for at, (o, v) in self._per_geometry(lambda r, g: rasterize_batch(r, g, grid), start, stop):
            occ[at], vis[at] = o, v
        return occ, vis

    def check_maps(self, grid: GridSpec | None = None) -> None:
        """Rasterize every frame on ``grid`` and keep nothing: a scan that cannot be rasterized
        is a :class:`RecordingError` now, in the memory of one batch of frames, where
        :meth:`maps` of the whole recording takes ``2 N H W`` bytes (``convert`` checks so)."""
        grid = grid or GridSpec()
        for _ in self._per_geometry(lambda r, g: rasterize_batch(r, g, grid), 0, len(self)):
            pass

    def subcell_maps(
        self, grid: GridSpec | None = None, start: int = 0, stop: int | None = None
    ) -> np.ndarray:
        """Where the returns of frames ``[start, stop)`` lie inside their cells: boolean
        ``(n, 2, H, W)`` (:func:`lidarflow.scan.subcell_batch`)."""
        grid = grid or GridSpec()
        stop = len(self) if stop is None else min(stop, len(self))
        out = np.zeros((max(stop - start, 0), 2, *grid.shape), dtype=bool)
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

    def _per_geometry(
        self, batch: Callable[[np.ndarray, BeamGeometry], T], start: int, stop: int
    ) -> Iterator[tuple[slice, T]]:
        """``batch(ranges (b - a, count), geometry)`` for each run of frames ``[a, b)`` of
        ``[start, stop)`` that share one geometry (at most ``_BATCH_FRAMES`` at a time: a batch's
        float intermediates are several times its boolean maps), with the frames' place in an
        output starting at ``start``; a scan it cannot take is a :class:`RecordingError` naming
        the frames."""
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
        """Whether ``extra`` holds one entry per frame (its first axis is the frame count), so
        that a recording made of some of the frames takes the same ones of it."""
        return bool(extra.ndim) and extra.shape[0] == len(self)

    def slice(self, start: int, stop: int) -> Recording:
        """Frames ``[start, stop)`` as a new recording (per-frame extras are sliced too)."""
        a, b = int(self.offsets[start]), int(self.offsets[stop])
        extras = {k: (v[start:stop] if self.is_per_frame(v) else v) for k, v in self.extras.items()}
        return Recording(
            ranges=self.ranges[a:b],
            offsets=self.offsets[start : stop + 1] - a,
            angle_min=self.angle_min[start:stop],
            angle_increment=self.angle_increment[start:stop],
            range_min=self.range_min[start:stop],
            range_max=self.range_max[start:stop],
            stamps_ns=self.stamps_ns[start:stop],
            poses=None if self.poses is None else self.poses[start:stop],
            meta=self._sliced_meta(start, stop),
            extras=extras,
        )

    def every(self, step: int) -> Recording:
        """Every ``step``-th frame from the first, with its pose and per-frame extras: what a
        sensor ``step`` times slower would have given. Ground-truth flow (``flow_*`` extras,
        between consecutive frames) does not hold between the frames kept and is left out, as
        are the metadata that number this recording's frames (``clock_jumps``, ``episodes``).
        """
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

    # ----------------------------------------------------------------- persistence
    def save(self, path: str | Path) -> Path:
        """Write the recording to ``path`` (``.npz`` is appended when missing), whole or not at
        all (:func:`lidarflow.atomic.atomic_path`: an existing file is replaced only once the
        new one is complete)."""
        from lidarflow.atomic import atomic_path

        path = Path(path)
        if path.suffix != ".npz":
            path = path.with_name(path.name + ".npz")
        arrays: dict[str, np.ndarray] = {
            "ranges": np.asarray(self.ranges, np.float32),  # no copy where it is float32
            "offsets": self.offsets,
            "angle_min": self.angle_min,
            "angle_increment": self.angle_increment,
            "range_min": self.range_min,
            "range_max": self.range_max,
            "stamps_ns": self.stamps_ns,
            "meta_json": np.frombuffer(
                json.dumps({**self.meta, "format_version": FORMAT_VERSION}).encode(), np.uint8
            ),
        }
        if self.poses is not None:
            arrays["poses"] = self.poses
        for key, value in self.extras.items():
            arrays[_EXTRA_PREFIX + key] = value
        with atomic_path(path) as tmp:
            np.savez_compressed(tmp, **arrays)
        return path


#: How every zip archive (an .npz is one) begins: a member, or for an empty one its directory.
_ZIP_STARTS = (b"PK\x03\x04", b"PK\x05\x06")

#: Deflate cannot expand data more than 1032-fold; a member claiming more (plus a header's
#: worth) than this many times its compressed size lies about its size.
_DEFLATE_MOST = 1100


def _check_member(path: Path, archive: zipfile.ZipFile, key: str) -> None:
    """Refuse the array ``key`` of the .npz ``path`` before NumPy allocates it: one whose
    header declares more (or fewer) values than its member holds (a damaged or crafted file:
    NumPy allocates the declared shape first, 14.6 TiB for a header claiming 4e12 floats), and
    one of values that are no real numbers (complex, text, records). Python objects are left
    to :func:`_read_arrays`, which says so."""
    if f"{key}.npy" not in archive.namelist():
        raise RecordingError(f"{path}: not a lidarflow recording (its member {key!r} is no array)")
    info = archive.getinfo(f"{key}.npy")
    stored = info.compress_size * _DEFLATE_MOST + 4096
    if info.compress_type == zipfile.ZIP_STORED:
        stored = info.compress_size
    if info.file_size > stored:
        raise RecordingError(
            f"{path}: a damaged recording (its array {key!r} claims {info.file_size:,} bytes "
            f"in {info.compress_size:,} compressed); convert its source again"
        )
    with archive.open(info) as member:
        version = np.lib.format.read_magic(member)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(member)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(member)
        else:  # 3.0 is for record field names beyond latin-1: no array of a recording
            raise RecordingError(
                f"{path}: not a lidarflow recording (its array {key!r} is in .npy format "
                f"{version[0]}.{version[1]}, which lidarflow does not write)"
            )
        header = member.tell()
    if dtype.hasobject:
        return
    if dtype.kind not in "biuf":
        raise RecordingError(
            f"{path}: not a lidarflow recording (its array {key!r} holds {dtype} values, not "
            "real numbers)"
        )
    declared = math.prod(shape) * dtype.itemsize
    if declared != info.file_size - header:
        raise RecordingError(
            f"{path}: a damaged recording (its array {key!r} declares shape {shape} of {dtype}, "
            f"{declared:,} bytes, and holds {info.file_size - header:,}); convert its source "
            "again"
        )


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    """Every array of the .npz ``path``, or a :class:`RecordingError` saying what the file is
    instead, in lidarflow's words: not an .npz at all, one cut short, or one holding Python
    objects (which a recording never does, and which unpickling would run as code)."""
    with path.open("rb") as f:
        start = f.read(4)
    if not start:
        raise RecordingError(f"{path}: not a lidarflow recording (the file is empty)")
    if start not in _ZIP_STARTS:
        raise RecordingError(
            f"{path}: not a lidarflow recording (not an .npz archive, as `lidarflow convert` "
            "writes)"
        )
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {}
            for key in z.files:
                _check_member(path, z.zip, key)
                try:
                    data[key] = z[key]
                except ValueError as err:
                    raise RecordingError(
                        f"{path}: not a lidarflow recording (its array {key!r} is not plain "
                        "numbers: Python objects, which lidarflow does not load)"
                    ) from err
    except (OSError, zipfile.BadZipFile, EOFError, ValueError) as err:
        raise RecordingError(
            f"{path}: a damaged recording (cut short, or its archive broken); convert its "
            "source again"
        ) from err
    return data


def load_recording(path: str | Path) -> Recording:
    """Read a recording written by :meth:`Recording.save`."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    check_regular(path, RecordingError)
    data = _read_arrays(path)
    required = ("ranges", "offsets", "angle_min", "angle_increment", "range_min", "range_max")
    missing = [k for k in (*required, "stamps_ns", "meta_json") if k not in data]
    if missing:
        raise RecordingError(f"{path}: not a lidarflow recording (missing {', '.join(missing)})")
    try:
        meta = json.loads(bytes(data["meta_json"]).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RecordingError(f"{path}: corrupt metadata ({err})") from err
    if meta.get("format_version", 0) > FORMAT_VERSION:
        raise RecordingError(
            f"{path}: written by a newer lidarflow (format {meta['format_version']}); upgrade"
        )
    extras = {k[len(_EXTRA_PREFIX) :]: v for k, v in data.items() if k.startswith(_EXTRA_PREFIX)}
    beams = np.diff(data["offsets"].astype(np.int64))
    if beams.size and beams.max() > MAX_BEAMS:
        frame = int(np.argmax(beams))
        raise RecordingError(
            f"{path}: scan {frame} has {int(beams[frame]):,} beams; real scanners give at most "
            f"a few thousand (lidarflow takes up to {MAX_BEAMS:,}): the recording is damaged"
        )
    return Recording(
        ranges=data["ranges"],
        offsets=data["offsets"].astype(np.int64),
        angle_min=data["angle_min"],
        angle_increment=data["angle_increment"],
        range_min=data["range_min"],
        range_max=data["range_max"],
        stamps_ns=data["stamps_ns"].astype(np.int64),
        poses=data.get("poses"),
        meta=meta,
        extras=extras,
    )
