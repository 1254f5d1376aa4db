"""Bags cut short (a robot that lost power, a writer stopped early) read up to their last intact
message: ROS 1 bags without their index, MCAP files (ROS 1 and ROS 2) without their summary."""

from __future__ import annotations

import re
import shutil
import struct

import numpy as np
import pytest
import rosbags.rosbag1
from rosbags.typesys import Stores, get_typestore

from lidarflow.data import load_recording, read_bag, sample_bag_path
from lidarflow.data.mcapfile import McapReader
from lidarflow.data.ros1bag import Ros1BagSequentialReader
from lidarflow.data.sources import topic_notes
from lidarflow.errors import BagError
from tests.bagutil import write_bag, write_ros1_mcap
from tests.test_cli import run


def _cut(source, path, keep):
    """A copy of ``source`` holding its first ``keep`` bytes (or that share of them)."""
    data = source.read_bytes()
    path.write_bytes(data[: keep if isinstance(keep, int) else int(len(data) * keep)])
    return path


def _assert_prefix(cut, whole):
    """The cut recording's scans are the whole one's first scans, identical."""
    n = len(cut)
    assert 0 < n <= len(whole)
    np.testing.assert_array_equal(cut.stamps_ns, whole.stamps_ns[:n])
    np.testing.assert_array_equal(cut.offsets, whole.offsets[: n + 1])
    np.testing.assert_array_equal(cut.ranges, whole.ranges[: cut.offsets[-1]])
    np.testing.assert_array_equal(cut.angle_increment, whole.angle_increment[:n])


def _scans_in_note(note):
    return int(re.search(r"read (\d+) scans", note).group(1))


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    return read_bag(sample_bag_path())


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.97])
def test_a_ros1_bag_cut_short_reads_up_to_its_last_intact_message(tmp_path, sample, keep):
    # the sample is one uncompressed chunk: every cut is mid-chunk
    rec = read_bag(_cut(sample_bag_path(), tmp_path / "cut.bag", keep))
    _assert_prefix(rec, sample)
    # what is lost is at most the message the file ends in
    assert len(rec) >= int(keep * len(sample)) - 2
    note = rec.meta["recovered"]
    assert note.startswith("cut short; read") and _scans_in_note(note) == len(rec)
    # the header's index position says how large the bag was: the estimate is near the truth
    whole = int(re.search(r"of ~(\d+) in the whole recording", note).group(1))
    assert abs(whole - len(sample)) <= 3
    assert "unreadable" in note


def test_a_cut_inside_a_message_loses_that_message_only(tmp_path, sample):
    store = get_typestore(Stores.ROS1_NOETIC)
    cut = _cut(sample_bag_path(), tmp_path / "a.bag", 0.6)
    end = Ros1BagSequentialReader(cut, store).recovered.read_to  # where its last message ends
    at_end = read_bag(_cut(sample_bag_path(), tmp_path / "b.bag", end))
    inside = read_bag(_cut(sample_bag_path(), tmp_path / "c.bag", end - 1))
    assert len(inside) == len(at_end) - 1
    _assert_prefix(at_end, sample)
    _assert_prefix(inside, sample)
    assert "unreadable" not in at_end.meta["recovered"]  # nothing after its last message


def test_a_bag_its_writer_never_closed_reads_whole(tmp_path, sample):
    # `rosbag record` killed: the data is all there, the index never written (index_pos 0)
    data = bytearray(sample_bag_path().read_bytes())
    at = data.index(b"index_pos=") + len(b"index_pos=")
    index_pos = struct.unpack_from("<Q", data, at)[0]
    data[at : at + 8] = bytes(8)
    path = tmp_path / "open.bag"
    path.write_bytes(bytes(data[:index_pos]))
    rec = read_bag(path)
    _assert_prefix(rec, sample)
    assert len(rec) == len(sample)
    note = rec.meta["recovered"]
    assert note.startswith(f"never closed by its writer (no index); read {len(rec)} scans")


class _SmallChunks(rosbags.rosbag1.Writer):
    """rosbags' ROS 1 writer closing a chunk every 4 kB (``rosbag record`` closes one every
    768 kB), so that a small bag has many."""

    def __init__(self, path):
        super().__init__(path)
        self.chunk_threshold = 4096


@pytest.mark.parametrize("compression", ["bz2", "lz4", None])
def test_a_compressed_ros1_bag_cut_short_reads_its_intact_chunks(
    tmp_path, monkeypatch, compression
):
    monkeypatch.setattr(rosbags.rosbag1, "Writer", _SmallChunks)
    rng = np.random.default_rng(3)
    frames = [rng.uniform(0.3, 7.0, 300) for _ in range(120)]
    bag = write_bag(tmp_path / "w.bag", "ros1", {"/scan": frames}, compression=compression)
    whole = read_bag(bag)
    for keep in (0.5, 0.9):
        rec = read_bag(_cut(bag, tmp_path / "cut.bag", keep))
        _assert_prefix(rec, whole)
        assert len(rec) >= int(keep * 120) - 6  # a chunk holds 3 or 4 scans
        assert _scans_in_note(rec.meta["recovered"]) == len(rec)


def test_a_cut_bag_keeps_its_connections_as_rosbags_reads_them(tmp_path):
    # what a writer that copies the input's topics needs: types, definitions, MD5 sums
    from rosbags.highlevel import AnyReader

    store = get_typestore(Stores.ROS1_NOETIC)
    cut = Ros1BagSequentialReader(_cut(sample_bag_path(), tmp_path / "c.bag", 0.5), store)
    with AnyReader([sample_bag_path()], default_typestore=store) as whole:
        (expected,) = whole.connections
        (conn,) = cut.connections
        assert (conn.topic, conn.msgtype, conn.digest) == (
            expected.topic, expected.msgtype, expected.digest)  # fmt: skip
        assert conn.msgdef == expected.msgdef and conn.ext == expected.ext
        raw = next(iter(cut.messages()))[2]
        first = next(iter(whole.messages()))
        assert raw == first[2] and next(iter(cut.messages()))[1] == first[1]
        assert cut.deserialize(raw, conn.msgtype).header.frame_id == "right_laser"


@pytest.mark.parametrize("compression", ["", "lz4", "zstd", None])
@pytest.mark.parametrize("keep", [0.5, 0.9])
def test_a_ros1_mcap_cut_short_reads_up_to_its_last_intact_message(tmp_path, compression, keep):
    rng = np.random.default_rng(4)
    frames = [rng.uniform(0.3, 7.0, 400) for _ in range(150)]  # several lz4 / zstd blocks
    kw = {"odom": True, "mount": (0.3, -0.1, 0.4), "compression": compression}
    path = write_ros1_mcap(tmp_path / "w.mcap", frames, summary=True, **kw)
    whole = read_bag(path)
    assert "recovered" not in whole.meta
    rec = read_bag(_cut(path, tmp_path / "cut.mcap", keep))
    _assert_prefix(rec, whole)
    # a compressed chunk cut short reads as far as its blocks decompress (64 kB of lz4 is 40
    # scans, 128 kB of zstd 80); an uncompressed one to the message it ends in
    assert len(rec) >= int(keep * 150) - (2 if not compression else 85)
    assert rec.meta["sensor_mount"] == [0.3, -0.1, 0.4]
    assert rec.meta["recovered"].startswith("cut short; read")
    assert _scans_in_note(rec.meta["recovered"]) == len(rec)


def test_an_mcap_cut_before_its_first_message_is_a_clear_error(tmp_path):
    path = write_ros1_mcap(tmp_path / "w.mcap", [np.full(50, 2.0)] * 5, compression=None)
    with pytest.raises(BagError, match=r"cut\.mcap: cannot open as a bag"):
        read_bag(_cut(path, tmp_path / "cut.mcap", 40))
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(bytes(range(256)) * 20)
    with pytest.raises(BagError, match=r"junk\.mcap: not an MCAP file"):
        read_bag(junk)


@pytest.mark.parametrize("compression", [None, "message"])
@pytest.mark.parametrize("keep", [0.5, 0.9])
def test_a_ros2_mcap_cut_short_reads_up_to_its_last_intact_message(tmp_path, keep, compression):
    # "message": `ros2 bag record --compression-mode message`, each message zstd on its own
    rng = np.random.default_rng(5)
    frames = [rng.uniform(0.3, 7.0, 300) for _ in range(150)]
    folder = write_bag(tmp_path / "w", "mcap", {"/scan": frames}, compression=compression)
    whole = read_bag(folder)
    (mcap,) = folder.glob("*.mcap")
    # the bare file, its folder with its metadata.yaml, and the folder without (as `ros2 bag
    # record` leaves one it could not close)
    cut_file = _cut(mcap, tmp_path / "cut.mcap", keep)
    with_metadata = shutil.copytree(folder, tmp_path / "with")
    _cut(mcap, next(with_metadata.glob("*.mcap")), keep)
    without = shutil.copytree(with_metadata, tmp_path / "without")
    (without / "metadata.yaml").unlink()
    for path in (cut_file, with_metadata, without):
        rec = read_bag(path)
        _assert_prefix(rec, whole)
        assert len(rec) >= int(keep * 150) - 2
        assert _scans_in_note(rec.meta["recovered"]) == len(rec)


def test_a_ros2_mcap_cut_short_keeps_its_types(tmp_path):
    folder = write_bag(tmp_path / "w", "mcap", {"/scan": [np.full(40, 2.0)] * 30}, odom=True)
    (mcap,) = folder.glob("*.mcap")
    cut = _cut(mcap, tmp_path / "cut.mcap", 0.7)
    reader = McapReader(cut, "cdr", get_typestore(Stores.ROS2_HUMBLE))
    types = {c.topic: c.msgtype for c in reader.connections}
    assert types == {"/scan": "sensor_msgs/msg/LaserScan", "/odom": "nav_msgs/msg/Odometry"}
    assert reader.recovered is not None and 0 < reader.recovered.read_to < cut.stat().st_size


def test_info_and_convert_of_a_cut_bag_say_how_much_was_read(tmp_path, capsys):
    cut = _cut(sample_bag_path(), tmp_path / "cut.bag", 0.9)
    code, out, err = run(["info", str(cut)], capsys)
    assert code == 0, err
    assert re.search(r"^cut\.bag: cut short; read \d+ scans", err, re.M)
    assert "recovered: cut short" in out
    npz = tmp_path / "cut.npz"
    code, out, err = run(["convert", str(cut), "-o", str(npz)], capsys)
    assert code == 0, err
    assert re.search(r"^cut\.bag: cut short; read \d+ scans", err, re.M)
    # the converted recording keeps the note: it still holds only that much
    rec = load_recording(npz)
    assert rec.meta["recovered"].startswith("cut short")
    assert topic_notes(npz, rec) == [f"cut.bag: {rec.meta['recovered']}"]
    code, _, err = run(["info", str(npz)], capsys)
    assert code == 0 and "cut.bag: cut short" in err
