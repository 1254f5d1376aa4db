"""A classical tracker: background, clusters, constant-velocity motion; causal, NumPy (its
per-cell loops compiled where :mod:`lidarflow.compiled` is available, to the same bits).

Each frame:

1. **Background**: a per-cell running occupancy rate (weight ``alpha`` for the new frame),
   updated only where the cell is visible, so a person in front of a wall does not erase it.
   It lives in the world: each frame it is first moved into the new sensor frame by the ego
   motion. A cell seen for the first time starts at its occupancy, so the first frame and the
   walls a driving platform comes upon are background at once.
2. **Foreground**: occupied cells whose background rate, the largest over their 3 x 3
   neighbourhood, is under ``background_threshold`` (the neighbourhood absorbs a wall's returns
   that cross a cell edge).
3. **Clusters**: foreground cells within ``link`` of each other (a person's two legs are one).
4. **Association**: greedily the nearest (track predicted one frame on, cluster) pairs within
   ``gate``; an unmatched cluster starts a track at rest; a track missed more than
   ``max_missed`` frames in a row ends.
5. **Motion**: per track a constant-velocity Kalman filter on the centroid, state
   ``(x, y, vx, vy)`` in cells and cells per frame in the sensor frame (x forward, y left),
   re-expressed in each new sensor frame with the ego motion, so its velocity is the world's.

The prediction ``k`` frames ahead (:meth:`Tracker.ahead`) is the background part of the map
unmoved and each track seen this frame as its cells shifted by ``k`` times its velocity, then
the whole map moved into the sensor frame ``k`` guessed steps on (the last motion again).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lidarflow.baselines.method import NOTHING_MORE, FrameInputs, Takes
from lidarflow.geometry import rigid_moved
from lidarflow.motion.pacing import paced_motion
from lidarflow.tracking.background import split
from lidarflow.tracking.clusters import associate, clusters
from lidarflow.tracking.tracks import Tracks

__all__ = ["Tracker", "TrackerConfig"]


@dataclass(frozen=True)
class TrackerConfig:
    """The tracker's few parameters, lengths in metres (``res`` turns them into cells).

    Attributes:
        alpha: weight of the new frame in the running background rate (1 / time constant in
            frames).
        background_threshold: a cell is background where the rate, the largest over its 3 x 3
            neighbourhood, reaches this.
        link: foreground cells this close (metres) belong to one cluster.
        gate: the farthest (metres) a cluster's centroid may lie from a track's predicted one
            to continue it.
        process_noise: standard deviation of the acceleration, cells per frame squared.
        measurement_noise: standard deviation of a measured centroid, cells.
        max_missed: frames in a row a track may go unseen before it ends.
    """

    alpha: float = 0.05
    background_threshold: float = 0.2
    link: float = 0.5
    gate: float = 1.0
    process_noise: float = 0.3
    measurement_noise: float = 1.0
    max_missed: int = 3

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha <= 1.0:
            raise ValueError(f"alpha must be in (0, 1], got {self.alpha}")
        if not 0.0 < self.background_threshold <= 1.0:
            raise ValueError(
                f"background_threshold must be in (0, 1], got {self.background_threshold}"
            )
        if self.link < 0 or self.gate <= 0:
            raise ValueError(f"need link >= 0 and gate > 0, got {self.link}, {self.gate}")
        if self.process_noise <= 0 or self.measurement_noise <= 0:
            raise ValueError("process_noise and measurement_noise must be > 0")
        if self.max_missed < 0:
            raise ValueError(f"max_missed must be >= 0, got {self.max_missed}")


@dataclass
class _Track:
    state: np.ndarray  # (x, y, vx, vy): cells, cells per frame, sensor frame
    covariance: np.ndarray  # (4, 4)
    cells: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), np.int64))
    missed: int = 0


class Tracker:
    """The tracking baseline (see the module docstring); a streaming ``Method`` that takes the
    ego motion where a recording has it (without, the sensor is taken to stand still)."""

    name = "tracker"
    takes = Takes(motion=True, poses_optional=True)

    def __init__(self, config: TrackerConfig | None = None, res: float = 0.1) -> None:
        if res <= 0:
            raise ValueError(f"res must be > 0, got {res}")
        self.config = config or TrackerConfig()
        self.res = res
        q, r = self.config.process_noise, self.config.measurement_noise
        self._transition = np.eye(4) + np.eye(4, k=2)  # x += vx, y += vy
        # white acceleration over one frame, per axis [[1/4, 1/2], [1/2, 1]] q^2
        block = np.array([[0.25, 0.5], [0.5, 1.0]]) * q * q
        self._process = np.kron(block, np.eye(2))
        self._measurement = np.eye(2) * r * r
        self.reset()

    def reset(self) -> None:
        self._background: np.ndarray | None = None
        self._seen: np.ndarray | None = None
        self._tracks: list[_Track] = []
        self._static: np.ndarray | None = None
        self._held: np.ndarray | None = None
        self._motion: np.ndarray | None = None

    @property
    def background(self) -> np.ndarray | None:
        """``(H, W)`` the running occupancy rate of each cell in the last frame (``None``
        before the first): low where movers pass, high on walls."""
        return self._background

    def update(
        self, occupancy: np.ndarray, visibility: np.ndarray, given: FrameInputs = NOTHING_MORE
    ) -> np.ndarray:
        """Take frame ``t`` (``given.motion``: its pose in frame ``t - 1``, cells and radians;
        ``given.pace`` as :meth:`observe`'s) and return the map predicted for ``t + 1``."""
        self.observe(occupancy, visibility, given.motion, given.pace)
        return self.ahead(1)[0]

    def observe(
        self,
        occupancy: np.ndarray,
        visibility: np.ndarray,
        motion: np.ndarray | None = None,
        pace: float | None = None,
    ) -> None:
        """Take frame ``t`` as :meth:`update` does, predicting nothing (a caller that wants
        only :meth:`tracks`, the engine, does not pay for the map)."""
        occupied = np.asarray(occupancy) > 0.5
        visible = (np.asarray(visibility) > 0.5) | occupied
        if motion is not None and np.any(np.asarray(motion) != 0):
            self._carry(np.asarray(motion, np.float64))
        guess = motion if pace is None else paced_motion(motion, pace)  # None without motion
        self._motion = guess if guess is not None and np.any(guess) else None
        if self._background is None or self._seen is None:
            self._background = occupied.astype(np.float64)
            self._seen = visible.copy()
        # held: rare here but beside a wall (the 3 x 3 neighbourhood): held, not tracked
        moving, self._held, self._static, self._background = split(
            occupied,
            visible,
            self._background,
            self._seen,
            self.config.alpha,
            self.config.background_threshold,
        )
        self._track(moving)

    def ahead(
        self,
        horizon: int,
        beside: np.ndarray | None = None,
        first: int = 1,
        tracks: Tracks | None = None,
    ) -> list[np.ndarray]:
        """The maps predicted ``first``..``horizon`` frames after the last one given, each
        ``(H, W)`` float32 in [0, 1] (see the module docstring). With ``beside`` ``(C, H, W)``
        bool, maps of the last frame moved alike in the same pass: each item is then
        ``(1 + C, H, W)``, the prediction first. ``tracks``: :meth:`tracks` of the last frame
        where the caller has them (what they computed is reused)."""
        if self._static is None:
            raise RuntimeError("ahead() before any update()")
        tracks, out = tracks if tracks is not None else self.tracks(), []
        for k in range(first, horizon + 1):
            mine = self._static | tracks.cells_at(k)
            both = mine if beside is None else np.concatenate([mine[None], beside])
            out.append(tracks.moved_to_sensor(both, k))
        return out

    def tracks(self, hold: int = 0) -> Tracks:
        """The objects tracked and seen in the last frame, frozen: what :class:`Tracks` moves
        ``k`` frames on, without the background (later updates do not change it); ``hold``: the
        held cells (:class:`Tracks`) are kept that many frames."""
        if self._static is None or self._held is None:
            raise RuntimeError("tracks() before any update()")
        seen = [(t.state.copy(), t.cells.copy()) for t in self._tracks if not t.missed]
        return Tracks(self._static.shape, seen, self._motion, self._held.copy(), hold, self.res)

    def _carry(self, motion: np.ndarray) -> None:
        """Re-express the background and the tracks in the new sensor frame."""
        if self._background is not None and self._seen is not None:
            # one warp for both: the same motion's sampling, built once
            both = rigid_moved(np.stack([self._background, self._seen]), motion)
            self._background, self._seen = both[0], both[1] > 0.5
        dx, dy, yaw = motion
        c, s = np.cos(yaw), np.sin(yaw)
        turn = np.array([[c, s], [-s, c]])  # R^T: old-frame vectors in the new frame
        # np.kron(np.eye(2), turn) without its cost: the same products, 1.0 * turn = turn and
        # 0.0 * turn (its signed zeros) off the diagonal
        both, off = np.zeros((4, 4)), 0.0 * turn
        both[:2, :2], both[2:, 2:], both[:2, 2:], both[2:, :2] = turn, turn, off, off
        for track in self._tracks:
            track.state = np.concatenate(
                [turn @ (track.state[:2] - [dx, dy]), turn @ track.state[2:]]
            )
            track.covariance = both @ track.covariance @ both.T

    def _track(self, moving: np.ndarray) -> None:
        """Cluster the foreground cells and continue, start and end tracks."""
        cfg = self.config
        # each cluster's cells (row, col) and its centroid in the sensor frame (x, y), in cells
        groups, centroids = clusters(moving, cfg.link / self.res)
        for track in self._tracks:  # one frame on, unseen until a cluster continues it
            track.state = self._transition @ track.state
            track.covariance = (
                self._transition @ track.covariance @ self._transition.T + self._process
            )
            track.missed += 1
        predicted = np.array([t.state[:2] for t in self._tracks]).reshape(-1, 2)
        pairs = associate(predicted, centroids, cfg.gate / self.res)
        matched = {c for _, c in pairs}
        for t, c in pairs:
            self._correct(self._tracks[t], centroids[c])
            self._tracks[t].cells = groups[c]
            self._tracks[t].missed = 0
        self._tracks = [t for t in self._tracks if t.missed <= cfg.max_missed]
        # a new object: at rest, its speed unknown up to a brisk walk (2 m/s at 10 Hz)
        speed = 0.2 / self.res
        start = np.diag([cfg.measurement_noise**2] * 2 + [speed**2] * 2)
        for c in range(len(groups)):
            if c not in matched:
                state = np.array([*centroids[c], 0.0, 0.0])
                self._tracks.append(_Track(state, start.copy(), groups[c]))

    def _correct(self, track: _Track, centroid: np.ndarray) -> None:
        """The Kalman update of ``track`` with a measured ``centroid``."""
        p = track.covariance
        innovation = centroid - track.state[:2]
        gain = p[:, :2] @ np.linalg.inv(p[:2, :2] + self._measurement)
        track.state = track.state + gain @ innovation
        track.covariance = p - gain @ p[:2, :]
