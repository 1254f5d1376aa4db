"""The input bag copied into a prediction output: every connection, every field, names as
recorded, raw bytes where the serialisation matches, converted where it does not."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from lidarflow.data import read_bag
from lidarflow.outputs.job import predict_to_bag
from lidarflow.predict import Predictor
from tests.conftest import FLOW_MODEL

T0, PERIOD, LAG = 1_700_000_000 * 10**9, 100_000_000, 7_000_000  # log times lag the stamps
FRAMES = 8


def _store(ros1: bool):
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in ts.types:
        definition = "geometry_msgs/TransformStamped[] transforms"
        ts.register(get_types_from_msg(definition, "tf2_msgs/msg/TFMessage"))
    return ts


def _header(ts, ros1: bool, stamp_ns: int, frame: str, seq: int = 0):
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    extra = {"seq": seq} if ros1 else {}
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame, **extra)


def _tf(ts, ros1: bool, stamp_ns: int, parent: str, child: str, x: float):
    t = ts.types
    transform = t["geometry_msgs/msg/Transform"](
        translation=t["geometry_msgs/msg/Vector3"](x=x, y=-0.25, z=0.3),
        rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.6, w=0.8),
    )
    stamped = t["geometry_msgs/msg/TransformStamped"](
        header=_header(ts, ros1, stamp_ns, parent, seq=3),
        child_frame_id=child,
        transform=transform,
    )
    return t["tf2_msgs/msg/TFMessage"](transforms=[stamped])


def write_robot_bag(path: Path, kind: str) -> Path:
    """A bag as a robot records one: a relative-named scan topic with every LaserScan field set
    (ROS 1 ``right_scan``, sequence numbers 100...; ROS 2 ``/right_scan``), ``/tf`` and a
    latched ``/tf_static``; log times a little after the stamps. ``kind``: "ros1" (.bag),
    "mcap" or "sqlite3" (a ROS 2 bag folder of that storage)."""
    ros1 = kind == "ros1"
    ts = _store(ros1)
    if ros1:
        from rosbags.rosbag1 import Writer

        writer = Writer(path)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer = Writer(path, version=9, storage_plugin=plugin)
    with writer:
        if ros1:
            scan_c = writer.add_connection("right_scan", "sensor_msgs/msg/LaserScan", typestore=ts,
                                           callerid="/sick_driver")  # fmt: skip
            tf_c = writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
            static_c = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts,
                                             latching=1)  # fmt: skip
            serialize = ts.serialize_ros1
        else:
            from rosbags.convert.converter import LATCH

            scan_c = writer.add_connection("/right_scan", "sensor_msgs/msg/LaserScan", typestore=ts)
            tf_c = writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=ts)
            static_c = writer.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts,
                                             offered_qos_profiles=LATCH)  # fmt: skip
            serialize = ts.serialize_cdr
        static = _tf(ts, ros1, T0, "base_link", "laser", 0.2)
        writer.write(static_c, T0, serialize(static, "tf2_msgs/msg/TFMessage"))
        beams = 181
        for i in range(FRAMES):
            stamp = T0 + i * PERIOD
            ranges = np.full(beams, 3.0, np.float32)
            ranges[40 + i : 60 + i] = 1.5  # something that moves
            scan = ts.types["sensor_msgs/msg/LaserScan"](
                header=_header(ts, ros1, stamp, "laser", seq=100 + i),
                angle_min=-np.pi / 2, angle_max=np.pi / 2, angle_increment=np.pi / (beams - 1),
                time_increment=1.25e-4, scan_time=0.1, range_min=0.05, range_max=8.0,
                ranges=ranges, intensities=np.arange(beams, dtype=np.float32) + i,
            )  # fmt: skip
            writer.write(scan_c, stamp + LAG, serialize(scan, "sensor_msgs/msg/LaserScan"))
            tf = _tf(ts, ros1, stamp, "odom", "base_link", 0.01 * i)
            writer.write(tf_c, stamp + LAG + 1, serialize(tf, "tf2_msgs/msg/TFMessage"))
    return path


def read_messages(path: Path):
    """``(topic, log time, raw, message, connection)`` of every message."""
    from rosbags.highlevel import AnyReader

    store = get_typestore(Stores.ROS1_NOETIC if path.suffix == ".bag" else Stores.ROS2_HUMBLE)
    with AnyReader([path], default_typestore=store) as reader:
        return [
            (c.topic, t, bytes(raw), reader.deserialize(raw, c.msgtype), c)
            for c, t, raw in reader.messages()
        ]


def plain(value):
    """A message as nested dicts and lists, header ``seq`` left out (ROS 2 has none)."""
    if dataclasses.is_dataclass(value):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)
                if f.name != "seq"}  # fmt: skip
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    return value


@pytest.fixture(scope="module")
def robot_bags(tmp_path_factory):
    folder = tmp_path_factory.mktemp("robot")
    return {
        "ros1": write_robot_bag(folder / "robot.bag", "ros1"),
        "mcap": write_robot_bag(folder / "robot2", "mcap"),
        "sqlite3": write_robot_bag(folder / "robot3", "sqlite3"),
    }


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "output"),
    [(k, o) for k in ("ros1", "mcap") for o in ("out.bag", "out.mcap", "outdir")]
    + [("sqlite3", "out.mcap"), ("sqlite3", "out.bag")],
)
def test_every_input_message_is_copied_unchanged(tmp_path, robot_bags, kind, output):
    source = robot_bags[kind]
    if kind == "sqlite3":
        source = source / "robot3.db3"  # as a user may name it: the folder is read
    recording = read_bag(source)
    # a flow model, so that every prediction topic is written (the bundled one has no moving)
    predict_to_bag(recording, Predictor(FLOW_MODEL), tmp_path / output, source=source)
    ros1_in, ros1_out = kind == "ros1", output.endswith(".bag")
    given, written = read_messages(robot_bags[kind]), read_messages(tmp_path / output)
    # names as recorded; made absolute for ROS 2 only
    scan_topic = "right_scan" if ros1_in and ros1_out else "/right_scan"
    names = {"right_scan": scan_topic, "/right_scan": scan_topic}
    copied = [m for m in written if not m[0].startswith("/lidarflow/")]
    assert [(names.get(m[0], m[0]), m[1]) for m in given] == [(m[0], m[1]) for m in copied]
    for before, after in zip(given, copied, strict=True):
        if ros1_in == ros1_out:
            assert before[2] == after[2], before[0]  # the same bytes
        else:
            assert plain(before[3]) == plain(after[3]), before[0]  # the same fields
    scans = [m[3] for m in copied if m[0] == scan_topic]
    assert scans[3].intensities.tolist() == (np.arange(181) + 3).tolist()
    assert (scans[3].scan_time, scans[3].time_increment) == (
        pytest.approx(0.1),
        pytest.approx(1.25e-4),
    )
    if ros1_out:  # seq as recorded; 0 where the input (ROS 2) had none
        assert scans[3].header.seq == (103 if ros1_in else 0)
    # /tf_static stays what late subscribers get
    static = next(m[4] for m in copied if m[0] == "/tf_static")
    if ros1_out:
        assert static.ext.latching == 1
    else:
        assert [q.durability.name for q in static.ext.offered_qos_profiles] == ["TRANSIENT_LOCAL"]
    # each prediction right after its scan, at its log time
    scan_times = [m[1] for m in copied if m[0] == scan_topic]
    predicted = [m[1] for m in written if m[0] == "/lidarflow/predicted"]
    assert predicted == scan_times
    order = [m[0] for m in written]
    first = order.index(scan_topic)
    assert order[first + 1 : first + 5] == [
        "/lidarflow/occupancy", "/lidarflow/predicted", "/lidarflow/decided", "/lidarflow/moving"
    ]  # fmt: skip
    # and lidarflow reads the output as it read the input
    back = read_bag(tmp_path / output)
    np.testing.assert_array_equal(back.stamps_ns, recording.stamps_ns)
    np.testing.assert_array_equal(back.scan(5).ranges, recording.scan(5).ranges)


def test_an_earlier_prediction_in_the_input_is_not_copied(tmp_path, robot_bags):
    # predicting on predict's own output: the old /lidarflow topics would clash with the new
    first = tmp_path / "first.mcap"
    predict_to_bag(read_bag(robot_bags["mcap"]), Predictor(), first, source=robot_bags["mcap"])
    counts = predict_to_bag(read_bag(first), Predictor(), tmp_path / "second.bag", source=first)
    assert counts["/lidarflow/predicted"] == FRAMES and counts["/right_scan"] == FRAMES
    topics = {m[0] for m in read_messages(tmp_path / "second.bag")}
    assert topics >= {"/right_scan", "/tf", "/tf_static", "/lidarflow/predicted"}


@pytest.mark.parametrize("output", ["out.bag", "out.mcap"])
def test_ros1_messages_in_an_mcap_file_are_copied(tmp_path, output):
    # `mcap convert`'s ROS 1 MCAP: read by lidarflow's own reader (no is2, no msgdefs)
    from tests.bagutil import write_ros1_mcap

    source = write_ros1_mcap(
        tmp_path / "in.mcap", [np.full(50, 2.0 + 0.1 * i) for i in range(6)], mount=(0.1, 0, 0)
    )
    predict_to_bag(read_bag(source), Predictor(), tmp_path / output, source=source)
    from lidarflow.data.mcapfile import McapReader

    reader = McapReader(source, "ros1", get_typestore(Stores.ROS1_NOETIC))
    given = [(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()]
    copied = [m for m in read_messages(tmp_path / output) if not m[0].startswith("/lidarflow/")]
    assert [g[:2] for g in given] == [c[:2] for c in copied]
    if output.endswith(".bag"):
        assert [g[2] for g in given] == [c[2] for c in copied]
    else:
        laser = "sensor_msgs/msg/LaserScan"
        scans = [reader.deserialize(g[2], laser) for g in given if g[0] == "/scan"]
        assert [plain(s) for s in scans] == [plain(c[3]) for c in copied if c[0] == "/scan"]


def test_a_message_that_cannot_be_converted_is_one_clear_error(tmp_path):
    from rosbags.rosbag1 import Writer

    from lidarflow.errors import BagError
    from tests.bagutil import write_bag

    bag = write_bag(tmp_path / "in.bag", "ros1", {"/scan": [np.full(50, 2.0)] * 4})
    broken = tmp_path / "broken.bag"  # the same scans and a String whose length runs off
    given = read_messages(bag)
    with Writer(broken) as writer:
        store = get_typestore(Stores.ROS1_NOETIC)
        scans = writer.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=store)
        for _, log_time, raw, *_ in given:
            writer.write(scans, log_time, raw)
        chatter = writer.add_connection("/chatter", "std_msgs/msg/String", typestore=store)
        writer.write(chatter, given[-1][1], b"\xff\xff\xff\x7fabc")
    recording = read_bag(broken)
    with pytest.raises(BagError, match=r"cannot copy the input bag's messages .*--topics"):
        predict_to_bag(recording, Predictor(), tmp_path / "o.mcap", source=broken)
    assert list(tmp_path.glob("o.mcap*")) == []
    # raw bytes into a ROS 1 bag are copied as they are; without the input, no copy at all
    predict_to_bag(recording, Predictor(), tmp_path / "o.bag", source=broken)
    predict_to_bag(recording, Predictor(), tmp_path / "p.mcap", source=broken,
                   topics={"predicted"})  # fmt: skip
