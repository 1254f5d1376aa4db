"""Shared fixtures: small recordings made in memory, and the bundled real sample."""

from __future__ import annotations

import numpy as np
import pytest

from lidarflow.data import Recording, read_bag, sample_bag_path
from lidarflow.scan import BeamGeometry, Scan


def make_recording(
    n: int = 30, beams: int = 181, rate_hz: float = 10.0, seed: int = 0, poses: bool = False
) -> Recording:
    """A synthetic recording: a wall at 4 m with a few random returns, 180 degrees."""
    rng = np.random.default_rng(seed)
    geom = BeamGeometry(beams, -np.pi / 2, np.pi / (beams - 1), 0.05, 8.0)
    scans = []
    for i in range(n):
        ranges = np.full(beams, 4.0, dtype=np.float32) + rng.normal(0, 0.01, beams).astype(
            np.float32
        )
        ranges[rng.integers(0, beams, 5)] = np.inf
        ranges[rng.integers(0, beams, 3)] = np.nan
        scans.append(Scan(ranges, geom, int(1_000_000_000 + i * 1e9 / rate_hz)))
    pose_arr = np.column_stack([np.arange(n) * 0.1, np.zeros(n), np.zeros(n)]) if poses else None
    return Recording.from_scans(scans, poses=pose_arr, meta={"source": "synthetic"})


@pytest.fixture
def synthetic_recording() -> Recording:
    return make_recording()


@pytest.fixture(scope="session")
def sample_recording() -> Recording:
    return read_bag(sample_bag_path())
