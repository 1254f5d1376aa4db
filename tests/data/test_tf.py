"""The scanner's mount from TF: odometry poses of the base become poses of the scan frame."""

from __future__ import annotations

import math

import numpy as np

from lidarflow.data import read_bag
from lidarflow.data.tf import TransformTree, compose_poses
from lidarflow.motion.odometry import relative_motions
from lidarflow.sim.platform import compose, relative
from tests.bagutil import _tf_msg, write_bag


def test_poses_are_moved_to_the_scan_frame_through_the_tf_chain(tmp_path):
    mount = (0.85, 0.23, 0.73)
    base = read_bag(write_bag(tmp_path / "base.bag", "ros1", odom=True))
    rec = read_bag(write_bag(tmp_path / "mounted.bag", "ros1", odom=True, mount=mount))
    assert base.meta["sensor_mount"] is None  # odometry but no TF: the base's poses, said so
    np.testing.assert_allclose(rec.meta["sensor_mount"], mount, atol=1e-6)
    for i in (0, 7, 24):
        np.testing.assert_allclose(rec.poses[i], compose(base.poses[i], np.array(mount)), atol=1e-9)
    # the sensor's own motion: the base's increment seen from the mount (lever arm included)
    sensor, known = relative_motions(rec.poses)
    base_motion, _ = relative_motions(base.poses)
    m = np.array(mount)
    expected = relative(m, compose(base_motion[5], m))
    np.testing.assert_allclose(sensor[5], expected, atol=1e-9)
    assert known[1:].all()


def test_mount_walks_up_the_tree_and_reports_unconnected_frames():
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    tree = TransformTree()
    tree.add(_tf_msg(ts, 1, [("/base", "a", (1.0, 0.0, math.pi / 2))]))
    tree.add(_tf_msg(ts, 2, [("a", "b", (1.0, 0.0, 0.0)), ("/base", "a", (9.0, 9.0, 0.0))]))
    np.testing.assert_allclose(tree.mount("base", "b")[0], (1.0, 1.0, math.pi / 2), atol=1e-6)
    np.testing.assert_allclose(tree.mount("base", "base")[0], (0.0, 0.0, 0.0))
    assert tree.mount("b", "base") is None and tree.mount("base", "nowhere") is None
    assert np.isnan(compose_poses(np.full((1, 3), np.nan), (1.0, 0.0, 0.0))).all()


def test_convert_and_info_say_when_the_poses_are_not_the_scanners(tmp_path, capsys):
    from tests.test_cli import run

    for name, mount in (("base", None), ("mounted", (0.85, 0.23, 0.73))):
        bag = write_bag(tmp_path / f"{name}.bag", "ros1", odom=True, mount=mount)
        code, out, err = run(["convert", str(bag), "-o", str(tmp_path / f"{name}.npz")], capsys)
        assert code == 0, err
        assert ("no TF to the scanner" in out) is (mount is None) and "with poses" in out
        code, out, _ = run(["info", str(bag)], capsys)
        assert code == 0 and ("sensor_mount: None" in out) is (mount is None)


def test_a_scanner_mounted_upside_down_moves_mirrored(tmp_path):
    # under a platform, rolled 180 degrees: its y axis is the base's flipped, so when the base
    # turns left the scanner sees itself turn right; the upright mount's motions, mirrored
    from lidarflow.data.tf import mirrored

    upright = read_bag(write_bag(tmp_path / "u.bag", "ros1", odom=True, mount=(0.3, 0.1, 0.5)))
    flipped = read_bag(
        write_bag(tmp_path / "f.bag", "ros1", odom=True, mount=(0.3, 0.1, 0.5, math.pi))
    )
    assert flipped.meta["sensor_upside_down"] and "sensor_upside_down" not in upright.meta
    np.testing.assert_allclose(
        flipped.meta["sensor_mount"], upright.meta["sensor_mount"], atol=1e-6
    )
    up, _ = relative_motions(upright.poses)
    down, _ = relative_motions(flipped.poses)
    np.testing.assert_allclose(down[1:], mirrored(up[1:]), atol=1e-9)
    assert (np.sign(down[1:, 2]) == -np.sign(up[1:, 2])).all()  # the odometry turns left


def test_a_flipped_link_mirrors_what_lies_below_it():
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    tree = TransformTree()
    tree.add(_tf_msg(ts, 1, [("base", "under", (1.0, 0.0, 0.0, math.pi)),
                             ("under", "a", (0.0, 1.0, math.pi / 2)),
                             ("a", "b", (0.0, 0.0, 0.0, math.pi))]))  # fmt: skip
    pose, flipped = tree.mount("base", "a")
    # a's y offset of 1 and its quarter turn left are, seen from the base, to the right
    np.testing.assert_allclose(pose, (1.0, -1.0, -math.pi / 2), atol=1e-9)
    assert flipped
    pose, flipped = tree.mount("base", "b")  # flipped twice: upright again
    np.testing.assert_allclose(pose, (1.0, -1.0, -math.pi / 2), atol=1e-9)
    assert not flipped
    assert tree.mount("base", "nowhere") is None
