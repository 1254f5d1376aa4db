"""Scenario assembly: episodes of a world, a robot and people, turned into a recording.

Each episode builds a new world from ``(seed, episode index)``, so a seed gives the same run
however it is cut into files or spread over processes. Between episodes the stamps jump by one
second (no training window crosses worlds); an episode's last frame has zero flow.

The recording's ``extras`` hold the ground-truth flow (:mod:`lidarflow.sim.storage`) and
``moving`` bool ``(N, H, W)`` (cells of ``O^t`` hit on a moving object), ``true_poses`` float64
``(N, 3)`` (``Recording.poses`` is the odometry) and ``episode`` int32 ``(N,)``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from contextlib import closing
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from lidarflow.atomic import atomic_paths
from lidarflow.data.recording import Recording
from lidarflow.errors import SimError
from lidarflow.scan import GridSpec
from lidarflow.sim.groundtruth import ground_truth
from lidarflow.sim.lidar import STATIC_ID, LidarConfig, cast_rays, lidar_preset, measure
from lidarflow.sim.people import Crowd, PeopleConfig, legs_from
from lidarflow.sim.platform import Platform, PlatformConfig
from lidarflow.sim.social import SocialCrowd
from lidarflow.sim.storage import FLOW_STORAGES, fill_dense, to_sparse
from lidarflow.sim.world import World, WorldConfig, build_world

__all__ = ["Episode", "SimConfig", "simulate", "simulate_episode", "write_simulation"]

SCENARIOS = ("static", "dynamic")
#: The people's models: social forces with groups (:mod:`lidarflow.sim.social`) or the first
#: walkers (:mod:`lidarflow.sim.people`).
WALKERS = ("social", "legacy")
_START_NS = 1_000_000_000
_EPISODE_GAP_NS = 1_000_000_000


@dataclass(frozen=True)
class SimConfig:
    """What to simulate. ``scenario`` is ``"static"`` (the robot stands still) or ``"dynamic"``
    (it drives); ``walkers`` one of :data:`WALKERS`; the defaults give the paper's setting: a
    SICK TIM561 at 15 Hz and the 100 x 100 x 0.1 m grid."""

    scenario: str = "dynamic"
    sensor: LidarConfig = field(default_factory=lambda: lidar_preset("tim561"))
    people: PeopleConfig = field(default_factory=PeopleConfig)
    world: WorldConfig = field(default_factory=WorldConfig)
    platform: PlatformConfig = field(default_factory=PlatformConfig)
    grid: GridSpec = field(default_factory=GridSpec)
    episode_frames: int = 1500
    block_frames: int = 32
    flow_storage: str = "dense"
    walkers: str = "legacy"

    def __post_init__(self) -> None:
        choices = {"scenario": SCENARIOS, "walkers": WALKERS, "flow_storage": FLOW_STORAGES}
        for name, allowed in choices.items():
            if getattr(self, name) not in allowed:
                raise SimError(f"{name} must be one of {allowed}, got {getattr(self, name)!r}")
        if self.episode_frames < 2 or self.block_frames < 1:
            raise SimError("episode_frames must be >= 2 and block_frames >= 1")
        if self.platform.moving != (self.scenario == "dynamic"):
            object.__setattr__(
                self, "platform", replace(self.platform, moving=self.scenario == "dynamic")
            )

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["grid"] = self.grid.to_dict()
        return d


@dataclass
class Episode:
    """One simulated episode: ``n`` frames of ranges and ground truth (see the module doc)."""

    ranges: np.ndarray
    odom: np.ndarray
    true_poses: np.ndarray
    flow_backward: np.ndarray
    flow_forward: np.ndarray
    moving: np.ndarray


def _dynamics(config: SimConfig, rng: np.random.Generator, frames: int) -> tuple[Any, ...]:
    world = build_world(rng, config.world)
    platform = Platform(world, config.platform, rng)
    sensor = config.sensor
    reach = sensor.range_max
    kind = SocialCrowd if config.walkers == "social" else Crowd
    crowd = kind(world, config.people, rng, platform.pose, math.radians(sensor.fov_deg), reach)
    dt = 1.0 / sensor.rate_hz
    poses = np.empty((frames, 3))
    odom = np.empty((frames, 3))
    snaps = np.empty((frames, config.people.count, 5))
    for t in range(frames):
        poses[t], odom[t], snaps[t] = platform.pose, platform.odom, crowd.snapshot()
        people = crowd.pos[crowd.walking()]
        crowd.step(dt, platform.pose, config.platform.radius)
        platform.step(dt, people)
    return world, poses, odom, legs_from(snaps, crowd.hip, crowd.leg_r)


def simulate_episode(
    config: SimConfig,
    seed: int,
    episode: int,
    frames: int,
    out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> Episode:
    """Simulate episode ``episode`` of the run with ``seed``: ``frames`` frames. ``out``: zeroed
    ``(flow_backward, flow_forward, moving)`` arrays of ``frames`` frames to fill in place."""
    if frames < 1:
        raise SimError(f"an episode needs at least one frame, got {frames}")
    rng = np.random.default_rng([seed, episode])
    total = frames + 1  # one more state, so the last frame's motion is known for `moving`
    world, poses, odom, legs = _dynamics(config, rng, total)
    geom = config.sensor.geometry()
    true, ids = _cast(config, world, poses, legs)
    ranges = measure(true, config.sensor, rng)
    backward, forward, moving = out or _zeros(config, frames)
    for a in range(0, frames, config.block_frames):
        b = min(a + config.block_frames, frames)
        s = slice(a, b + 1)  # the block's frames and the one after
        moved = (backward[a:b], forward[a:b], moving[a:b])
        ground_truth(ranges[s], ids[s], poses[s], legs[s, :, :2], geom, config.grid, out=moved)
    backward[-1] = 0.0  # the episode's last frame has no next frame
    forward[-1] = 0.0
    return Episode(ranges[:frames], odom[:frames], poses[:frames], backward, forward, moving)


def _cast(
    config: SimConfig, world: World, poses: np.ndarray, legs: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cast_rays` of the episode, a block of frames at a time; a robot standing still
    casts on the walls and furniture once."""
    geom = config.sensor.geometry()
    leg_ids = np.arange(legs.shape[1], dtype=np.int32)
    static_scene = None
    if not config.platform.moving:
        static_scene = cast_rays(poses[:1], geom, world.segments, world.circles)
    cid = np.concatenate([np.full(len(world.circles), STATIC_ID, np.int32), leg_ids])
    true = np.empty((len(poses), geom.count))
    ids = np.empty((len(poses), geom.count), dtype=np.int32)
    for a in range(0, len(poses), config.block_frames):
        b = min(a + config.block_frames, len(poses))
        if static_scene is None:
            walls = np.broadcast_to(world.circles, (b - a, *world.circles.shape))
            circles = np.concatenate([walls, legs[a:b]], 1)
            true[a:b], ids[a:b] = cast_rays(poses[a:b], geom, world.segments, circles, cid)
        else:
            lr, lid = cast_rays(poses[a:b], geom, np.zeros((0, 4)), legs[a:b], leg_ids)
            closer = lr < static_scene[0]
            true[a:b] = np.where(closer, lr, static_scene[0])
            ids[a:b] = np.where(closer, lid, static_scene[1])
    return true, ids


def _zeros(config: SimConfig, frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    shape = (frames, 2, *config.grid.shape)
    return (
        np.zeros(shape, np.float16),
        np.zeros(shape, np.float16),
        np.zeros((frames, *config.grid.shape), bool),
    )


def _episode_plan(frames: int, episode_frames: int) -> list[tuple[int, int, int]]:
    """``(episode, first frame, frame count)`` of every episode of a run."""
    if frames < 1:
        raise SimError(f"frames must be >= 1, got {frames}")
    return [
        (e, a, min(episode_frames, frames - a))
        for e, a in enumerate(range(0, frames, episode_frames))
    ]


def _run_one(args: tuple[SimConfig, int, int, int]) -> tuple[Episode, tuple[np.ndarray, ...]]:
    """A worker's episode, its flows sent back sparse (a tenth of the bytes to pickle)."""
    ep = simulate_episode(*args)
    packed = (*to_sparse(ep.flow_backward), *to_sparse(ep.flow_forward))
    return replace(ep, flow_backward=None, flow_forward=None), packed


class _Source:
    """Episodes of a run in order: simulated here straight into the caller's arrays, or in a
    pool of processes and copied in."""

    def __init__(
        self, config: SimConfig, seed: int, plan: list[tuple[int, int, int]], workers: int
    ) -> None:
        self.config, self.seed = config, seed
        self.pool = None
        if seed < 0:  # numpy's generators take none
            raise SimError(f"seed (--seed) must be >= 0, got {seed}")
        # each worker simulates whole episodes: more than a few per core only share the cores
        most = 4 * (os.cpu_count() or 1)
        if not 1 <= workers <= most:
            raise SimError(
                f"workers (--workers): from 1 to {most} processes (4 per CPU core), got {workers}"
            )
        if workers > 1 and len(plan) > 1:
            import multiprocessing

            self.pool = multiprocessing.get_context("fork").Pool(workers)
            jobs = [(config, seed, e, k) for e, _, k in plan]
            self.results = self.pool.imap(_run_one, jobs)

    def next(
        self, episode: int, frames: int, out: tuple[np.ndarray, np.ndarray, np.ndarray]
    ) -> Episode:
        if self.pool is None:
            return simulate_episode(self.config, self.seed, episode, frames, out)
        ep, (bw_cells, bw_values, fw_cells, fw_values) = next(self.results)
        fill_dense(out[0], bw_cells, bw_values)
        fill_dense(out[1], fw_cells, fw_values)
        out[2][...] = ep.moving
        return Episode(ep.ranges, ep.odom, ep.true_poses, *out)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.close()
            self.pool.join()


def _recording(
    config: SimConfig,
    seed: int,
    plan: list[tuple[int, int, int]],
    source: _Source,
    progress: Callable[[int], object] | None,
) -> Recording:
    """The episodes of ``plan`` from ``source`` as one recording (module docstring)."""
    flows = _zeros(config, sum(k for _, _, k in plan))
    episodes, at = [], 0
    for e, _, k in plan:
        episodes.append(source.next(e, k, tuple(f[at : at + k] for f in flows)))
        at += k
        if progress:
            progress(k)
    geom = config.sensor.geometry()
    n = sum(p[2] for p in plan)
    period = round(1e9 / config.sensor.rate_hz)
    stamps = np.concatenate(
        [_START_NS + (a + np.arange(k)) * period + e * _EPISODE_GAP_NS for e, a, k in plan]
    )
    ranges = np.concatenate([ep.ranges for ep in episodes]).astype(np.float32)

    def cat(name: str) -> np.ndarray:
        return np.concatenate([getattr(ep, name) for ep in episodes])

    extras: dict[str, np.ndarray] = {}
    for name, flow in (("flow_backward", flows[0]), ("flow_forward", flows[1])):
        if config.flow_storage == "sparse":
            extras[f"{name}_cells"], extras[f"{name}_values"] = to_sparse(flow)
        else:
            extras[name] = flow
    extras |= {
        "moving": flows[2],
        "true_poses": cat("true_poses"),
        "episode": np.concatenate([np.full(k, e, np.int32) for e, _, k in plan]),
    }
    meta = {
        "source": f"simulator:{config.scenario}:seed{seed}",
        "topic": "/scan",
        "frame_id": "laser",
        "simulated": True,
        "scenario": config.scenario,
        "seed": seed,
        "sensor": config.sensor.name,
        "sim_config": config.to_dict(),
        "grid": config.grid.to_dict(),
        "flow_storage": config.flow_storage,
        "episodes": [[e, a, k] for e, a, k in plan],
    }
    return Recording(
        ranges=ranges.ravel(),
        offsets=np.arange(n + 1, dtype=np.int64) * geom.count,
        angle_min=np.full(n, geom.angle_min),
        angle_increment=np.full(n, geom.angle_increment),
        range_min=np.full(n, geom.range_min),
        range_max=np.full(n, geom.range_max),
        stamps_ns=stamps.astype(np.int64),
        poses=cat("odom"),
        meta=meta,
        extras=extras,
    )


def simulate(
    frames: int,
    seed: int = 0,
    config: SimConfig | None = None,
    workers: int = 1,
    progress: Callable[[int], object] | None = None,
) -> Recording:
    """Simulate ``frames`` frames into one in-memory recording (with ground truth in
    ``extras``); ``progress`` is called with the number of frames finished after each episode."""
    config = config or SimConfig()
    plan = _episode_plan(frames, config.episode_frames)
    with closing(_Source(config, seed, plan, workers)) as source:
        return _recording(config, seed, plan, source, progress)


def write_simulation(
    output: str | Path,
    frames: int,
    seed: int = 0,
    config: SimConfig | None = None,
    chunk_frames: int = 0,
    workers: int = 1,
    progress: Callable[[int], object] | None = None,
) -> list[Path]:
    """Simulate and write ``frames`` frames. With ``chunk_frames > 0`` and more frames than
    that, the run is written as ``STEM-000.npz``, ``STEM-001.npz``... each holding whole
    episodes (at most ``max(chunk_frames, episode_frames)`` frames); otherwise as one file."""
    config = config or SimConfig()
    output = Path(output)
    plan = _episode_plan(frames, config.episode_frames)
    groups: list[list[tuple[int, int, int]]] = [[]]
    for item in plan:
        size = sum(k for _, _, k in groups[-1])
        if groups[-1] and chunk_frames > 0 and size + item[2] > chunk_frames:
            groups.append([])
        groups[-1].append(item)
    stem = output.name[:-4] if output.name.endswith(".npz") else output.name
    paths = [output]
    if len(groups) > 1:
        paths = [output.with_name(f"{stem}-{i:03d}.npz") for i in range(len(groups))]
    # every file appears at the end, or none: a run stopped midway leaves no chunk behind
    with closing(_Source(config, seed, plan, workers)) as source, atomic_paths(paths) as temps:
        for i, (group, tmp) in enumerate(zip(groups, temps, strict=True)):
            recording = _recording(config, seed, group, source, progress)
            if len(groups) > 1:
                recording.meta.update(chunk=i, chunks=len(groups), first_frame=group[0][1])
            recording.save(tmp)
    return paths
