"""LaserScan -> occupancy and visibility maps (design notes, section 2; grid and visibility
rules in ``docs/guide/conventions.md``; beam validity in :mod:`lidarflow.beams`).

NumPy, or one compiled pass (:mod:`lidarflow.scan_loops`) where :mod:`lidarflow.compiled` is
available, to the bit the same maps. The per-cell beam lookup depends only on the grid and the
beam geometry, so it is cached per geometry: a scan then costs one gather and one comparison per
cell.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from lidarflow import scan_loops
from lidarflow.beams import mask_thresholds, return_masks
from lidarflow.compiled import available
from lidarflow.errors import ScanError
from lidarflow.geometry import cell_to_metric

__all__ = [
    "MAX_BEAMS",
    "MAX_GRID_CELLS",
    "MAX_RES",
    "BeamGeometry",
    "GridSpec",
    "Scan",
    "cell_centres",
    "rasterize",
    "rasterize_batch",
    "subcell_batch",
    "takes_subcell",
]


#: The most cells a grid may have: what a laptop's memory holds for a model step
#: (``docs/guide/conventions.md#grid``); a larger grid is refused before anything is allocated.
MAX_GRID_CELLS = 2048 * 2048
#: The most beams a scan read from a file may have: real scanners give a few thousand, so a
#: scan claiming more is damaged or crafted, and is refused before it is decoded.
MAX_BEAMS = 100_000
_MAX_SIDE = math.isqrt(MAX_GRID_CELLS)
#: The coarsest cell, in metres: coarser maps a whole scan into a few cells (and 1e300 m
#: overflows the arithmetic of rasterizing).
MAX_RES = 10.0


@dataclass(frozen=True)
class GridSpec:
    """The map grid: ``height`` rows along x (forward), ``width`` columns along y, cell ``res`` m.

    The defaults are the paper's: 100 x 100 cells of 0.1 m.
    """

    height: int = 100
    width: int = 100
    res: float = 0.1

    def __post_init__(self) -> None:
        if self.height <= 0 or self.width <= 0:
            raise ScanError(f"grid must have positive size, got {self.height} x {self.width}")
        if self.height * self.width > MAX_GRID_CELLS:
            raise ScanError(
                f"a grid of {self.height} x {self.width} cells is too large: at most "
                f"{MAX_GRID_CELLS:,} cells ({_MAX_SIDE} x {_MAX_SIDE}) fit in memory, a model "
                "taking about 1 kB a cell"
            )
        if not (self.res > 0 and math.isfinite(self.res)):
            raise ScanError(f"grid resolution must be a positive number of metres, got {self.res}")
        if self.res > MAX_RES:
            raise ScanError(
                f"a cell size (--res) of {self.res:g} m is too coarse: at most {MAX_RES:g} m "
                "(a 2-D LiDAR's whole scan in a few cells)"
            )

    @property
    def shape(self) -> tuple[int, int]:
        return (self.height, self.width)

    def to_dict(self) -> dict[str, float | int]:
        return {"height": self.height, "width": self.width, "res": self.res}


@dataclass(frozen=True)
class BeamGeometry:
    """Where the beams of a scan point: ``count`` beams from ``angle_min`` in steps of
    ``angle_increment`` radians (which may be negative), valid returns in
    ``[range_min, range_max)`` metres, at most one turn (a step or two of overlap allowed)."""

    count: int
    angle_min: float
    angle_increment: float
    range_min: float
    range_max: float

    def __post_init__(self) -> None:
        if self.count <= 0:
            raise ScanError(f"a scan needs at least one beam, got {self.count}")
        values = (self.angle_min, self.angle_increment, self.range_min, self.range_max)
        if not all(math.isfinite(v) for v in values):
            raise ScanError(f"beam geometry must be finite, got {self}")
        if self.angle_increment == 0 and self.count > 1:
            raise ScanError("angle_increment is 0 but the scan has more than one beam")
        sweep = abs(self.angle_increment) * (self.count - 1)
        if sweep > 2 * math.pi + 2 * abs(self.angle_increment):
            # an increment in degrees, say: every beam would wrap onto another's bearing
            raise ScanError(
                f"{self.count} beams {self.angle_increment:g} rad apart sweep "
                f"{math.degrees(sweep):.0f} degrees, more than a full turn"
            )
        if self.range_max <= 0 or self.range_min < 0 or self.range_min > self.range_max:
            raise ScanError(
                f"range limits must satisfy 0 <= range_min <= range_max, 0 < range_max; "
                f"got range_min={self.range_min}, range_max={self.range_max}"
            )

    @property
    def angles(self) -> np.ndarray:
        return self.angle_min + self.angle_increment * np.arange(self.count, dtype=np.float64)


@dataclass(frozen=True)
class Scan:
    """One LaserScan: ranges in metres, its beam geometry, a stamp in integer nanoseconds."""

    ranges: np.ndarray
    geometry: BeamGeometry
    stamp_ns: int = 0

    def __post_init__(self) -> None:
        if not isinstance(self.ranges, np.ndarray):  # a message's list, or rclpy's array.array
            try:
                object.__setattr__(self, "ranges", np.asarray(self.ranges, dtype=np.float32))
            except (TypeError, ValueError) as err:
                kind = type(self.ranges).__name__
                raise ScanError(f"ranges must be numbers, got a {kind} of others") from err
        if self.ranges.ndim != 1 or self.ranges.shape[0] != self.geometry.count:
            raise ScanError(
                f"ranges must be a 1-D array of {self.geometry.count} beams, "
                f"got shape {tuple(self.ranges.shape)}"
            )


def cell_centres(grid: GridSpec) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(x, y)`` of every cell centre in metres, each of shape ``(H, W)``.

    >>> x, y = cell_centres(GridSpec(2, 2, 1.0))
    >>> x.tolist(), y.tolist()
    ([[1.5, 1.5], [0.5, 0.5]], [[0.5, -0.5], [0.5, -0.5]])
    """
    rows = np.arange(grid.height, dtype=np.float64)[:, None]
    cols = np.arange(grid.width, dtype=np.float64)[None, :]
    x, y = cell_to_metric(rows, cols, grid.height, grid.width, grid.res)
    return np.broadcast_to(x, grid.shape).copy(), np.broadcast_to(y, grid.shape).copy()


@lru_cache(maxsize=64)
def _cell_lookup(grid: GridSpec, geometry: BeamGeometry) -> tuple[np.ndarray, np.ndarray]:
    """For every cell: the index of the beam nearest its centre's bearing (``count`` when no
    beam covers it) and the centre's distance from the sensor, both flattened to ``H*W``."""
    x, y = cell_centres(grid)
    bearing = np.arctan2(y, x).ravel()
    dist = np.hypot(x, y).ravel()
    # A lone beam with no increment is given a 0.1-degree width rather than the whole circle.
    step = abs(geometry.angle_increment) or math.radians(0.1)
    sign = 1.0 if geometry.angle_increment >= 0 else -1.0
    # Offset along the sweep direction, shifted by half a step so that floor() picks the nearest
    # beam, and wrapped so that 360-degree scans cover the seam.
    offset = np.mod(sign * (bearing - geometry.angle_min) + step / 2, 2 * math.pi)
    index = np.floor(offset / step).astype(np.int64)
    index[(index < 0) | (index >= geometry.count)] = geometry.count
    index.setflags(write=False)
    dist.setflags(write=False)
    return index, dist


@lru_cache(maxsize=64)
def _beam_directions(geometry: BeamGeometry) -> tuple[np.ndarray, np.ndarray]:
    cos, sin = np.cos(geometry.angles), np.sin(geometry.angles)
    cos.setflags(write=False)
    sin.setflags(write=False)
    return cos, sin


def _return_cells(
    r: np.ndarray, is_return: np.ndarray, geometry: BeamGeometry, grid: GridSpec
) -> tuple[np.ndarray, ...]:
    """Each beam's point as fractional grid coordinates ``(u, v)`` (float64 whatever ``r``'s
    dtype, so a point lands in the cell that contains it), its cell ``(row, col)`` and whether
    it is a return inside the grid."""
    cos, sin = _beam_directions(geometry)
    rho = np.where(is_return, r, 0.0).astype(np.float64)
    u = grid.height - rho * cos / grid.res
    v = grid.width / 2 - rho * sin / grid.res
    row, col = np.floor(u), np.floor(v)
    inside = is_return & (row >= 0) & (row < grid.height) & (col >= 0) & (col < grid.width)
    return u, v, row, col, inside


def _check_ranges(ranges: np.ndarray, geometry: BeamGeometry) -> np.ndarray:
    r = np.asarray(ranges)
    if r.ndim != 2 or r.shape[1] != geometry.count:
        raise ScanError(
            f"ranges must be (N, {geometry.count}) for this beam geometry, got {tuple(r.shape)}"
        )
    if not np.issubdtype(r.dtype, np.floating):
        r = r.astype(np.float64)
    return r


def rasterize_batch(
    ranges: np.ndarray, geometry: BeamGeometry, grid: GridSpec | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Rasterize ``N`` scans that share one beam geometry into ``(occupancy, visibility)``,
    each boolean ``(N, H, W)``. ``ranges`` is ``(N, geometry.count)`` metres, NaN/inf allowed;
    comparisons run in its dtype. ``grid`` defaults to the paper's.

    >>> g = BeamGeometry(3, -0.1, 0.1, 0.05, 10.0)
    >>> occ, vis = rasterize_batch(np.array([[5.0, 5.0, 5.0]]), g, GridSpec(100, 100, 0.1))
    >>> bool(occ[0, 50, 50]), bool(vis[0, 60, 50]), bool(vis[0, 40, 50])
    (True, True, False)
    """
    grid = grid or GridSpec()
    r = _check_ranges(ranges, geometry)
    if _compiles(r) and (maps := scan_loops.rasterized(r, _plan_of(r, geometry, grid))):
        return maps
    n = r.shape[0]
    occupancy = np.empty((n, *grid.shape), dtype=bool)
    visibility = np.empty((n, *grid.shape), dtype=bool)
    # Chunks keep the per-cell temporaries in cache; larger batches only cost memory traffic.
    for a in range(0, n, _CHUNK):
        b = min(a + _CHUNK, n)
        occupancy[a:b], visibility[a:b] = _rasterize_chunk(r[a:b], geometry, grid)
    return occupancy, visibility


_CHUNK = 64


def _compiles(r: np.ndarray) -> bool:
    """Whether the compiled passes take ranges ``r`` (float32 or float64, a scan or more)."""
    return available() and r.shape[0] > 0 and r.dtype in (np.float32, np.float64)


def _no_return_reach(dtype: np.dtype, range_max: float) -> np.floating:
    """How far a no-return beam sees: ``range_max`` inclusive, in ``dtype`` (hence the next
    value up; a ``range_max`` beyond float32 reaches everywhere)."""
    with np.errstate(over="ignore"):
        return np.nextafter(dtype.type(range_max), dtype.type(math.inf))


@lru_cache(maxsize=64)
def _plan(grid: GridSpec, geometry: BeamGeometry, dtype: str, low: type) -> scan_loops.Plan:
    """The compiled passes' :class:`~lidarflow.scan_loops.Plan` for ranges of ``dtype`` (``low``:
    the type of ``geometry.range_min``, which NumPy compares in its own dtype where it is a NumPy
    float: a geometry equal in value but not in type gets its own plan)."""
    index, dist = _cell_lookup(grid, geometry)
    kind = np.dtype(dtype)
    thresholds = mask_thresholds(kind, geometry.range_min, geometry.range_max, geometry.count)
    reach = float(_no_return_reach(kind, geometry.range_max))
    return scan_loops.Plan(
        grid.height, grid.width, grid.res, index, dist.astype(kind), *_beam_directions(geometry),
        thresholds, reach,
    )  # fmt: skip


def _plan_of(r: np.ndarray, geometry: BeamGeometry, grid: GridSpec) -> scan_loops.Plan:
    return _plan(grid, geometry, r.dtype.str, type(geometry.range_min))


def _rasterize_chunk(
    r: np.ndarray, geometry: BeamGeometry, grid: GridSpec
) -> tuple[np.ndarray, np.ndarray]:
    n = r.shape[0]
    height, width = grid.shape
    index, dist = _cell_lookup(grid, geometry)
    dtype = r.dtype
    is_return, beyond = return_masks(r, geometry.range_min, geometry.range_max)
    # "Visible iff the centre is nearer than the beam's reach": a return reaches rho (strict), a
    # no-return reaches range_max (inclusive, hence nextafter), an unknown beam reaches nowhere,
    # and the extra last column is the "no beam covers this cell" sentinel.
    reach = np.full((n, geometry.count + 1), -1.0, dtype=dtype)
    no_return_reach = _no_return_reach(dtype, geometry.range_max)
    reach[:, :-1] = np.where(is_return, r, np.where(beyond, no_return_reach, dtype.type(-1.0)))
    visibility = dist.astype(dtype, copy=False)[None, :] < reach[:, index]

    _, _, row, col, inside = _return_cells(r, is_return, geometry, grid)
    flat = (row * width + col)[inside].astype(np.int64)
    flat += np.nonzero(inside)[0] * (height * width)
    occupancy = np.zeros(n * height * width, dtype=bool)
    occupancy[flat] = True
    occupancy = occupancy.reshape(n, height * width)
    visibility |= occupancy
    return occupancy.reshape(n, height, width), visibility.reshape(n, height, width)


def rasterize(scan: Scan, grid: GridSpec | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Rasterize one scan into ``(occupancy, visibility)`` boolean maps of shape ``(H, W)``."""
    occ, vis = rasterize_batch(scan.ranges[None, :], scan.geometry, grid)
    return occ[0], vis[0]


#: Sub-cells per cell side of :func:`subcell_batch`: a return within ``res / SUBCELL`` of a cell's
#: edge is "at the edge".
SUBCELL = 4
#: Channels of a frame's maps: occupancy and visibility (Table I's input).
MAP_CHANNELS = 2


def takes_subcell(input_channels: int) -> bool:
    """Whether a model that takes ``input_channels`` maps per frame wants :func:`subcell_batch`'s
    two after ``(O, V)`` (``subcell_input``), so must be fed scans rather than maps alone.

    >>> takes_subcell(2), takes_subcell(4)
    (False, True)
    """
    return input_channels > MAP_CHANNELS


def subcell_batch(
    ranges: np.ndarray, geometry: BeamGeometry, grid: GridSpec | None = None
) -> np.ndarray:
    """Where inside their cells the returns of ``N`` scans lie: ``(N, 2, H, W)`` bool.

    Channel 0 (``edge``): the cell is occupied and every return in it lies within
    ``res / SUBCELL`` of its border. Channel 1 (``near``): a return in one of the cell's four
    neighbours lies within ``res / SUBCELL`` of the edge they share.

    Both are zero for a return at a cell's centre, the neutral input where no scan is known
    (``docs/research/subcell/``); an ``edge`` cell is always one :func:`rasterize_batch` marks.

    Straight ahead on a grid 101 cells wide (the beam runs down the middle of column 50), a
    return 1 cm short of cell 49's near edge, then one at its centre:

    >>> g = BeamGeometry(1, 0.0, 0.0, 0.05, 10.0)
    >>> f = subcell_batch(np.array([[5.01], [5.05]]), g, GridSpec(100, 101, 0.1))
    >>> bool(f[0, 0, 49, 50]), bool(f[0, 1, 50, 50]), bool(f[1, 0, 49, 50]), bool(f[1, 1].any())
    (True, True, False, False)
    """
    grid = grid or GridSpec()
    r = _check_ranges(ranges, geometry)
    n, (height, width) = r.shape[0], grid.shape
    if _compiles(r):
        subcell = scan_loops.subcells(r, _plan_of(r, geometry, grid), SUBCELL)
        if subcell is not None:
            return subcell
    is_return, _ = return_masks(r, geometry.range_min, geometry.range_max)
    u, v, row, col, inside = _return_cells(r, is_return, geometry, grid)
    frame = np.nonzero(inside)[0]
    u, v = u[inside], v[inside]
    row, col = row[inside].astype(np.int64), col[inside].astype(np.int64)
    last = SUBCELL - 1
    sub_r = np.clip(np.floor((u - row) * SUBCELL), 0, last).astype(np.int64)
    sub_c = np.clip(np.floor((v - col) * SUBCELL), 0, last).astype(np.int64)
    cells = (frame * height + row) * width + col
    size = n * height * width
    occupied = np.zeros(size, dtype=bool)
    occupied[cells] = True
    interior = np.zeros(size, dtype=bool)
    deep = (sub_r > 0) & (sub_r < last) & (sub_c > 0) & (sub_c < last)
    interior[cells[deep]] = True
    near = np.zeros((n, height, width), dtype=bool)
    for at_edge, dr, dc in (
        (sub_r == 0, -1, 0), (sub_r == last, 1, 0), (sub_c == 0, 0, -1), (sub_c == last, 0, 1),
    ):  # fmt: skip
        nr, nc = row[at_edge] + dr, col[at_edge] + dc
        ok = (nr >= 0) & (nr < height) & (nc >= 0) & (nc < width)
        near[frame[at_edge][ok], nr[ok], nc[ok]] = True
    edge = (occupied & ~interior).reshape(n, height, width)
    return np.stack([edge, near], axis=1)
