"""Reading bags of every kind, topic choice, odometry, and every bad input."""

from __future__ import annotations

import shutil
import zipfile

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from lidarflow.data import (
    describe_recording,
    find_gaps,
    list_topics,
    load_any,
    mcapfile,
    read_bag,
    sample_bag_path,
    split_segments,
)
from lidarflow.data.mcapfile import McapReader
from lidarflow.errors import BagError, RecordingError
from tests.bagutil import write_bag, write_ros1_mcap


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_every_bag_kind_reads_back_what_was_written(tmp_path, kind):
    frames = [np.linspace(1.0, 5.0, 40) + i * 0.01 for i in range(12)]
    frames[3][5] = np.nan
    path = tmp_path / ("b.bag" if kind == "ros1" else "b")
    write_bag(path, kind, {"/scan": frames}, rate_hz=10.0)
    rec = read_bag(path)
    assert len(rec) == 12
    assert rec.meta["topic"] == "/scan" and rec.meta["frame_id"] == "laser"
    np.testing.assert_allclose(rec.scan(7).ranges, frames[7].astype(np.float32))
    assert np.isnan(rec.scan(3).ranges[5])
    assert rec.frame_rate == pytest.approx(10.0)
    assert rec.geometry(0).count == 40
    assert rec.poses is None


@pytest.mark.parametrize(
    ("kind", "compression"),
    [("ros1", "bz2"), ("ros1", "lz4"), ("sqlite3", "file"), ("sqlite3", "message"),
     ("mcap", "file"), ("mcap", "message")],
)  # fmt: skip
def test_compressed_bags_read_as_plain_ones(tmp_path, kind, compression):
    # rosbag record --lz4 / -j, ros2 bag record --compression-mode file|message (zstd)
    frames = [np.linspace(1.0, 5.0, 40) + i * 0.01 for i in range(12)]
    path = tmp_path / ("b.bag" if kind == "ros1" else "b")
    write_bag(path, kind, {"/scan": frames}, compression=compression)
    if compression == "file":
        assert list(path.glob("*.zstd"))  # the storage file itself compressed
    rec = read_bag(path)
    assert len(rec) == 12
    np.testing.assert_allclose(rec.scan(7).ranges, frames[7].astype(np.float32))


def test_bare_mcap_file_and_db3_file_are_accepted(tmp_path):
    write_bag(tmp_path / "m", "mcap")
    write_bag(tmp_path / "s", "sqlite3")
    assert len(read_bag(next((tmp_path / "m").glob("*.mcap")))) == 25
    assert len(read_bag(next((tmp_path / "s").glob("*.db3")))) == 25
    assert len(read_bag(tmp_path / "s" / "metadata.yaml")) == 25  # its folder's description


@pytest.mark.parametrize("compression", ["", "lz4", "zstd", None])
def test_mcap_of_ros1_messages_reads_as_the_bag_it_came_from(tmp_path, compression):
    # `mcap convert x.bag x.mcap` keeps ROS 1 serialisation, which rosbags cannot read.
    rng = np.random.default_rng(1)
    frames = [rng.uniform(0.3, 7.0, 60) for _ in range(15)]
    frames[4][7] = np.inf
    bag = read_bag(write_bag(tmp_path / "a.bag", "ros1", {"/scan": frames}, odom=True,
                             mount=(0.3, -0.1, 0.4)))  # fmt: skip
    mcap = tmp_path / "a.mcap"
    write_ros1_mcap(mcap, frames, odom=True, mount=(0.3, -0.1, 0.4), compression=compression)
    rec = read_bag(mcap)
    np.testing.assert_array_equal(rec.ranges, bag.ranges)
    np.testing.assert_array_equal(rec.stamps_ns, bag.stamps_ns)
    np.testing.assert_allclose(rec.poses, bag.poses)
    assert rec.meta["sensor_mount"] == bag.meta["sensor_mount"] == [0.3, -0.1, 0.4]
    assert rec.meta["frame_id"] == "laser" and rec.meta["pose_topic"] == "/odom"
    assert list_topics(mcap) == list_topics(tmp_path / "a.bag")


@pytest.mark.parametrize("compression", ["lz4", None])
def test_ros1_mcap_with_a_summary_opens_from_it(tmp_path, monkeypatch, compression):
    rng = np.random.default_rng(2)
    frames = [rng.uniform(0.3, 7.0, 40) for _ in range(12)]
    kw = {"odom": True, "mount": (0.3, -0.1, 0.4), "compression": compression}
    plain = read_bag(write_ros1_mcap(tmp_path / "plain.mcap", frames, **kw))
    path = write_ros1_mcap(tmp_path / "summary.mcap", frames, summary=True, **kw)
    rec = read_bag(path)
    np.testing.assert_array_equal(rec.ranges, plain.ranges)
    np.testing.assert_allclose(rec.poses, plain.poses)
    assert rec.meta["sensor_mount"] == plain.meta["sensor_mount"]
    assert list_topics(path) == list_topics(tmp_path / "plain.mcap")
    # Opening takes the channels and counts from the summary alone, without a pass over the
    # data section (the pass a file without a summary needs).
    typestore = get_typestore(Stores.ROS1_NOETIC)
    with monkeypatch.context() as patch:
        patch.setattr(mcapfile._DataSection, "__iter__", _no_data_pass)
        reader = McapReader(path, "ros1", typestore)
        counts = {c.topic: c.msgcount for c in reader.connections}
        with pytest.raises(AssertionError, match="data section"):
            McapReader(tmp_path / "plain.mcap", "ros1", typestore)
    assert counts == {"/scan": 12, "/odom": 25, "/tf": 1}
    assert reader.recovered is None
    plain_counts = McapReader(tmp_path / "plain.mcap", "ros1", typestore).connections
    assert counts == {c.topic: c.msgcount for c in plain_counts}
    # a ROS 1 bag writer copying these connections needs their types' MD5 sums
    digests = {c.topic: c.digest for c in plain_counts}
    assert digests["/scan"] == "90c7ef2dc6895d81024acba2ac42f369"


def _no_data_pass(self):
    raise AssertionError("read the data section")


def test_zipped_bag(tmp_path):
    bag = write_bag(tmp_path / "z.bag", "ros1")
    with zipfile.ZipFile(tmp_path / "z.bag.zip", "w") as zf:
        zf.write(bag, "z.bag")
    assert len(read_bag(tmp_path / "z.bag.zip")) == 25


def test_odometry_is_interpolated_at_scan_stamps(tmp_path):
    path = write_bag(tmp_path / "o.bag", "ros1", odom=True)
    rec = read_bag(path)
    assert rec.meta["pose_topic"] == "/odom" and rec.has_poses
    # odometry: x = 0.05 i at t0 + i * period / 2, so x = 0.1 k at scan k
    np.testing.assert_allclose(rec.poses[:, 0], 0.1 * np.arange(25), atol=1e-9)
    np.testing.assert_allclose(rec.poses[:, 2], 0.02 * np.arange(25), atol=1e-9)


def test_of_several_odometry_topics_the_fused_one_is_read_and_the_choice_said(tmp_path):
    # Robots commonly record wheel odometry beside robot_localization's fused estimate; with
    # no topic named, poses were silently dropped.
    topics = ["/odom", "/odometry/filtered", "/wheel/odom"]
    rec = read_bag(write_bag(tmp_path / "o.bag", "ros1", odom=topics))
    assert rec.meta["pose_topic"] == "/odometry/filtered" and rec.has_poses
    np.testing.assert_allclose(rec.poses[:, 0], 0.2 * np.arange(25), atol=1e-9)  # 2x as fast
    assert rec.meta["pose_topic_choice"] == (
        "/odometry/filtered chosen over /odom, /wheel/odom; --odom-topic to pick another"
    )
    assert describe_recording(rec)["pose_topic_choice"] == rec.meta["pose_topic_choice"]
    rec = read_bag(write_bag(tmp_path / "w.bag", "ros1", odom=["/a/odom", "/b"]))
    assert rec.meta["pose_topic"] == "/a/odom"
    chosen = read_bag(tmp_path / "w.bag", odom_topic="/b")
    assert chosen.meta["pose_topic"] == "/b" and "pose_topic_choice" not in chosen.meta
    single = read_bag(write_bag(tmp_path / "s.bag", "ros1", odom=True))
    assert "pose_topic_choice" not in single.meta


def test_a_simulator_clock_starting_at_zero_keeps_its_first_stamp(tmp_path):
    # Sim time starts at 0: a first scan stamped 0.0 is the first instant, not an unset stamp
    # (taken for one, its wall-clock log time read as a 54-year clock jump).
    sim = [i * 100_000_000 for i in range(25)]
    rec = read_bag(write_bag(tmp_path / "sim.bag", "ros1", header_stamps=sim))
    assert rec.stamps_ns.tolist() == sim
    assert not rec.meta["clock_jumps"] and find_gaps(rec) == []
    # a later zero on that clock is an unset stamp: the stamps around it stand in
    unset = [*sim[:12], 0, *sim[13:]]
    rec = read_bag(write_bag(tmp_path / "unset.bag", "ros1", header_stamps=unset))
    assert rec.stamps_ns.tolist() == sim
    assert not rec.meta["clock_jumps"] and find_gaps(rec) == []
    # on a wall clock a zero stamp is a driver's unset one: its log time stands in
    wall = [1_700_000_000 * 10**9 + s for s in sim]
    wall[3] = 0
    rec = read_bag(write_bag(tmp_path / "wall.bag", "ros1", header_stamps=wall))
    assert rec.stamps_ns[3] == 1_700_000_000 * 10**9 + sim[3]
    assert not rec.meta["clock_jumps"] and find_gaps(rec) == []


def test_of_several_scan_topics_one_is_read_and_the_choice_said(tmp_path):
    # `lidarflow evaluate SOME.bag` works on any bag as it is (design notes, section 9)
    path = write_bag(
        tmp_path / "two.bag", "ros1", {"/front": [np.ones(10)] * 3, "/rear": [np.ones(10)] * 4}
    )
    rec = read_bag(path)  # neither is named scan: the busiest
    assert rec.meta["topic"] == "/rear" and len(rec) == 4
    assert rec.meta["topic_choice"] == "/rear chosen over /front; --topic to pick another"
    assert describe_recording(rec)["topic_choice"] == rec.meta["topic_choice"]
    named = write_bag(
        tmp_path / "s.bag",
        "ros1",
        {"/scan": [np.ones(10)] * 3, "/scan_filtered": [np.ones(10)] * 4},
    )
    assert read_bag(named).meta["topic"] == "/scan"  # REP 105's name first
    chosen = read_bag(path, topic="/front")
    assert len(chosen) == 3 and "topic_choice" not in chosen.meta
    with pytest.raises(BagError, match=r"no topic /side; scan topics here: /front, /rear"):
        read_bag(path, topic="/side")


def test_a_multi_echo_scan_is_read_as_each_beams_nearest_echo(tmp_path):
    # Cartographer's backpack recordings hold MultiEchoLaserScan topics and no LaserScan
    beams = [[2.0, 3.5], [np.inf], [], [0.01, 4.0], [np.nan], [0.0], [9.0, 7.0]]
    path = write_bag(tmp_path / "e.bag", "ros1", scans={}, echoes=[beams] * 12)
    rec = read_bag(path)
    assert rec.meta["topic"] == "/horizontal_laser_2d" and len(rec) == 12
    np.testing.assert_array_equal(  # below range_min (0.05) and 0 are no surface met
        rec.scan(0).ranges, np.array([2.0, np.inf, np.nan, 4.0, np.nan, np.nan, 7.0], np.float32)
    )
    assert describe_recording(rec)["scan_type"].startswith("MultiEchoLaserScan")
    # beside a LaserScan topic it is no second choice, unless named
    both = write_bag(tmp_path / "b.bag", "ros1", echoes=[beams] * 12)
    assert read_bag(both).meta["topic"] == "/scan"
    assert read_bag(both, topic="/horizontal_laser_2d").meta["scan_type"]


def test_which_scan_topic_is_read_among_laserscan_and_multi_echo_ones(tmp_path):
    beams = [[2.0, 3.5]] * 20
    # a busier multi-echo topic beside a LaserScan one not named scan: still no choice to make
    rec = read_bag(write_bag(tmp_path / "a.bag", "ros1", {"/front": [np.ones(20)] * 12},
                             echoes=[beams] * 20))  # fmt: skip
    assert rec.meta["topic"] == "/front" and "topic_choice" not in rec.meta
    # a LaserScan topic subscribed to and never published on is none either
    rec = read_bag(write_bag(tmp_path / "b.bag", "ros1", {"/scan": []}, echoes=[beams] * 12))
    assert rec.meta["topic"] == "/horizontal_laser_2d"
    # Cartographer's backpack: the horizontal scanner, not the busier vertical one
    both = {"/horizontal_laser_2d": [beams] * 12, "/vertical_laser_2d": [beams] * 14}
    rec = read_bag(write_bag(tmp_path / "c.bag", "ros1", {}, echoes=both))
    assert (
        rec.meta["topic"] == "/horizontal_laser_2d"
        and "/vertical_laser_2d" in (rec.meta["topic_choice"])
    )


def test_a_chosen_topic_with_nothing_in_it_names_the_others(tmp_path):
    path = write_bag(
        tmp_path / "e.bag", "ros1", {"/a": [np.zeros(0)] * 20, "/b": [np.ones(10)] * 12}
    )
    with pytest.raises(BagError, match=r"/a holds no non-empty scans \(/a chosen over /b; --topic"):
        read_bag(path)
    assert len(read_bag(path, topic="/b")) == 12


def test_no_laserscan_topic(tmp_path):
    path = write_bag(tmp_path / "none.bag", "ros1", scans={}, extra_string_topic=True)
    with pytest.raises(BagError, match=r"no sensor_msgs/LaserScan \(or MultiEchoLaserScan\) topic"):
        read_bag(path)
    with pytest.raises(BagError, match=r"/chatter is std_msgs/msg/String, not a LaserScan"):
        read_bag(path, topic="/chatter")


def test_empty_scans(tmp_path):
    path = write_bag(tmp_path / "empty.bag", "ros1", {"/scan": [np.zeros(0)] * 5})
    with pytest.raises(BagError, match="holds no non-empty scans"):
        read_bag(path)


def test_missing_file_and_not_a_bag(tmp_path):
    with pytest.raises(BagError, match="no such file"):
        load_any(tmp_path / "nope.bag")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(BagError, match="not a bag"):
        read_bag(tmp_path / "notes.txt")
    with pytest.raises(RecordingError, match="no such file"):
        load_any(tmp_path / "nope.npz")


@pytest.mark.parametrize("keep", [20, 3000])
def test_a_bag_cut_before_its_first_message_is_a_clear_error(tmp_path, keep):
    # a bag cut short is read up to its last intact message (tests/data/test_cut_bags.py);
    # one cut in its header record holds none
    broken = tmp_path / "broken.bag"
    broken.write_bytes(sample_bag_path().read_bytes()[:keep])
    with pytest.raises(BagError, match=r"broken\.bag: cannot open as a bag"):
        read_bag(broken)


def test_garbage_bag_is_a_clear_error(tmp_path):
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"#ROSBAG V2.0\n" + bytes(range(256)) * 40)
    with pytest.raises(BagError, match=r"junk\.bag"):
        read_bag(junk)
    folder = tmp_path / "ros2"
    folder.mkdir()
    with pytest.raises(BagError, match="cannot open"):
        read_bag(folder)


def test_real_sample_converts(sample_recording):
    rec = sample_recording
    assert len(rec) == 243
    assert rec.meta["topic"] == "right_scan" and rec.meta["frame_id"] == "right_laser"
    assert rec.geometry(0).count == 768
    assert rec.frame_rate == pytest.approx(7.5, abs=0.1)
    occ, vis = rec.maps()
    assert occ.shape == (243, 100, 100)
    assert 50 < occ.sum(axis=(1, 2)).mean() < 2000
    assert (vis | ~occ).all()


def test_topics_of_the_sample():
    topics = list_topics(sample_bag_path())
    assert [(t.topic, t.msgtype) for t in topics] == [("right_scan", "sensor_msgs/msg/LaserScan")]


def test_copying_a_folder_bag_keeps_it_readable(tmp_path):
    src = write_bag(tmp_path / "a", "sqlite3")
    shutil.copytree(src, tmp_path / "b")
    assert len(read_bag(tmp_path / "b")) == 25


def test_a_topic_is_found_with_or_without_its_leading_slash(tmp_path):
    # ROS 1 bags may name a topic `right_scan` (as the development bags do) where a user types
    # `/right_scan`, and ROS 2 bags `/scan` where a user types `scan`
    path = write_bag(
        tmp_path / "two.bag", "ros1", {"right_scan": [np.ones(10)] * 3, "/rear": [np.ones(10)] * 4}
    )
    assert read_bag(path, topic="/right_scan").meta["topic"] == "right_scan"
    assert read_bag(path, topic="rear/").meta["topic"] == "/rear"
    with pytest.raises(BagError, match="no topic /side"):
        read_bag(path, topic="/side")


@pytest.mark.parametrize("kind", ["ros1", "sqlite3", "mcap"])
def test_an_unpublished_scan_topic_is_no_choice(tmp_path, kind):
    # a ROS 2 bag lists every topic it subscribed to, messages or not
    name = "u.bag" if kind == "ros1" else "u"
    path = write_bag(tmp_path / name, kind, {"/scan": [np.ones(10)] * 3, "/scan_filtered": []})
    assert read_bag(path).meta["topic"] == "/scan"


def test_a_scan_recorded_twice_is_read_once(tmp_path):
    frames = [np.full(10, 2.0 + 0.1 * i) for i in range(5)]
    rec = read_bag(write_bag(tmp_path / "d.bag", "ros1", {"/scan": frames}, copies=2))
    assert len(rec) == 5 and rec.meta["duplicate_scans_dropped"] == 5
    assert rec.meta["empty_scans_dropped"] == 0
    # ... and `info` says so
    dropped = describe_recording(rec)["scans_dropped"]
    assert dropped == {"empty": 0, "duplicate": 5, "malformed": 0}
    plain = describe_recording(read_bag(write_bag(tmp_path / "o.bag", "ros1")))
    assert "scans_dropped" not in plain and "stamps" not in plain
    np.testing.assert_array_equal(rec.scan(4).ranges, frames[4].astype(np.float32))


def test_a_malformed_scan_is_dropped_not_the_recording(tmp_path):
    frames = [np.full(10, 2.0)] * 6
    glitch = {0: {"angle_increment": 0.0}, 3: {"range_max": float("nan")}}
    rec = read_bag(write_bag(tmp_path / "g.bag", "ros1", {"/scan": frames}, overrides=glitch))
    assert len(rec) == 4 and rec.meta["malformed_scans_dropped"] == 2
    assert rec.meta["empty_scans_dropped"] == 0
    every = {i: {"range_max": -1.0} for i in range(6)}
    path = write_bag(tmp_path / "b.bag", "ros1", {"/scan": frames}, overrides=every)
    with pytest.raises(BagError, match=r"every scan is a malformed LaserScan.*range_max=-1"):
        read_bag(path)


def test_a_ros2_folder_without_its_metadata(tmp_path):
    # `ros2 bag record` writes metadata.yaml last: an interrupted recording's MCAP file still
    # reads on its own; any other folder is named for what it lacks
    shutil.copytree(write_bag(tmp_path / "m", "mcap"), tmp_path / "cut")
    (tmp_path / "cut" / "metadata.yaml").unlink()
    assert len(read_bag(tmp_path / "cut")) == 25
    (tmp_path / "notes").mkdir()
    with pytest.raises(BagError, match=r"a folder with no metadata\.yaml is no ROS 2 bag"):
        read_bag(tmp_path / "notes")


def test_header_stamps_that_never_advance_give_way_to_log_times(tmp_path):
    frames = [np.full(10, 2.0 + 0.1 * i) for i in range(12)]
    stuck = [1_600_000_000 * 10**9] * 12  # a driver that stamps every scan alike
    rec = read_bag(write_bag(tmp_path / "s.bag", "ros1", {"/scan": frames}, odom=True,
                             header_stamps=stuck))  # fmt: skip
    assert rec.meta["stamps"].startswith("log time") and rec.frame_rate == pytest.approx(10.0)
    assert describe_recording(rec)["stamps"].startswith("log time")  # `info` says so
    np.testing.assert_array_equal(rec.scan(11).ranges, frames[11].astype(np.float32))
    np.testing.assert_allclose(rec.poses[:, 0], 0.1 * np.arange(12), atol=1e-9)  # not one pose
    rec = read_bag(write_bag(tmp_path / "h.bag", "ros1", {"/scan": frames}))
    assert rec.meta["stamps"] == "header"


T0, PERIOD = 1_700_000_000 * 10**9, 100_000_000  # write_bag's first log time and 10 Hz period


def _written(rec, frames) -> list[int]:
    """Which of the written ``frames`` each frame of ``rec`` is (each frame's ranges differ)."""
    keys = [float(np.float32(f[0])) for f in frames]
    return [keys.index(float(rec.scan(i).ranges[0])) for i in range(len(rec))]


def _restarted(at: int, back: int):
    """A header clock that goes back ``back`` periods from scan ``at``'s log time on."""
    return lambda t: t - back * PERIOD if t >= T0 + at * PERIOD else t


@pytest.mark.parametrize("kind", ["ros1", "mcap"])
def test_sessions_whose_header_clocks_overlap_read_one_after_the_other(tmp_path, kind):
    # a simulator's /clock reset (or two sessions in one bag): at scan 12 the header clock goes
    # back 10 periods, so sessions overlap; sorted by header stamp they would alternate
    frames = [np.full(10, 1.0 + 0.1 * i) for i in range(24)]
    headers = [T0 + i * PERIOD for i in range(24)]
    headers[15], headers[16] = headers[16], headers[15]  # and jitter inside session 2
    path = tmp_path / ("j.bag" if kind == "ros1" else "j")
    rec = read_bag(write_bag(path, kind, {"/scan": frames}, header_stamps=headers,
                             clock=_restarted(12, 10)))  # fmt: skip
    assert _written(rec, frames) == [*range(15), 16, 15, *range(17, 24)]
    np.testing.assert_array_equal(rec.stamps_ns[:12], T0 + PERIOD * np.arange(12))  # kept
    # the second session keeps its header steps and follows the first after a 1 s gap
    np.testing.assert_array_equal(np.diff(rec.stamps_ns[12:]), PERIOD)
    assert rec.stamps_ns[12] - rec.stamps_ns[11] == 10 * PERIOD
    assert find_gaps(rec) == [(12, 1.0)] and split_segments(rec) == [(0, 12), (12, 24)]
    assert rec.frame_rate == pytest.approx(10.0)
    jump = {"before_frame": 12, "back_s": 0.9, "shift_s": 1.9, "shift_ns": 1_900_000_000}
    assert rec.meta["clock_jumps"] == [jump] and rec.meta["stamps"] == "header"
    assert describe_recording(rec)["clock_jumps"] == [jump]  # `info` says so


def test_a_simulator_replaying_itself_after_a_clock_reset_is_not_a_duplicate(tmp_path):
    # noise-free and standing still: after /clock goes back to the start, the same scans come
    # with the same stamps a session later; copies of one message come together
    frames = [np.full(10, 1.0 + 0.1 * (i % 12)) for i in range(24)]
    headers = [T0 + (i % 12) * PERIOD for i in range(24)]
    rec = read_bag(write_bag(tmp_path / "r.bag", "ros1", {"/scan": frames}, header_stamps=headers))
    assert len(rec) == 24 and rec.meta["duplicate_scans_dropped"] == 0
    assert [j["before_frame"] for j in rec.meta["clock_jumps"]] == [12]


def test_a_slice_keeps_the_bags_own_stamps_where_its_clock_went_back(tmp_path):
    from lidarflow.data.sessions import recorded_stamps

    frames = [np.full(10, 1.0 + 0.1 * i) for i in range(24)]
    rec = read_bag(write_bag(tmp_path / "j.bag", "ros1", {"/scan": frames},
                             clock=_restarted(12, 10)))  # fmt: skip
    bag_stamps = recorded_stamps(rec.stamps_ns, rec.meta["clock_jumps"])
    for start, stop in ((4, 20), (14, 24), (0, 12)):
        part = rec.slice(start, stop)
        got = recorded_stamps(part.stamps_ns, part.meta["clock_jumps"])
        np.testing.assert_array_equal(got, bag_stamps[start:stop])


def test_header_stamps_that_jitter_keep_header_order(tmp_path):
    # a multi-connection bag: arrival order differs from header order by a few frames
    frames = [np.full(10, 1.0 + 0.1 * i) for i in range(20)]
    shuffled = [0, 2, 1, 3, 4, 7, 5, 6, 8, 9, 10, 14, 11, 12, 13, 15, 16, 17, 19, 18]
    headers = [T0 + k * PERIOD for k in shuffled]
    rec = read_bag(write_bag(tmp_path / "j.bag", "ros1", {"/scan": frames}, header_stamps=headers))
    assert [shuffled[i] for i in _written(rec, frames)] == list(range(20))
    np.testing.assert_array_equal(rec.stamps_ns, T0 + PERIOD * np.arange(20))
    assert rec.meta["clock_jumps"] == [] and "clock_jumps" not in describe_recording(rec)


def test_odometry_whose_clock_jumps_with_the_scans_keeps_matching_them(tmp_path):
    frames = [np.full(10, 1.0 + 0.1 * i) for i in range(24)]
    path = write_bag(tmp_path / "o.bag", "ros1", {"/scan": frames}, odom=True,
                     clock=_restarted(12, 10))  # fmt: skip
    rec = read_bag(path)
    assert _written(rec, frames) == list(range(24))
    # odometry: x = 0.05 i at log time t0 + i * period / 2, so x = 0.1 k at scan k
    np.testing.assert_allclose(rec.poses[:, 0], 0.1 * np.arange(24), atol=1e-9)
    assert rec.meta["clock_jumps"] == [
        {
            "before_frame": 12,
            "back_s": 0.9,
            "shift_s": 1.9,
            "shift_ns": 1_900_000_000,
            "poses_matched": True,
        }
    ]


def test_odometry_whose_clock_does_not_jump_gives_no_poses_after_the_jump(tmp_path):
    # only the scanner's clock went back (a driver restart stamping with its own clock): its
    # later stamps say nothing about which odometry was then; no poses beat wrong ones
    frames = [np.full(10, 1.0 + 0.1 * i) for i in range(24)]
    headers = [_restarted(12, 10)(T0 + i * PERIOD) for i in range(24)]
    rec = read_bag(write_bag(tmp_path / "o.bag", "ros1", {"/scan": frames}, odom=True,
                             header_stamps=headers))  # fmt: skip
    assert _written(rec, frames) == list(range(24))
    np.testing.assert_allclose(rec.poses[:12, 0], 0.1 * np.arange(12), atol=1e-9)
    assert np.isnan(rec.poses[12:]).all()
    assert rec.meta["clock_jumps"][0]["poses_matched"] is False
    assert describe_recording(rec)["clock_jumps"][0]["poses_matched"] is False


def test_pose_of_reads_the_planar_pose_of_odometry_and_pose_stamped():
    from types import SimpleNamespace as Ns

    from lidarflow.data.poses import pose_of

    yaw = 0.7
    q = Ns(x=0.0, y=0.0, z=float(np.sin(yaw / 2)), w=float(np.cos(yaw / 2)))
    pose = Ns(position=Ns(x=1.5, y=-2.0, z=9.0), orientation=q)
    odometry = Ns(pose=Ns(pose=pose, covariance=[0.0] * 36))  # nav_msgs/Odometry
    stamped = Ns(pose=pose)  # geometry_msgs/PoseStamped
    for msg in (odometry, stamped):
        x, y, theta = pose_of(msg)
        assert (x, y) == (1.5, -2.0) and theta == pytest.approx(yaw)
