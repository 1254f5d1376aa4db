"""Small inputs that would take gigabytes (issue 51) end in one line under a memory limit: a
scan of millions of beams in a few kB of compressed bag."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from lidarflow.data.messages import declared_beams
from lidarflow.scan import MAX_BEAMS
from tests.bagutil import _scan_msg, write_bag, write_ros1_mcap
from tests.memlimit import GIB, one_line_error, run_limited

#: 10 million beams a scan: 40 MB each, that compress to almost nothing; a half turn
HUGE = 10_000_000
INC = 3.0 / HUGE


@pytest.mark.parametrize("store", ["ros1", "ros2"])
@pytest.mark.parametrize("beams", [0, 1081, 123_457])
def test_declared_beams_reads_the_count_of_a_serialised_scan(store, beams):
    ts = get_typestore(Stores.ROS1_NOETIC if store == "ros1" else Stores.ROS2_HUMBLE)
    ser = ts.serialize_ros1 if store == "ros1" else ts.serialize_cdr
    for frame in ("", "l", "laser", "base_scan_x"):  # every padding of the frame id
        msg = _scan_msg(ts, np.ones(beams, np.float32), 1, frame=frame)
        raw = ser(msg, "sensor_msgs/msg/LaserScan")
        assert declared_beams(raw, ros1=store == "ros1") == beams
        assert declared_beams(raw[:10], ros1=store == "ros1") is None


@pytest.mark.parametrize("store", ["ros1", "ros2"])
def test_declared_beams_of_a_multi_echo_scan(store):
    ts = get_typestore(Stores.ROS1_NOETIC if store == "ros1" else Stores.ROS2_HUMBLE)
    ser = ts.serialize_ros1 if store == "ros1" else ts.serialize_cdr
    Echoes = ts.types["sensor_msgs/msg/MultiEchoLaserScan"]
    Echo = ts.types["sensor_msgs/msg/LaserEcho"]
    scan = _scan_msg(ts, np.ones(7, np.float32), 1, frame="abc")
    msg = Echoes(
        header=scan.header, angle_min=0.0, angle_max=0.1, angle_increment=0.01,
        time_increment=0.0, scan_time=0.1, range_min=0.05, range_max=8.0,
        ranges=[Echo(echoes=np.full(2, 3.0, np.float32))] * 7, intensities=[],
    )  # fmt: skip
    raw = ser(msg, "sensor_msgs/msg/MultiEchoLaserScan")
    assert declared_beams(raw, ros1=store == "ros1") == 7


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "command"), [("ros1", "convert"), ("ros2", "evaluate"), ("mcap", "predict")]
)
def test_a_scan_of_millions_of_beams_is_one_line_under_a_memory_limit(tmp_path, kind, command):
    frames = [np.full(HUGE, 3.0, np.float32)] * 3
    sweep = {"angle_min": -1.5, "angle_max": 1.5, "angle_increment": INC}
    if kind == "ros1":
        bag = write_bag(tmp_path / "huge.bag", "ros1", {"/scan": frames}, compression="lz4",
                        overrides=dict.fromkeys(range(3), sweep))  # fmt: skip
    elif kind == "ros2":  # a ROS 2 bag folder, each message zstd-compressed
        bag = write_bag(tmp_path / "huge", "mcap", {"/scan": frames}, compression="message",
                        overrides=dict.fromkeys(range(3), sweep))  # fmt: skip
    else:  # a bare MCAP file of ROS 1 messages, zstd-compressed (`mcap convert`'s)
        bag = write_ros1_mcap(tmp_path / "huge.mcap", frames, compression="zstd",
                              angle_increment=INC)  # fmt: skip
    out = {"convert": ["-o", "r.npz"], "predict": ["-o", "p.mcap"], "evaluate": ["--warmup", "1"]}
    out = out[command]
    done = run_limited([command, str(bag), *out], tmp_path, limit_bytes=2 * GIB)
    line = one_line_error(done)
    assert bag.name in line and "/scan" in line and f"{HUGE:,}" in line
    assert f"{MAX_BEAMS:,}" in line


def _long_recording(n: int, beams: int = 19):
    from lidarflow.data.recording import Recording

    ranges = np.full(n * beams, 3.0, np.float32)
    ranges[::5] = 6.0
    return Recording(
        ranges=ranges, offsets=np.arange(n + 1) * beams, angle_min=np.full(n, -np.pi / 2),
        angle_increment=np.full(n, np.pi / (beams - 1)), range_min=np.full(n, 0.05),
        range_max=np.full(n, 8.0), stamps_ns=1_700_000_000 * 10**9 + np.arange(n) * 10**8,
        meta={"source": "long", "topic": "/scan"},
    )  # fmt: skip


@pytest.mark.slow
def test_convert_checks_a_long_recording_a_batch_at_a_time_under_a_memory_limit(tmp_path):
    """40,000 scans: their maps at once take 800 MB (200,000 took 4 GB; on --grid 200, 16)."""
    from lidarflow.data.recordfile import load_recording

    source = _long_recording(40_000).save(tmp_path / "long.npz")
    done = run_limited(["convert", str(source), "-o", "out.npz"], tmp_path, GIB * 3 // 4)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "40000 scans" in done.stdout
    back = load_recording(tmp_path / "out.npz")
    assert len(back) == 40_000 and back.ranges.dtype == np.float32
    np.testing.assert_array_equal(back.ranges, load_recording(source).ranges)
    assert back.meta["grid"] == {"height": 100, "width": 100, "res": 0.1}


def _with_member(source, target, key, header: dict, data: bytes):
    """``source`` (an .npz) with its array ``key`` replaced by ``header`` and ``data``."""
    import io
    import zipfile

    npy = io.BytesIO()
    np.lib.format.write_array_header_1_0(npy, header)
    with zipfile.ZipFile(source) as old, zipfile.ZipFile(target, "w", zipfile.ZIP_DEFLATED) as new:
        for name in old.namelist():
            body = npy.getvalue() + data if name == f"{key}.npy" else old.read(name)
            new.writestr(name, body)
    return target


@pytest.mark.slow
@pytest.mark.parametrize("command", ["info", "evaluate"])
def test_a_recording_whose_header_claims_4e12_floats_is_one_line(tmp_path, command):
    source = _long_recording(20).save(tmp_path / "ok.npz")
    claim = {"descr": "<f4", "fortran_order": False, "shape": (4_000_000_000_000,)}
    bad = _with_member(source, tmp_path / "claims.npz", "ranges", claim, bytes(16))
    done = run_limited([command, str(bad)], tmp_path, limit_bytes=2 * GIB)
    line = one_line_error(done)
    assert "claims.npz" in line and "'ranges'" in line and "damaged" in line


@pytest.mark.parametrize("dtype", ["<c8", "<U4", "|V8"])
def test_a_recording_of_complex_ranges_is_one_line(tmp_path, dtype):
    source = _long_recording(20).save(tmp_path / "ok.npz")
    ranges = np.full(20 * 19, 3.0, np.complex64).view(np.uint8).tobytes()
    header = {"descr": dtype, "fortran_order": False, "shape": (len(ranges) // 8,)}
    bad = _with_member(source, tmp_path / "complex.npz", "ranges", header, ranges)
    line = one_line_error(run_limited(["info", str(bad)], tmp_path))
    assert "complex.npz" in line and "'ranges'" in line and "not real numbers" in line


def test_an_array_whose_member_holds_more_than_its_header_says_is_one_line(tmp_path):
    source = _long_recording(20).save(tmp_path / "ok.npz")
    header = {"descr": "<f4", "fortran_order": False, "shape": (4,)}
    bad = _with_member(source, tmp_path / "long.npz", "offsets", header, bytes(400))
    line = one_line_error(run_limited(["info", str(bad)], tmp_path))
    assert "'offsets'" in line and "damaged" in line


@pytest.mark.slow
def test_a_recording_of_millions_of_beams_a_scan_is_one_line_under_a_memory_limit(tmp_path):
    from lidarflow.data.recording import Recording

    n = 3
    source = Recording(
        ranges=np.full(n * HUGE, 3.0, np.float32), offsets=np.arange(n + 1) * HUGE,
        angle_min=np.full(n, -1.5), angle_increment=np.full(n, INC), range_min=np.full(n, 0.05),
        range_max=np.full(n, 8.0), stamps_ns=np.arange(n) * 10**8, meta={"source": "huge"},
    ).save(tmp_path / "huge.npz")  # fmt: skip
    argv = ["evaluate", str(source), "--warmup", "1", "--baselines-only"]
    done = run_limited(argv, tmp_path, 2 * GIB)
    line = one_line_error(done)
    assert "huge.npz" in line and f"{HUGE:,} beams" in line
