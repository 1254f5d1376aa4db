"""The recording on disk: one ``.npz`` (NumPy, no pickle), written whole or not at all.

The arrays of :class:`~lidarflow.data.recording.Recording` each as a member, the metadata as
JSON (``meta_json``, with :data:`FORMAT_VERSION`), each extra as ``extra__NAME``. Reading checks
every member before NumPy allocates it: a damaged, crafted or foreign file is a
:class:`RecordingError` saying which, in one line.
"""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path

import numpy as np

from lidarflow.atomic import atomic_path
from lidarflow.data.inputs import check_regular
from lidarflow.data.recording import GEOMETRY_FIELDS, Recording
from lidarflow.errors import RecordingError
from lidarflow.scan import MAX_BEAMS

__all__ = ["FORMAT_VERSION", "load_recording", "save_recording"]

FORMAT_VERSION = 1
_EXTRA_PREFIX = "extra__"
#: The arrays every recording file holds, one member each, as :class:`Recording` names them.
_ARRAYS = ("ranges", "offsets", *GEOMETRY_FIELDS, "stamps_ns")


def save_recording(recording: Recording, path: str | Path) -> Path:
    """Write ``recording`` to ``path`` (``.npz`` appended when missing), whole or not at all
    (:func:`lidarflow.atomic.atomic_path`); returns the path written."""
    path = Path(path)
    if path.suffix != ".npz":
        path = path.with_name(path.name + ".npz")
    arrays = {name: getattr(recording, name) for name in _ARRAYS}
    arrays["ranges"] = np.asarray(recording.ranges, np.float32)  # no copy where it is float32
    meta = json.dumps({**recording.meta, "format_version": FORMAT_VERSION})
    arrays["meta_json"] = np.frombuffer(meta.encode(), np.uint8)
    if recording.poses is not None:
        arrays["poses"] = recording.poses
    for key, value in recording.extras.items():
        arrays[_EXTRA_PREFIX + key] = value
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, **arrays)
    return path


#: How every zip archive (an .npz is one) begins: a member, or for an empty one its directory.
_ZIP_STARTS = (b"PK\x03\x04", b"PK\x05\x06")

#: Deflate cannot expand data more than 1032-fold; a member claiming more (plus a header's
#: worth) than this many times its compressed size lies about its size.
_DEFLATE_MOST = 1100


def _check_member(path: Path, archive: zipfile.ZipFile, key: str) -> None:
    """Refuse the array ``key`` of the .npz ``path`` before NumPy allocates it (its declared
    shape first): one whose header declares other than its member holds, and one of values
    that are no real numbers. Python objects are left to :func:`_read_arrays`."""
    if f"{key}.npy" not in archive.namelist():
        raise RecordingError(f"{path}: not a lidarflow recording (its member {key!r} is no array)")
    info = archive.getinfo(f"{key}.npy")
    stored = info.compress_size * _DEFLATE_MOST + 4096
    if info.compress_type == zipfile.ZIP_STORED:
        stored = info.compress_size
    if info.file_size > stored:
        raise RecordingError(
            f"{path}: a damaged recording (its array {key!r} claims {info.file_size:,} bytes "
            f"in {info.compress_size:,} compressed); convert its source again"
        )
    with archive.open(info) as member:
        version = np.lib.format.read_magic(member)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(member)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(member)
        else:  # 3.0 is for record field names beyond latin-1: no array of a recording
            raise RecordingError(
                f"{path}: not a lidarflow recording (its array {key!r} is in .npy format "
                f"{version[0]}.{version[1]}, which lidarflow does not write)"
            )
        header = member.tell()
    if dtype.hasobject:
        return
    if dtype.kind not in "biuf":
        raise RecordingError(
            f"{path}: not a lidarflow recording (its array {key!r} holds {dtype} values, not "
            "real numbers)"
        )
    declared = math.prod(shape) * dtype.itemsize
    if declared != info.file_size - header:
        raise RecordingError(
            f"{path}: a damaged recording (its array {key!r} declares shape {shape} of {dtype}, "
            f"{declared:,} bytes, and holds {info.file_size - header:,}); convert its source "
            "again"
        )


def _read_arrays(path: Path) -> dict[str, np.ndarray]:
    """Every array of the .npz ``path``, or a :class:`RecordingError` saying what the file is
    instead: not an .npz, one cut short, or one holding Python objects."""
    with path.open("rb") as f:
        start = f.read(4)
    if not start:
        raise RecordingError(f"{path}: not a lidarflow recording (the file is empty)")
    if start not in _ZIP_STARTS:
        raise RecordingError(
            f"{path}: not a lidarflow recording (not an .npz archive, as `lidarflow convert` "
            "writes)"
        )
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {}
            for key in z.files:
                _check_member(path, z.zip, key)
                try:
                    data[key] = z[key]
                except ValueError as err:
                    raise RecordingError(
                        f"{path}: not a lidarflow recording (its array {key!r} is not plain "
                        "numbers: Python objects, which lidarflow does not load)"
                    ) from err
    except (OSError, zipfile.BadZipFile, EOFError, ValueError) as err:
        raise RecordingError(
            f"{path}: a damaged recording (cut short, or its archive broken); convert its "
            "source again"
        ) from err
    return data


def load_recording(path: str | Path) -> Recording:
    """Read a recording written by :meth:`Recording.save`."""
    path = Path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    check_regular(path, RecordingError)
    data = _read_arrays(path)
    missing = [k for k in (*_ARRAYS, "meta_json") if k not in data]
    if missing:
        raise RecordingError(f"{path}: not a lidarflow recording (missing {', '.join(missing)})")
    try:
        meta = json.loads(bytes(data["meta_json"]).decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RecordingError(f"{path}: corrupt metadata ({err})") from err
    if meta.get("format_version", 0) > FORMAT_VERSION:
        raise RecordingError(
            f"{path}: written by a newer lidarflow (format {meta['format_version']}); upgrade"
        )
    extras = {k[len(_EXTRA_PREFIX) :]: v for k, v in data.items() if k.startswith(_EXTRA_PREFIX)}
    arrays = {name: data[name] for name in _ARRAYS}
    arrays["offsets"] = arrays["offsets"].astype(np.int64)
    arrays["stamps_ns"] = arrays["stamps_ns"].astype(np.int64)
    beams = np.diff(arrays["offsets"])
    if beams.size and beams.max() > MAX_BEAMS:
        frame = int(np.argmax(beams))
        raise RecordingError(
            f"{path}: scan {frame} has {int(beams[frame]):,} beams; real scanners give at most "
            f"a few thousand (lidarflow takes up to {MAX_BEAMS:,}): the recording is damaged"
        )
    return Recording(**arrays, poses=data.get("poses"), meta=meta, extras=extras)
