"""Scenario assembly: determinism, the recording format, chunked writing, motion limits, CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from lidarflow.cli import main
from lidarflow.data import load_recording
from lidarflow.errors import SimError
from lidarflow.scan import GridSpec
from lidarflow.sim import PeopleConfig, PlatformConfig, SimConfig, lidar_preset, simulate
from lidarflow.sim.scenario import write_simulation

SMALL = SimConfig(scenario="dynamic", episode_frames=40, grid=GridSpec(60, 60, 0.1))


def _same(a, b) -> bool:
    return (
        np.array_equal(a.ranges, b.ranges, equal_nan=True)
        and np.array_equal(a.poses, b.poses)
        and np.array_equal(a.stamps_ns, b.stamps_ns)
        and a.extras.keys() == b.extras.keys()
        and all(np.array_equal(a.extras[k], b.extras[k]) for k in a.extras)
    )


def test_same_seed_same_recording_different_seed_differs():
    a = simulate(60, seed=11, config=SMALL)
    b = simulate(60, seed=11, config=SMALL)
    c = simulate(60, seed=12, config=SMALL)
    assert _same(a, b)
    assert not np.array_equal(a.ranges, c.ranges, equal_nan=True)
    assert not np.array_equal(a.extras["true_poses"], c.extras["true_poses"])


def test_recording_layout_and_meta():
    rec = simulate(60, seed=3, config=SMALL)
    n, (h, w) = 60, SMALL.grid.shape
    assert len(rec) == n and rec.geometry(0).count == 811
    assert rec.extras["flow_backward"].shape == (n, 2, h, w)
    assert rec.extras["flow_backward"].dtype == np.float16
    assert rec.extras["flow_forward"].shape == (n, 2, h, w)
    assert rec.extras["moving"].shape == (n, h, w) and rec.extras["moving"].dtype == bool
    assert rec.extras["true_poses"].shape == (n, 3)
    assert rec.meta["grid"] == SMALL.grid.to_dict()
    assert rec.meta["simulated"] is True and rec.meta["seed"] == 3
    assert rec.meta["scenario"] == "dynamic" and rec.meta["sensor"] == "tim561"
    assert rec.frame_rate == pytest.approx(15.0)
    # Two episodes: the last frame of each has no flow, and a gap separates them.
    for last in (39, 59):
        assert not rec.extras["flow_forward"][last].any()
        assert not rec.extras["flow_backward"][last].any()
    assert rec.extras["flow_forward"][38].any()
    assert np.diff(rec.stamps_ns)[39] > 10 * np.diff(rec.stamps_ns)[0]
    from lidarflow.data import split_segments

    assert split_segments(rec) == [(0, 40), (40, 60)]


def test_written_recording_loads_back_with_extras(tmp_path):
    rec = simulate(50, seed=4, config=SMALL)
    loaded = load_recording(rec.save(tmp_path / "sim.npz"))
    assert _same(rec, loaded)
    assert loaded.meta["sim_config"]["sensor"]["name"] == "tim561"
    part = loaded.slice(10, 20)
    assert part.extras["flow_forward"].shape[0] == 10
    np.testing.assert_array_equal(part.extras["moving"], rec.extras["moving"][10:20])


def test_chunked_writing_equals_one_run(tmp_path):
    paths = write_simulation(tmp_path / "run.npz", 100, seed=8, config=SMALL, chunk_frames=80)
    assert [p.name for p in paths] == ["run-000.npz", "run-001.npz"]
    parts = [load_recording(p) for p in paths]
    assert [len(p) for p in parts] == [80, 20]  # whole episodes of 40 frames
    whole = simulate(100, seed=8, config=SMALL)
    joined = np.concatenate([p.extras["flow_backward"] for p in parts])
    np.testing.assert_array_equal(joined, whole.extras["flow_backward"])
    np.testing.assert_array_equal(np.concatenate([p.stamps_ns for p in parts]), whole.stamps_ns)
    two = write_simulation(
        tmp_path / "par.npz", 100, seed=8, config=SMALL, chunk_frames=80, workers=2
    )
    assert _same(load_recording(two[1]), parts[1])


def test_driving_respects_the_platform_limits_and_odometry():
    rate = SMALL.sensor.rate_hz
    rec = simulate(120, seed=6, config=SimConfig(episode_frames=120, grid=SMALL.grid))
    true = rec.extras["true_poses"]
    speed = np.hypot(*np.diff(true[:, :2], axis=0).T) * rate
    turn = np.abs(np.diff(np.unwrap(true[:, 2]))) * rate
    assert speed.max() <= 1.0 + 1e-9 and turn.max() <= 1.0 + 1e-9
    assert speed.sum() / rate > 1.0  # it does drive
    np.testing.assert_array_equal(rec.poses, true)
    drift = SimConfig(episode_frames=120, grid=SMALL.grid, platform=PlatformConfig(odom_drift=0.05))
    odo = simulate(120, seed=6, config=drift)
    np.testing.assert_array_equal(odo.extras["true_poses"], true)
    err = np.hypot(*(odo.poses[:, :2] - true[:, :2]).T)
    assert 0 < err[-1] < 0.2 * speed.sum() / rate + 0.05


def test_static_platform_stands_still():
    rec = simulate(40, seed=1, config=SimConfig(scenario="static", episode_frames=40))
    assert np.ptp(rec.extras["true_poses"], axis=0).max() == 0


def test_people_walk_within_human_speeds_on_two_legs():
    from lidarflow.sim.people import Crowd
    from lidarflow.sim.platform import Platform
    from lidarflow.sim.world import build_world

    rng = np.random.default_rng(0)
    world = build_world(rng)
    robot = Platform(world, PlatformConfig(moving=False), rng)
    crowd = Crowd(world, PeopleConfig(count=8), rng, robot.pose, math.radians(270), 10.0)
    dt = 1 / 15
    pos, legs = [], []
    for _ in range(300):
        crowd.step(dt, robot.pose)
        pos.append(np.where(crowd.walking()[:, None], crowd.pos, np.nan))
        legs.append(crowd.legs())
    pos, legs = np.array(pos), np.array(legs)
    speed = np.hypot(*np.diff(pos, axis=0).transpose(2, 0, 1)) / dt
    assert np.nanmax(speed) <= 1.8 + 1e-9
    assert np.nanmean(speed[speed > 0.2]) > 0.6
    radius = legs[..., 2][np.isfinite(legs[..., 2])]
    assert radius.min() >= 0.06 and radius.max() <= 0.08
    # Two legs a person's width apart, swinging: their distance varies while walking.
    gap = np.hypot(*(legs[:, 0::2, :2] - legs[:, 1::2, :2]).transpose(2, 0, 1))
    assert np.nanmin(gap) >= 0.15 and np.nanmax(gap) < 0.7
    assert np.nanmax(gap) > 0.35


@pytest.mark.parametrize("sensor", ["hokuyo-urg", "hokuyo-utm", "rplidar"])
def test_other_sensors_simulate(sensor):
    cfg = SimConfig(sensor=lidar_preset(sensor), episode_frames=20, grid=SMALL.grid)
    rec = simulate(20, seed=0, config=cfg)
    assert rec.geometry(0).count == lidar_preset(sensor).beams
    assert rec.frame_rate == pytest.approx(lidar_preset(sensor).rate_hz, rel=1e-3)


def test_bad_configuration_is_a_sim_error():
    with pytest.raises(SimError, match="scenario"):
        SimConfig(scenario="flying")
    with pytest.raises(SimError, match="frames"):
        simulate(0)


@pytest.mark.slow
def test_cli_simulate_then_show(tmp_path, capsys):
    out = tmp_path / "s.npz"
    with pytest.raises(SystemExit) as done:
        main(
            [
                "simulate",
                "--scenario",
                "static",
                "--frames",
                "30",
                "--seed",
                "2",
                "-o",
                str(out),
                "--sensor",
                "hokuyo-urg",
                "--people",
                "3",
                "--episode-frames",
                "30",
            ]
        )
    assert done.value.code == 0
    rec = load_recording(out)
    assert len(rec) == 30 and rec.geometry(0).count == 512 and rec.meta["seed"] == 2
    record = json.loads((tmp_path / "s.json").read_text())
    assert record["files"] == [str(out)] and record["config"]["scenario"] == "static"
    with pytest.raises(SystemExit) as done:
        main(["show", str(out), "-f", "5", "-o", str(tmp_path / "m.png")])
    assert done.value.code == 0 and (tmp_path / "m.png").stat().st_size > 0
    with pytest.raises(SystemExit) as done:
        main(["simulate", "--scenario", "nope", "-o", str(out)])
    assert done.value.code == 2
    sparse = tmp_path / "sp.npz"
    with pytest.raises(SystemExit) as done:
        main(
            [
                "simulate",
                "--frames",
                "20",
                "-o",
                str(sparse),
                "--flow-storage",
                "sparse",
                "--grid",
                "60",
            ]
        )
    assert done.value.code == 0 and load_recording(sparse).meta["flow_storage"] == "sparse"
    with pytest.raises(SystemExit) as done:
        main(["show", str(sparse), "-f", "3", "--grid", "60", "-o", str(tmp_path / "s.png")])
    assert done.value.code == 0


def test_sparse_storage_gives_back_the_dense_flow(tmp_path):
    from dataclasses import replace

    from lidarflow.sim import dense_flow

    dense = simulate(60, seed=9, config=SMALL)
    sparse = simulate(60, seed=9, config=replace(SMALL, flow_storage="sparse"))
    assert "flow_forward" not in sparse.extras and sparse.meta["flow_storage"] == "sparse"
    loaded = load_recording(sparse.save(tmp_path / "sparse.npz"))
    part = loaded.slice(20, 60)
    for t in (0, 17, 38, 39, 59):
        bw, fw = dense_flow(loaded, t)
        np.testing.assert_array_equal(bw, dense.extras["flow_backward"][t].astype(np.float32))
        np.testing.assert_array_equal(fw, dense.extras["flow_forward"][t].astype(np.float32))
        np.testing.assert_array_equal(dense_flow(dense, t)[1], fw)
        if t >= 20:
            np.testing.assert_array_equal(dense_flow(part, t - 20)[1], fw)
    assert sparse.extras["flow_forward_cells"].shape[1] <= sparse.geometry(0).count
    with pytest.raises(SimError, match="flow_storage"):
        replace(SMALL, flow_storage="zip")
