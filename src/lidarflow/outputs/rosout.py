"""Write scans and predicted maps into ROS 1 bags, ROS 2 bags and MCAP files (design notes §8).

Maps are ``nav_msgs/OccupancyGrid`` laid out as :mod:`lidarflow.outputs.grids` says; flow is a
``sensor_msgs/Image`` ``32FC2`` of ``(column, row)`` displacements in cells and pictures ``rgb8``,
both with row 0 the map's far edge. A message's log time is its own argument (default: the
header stamp). Chunks are compressed: zstd in MCAP storage, lz4 in ROS 1 bags.
"""

from __future__ import annotations

from pathlib import Path
from types import TracebackType
from typing import Any, NoReturn

import numpy as np

from lidarflow.atomic import check_writable, commit, discard, named_for, temporary
from lidarflow.errors import PredictError
from lidarflow.outputs.grids import GridLayout, OutGrid, grid_data, map_from_grid_data
from lidarflow.scan import GridSpec, Scan

__all__ = ["BagOutput", "grid_data", "map_from_grid_data", "output_kind"]


def output_kind(path: Path) -> str:
    """``ros1`` for ``.bag``, ``mcap`` for a ``.mcap`` file, ``ros2`` (a ROS 2 bag folder with
    MCAP storage) for anything else."""
    suffix = path.suffix.lower()
    return {".bag": "ros1", ".mcap": "mcap"}.get(suffix, "ros2")


class BagOutput:
    """A bag being written: LaserScans, OccupancyGrids and images, by topic.

    ``with BagOutput(path) as out: out.write_scan("/scan", scan, "laser")``. The target must
    not exist unless ``force``. The bag is written under a temporary name and renamed onto the
    target when closed (:mod:`lidarflow.atomic`), so the target is never a bag cut short; an
    error or interrupt removes what was written. A ``.mcap`` target is a ROS 2 bag's single
    MCAP file.
    """

    def __init__(self, path: str | Path, force: bool = False) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        self.kind = output_kind(self.path)
        check_writable(self.path, force, folder=self.kind == "ros2")
        if not self.path.parent.exists():
            raise PredictError(f"{self.path.parent}: no such folder for the output")
        self.ros1 = self.kind == "ros1"
        self.typestore = get_typestore(Stores.ROS1_NOETIC if self.ros1 else Stores.ROS2_HUMBLE)
        self._serialize = (
            self.typestore.serialize_ros1 if self.ros1 else self.typestore.serialize_cdr
        )
        self._staged: Path | None = None  # what the writer writes, under a temporary name
        self._written: Path | None = None  # what becomes the target: the bag file or folder
        self._writer: Any = None
        self._connections: dict[str, Any] = {}
        self._copies: dict[tuple[Any, ...], Any] = {}

    # ------------------------------------------------------------------ lifecycle
    def __enter__(self) -> BagOutput:
        from rosbags.rosbag1 import Writer as Writer1
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

        self._staged = temporary(self.path)
        try:
            if self.ros1:
                self._written = self._staged
                self._writer = Writer1(self._staged)
                self._writer.set_compression(Writer1.CompressionFormat.LZ4)
            else:
                # rosbags names the storage file after the bag's folder: stage a folder of the
                # target's own name, then move it (ROS 2) or its .mcap file (MCAP) onto it
                self._staged.mkdir()
                folder = self._staged / self.path.stem
                mcap = folder / f"{self.path.stem}.mcap"
                self._written = folder if self.kind == "ros2" else mcap
                self._writer = Writer2(folder, version=9, storage_plugin=StoragePlugin.MCAP)
                # STORAGE: the MCAP file's own chunks are zstd-compressed (what Foxglove and
                # the rosbag2 MCAP plugin read), not the whole file or each message
                self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
            self._writer.open()
        except BaseException as err:
            discard(self._staged)
            self._raise_named(err)  # an interrupt as it came
        return self

    def _named(self, err: BaseException) -> BaseException:
        """``err`` naming the target the user asked for, not the temporary it was staged in
        (the file system's refusal, under what rosbags wraps it in: :func:`named_for`)."""
        cause = err
        while not isinstance(cause, OSError) and cause.__cause__ is not None:
            cause = cause.__cause__
        if isinstance(cause, OSError) and self._staged is not None:
            return named_for(cause, [self._staged], [self.path])
        if isinstance(err, Exception):
            return PredictError(f"{self.path}: cannot open for writing ({err})")
        return err

    def _raise_named(self, err: BaseException) -> NoReturn:
        named = self._named(err)
        if named is err:
            raise err
        raise named from err

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        assert self._staged is not None and self._written is not None
        try:
            try:
                self._writer.close()
            except OSError as err:
                if exc is None:
                    self._raise_named(err)  # another file's refusal as it came
            # A bag cut short by an error or Ctrl-C reads back as a whole one (closed, indexed):
            # it never takes the target's name.
            if exc is None:
                commit(self._written, self.path)
        finally:
            discard(self._staged)
        if isinstance(exc, OSError):  # a full disk while writing: the target, not the temporary
            named = self._named(exc)
            if named is not exc:  # else it goes on as it came
                raise named from exc

    # ------------------------------------------------------------------ messages
    def _time(self, stamp_ns: int) -> Any:
        return self.typestore.types["builtin_interfaces/msg/Time"](
            sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000)
        )

    def _header(self, stamp_ns: int, frame_id: str, seq: int = 0) -> Any:
        header = self.typestore.types["std_msgs/msg/Header"]
        if self.ros1:
            return header(seq=seq, stamp=self._time(stamp_ns), frame_id=frame_id)
        return header(stamp=self._time(stamp_ns), frame_id=frame_id)

    def _write(
        self, topic: str, msgtype: str, msg: Any, stamp_ns: int, log_time_ns: int | None
    ) -> None:
        """``msg`` logged at ``log_time_ns``, by default its header stamp ``stamp_ns``."""
        conn = self._connections.get(topic)
        if conn is None:
            conn = self._writer.add_connection(topic, msgtype, typestore=self.typestore)
            self._connections[topic] = conn
        at = stamp_ns if log_time_ns is None else log_time_ns
        self._writer.write(conn, int(at), self._serialize(msg, msgtype))

    def add_copy(
        self,
        topic: str,
        msgtype: str,
        msgdef: str,
        digest: str,
        latching: bool = False,
        callerid: str | None = None,
        qos: Any = None,
    ) -> Any:
        """The connection that copied messages of ``topic`` go to: ``msgdef`` and ``digest``
        (ROS 1: the md5sum; ROS 2: the RIHS01 hash) say what their bytes are. A topic latched in
        ROS 1 (``/tf_static``) is offered transient-local in ROS 2 (``qos``: the ROS 2
        profiles to offer as recorded, where known), and the other way round. Asked twice for
        the same, gives the one connection (ROS 2 takes each topic and type once)."""
        key = (topic, msgtype, latching, callerid if self.ros1 else None)
        conn = self._copies.get(key)
        if conn is not None:
            return conn
        if self.ros1:
            conn = self._writer.add_connection(
                topic,
                msgtype,
                msgdef=msgdef,
                md5sum=digest,
                callerid=callerid,
                latching=int(latching) if latching else None,
            )
        else:
            if qos is None:
                from rosbags.convert.converter import LATCH

                qos = LATCH if latching else []
            conn = self._writer.add_connection(
                topic, msgtype, msgdef=msgdef, rihs01=digest, offered_qos_profiles=qos
            )
        self._copies[key] = conn
        return conn

    def write_raw(self, connection: Any, log_time_ns: int, data: bytes | memoryview) -> None:
        """A message already serialised as the output takes it (:meth:`add_copy`)."""
        self._writer.write(connection, int(log_time_ns), data)

    def write_scan(
        self,
        topic: str,
        scan: Scan,
        frame_id: str,
        log_time_ns: int | None = None,
        seq: int = 0,
    ) -> None:
        """``scan`` stamped with its stamp; logged at ``log_time_ns`` (default: the stamp);
        ``seq``: its header's sequence number (ROS 1 only)."""
        g = scan.geometry
        msg = self.typestore.types["sensor_msgs/msg/LaserScan"](
            header=self._header(scan.stamp_ns, frame_id, seq),
            angle_min=g.angle_min,
            angle_max=g.angle_min + g.angle_increment * (g.count - 1),
            angle_increment=g.angle_increment,
            time_increment=0.0,
            scan_time=0.0,
            range_min=g.range_min,
            range_max=g.range_max,
            ranges=np.asarray(scan.ranges, np.float32),
            intensities=np.zeros(0, np.float32),
        )
        self._write(topic, "sensor_msgs/msg/LaserScan", msg, scan.stamp_ns, log_time_ns)

    def write_grid_data(
        self, out: OutGrid, grid: GridSpec, frame_id: str, log_time_ns: int | None = None
    ) -> None:
        """One grid of :func:`lidarflow.outputs.grids.prediction_grids` as an OccupancyGrid,
        laid out in the scan's frame as the live nodes lay theirs (:class:`GridLayout`)."""
        types = self.typestore.types
        if out.data.size != grid.height * grid.width:
            raise PredictError(f"a map of {out.data.size} cells does not fit the grid {grid}")
        layout = GridLayout.of(grid)
        origin = types["geometry_msgs/msg/Pose"](
            position=types["geometry_msgs/msg/Point"](x=layout.origin_x, y=layout.origin_y, z=0.0),
            orientation=types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
        )
        info = types["nav_msgs/msg/MapMetaData"](
            map_load_time=self._time(out.scan_stamp_ns),
            resolution=layout.resolution,
            width=layout.width,
            height=layout.height,
            origin=origin,
        )
        msg = types["nav_msgs/msg/OccupancyGrid"](
            header=self._header(out.stamp_ns, frame_id), info=info, data=out.data
        )
        self._write(out.topic, "nav_msgs/msg/OccupancyGrid", msg, out.stamp_ns, log_time_ns)

    def write_flow(
        self,
        topic: str,
        flow: np.ndarray,
        stamp_ns: int,
        frame_id: str,
        log_time_ns: int | None = None,
    ) -> None:
        """Flow ``(2, H, W)`` in cells as a ``32FC2`` image (row 0 the map's far edge)."""
        if flow.ndim != 3 or flow.shape[0] != 2:
            raise PredictError(f"flow must be (2, H, W), got {tuple(flow.shape)}")
        pixels = np.moveaxis(flow.astype("<f4"), 0, -1)
        self._write_image(topic, pixels, "32FC2", stamp_ns, frame_id, log_time_ns)

    def write_rgb(
        self,
        topic: str,
        pixels: np.ndarray,
        stamp_ns: int,
        frame_id: str,
        log_time_ns: int | None = None,
    ) -> None:
        """A picture ``(H, W, 3)`` of ``uint8`` as an ``rgb8`` image (Foxglove and RViz show it)."""
        if pixels.ndim != 3 or pixels.shape[2] != 3 or pixels.dtype != np.uint8:
            raise PredictError(f"an rgb8 image must be (H, W, 3) uint8, got {pixels.shape}")
        self._write_image(topic, pixels, "rgb8", stamp_ns, frame_id, log_time_ns)

    def _write_image(
        self,
        topic: str,
        pixels: np.ndarray,
        encoding: str,
        stamp_ns: int,
        frame_id: str,
        log_time_ns: int | None,
    ) -> None:
        """``pixels`` ``(H, W, channels)`` (little-endian) as a ``sensor_msgs/Image``."""
        h, w, _ = pixels.shape
        data = np.ascontiguousarray(pixels).view(np.uint8).reshape(h, -1)
        msg = self.typestore.types["sensor_msgs/msg/Image"](
            header=self._header(stamp_ns, frame_id),
            height=h,
            width=w,
            encoding=encoding,
            is_bigendian=0,
            step=data.shape[1],
            data=data.ravel(),
        )
        self._write(topic, "sensor_msgs/msg/Image", msg, stamp_ns, log_time_ns)
