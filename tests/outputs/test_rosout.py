"""Predicted maps written as OccupancyGrid line up with the scan: checked on asymmetric maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lidarflow.atomic import STAMP
from lidarflow.data import read_bag
from lidarflow.errors import OutputError, PredictError
from lidarflow.outputs.grids import OutGrid
from lidarflow.outputs.rosout import BagOutput, grid_data, map_from_grid_data
from lidarflow.scan import BeamGeometry, GridSpec, Scan, cell_centres

GRID = GridSpec(6, 4, 0.5)  # deliberately not square


def write_grid(out, topic, probability, grid, stamp_ns, frame_id, log_time_ns=None, made_ns=None):
    """``probability`` as an OccupancyGrid for ``stamp_ns``, made from the scan of ``made_ns``
    (default ``stamp_ns``: a map of the present)."""
    made = stamp_ns if made_ns is None else made_ns
    grid_out = OutGrid(topic, grid_data(probability), stamp_ns, made)
    out.write_grid_data(grid_out, grid, frame_id, log_time_ns)


def asymmetric_map() -> np.ndarray:
    m = np.zeros(GRID.shape)
    m[0, 0] = 1.0  # far left
    m[5, 3] = 0.5  # near right
    m[2, 1] = 0.25
    return m


def test_grid_cell_centres_land_on_the_map_cell_centres():
    data = grid_data(asymmetric_map()).reshape(GRID.width, GRID.height)  # [j, i]
    x, y = cell_centres(GRID)
    origin_y = -GRID.width / 2 * GRID.res
    for r, c in [(0, 0), (5, 3), (2, 1)]:
        hits = np.argwhere(data == round(asymmetric_map()[r, c] * 100))
        ((j, i),) = hits
        assert (i + 0.5) * GRID.res == pytest.approx(x[r, c])
        assert origin_y + (j + 0.5) * GRID.res == pytest.approx(y[r, c])


def test_grid_data_round_trip_and_unknown():
    unknown = np.zeros(GRID.shape, bool)
    unknown[1, 2] = True
    data = grid_data(asymmetric_map(), unknown)
    assert data.dtype == np.int8 and data.size == GRID.height * GRID.width
    back = map_from_grid_data(data, GRID.height, GRID.width)
    assert back[1, 2] == -1
    expected = np.rint(asymmetric_map() * 100).astype(np.int8)
    expected[1, 2] = -1
    np.testing.assert_array_equal(back, expected)


def read_all(path: Path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.ROS2_HUMBLE)
    out: dict[str, list] = {}
    with AnyReader([path], default_typestore=store) as reader:
        for conn, _, raw in reader.messages():
            out.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    return out


@pytest.mark.parametrize("name", ["out.bag", "out.mcap", "outdir"])
def test_every_output_kind_reads_back(tmp_path, name):
    path = tmp_path / name
    geom = BeamGeometry(5, -0.2, 0.1, 0.05, 8.0)
    flow = np.stack([np.full(GRID.shape, 1.5), np.arange(24, dtype=float).reshape(GRID.shape)])
    with BagOutput(path) as out:
        for k in range(3):
            scan = Scan(np.full(5, 2.0 + k, np.float32), geom, 1_000_000_000 + k * 100_000_000)
            out.write_scan("/scan", scan, "laser")
            write_grid(out, "/pred", asymmetric_map(), GRID, scan.stamp_ns, "laser")
            out.write_flow("/flow", flow, scan.stamp_ns, "laser")
    msgs = read_all(path)
    assert len(msgs["/scan"]) == 3 and len(msgs["/pred"]) == 3
    grid = msgs["/pred"][0]
    assert grid.header.frame_id == "laser"
    assert (grid.info.width, grid.info.height) == (GRID.height, GRID.width)
    assert grid.info.resolution == pytest.approx(0.5)
    assert grid.info.origin.position.y == pytest.approx(-1.0)
    back = map_from_grid_data(grid.data, GRID.height, GRID.width)
    np.testing.assert_array_equal(back, np.rint(asymmetric_map() * 100))
    image = msgs["/flow"][0]
    pixels = np.frombuffer(bytes(image.data), "<f4").reshape(image.height, image.width, 2)
    np.testing.assert_array_equal(np.moveaxis(pixels, -1, 0), flow.astype(np.float32))
    rec = read_bag(path, topic="/scan")
    assert len(rec) == 3 and rec.scan(2).ranges[0] == pytest.approx(4.0)


@pytest.mark.parametrize("name", ["out.bag", "out.mcap", "outdir"])
def test_an_interrupted_output_leaves_nothing(tmp_path, name):
    # a .bag or ROS 2 folder cut short stayed, passed for a whole bag and blocked the rerun
    path = tmp_path / name
    geom = BeamGeometry(5, -0.2, 0.1, 0.05, 8.0)
    with pytest.raises(KeyboardInterrupt), BagOutput(path) as out:
        out.write_scan("/scan", Scan(np.full(5, 2.0, np.float32), geom, 1_000_000_000), "laser")
        raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_existing_output_is_refused(tmp_path):
    (tmp_path / "x.bag").write_bytes(b"")
    with pytest.raises(OutputError, match="already exists; use --force"):
        BagOutput(tmp_path / "x.bag")
    with pytest.raises(PredictError, match="no such folder"):
        BagOutput(tmp_path / "missing" / "x.mcap")


@pytest.mark.parametrize("name", ["out.bag", "out.mcap", "outdir"])
def test_the_target_appears_only_when_the_bag_is_closed_and_force_replaces_it(tmp_path, name):
    path = tmp_path / name
    if name == "outdir":
        path.mkdir()
        (path / STAMP).write_text("{}")  # a bag lidarflow wrote
        (path / "metadata.yaml").write_text("old bag")
    else:
        path.write_bytes(b"old")
    geom = BeamGeometry(5, -0.2, 0.1, 0.05, 8.0)
    with BagOutput(path, force=True) as out:
        out.write_scan("/scan", Scan(np.full(5, 2.0, np.float32), geom, 1_000_000_000), "laser")
        staged = [p.name for p in tmp_path.iterdir() if p.name != name]
        assert len(staged) == 1 and ".partial" in staged[0]  # written beside, not in place
        assert path.is_dir() if name == "outdir" else path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == [name]
    assert len(read_all(path)["/scan"]) == 1


def test_force_does_not_empty_a_folder_that_is_not_a_bag(tmp_path):
    (tmp_path / "keep.txt").write_text("mine")
    with pytest.raises(OutputError, match="not a folder lidarflow wrote"):
        BagOutput(tmp_path, force=True)
    assert (tmp_path / "keep.txt").read_text() == "mine"


def mcap_chunk_compressions(path: Path) -> list[str]:
    """The compression of every chunk of an MCAP file, as the ``mcap`` library reads it."""
    from mcap.reader import make_reader

    with path.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    return [index.compression for index in summary.chunk_indexes]


def ros1_chunk_compressions(path: Path) -> list[str]:
    """The ``compression`` field of every chunk record (op 0x05) of a ROS 1 bag."""
    import struct

    data = path.read_bytes()
    assert data.startswith(b"#ROSBAG V2.0\n")
    at, found = 13, []
    while at < len(data):
        (size,) = struct.unpack_from("<I", data, at)
        header, fields, pos = data[at + 4 : at + 4 + size], {}, 0
        while pos < len(header):
            (n,) = struct.unpack_from("<I", header, pos)
            name, _, value = header[pos + 4 : pos + 4 + n].partition(b"=")
            fields[name], pos = value, pos + 4 + n
        at += 4 + size
        (size,) = struct.unpack_from("<I", data, at)
        at += 4 + size
        if fields[b"op"] == b"\x05":
            found.append(fields[b"compression"].decode())
    return found


@pytest.mark.parametrize("name", ["out.bag", "out.mcap", "outdir"])
def test_chunks_are_compressed(tmp_path, name):
    # uncompressed, a 1 MB bag's predictions took 70 MB
    path = tmp_path / name
    maps = np.random.default_rng(0).random((40, *GRID.shape)).round(1)
    with BagOutput(path) as out:
        for k, m in enumerate(maps):
            write_grid(out, "/pred", m, GRID, 1_000_000_000 + k, "laser")
    if name == "out.bag":
        assert set(ros1_chunk_compressions(path)) == {"lz4"}
    else:
        mcap = path if name == "out.mcap" else next(path.glob("*.mcap"))
        assert set(mcap_chunk_compressions(mcap)) == {"zstd"}
        from mcap.reader import make_reader

        with mcap.open("rb") as stream:  # and a reader other than rosbags' decodes them
            assert sum(1 for _ in make_reader(stream).iter_messages(topics=["/pred"])) == 40
    back = read_all(path)["/pred"]
    np.testing.assert_array_equal(
        map_from_grid_data(back[7].data, GRID.height, GRID.width), np.rint(maps[7] * 100)
    )


@pytest.mark.parametrize("name", ["out.bag", "out.mcap"])
def test_a_grid_says_when_it_is_for_and_when_it_was_made(tmp_path, name):
    path = tmp_path / name
    with BagOutput(path) as out:
        write_grid(out, "/now", asymmetric_map(), GRID, 5_000_000_000, "laser")
        write_grid(
            out, "/ahead", asymmetric_map(), GRID, 5_100_000_000, "laser",
            log_time_ns=5_000_000_000, made_ns=5_000_000_000,
        )  # fmt: skip
    msgs = read_all(path)

    def ns(t):
        return t.sec * 10**9 + t.nanosec

    now, ahead = msgs["/now"][0], msgs["/ahead"][0]
    assert ns(now.header.stamp) == ns(now.info.map_load_time) == 5_000_000_000
    assert ns(ahead.header.stamp) == 5_100_000_000
    assert ns(ahead.info.map_load_time) == 5_000_000_000


@pytest.mark.parametrize("name", ["out.bag", "out.mcap"])
def test_rgb_image_reads_back(tmp_path, name):
    pixels = np.random.default_rng(1).integers(0, 256, (6, 4, 3), dtype=np.uint8)
    with BagOutput(tmp_path / name) as out:
        out.write_rgb("/picture", pixels, 1_000_000_000, "laser")
        with pytest.raises(PredictError, match="rgb8"):
            out.write_rgb("/picture", pixels[..., :2], 1_000_000_000, "laser")
    (image,) = read_all(tmp_path / name)["/picture"]
    assert (image.encoding, image.height, image.width, image.step) == ("rgb8", 6, 4, 12)
    np.testing.assert_array_equal(np.asarray(image.data).reshape(6, 4, 3), pixels)


@pytest.mark.parametrize("name", ["out.bag", "out.mcap"])
def test_a_full_disk_names_the_target_and_another_files_refusal_stays_as_it_came(tmp_path, name):
    import errno

    path = tmp_path / name
    full = rf"{name}: cannot be written there \(No space left"
    with pytest.raises(OutputError, match=full), BagOutput(path):
        raise OSError(errno.ENOSPC, "No space left on device")
    elsewhere = tmp_path / "input.bag"
    with pytest.raises(PermissionError) as caught, BagOutput(path):
        raise PermissionError(errno.EACCES, "Permission denied", str(elsewhere))
    assert caught.value.filename == str(elsewhere) and caught.value.__cause__ is None
    assert not path.exists() and list(tmp_path.iterdir()) == []
