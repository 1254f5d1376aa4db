"""Small recordings of a moving object with known ground-truth flow, for the training tests."""

from __future__ import annotations

import numpy as np

from lidarflow.data import Recording
from lidarflow.scan import BeamGeometry, GridSpec, Scan

GRID = GridSpec(32, 32, 0.1)


def blob_recording(
    n: int = 60,
    beams: int = 181,
    speed_cells: float = 1.0,
    seed: int = 0,
    with_flow: bool = True,
    wall: bool = True,
    width: float = 0.3,
) -> Recording:
    """A 180° scan of a back wall at 2.9 m (unless ``wall=False``) and an object ``width`` m
    wide at 1.55 m that moves sideways by ``speed_cells`` cells per frame (bouncing at the
    sides), on a 32 x 32 grid of 0.1 m.

    ``extras["flow_backward"][t]`` is the ground truth ``B^t`` (design notes §3, cells) on the
    32 x 32 grid: ``O^{t+1}(p) = O^t(p + B^t(p))`` for the object's cells of frame ``t+1``:
    column displacement ``-v_t`` where the object moves by ``v_t`` columns, zero elsewhere.
    """
    rng = np.random.default_rng(seed)
    geom = BeamGeometry(beams, -np.pi / 2, np.pi / (beams - 1), 0.05, 8.0)
    angles = geom.angle_min + geom.angle_increment * np.arange(beams)
    res = GRID.res
    x_obj = 1.55  # object row band (metres forward)
    y = 0.8  # object centre (metres left)
    vy = -speed_cells * res  # moving right (towards -y) by speed_cells cells per frame
    scans = []
    centres = []
    for i in range(n):
        if not -1.2 < y + vy < 1.2:
            vy = -vy
        centres.append(y)
        # back wall at x = 2.9 m: range = 2.9 / cos(theta) where it is in front
        ranges = np.full(beams, np.inf, dtype=np.float32)
        front = np.cos(angles) > 0.05
        if wall:
            ranges[front] = 2.9 / np.cos(angles[front])
        # object: a short segment across y at x = x_obj
        bearing_lo = np.arctan2(y - width / 2, x_obj)
        bearing_hi = np.arctan2(y + width / 2, x_obj)
        hit = (angles >= bearing_lo) & (angles <= bearing_hi)
        ranges[hit] = x_obj / np.cos(angles[hit])
        ranges += rng.normal(0, 0.005, beams).astype(np.float32)
        scans.append(Scan(ranges.astype(np.float32), geom, int(1e9 + i * 1e8)))
        y += vy
    rec = Recording.from_scans(scans, meta={"source": f"blob{seed}"})
    if with_flow:
        occ, _ = rec.maps(GRID)
        flow = np.zeros((n, 2, *GRID.shape), dtype=np.float32)
        for t in range(n - 1):
            dcol = (centres[t] - centres[t + 1]) / res  # +y left is -column
            # B^t on frame t+1's object cells: sample frame t at p - dcol
            obj = occ[t + 1].copy()
            obj[: GRID.height - int(2.8 / res)] = False  # drop the back wall rows
            flow[t, 0][obj] = -dcol
        rec.extras["flow_backward"] = flow
    return rec
