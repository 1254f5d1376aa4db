"""The static world: an indoor floor plan of rooms and corridors with doors and furniture.

Everything is in a fixed world frame, metres. The floor plan is a binary space partition of a
rectangle into rooms and corridors; neighbouring rooms share a wall with a door, a wide opening
or no wall at all. Two geometries are kept: what the LiDAR sees (``segments``, ``circles``) and
what people and the robot keep clear of (``avoid_segments``, ``avoid_circles``): a table is four
legs to the sensor but a whole rectangle to someone walking.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from lidarflow.errors import SimError
from lidarflow.sim.field import DistanceField
from lidarflow.sim.furniture import Furniture

__all__ = ["Door", "World", "WorldConfig", "build_world", "outline"]


@dataclass(frozen=True)
class WorldConfig:
    """Floor plan and furniture parameters (metres)."""

    size_min: float = 10.0
    size_max: float = 26.0
    room_min: float = 3.0
    room_max: float = 12.0
    corridor_width: tuple[float, float] = (1.6, 3.0)
    corridor_prob: float = 0.4
    door_width: tuple[float, float] = (0.8, 1.3)
    wide_opening_prob: float = 0.2
    no_wall_prob: float = 0.08
    extra_door_prob: float = 0.3
    door_leaf_prob: float = 0.4
    clutter: float = 1.0

    def __post_init__(self) -> None:
        if not 0 < self.room_min * 2 <= self.size_min <= self.size_max:
            raise SimError(f"world sizes need 0 < 2*room_min <= size_min <= size_max: {self}")
        if self.room_max < 2 * self.room_min:
            raise SimError("room_max must be at least twice room_min so that rooms can be split")


@dataclass(frozen=True)
class Door:
    """A passage between rooms ``a`` and ``b``: centre, unit normal pointing from ``a`` to ``b``,
    and width."""

    a: int
    b: int
    centre: tuple[float, float]
    normal: tuple[float, float]
    width: float


@dataclass
class World:
    """A built world. ``segments (S, 4)`` and ``circles (C, 3)`` are what the LiDAR sees;
    ``avoid_segments``/``avoid_circles`` what walkers keep clear of; ``rooms (R, 4)`` are
    ``(x0, y0, x1, y1)`` with ``corridor`` flags; ``reachable`` marks rooms joined to room 0's
    component by passages."""

    segments: np.ndarray
    circles: np.ndarray
    avoid_segments: np.ndarray
    avoid_circles: np.ndarray
    rooms: np.ndarray
    corridor: np.ndarray
    doors: list[Door]
    reachable: np.ndarray
    bounds: tuple[float, float, float, float]
    _adjacency: dict[int, list[int]] = field(default_factory=dict, repr=False)
    _field: DistanceField | None = field(default=None, repr=False)

    @property
    def field(self) -> DistanceField:
        """Distance to what walkers avoid, as a lookup table (built on first use)."""
        if self._field is None:
            self._field = DistanceField(self.avoid_segments, self.avoid_circles, self.bounds)
        return self._field

    def __post_init__(self) -> None:
        adjacency: dict[int, list[int]] = {i: [] for i in range(len(self.rooms))}
        for k, d in enumerate(self.doors):
            adjacency[d.a].append(k)
            adjacency[d.b].append(k)
        self._adjacency = adjacency

    # ------------------------------------------------------------- queries
    def room_of(self, xy: np.ndarray) -> np.ndarray:
        """Index of the room containing each point ``(N, 2)`` (``-1`` outside every room)."""
        xy = np.atleast_2d(xy)
        r = self.rooms
        inside = (
            (xy[:, None, 0] >= r[None, :, 0])
            & (xy[:, None, 0] < r[None, :, 2])
            & (xy[:, None, 1] >= r[None, :, 1])
            & (xy[:, None, 1] < r[None, :, 3])
        )
        return np.where(inside.any(1), inside.argmax(1), -1)

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """Distance (m, at most 1.5) from each point ``(N, 2)`` to the nearest thing walkers
        avoid, to within the 0.05 m lookup grid."""
        return self.field.lookup(xy)[0]

    def sample_free(
        self,
        rng: np.random.Generator,
        room: int | None = None,
        clearance: float = 0.45,
        tries: int = 30,
    ) -> np.ndarray | None:
        """A random point at least ``clearance`` m from obstacles in ``room`` (a random
        reachable room when None), or None when none was found."""
        rooms = np.flatnonzero(self.reachable) if room is None else np.array([room])
        choice = rooms[rng.integers(0, len(rooms), tries)]
        r = self.rooms[choice]
        pts = np.column_stack([rng.uniform(r[:, 0], r[:, 2]), rng.uniform(r[:, 1], r[:, 3])])
        ok = np.flatnonzero(self.clearance(pts) >= clearance)
        return pts[ok[0]].copy() if ok.size else None

    def occluded(self, origin: np.ndarray, xy: np.ndarray) -> np.ndarray:
        """Whether the straight line from ``origin (2,)`` to each point ``(N, 2)`` crosses a
        wall or piece of furniture the LiDAR sees."""
        xy = np.atleast_2d(xy)
        s = self.segments
        p = np.asarray(origin, np.float64)
        r = xy - p  # N,2
        q = s[:, :2] - p  # S,2
        e = s[:, 2:] - s[:, :2]  # S,2
        den = r[:, None, 0] * e[None, :, 1] - r[:, None, 1] * e[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (q[None, :, 0] * e[None, :, 1] - q[None, :, 1] * e[None, :, 0]) / den
            u = (q[None, :, 0] * r[:, None, 1] - q[None, :, 1] * r[:, None, 0]) / den
        return ((t > 0) & (t < 1) & (u >= 0) & (u <= 1)).any(1)

    def route(self, start: np.ndarray, goal: np.ndarray) -> list[np.ndarray] | None:
        """Waypoints from ``start`` to ``goal`` through doors (the goal last), or None when the
        goal cannot be reached."""
        a, b = (int(v) for v in self.room_of(np.stack([start, goal])))
        if a < 0 or b < 0:
            return None
        prev: dict[int, tuple[int, int]] = {a: (-1, -1)}
        todo = deque([a])
        while todo and b not in prev:
            room = todo.popleft()
            for k in self._adjacency[room]:
                d = self.doors[k]
                other = d.b if d.a == room else d.a
                if other not in prev:
                    prev[other] = (room, k)
                    todo.append(other)
        if b not in prev:
            return None
        path: list[np.ndarray] = [np.asarray(goal, np.float64)]
        room = b
        while room != a:
            parent, k = prev[room]
            d = self.doors[k]
            n = np.array(d.normal) * (1.0 if d.a == parent else -1.0)  # from parent to room
            c = np.array(d.centre)
            path[:0] = [c - 0.5 * n, c + 0.5 * n]
            room = parent
        return path


def outline(width: float, height: float) -> list[list[float]]:
    """The four walls ``(x0, y0, x1, y1)`` of a ``width x height`` m rectangle at the origin."""
    x, y = width, height
    return [[0, 0, x, 0], [x, 0, x, y], [x, y, 0, y], [0, y, 0, 0]]


# ------------------------------------------------------------------ floor plan
def _partition(
    rng: np.random.Generator,
    cfg: WorldConfig,
    rect: tuple[float, float, float, float],
    depth: int,
    out: list[tuple[tuple[float, float, float, float], bool]],
) -> None:
    x0, y0, x1, y1 = rect
    w, h = x1 - x0, y1 - y0
    long_x = w >= h
    long_len, short_len = (w, h) if long_x else (h, w)
    cw = rng.uniform(*cfg.corridor_width)
    if (
        depth < 3
        and long_len >= 6.0
        and short_len >= cfg.room_min + cw
        and rng.random() < cfg.corridor_prob
    ):
        # A corridor along the long side, rooms on one or both sides of it.
        lo = short_len - cw
        if lo >= 2 * cfg.room_min:
            first = rng.uniform(cfg.room_min, lo - cfg.room_min)
        else:
            first = lo if rng.random() < 0.5 else 0.0
        base = y0 if long_x else x0
        edges = [base, base + first, base + (first + cw), base + short_len]
        for k, (a, b) in enumerate(pairwise(edges)):
            if b - a < 1e-6:
                continue
            sub = (x0, a, x1, b) if long_x else (a, y0, b, y1)
            if k == 1:
                out.append((sub, True))
            else:
                _partition(rng, cfg, sub, depth + 1, out)
        return
    must = long_len > cfg.room_max
    may = long_len >= 2 * cfg.room_min and rng.random() < 0.55
    if not (must or may):
        out.append((rect, False))
        return
    cut = rng.uniform(cfg.room_min, long_len - cfg.room_min)
    if long_x:
        parts = [(x0, y0, x0 + cut, y1), (x0 + cut, y0, x1, y1)]
    else:
        parts = [(x0, y0, x1, y0 + cut), (x0, y0 + cut, x1, y1)]
    for sub in parts:
        _partition(rng, cfg, sub, depth + 1, out)


def _shared_edge(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The boundary segment two rooms share (start, end), or None."""
    eps = 1e-6
    for ax in (0, 1):
        other = 1 - ax
        for ea, eb in ((a[ax + 2], b[ax]), (a[ax], b[ax + 2])):
            if abs(ea - eb) < eps:
                lo = max(a[other], b[other])
                hi = min(a[other + 2], b[other + 2])
                if hi - lo > eps:
                    p, q = np.zeros(2), np.zeros(2)
                    p[ax] = q[ax] = ea
                    p[other], q[other] = lo, hi
                    return p, q
    return None


def _gap(
    rng: np.random.Generator, cfg: WorldConfig, length: float, door: float, corridor: bool
) -> tuple[float, float]:
    """Where a passage opens along a shared wall of ``length`` m, from its start: no wall at
    all (not beside corridors), a wide opening, or a door ``door`` m wide."""
    roll = rng.random()
    if roll < cfg.no_wall_prob and not corridor:
        return 0.0, length
    if roll < cfg.no_wall_prob + cfg.wide_opening_prob and length > 3.0:
        door = rng.uniform(2.0, min(4.0, length - 0.6))
    start = rng.uniform(0.3, length - 0.3 - door)
    return start, start + door


def _door_leaf(
    rng: np.random.Generator,
    p: np.ndarray,
    along: np.ndarray,
    normal: np.ndarray,
    gap: tuple[float, float],
) -> list[float]:
    """An open door leaf in the ``gap`` of the wall from ``p`` along ``along``: hinged at one
    jamb, swung 75-100 degrees into one of the rooms."""
    hinge_at_start = rng.random() < 0.5
    hinge = p + along * (gap[0] if hinge_at_start else gap[1])
    towards = along if hinge_at_start else -along
    side = normal if rng.random() < 0.5 else -normal
    ang = math.radians(rng.uniform(75, 100))
    leaf = (math.cos(ang) * towards + math.sin(ang) * side) * (gap[1] - gap[0] - 0.05)
    return [*hinge, *(hinge + leaf)]


def build_world(rng: np.random.Generator, config: WorldConfig | None = None) -> World:
    """Build a random floor plan with furniture (deterministic for the generator's state)."""
    cfg = config or WorldConfig()
    width = rng.uniform(cfg.size_min, cfg.size_max)
    height = rng.uniform(cfg.size_min, cfg.size_max)
    leaves: list[tuple[tuple[float, float, float, float], bool]] = []
    _partition(rng, cfg, (0.0, 0.0, width, height), 0, leaves)
    rooms = np.array([r for r, _ in leaves], dtype=np.float64)
    corridor = np.array([c for _, c in leaves], dtype=bool)

    # Shared walls; a random spanning tree of them gets passages so every room is reachable.
    edges = []
    for i in range(len(rooms)):
        for j in range(i + 1, len(rooms)):
            shared = _shared_edge(rooms[i], rooms[j])
            if shared is not None:
                edges.append((i, j, *shared))
    order = rng.permutation(len(edges))
    parent = list(range(len(rooms)))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    segments = outline(width, height)
    doors: list[Door] = []
    for k in order:
        i, j, p, q = edges[k]
        length = float(np.hypot(*(q - p)))
        joins = find(i) != find(j)
        corr = corridor[i] or corridor[j]
        wants = joins or rng.random() < (0.85 if corr else cfg.extra_door_prob)
        dw = rng.uniform(*cfg.door_width)
        if not wants or length < dw + 0.6:
            segments.append([*p, *q])
            continue
        parent[find(i)] = find(j)
        along = (q - p) / length
        normal = np.array([along[1], -along[0]])
        centre_i = (rooms[i, :2] + rooms[i, 2:]) / 2
        if normal @ (p - centre_i) < 0:
            normal = -normal  # from room i towards room j
        gap = _gap(rng, cfg, length, dw, corr)
        if gap[0] > 1e-6:
            segments.append([*p, *(p + along * gap[0])])
        if gap[1] < length - 1e-6:
            segments.append([*(p + along * gap[1]), *q])
        (cx, cy), (nx, ny) = (p + along * (gap[0] + gap[1]) / 2).tolist(), normal.tolist()
        doors.append(Door(int(i), int(j), (cx, cy), (nx, ny), gap[1] - gap[0]))
        if gap[1] - gap[0] < 1.5 and rng.random() < cfg.door_leaf_prob:
            segments.append(_door_leaf(rng, p, along, normal, gap))

    # The largest group of rooms joined by passages is where people and the robot go.
    roots = [find(i) for i in range(len(rooms))]
    best = max(set(roots), key=roots.count)
    reachable = np.array([r == best for r in roots])

    furniture = Furniture(rng, [d.centre for d in doors])
    for i, room in enumerate(rooms):
        furniture.furnish(room, bool(corridor[i]), cfg.clutter)
    seg = np.array(segments + furniture.segments, dtype=np.float64).reshape(-1, 4)
    avoid = np.array(
        segments + furniture.segments + furniture.avoid_segments, dtype=np.float64
    ).reshape(-1, 4)
    circles = np.array(furniture.circles, dtype=np.float64).reshape(-1, 3)
    avoid_circles = np.array(furniture.avoid_circles, dtype=np.float64).reshape(-1, 3)
    bounds = (0.0, 0.0, width, height)
    return World(seg, circles, avoid, avoid_circles, rooms, corridor, doors, reachable, bounds)
