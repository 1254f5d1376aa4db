"""Furniture as a shin-height LiDAR sees it, placed room by room.

Cabinets and desks against walls and free-standing boxes are outlines (segments); tables and
chairs are their four legs (small circles) for the sensor but a whole rectangle for walkers to
avoid; pillars, bins and plants are circles. Doors and a walking passage are kept clear.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["Furniture"]


def _box(cx: float, cy: float, length: float, depth: float, angle: float) -> list[list[float]]:
    c, s = math.cos(angle), math.sin(angle)
    corners = [(dx * length / 2, dy * depth / 2) for dx, dy in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    pts = [(cx + c * x - s * y, cy + s * x + c * y) for x, y in corners]
    return [[*pts[k], *pts[(k + 1) % 4]] for k in range(4)]


class Furniture:
    """Places furniture room by room, keeping doors and a walking passage clear."""

    def __init__(self, rng: np.random.Generator, door_centres: list[tuple[float, float]]) -> None:
        self.rng = rng
        self.door_centres = np.array(door_centres, dtype=np.float64).reshape(-1, 2)
        self.segments: list[list[float]] = []
        self.avoid_segments: list[list[float]] = []
        self.circles: list[list[float]] = []
        self.avoid_circles: list[list[float]] = []
        self.taken: list[tuple[float, float, float]] = []  # footprint circles

    def _free(self, x: float, y: float, radius: float, gap: float = 0.6) -> bool:
        if len(self.door_centres):
            d = np.hypot(self.door_centres[:, 0] - x, self.door_centres[:, 1] - y)
            if d.min() < radius + 0.9:
                return False
        return all(math.hypot(x - a, y - b) > radius + r + gap for a, b, r in self.taken)

    def furnish(self, room: np.ndarray, corridor: bool, clutter: float) -> None:
        rng = self.rng
        x0, y0, x1, y1 = room
        w, h = x1 - x0, y1 - y0
        count = rng.poisson(clutter * (w * h / (14.0 if corridor else 5.0)))
        for _ in range(count):
            kind = rng.choice(
                ["wall_box", "table", "chair", "round", "box"],
                p=[0.1, 0.0, 0.0, 0.9, 0.0] if corridor else [0.3, 0.2, 0.2, 0.15, 0.15],
            )
            if kind == "wall_box":
                self._wall_box(room)
            elif kind == "round":
                r = rng.uniform(0.1, 0.3)
                self._place_circle(room, r, margin=0.0 if rng.random() < 0.5 else 1.0)
            else:
                self._free_standing(room, kind)

    def _wall_box(self, room: np.ndarray) -> None:
        rng = self.rng
        x0, y0, x1, y1 = room
        length, depth = rng.uniform(0.6, 2.0), rng.uniform(0.4, 0.8)
        side = rng.integers(4)
        horizontal = side in (0, 2)
        span = (x1 - x0) if horizontal else (y1 - y0)
        if span < length + 0.2:
            return
        t = rng.uniform(length / 2 + 0.05, span - length / 2 - 0.05)
        if horizontal:
            cx = x0 + t
            cy = y0 + depth / 2 + 0.02 if side == 0 else y1 - depth / 2 - 0.02
            angle = 0.0
        else:
            cy = y0 + t
            cx = x0 + depth / 2 + 0.02 if side == 3 else x1 - depth / 2 - 0.02
            angle = math.pi / 2
        radius = math.hypot(length, depth) / 2
        if not self._free(cx, cy, radius, gap=0.0):
            return
        self.taken.append((cx, cy, radius))
        self.segments.extend(_box(cx, cy, length, depth, angle))

    def _free_standing(self, room: np.ndarray, kind: str) -> None:
        rng = self.rng
        if kind == "table":
            length, depth = rng.uniform(1.0, 1.8), rng.uniform(0.6, 0.9)
            leg = rng.uniform(0.02, 0.035)
        elif kind == "chair":
            length = depth = rng.uniform(0.38, 0.48)
            leg = rng.uniform(0.012, 0.02)
        else:
            length, depth, leg = rng.uniform(0.3, 1.0), rng.uniform(0.3, 1.0), 0.0
        radius = math.hypot(length, depth) / 2
        spot = self._spot(room, radius, margin=0.3 if kind == "box" else 0.5)
        if spot is None:
            return
        cx, cy = spot
        if rng.random() < 0.7:  # mostly square to the walls
            angle = rng.choice([0.0, math.pi / 2]) + rng.normal(0, 0.1)
        else:
            angle = rng.uniform(0, math.pi)
        outline = _box(cx, cy, length, depth, angle)
        self.taken.append((cx, cy, radius))
        if kind == "box":
            self.segments.extend(outline)
            return
        self.avoid_segments.extend(outline)
        inset = 0.04
        c, s = math.cos(angle), math.sin(angle)
        for dx, dy in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            lx, ly = dx * (length / 2 - inset), dy * (depth / 2 - inset)
            self.circles.append([cx + c * lx - s * ly, cy + s * lx + c * ly, leg])

    def _spot(self, room: np.ndarray, radius: float, margin: float) -> tuple[float, float] | None:
        x0, y0, x1, y1 = room
        lo_x, hi_x = x0 + radius + margin, x1 - radius - margin
        lo_y, hi_y = y0 + radius + margin, y1 - radius - margin
        if lo_x >= hi_x or lo_y >= hi_y:
            return None
        for _ in range(8):
            x, y = self.rng.uniform(lo_x, hi_x), self.rng.uniform(lo_y, hi_y)
            if self._free(x, y, radius):
                return x, y
        return None

    def _place_circle(self, room: np.ndarray, r: float, margin: float) -> None:
        spot = self._spot(room, r, margin + 0.05)
        if spot is None:
            return
        self.taken.append((*spot, r))
        self.circles.append([*spot, r])
        self.avoid_circles.append([*spot, r])
