"""The simulated 2-D LiDAR: sensor presets and vectorised ray casting.

Angles follow REP 103. The ray caster turns the world into each frame's sensor frame and casts
all beams of all frames of a block together; each object is intersected only with the beams its
angular extent covers, so the cost follows beams times the scene's depth, not beams times objects.

A hit reports its range and the id of the object hit: ``-1`` for static structure (walls,
furniture), ``k >= 0`` for dynamic circle ``k`` (a person's leg), ``NO_HIT`` (-2) for no hit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from lidarflow.errors import SimError
from lidarflow.scan import BeamGeometry

__all__ = [
    "NO_HIT",
    "PRESETS",
    "STATIC_ID",
    "LidarConfig",
    "cast_rays",
    "lidar_preset",
    "measure",
]

STATIC_ID = -1
NO_HIT = -2
_TWO_PI = 2.0 * math.pi


@dataclass(frozen=True)
class LidarConfig:
    """A 2-D LiDAR. The defaults are the paper's SICK TIM561-2050101: 15 Hz, 270°, 0.33°, 10 m.

    ``noise_std`` is the Gaussian range noise (m); ``dropout_prob`` the chance that a beam reports
    nothing (written ``NaN`` or ``0`` per ``dropout_value``: ``"nan"``, ``"zero"`` or ``"mixed"``).
    ``mixed_pixel_prob`` is the chance that a beam at a depth edge (a jump of more than
    ``mixed_pixel_jump`` m to its neighbour) reports a range in between.
    """

    name: str = "tim561"
    rate_hz: float = 15.0
    fov_deg: float = 270.0
    beams: int = 811
    range_min: float = 0.05
    range_max: float = 10.0
    noise_std: float = 0.015
    dropout_prob: float = 0.005
    dropout_value: str = "nan"
    mixed_pixel_prob: float = 0.0
    mixed_pixel_jump: float = 0.3

    def __post_init__(self) -> None:
        if self.beams < 2 or not 0 < self.fov_deg <= 360:
            raise SimError(f"lidar needs >= 2 beams and 0 < fov <= 360 deg, got {self}")
        if self.rate_hz <= 0 or not 0 <= self.range_min < self.range_max:
            raise SimError(
                f"lidar rate must be > 0 and 0 <= range_min < range_max, got rate={self.rate_hz} "
                f"range_min={self.range_min} range_max={self.range_max}"
            )
        if not (0 <= self.dropout_prob < 1 and 0 <= self.mixed_pixel_prob <= 1):
            raise SimError("dropout_prob must be in [0, 1) and mixed_pixel_prob in [0, 1]")
        if self.noise_std < 0:
            raise SimError(f"noise_std must be >= 0, got {self.noise_std}")
        if self.dropout_value not in ("nan", "zero", "mixed"):
            raise SimError(f"dropout_value must be nan, zero or mixed, got {self.dropout_value!r}")

    @property
    def full_circle(self) -> bool:
        return self.fov_deg >= 360.0

    def geometry(self) -> BeamGeometry:
        """Beam geometry: a partial field of view is centred on the x axis with beams on both
        ends; a full circle starts at -180° with ``beams`` equal steps (no duplicate beam)."""
        fov = math.radians(self.fov_deg)
        if self.full_circle:
            return BeamGeometry(
                self.beams, -math.pi, _TWO_PI / self.beams, self.range_min, self.range_max
            )
        return BeamGeometry(
            self.beams, -fov / 2, fov / (self.beams - 1), self.range_min, self.range_max
        )


PRESETS: dict[str, LidarConfig] = {
    # The paper's sensor: 811 beams is what the sick_tim driver publishes for a TIM561. Mixed
    # pixels at depth edges are common on real scanners (the URG-04LX is notorious for them).
    "tim561": LidarConfig(mixed_pixel_prob=0.1),
    # Hokuyo URG-04LX-like, as in demo_stationary_simple_environment.bag.
    "hokuyo-urg": LidarConfig(
        name="hokuyo-urg",
        rate_hz=10.0,
        fov_deg=180.0,
        beams=512,
        range_min=0.02,
        range_max=5.6,
        noise_std=0.02,
        dropout_prob=0.01,
        dropout_value="zero",
        mixed_pixel_prob=0.3,
    ),
    # Hokuyo UTM-30LX-like at 768 beams over 270°, as in the leg_tracker positive_*.bag.
    "hokuyo-utm": LidarConfig(
        name="hokuyo-utm",
        rate_hz=7.5,
        fov_deg=270.0,
        beams=768,
        range_min=0.02,
        range_max=11.0,
        noise_std=0.01,
        dropout_prob=0.005,
        dropout_value="mixed",
        mixed_pixel_prob=0.15,
    ),
    # RPLidar-like 360° sensor, as in datmo_overtakes.bag.
    "rplidar": LidarConfig(
        name="rplidar",
        rate_hz=10.0,
        fov_deg=360.0,
        beams=360,
        range_min=0.15,
        range_max=8.0,
        noise_std=0.02,
        dropout_prob=0.02,
        dropout_value="zero",
        mixed_pixel_prob=0.1,
    ),
}


def lidar_preset(name: str, **overrides: object) -> LidarConfig:
    """A preset by name (``tim561``, ``hokuyo-urg``, ``hokuyo-utm``, ``rplidar``), optionally
    with fields replaced."""
    try:
        base = PRESETS[name]
    except KeyError as err:
        raise SimError(f"unknown sensor preset {name!r}; choose one of {sorted(PRESETS)}") from err
    return replace(base, **overrides) if overrides else base


def _to_sensor(poses: np.ndarray, xy: np.ndarray, per_frame: bool = False) -> np.ndarray:
    """World points ``xy (..., 2)`` (or ``(F, ..., 2)`` with ``per_frame``) seen from
    ``poses (F, 3)`` -> sensor frame ``(F, ..., 2)``."""
    extra = (1,) * (xy.ndim - (2 if per_frame else 1))
    x0 = poses[:, 0].reshape(-1, *extra)
    y0 = poses[:, 1].reshape(-1, *extra)
    c = np.cos(poses[:, 2]).reshape(-1, *extra)
    s = np.sin(poses[:, 2]).reshape(-1, *extra)
    dx, dy = xy[..., 0] - x0, xy[..., 1] - y0
    return np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)


def _beam_ranges(
    lo: np.ndarray, extent: np.ndarray, geometry: BeamGeometry
) -> tuple[np.ndarray, np.ndarray]:
    """Inclusive beam index ranges ``(first, last)`` covering the angular intervals
    ``[lo, lo + extent]`` (sensor-frame radians), generous by one beam on each side, clipped to the
    scan; each interval yields two candidate ranges (the second shifted by a full turn) so that
    intervals across the seam of the scan are covered. Empty ranges have ``last < first``."""
    inc = geometry.angle_increment
    n = geometry.count
    span = (n - 1) * inc
    gap = _TWO_PI - span
    rel = np.mod(lo - geometry.angle_min + gap / 2, _TWO_PI) - gap / 2
    first = np.floor(rel / inc) - 1
    last = np.ceil((rel + extent) / inc) + 1
    turn = _TWO_PI / inc
    firsts = np.stack([first, first - turn]).round()
    lasts = np.stack([last, last - turn]).round()
    firsts = np.clip(firsts, 0, n).astype(np.int64)
    lasts = np.clip(lasts, -1, n - 1).astype(np.int64)
    lasts[lasts < firsts] = firsts[lasts < firsts] - 1
    # Wrapped copies can overlap the first range for a full circle; drop the overlap.
    lasts[1] = np.minimum(lasts[1], firsts[0] - 1)
    lasts[1][lasts[1] < firsts[1]] = firsts[1][lasts[1] < firsts[1]] - 1
    return firsts, lasts


class _Pairs:
    """Every (item, beam) pair of the beam ranges ``(2, M)`` of :func:`_beam_ranges` (two
    candidate ranges per item), ordered by range then item: ``beam`` their beam index."""

    def __init__(self, lo: np.ndarray, extent: np.ndarray, geometry: BeamGeometry) -> None:
        firsts, lasts = _beam_ranges(lo, extent, geometry)
        self.counts = np.maximum(lasts - firsts + 1, 0).ravel()
        starts = np.repeat(np.cumsum(self.counts) - self.counts - firsts.ravel(), self.counts)
        self.beam = np.arange(int(self.counts.sum())) - starts

    def each(self, v: np.ndarray) -> np.ndarray:
        """Per-item values ``v (M,)`` repeated for each of the item's pairs."""
        return np.repeat(np.tile(v, 2), self.counts)


def cast_rays(
    poses: np.ndarray,
    geometry: BeamGeometry,
    segments: np.ndarray,
    circles: np.ndarray | None = None,
    circle_ids: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact ranges of every beam of ``F`` frames.

    Args:
        poses: ``(F, 3)`` sensor poses ``(x, y, yaw)`` in the world frame (m, rad).
        geometry: the beams (``angle_increment`` must be positive).
        segments: ``(S, 4)`` static segments ``(x0, y0, x1, y1)`` in the world frame; all have
            the object id ``STATIC_ID``.
        circles: ``(F, K, 3)`` or ``(K, 3)`` circles ``(x, y, r)`` per frame; rows with NaN are
            absent.
        circle_ids: ``(K,)`` object id of each circle (default: ``STATIC_ID`` for all).

    Returns:
        ``(ranges, ids)``: ``(F, B)`` float64 ranges (``inf`` where nothing is hit within
        ``range_max`` plus a margin) and ``(F, B)`` int32 object ids (``NO_HIT`` for no hit).
    """
    poses = np.asarray(poses, dtype=np.float64)
    if poses.ndim != 2 or poses.shape[1] != 3:
        raise SimError(f"poses must be (F, 3), got {poses.shape}")
    if geometry.angle_increment <= 0:
        raise SimError("the ray caster needs a positive angle_increment")
    frames, beams = poses.shape[0], geometry.count
    best = np.full(frames * beams, np.inf)
    ids = np.full(frames * beams, NO_HIT, dtype=np.int32)
    hits = []
    if len(segments):
        hits.append(_segment_hits(poses, geometry, np.asarray(segments, np.float64)))
    if circles is not None and np.size(circles):
        circles = np.asarray(circles, np.float64)
        if circles.ndim == 2:
            circles = np.broadcast_to(circles, (frames, *circles.shape))
        if circle_ids is None:
            circle_ids = np.full(circles.shape[1], STATIC_ID, np.int32)
        hits.append(_circle_hits(poses, geometry, circles, np.asarray(circle_ids, np.int32)))
    if hits:
        t, key, obj = (np.concatenate(parts) for parts in zip(*hits, strict=True))
        np.minimum.at(best, key, t)
        win = t == best[key]
        ids[key[win]] = obj[win]
    return best.reshape(frames, beams), ids.reshape(frames, beams)


def _segment_hits(
    poses: np.ndarray, geometry: BeamGeometry, segments: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ranges, flat ``frame * beams + beam`` keys and ids of the beams' hits on ``segments``."""
    ends = _to_sensor(poses, segments.reshape(-1, 2, 2))  # F,S,2,2
    p, q = ends[:, :, 0], ends[:, :, 1]
    e = q - p
    # Cull segments farther than the sensor reaches (distance from origin to segment).
    ee = np.maximum((e * e).sum(-1), 1e-12)
    u = np.clip(-(p * e).sum(-1) / ee, 0.0, 1.0)
    reach = geometry.range_max + 0.5
    near = np.hypot(p[..., 0] + u * e[..., 0], p[..., 1] + u * e[..., 1]) <= reach
    f_idx, s_idx = np.nonzero(near)
    p, e = p[f_idx, s_idx], e[f_idx, s_idx]
    a0 = np.arctan2(p[:, 1], p[:, 0])
    a1 = np.arctan2(p[:, 1] + e[:, 1], p[:, 0] + e[:, 0])
    d = np.mod(a1 - a0 + math.pi, _TWO_PI) - math.pi
    pairs = _Pairs(np.where(d >= 0, a0, a1), np.abs(d), geometry)
    beam, rep = pairs.beam, pairs.each
    angles = geometry.angles
    dx, dy = np.cos(angles)[beam], np.sin(angles)[beam]
    px, py, ex, ey = rep(p[:, 0]), rep(p[:, 1]), rep(e[:, 0]), rep(e[:, 1])
    den = dx * ey - dy * ex
    with np.errstate(divide="ignore", invalid="ignore"):
        t = rep(p[:, 0] * e[:, 1] - p[:, 1] * e[:, 0]) / den
        s = (px * dy - py * dx) / den
    # den == 0 gives inf/NaN, which fail these tests.
    ok = (t > 0) & (s >= 0) & (s <= 1)
    key = rep(f_idx * geometry.count)[ok] + beam[ok]
    return t[ok], key, np.full(int(ok.sum()), STATIC_ID, dtype=np.int32)


def _circle_hits(
    poses: np.ndarray, geometry: BeamGeometry, circles: np.ndarray, circle_ids: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """As :func:`_segment_hits`, on circles ``(F, K, 3)`` with ids ``(K,)``."""
    centre = _to_sensor(poses, circles[..., :2], per_frame=True)  # F,K,2
    radius = circles[..., 2]
    dist = np.hypot(centre[..., 0], centre[..., 1])
    with np.errstate(invalid="ignore"):
        near = (dist - radius <= geometry.range_max + 0.5) & (dist > radius)
    f_idx, c_idx = np.nonzero(near)
    c, r, dist = centre[f_idx, c_idx], radius[f_idx, c_idx], dist[f_idx, c_idx]
    half = np.arcsin(np.clip(r / dist, 0.0, 1.0))
    pairs = _Pairs(np.arctan2(c[:, 1], c[:, 0]) - half, 2 * half, geometry)
    beam, rep = pairs.beam, pairs.each
    angles = geometry.angles
    cx, cy, rr = rep(c[:, 0]), rep(c[:, 1]), rep(r)
    proj = cx * np.cos(angles)[beam] + cy * np.sin(angles)[beam]
    disc = rr * rr - (cx * cx + cy * cy - proj * proj)
    ok = (disc >= 0) & (proj > 0)
    key = rep(f_idx * geometry.count)[ok] + beam[ok]
    return proj[ok] - np.sqrt(disc[ok]), key, rep(circle_ids[c_idx])[ok]


def measure(true_ranges: np.ndarray, config: LidarConfig, rng: np.random.Generator) -> np.ndarray:
    """Turn exact ranges ``(F, B)`` into what the sensor reports (float32): mixed pixels at
    depth edges, Gaussian noise, ``+inf`` beyond ``range_max``, dropouts as NaN/0, and readings
    below ``range_min`` as 0 (unknown)."""
    r = np.array(true_ranges, dtype=np.float64)
    if config.mixed_pixel_prob > 0:
        nxt = np.roll(r, -1, axis=1)
        with np.errstate(invalid="ignore"):  # inf - inf where neither beam hits anything
            edge = np.abs(nxt - r) > config.mixed_pixel_jump
        edge[:, -1] = False
        edge &= (r <= config.range_max) & (nxt <= config.range_max)
        edge &= rng.random(r.shape) < config.mixed_pixel_prob
        alpha = rng.uniform(0.15, 0.85, r.shape)
        r[edge] += alpha[edge] * (nxt[edge] - r[edge])
    beyond = ~(r <= config.range_max)
    if config.noise_std > 0:
        r = r + rng.normal(0.0, config.noise_std, r.shape)
    r[beyond] = np.inf
    # A return that noise pushes to range_max or past it is reported as measured (some
    # drivers clip it or write +inf instead); either way it reads as no return (lidarflow.scan).
    r[r < config.range_min] = 0.0
    if config.dropout_prob > 0:
        drop = rng.random(r.shape) < config.dropout_prob
        if config.dropout_value == "nan":
            r[drop] = np.nan
        elif config.dropout_value == "zero":
            r[drop] = 0.0
        else:
            r[drop] = np.where(rng.random(int(drop.sum())) < 0.5, np.nan, 0.0)
    return r.astype(np.float32)
