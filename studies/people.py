"""Annotated people against a predicted map: is a person at ``t + k`` covered by the prediction?

A recording with hand-annotated people (``general_tracking_moving_1``'s
``/ground_truth_people_tracks``: positions in the laser frame, one message per person and scan)
gives a check of the mover metric that needs no dynamic region: of the people annotated at
frame ``t + k``, the share that the prediction ``k`` ahead covers with an occupied cell whose
centre lies within :data:`RADIUS` of the person's position. Positions are in metres in the
sensor frame of the target frame (REP 103, :mod:`lidarflow.scan`'s grid convention); people
outside the grid are not counted.

Pure NumPy; reading the annotations from a bag is the caller's (they are no recording data).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidarflow.scan import GridSpec, cell_centres

__all__ = ["RADIUS", "PeopleCounts", "frames_of", "people_found"]

#: How near (metres) an occupied cell's centre must lie to a person for the person to count as
#: covered: about a person's radius plus half a cell.
RADIUS = 0.3


@dataclass
class PeopleCounts:
    """People found (a predicted occupied cell within the radius) and people counted."""

    found: int = 0
    counted: int = 0

    def __add__(self, other: PeopleCounts) -> PeopleCounts:
        return PeopleCounts(self.found + other.found, self.counted + other.counted)

    @property
    def share(self) -> float | None:
        """``found / counted``; ``None`` when nobody was counted."""
        return self.found / self.counted if self.counted else None


def people_found(
    decided: np.ndarray, people_xy: np.ndarray, grid: GridSpec, radius: float = RADIUS
) -> PeopleCounts:
    """Of the people at ``people_xy`` (``(P, 2)`` metres, sensor frame) inside ``grid``, how
    many have an occupied cell of the bool map ``decided`` ``(H, W)`` within ``radius`` metres
    (cell centre to position).

    >>> grid = GridSpec(4, 4, 1.0)
    >>> occupied = np.zeros((4, 4), bool); occupied[0, 0] = True  # centre x 3.5, y 1.5
    >>> people_found(occupied, np.array([[3.6, 1.4], [0.5, 0.5], [9.0, 0.0]]), grid)
    PeopleCounts(found=1, counted=2)
    """
    decided = np.asarray(decided, bool)
    if decided.shape != grid.shape:
        raise ValueError(f"decided must be {grid.shape} (the grid), got {decided.shape}")
    xy = np.asarray(people_xy, np.float64).reshape(-1, 2)
    if radius < 0:
        raise ValueError(f"radius must be >= 0, got {radius}")
    half = grid.width / 2 * grid.res
    inside = (xy[:, 0] >= 0) & (xy[:, 0] < grid.height * grid.res) & (np.abs(xy[:, 1]) < half)
    xy = xy[inside]
    x, y = cell_centres(grid)
    cells = np.stack([x[decided], y[decided]], axis=1)  # (N, 2)
    if not len(xy) or not len(cells):
        return PeopleCounts(0, len(xy))
    distance = np.hypot(xy[:, None, 0] - cells[None, :, 0], xy[:, None, 1] - cells[None, :, 1])
    return PeopleCounts(int((distance.min(axis=1) <= radius).sum()), len(xy))


def frames_of(stamps_ns: np.ndarray, scan_stamps_ns: np.ndarray, lag_ns: int = 0) -> np.ndarray:
    """The frame each annotation belongs to: the scan whose stamp is nearest to the
    annotation's stamp less ``lag_ns`` (an annotation logged one scan period after the scan it
    annotates: ``lag_ns`` one period). ``scan_stamps_ns`` ascending.

    >>> frames_of(np.array([100, 210, 260]), np.array([0, 100, 200]), lag_ns=100).tolist()
    [0, 1, 2]
    """
    scans = np.asarray(scan_stamps_ns, np.int64)
    if scans.ndim != 1 or not len(scans):
        raise ValueError(f"scan_stamps_ns must be a non-empty (N,), got {scans.shape}")
    if np.any(np.diff(scans) < 0):
        raise ValueError("scan_stamps_ns must be ascending")
    wanted = np.asarray(stamps_ns, np.int64) - int(lag_ns)
    after = np.clip(np.searchsorted(scans, wanted), 1, len(scans) - 1) if len(scans) > 1 else None
    if after is None:
        return np.zeros(len(wanted), np.int64)
    before = after - 1
    nearer_after = np.abs(scans[after] - wanted) < np.abs(wanted - scans[before])
    return np.where(nearer_after, after, before).astype(np.int64)
