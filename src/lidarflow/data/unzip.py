"""A zipped ROS 1 bag (``.bag.zip``) unpacked to a temporary file for as long as it is read.

What an archive may unpack to is capped, so a zip bomb or a full disk is refused in one line;
what a process killed outright leaves behind is removed by the next unpacking.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import zipfile
from collections.abc import Iterator
from pathlib import Path

from lidarflow.atomic import discard, temporary
from lidarflow.data.readers import size_text
from lidarflow.errors import BagError

__all__ = ["UNZIP_FLOOR", "UNZIP_RATIO", "UNZIP_RESERVE", "unzip_folder", "unzipped_bag"]

#: What a zipped bag may unpack to: this many times the archive's size (a bag of scans unzips
#: to about ten, a zip bomb's zeros to a thousand), and at least :data:`UNZIP_FLOOR` bytes.
UNZIP_RATIO = 50
UNZIP_FLOOR = 64 << 20
#: The free space an unpacked bag leaves on the file system it is unpacked to.
UNZIP_RESERVE = 256 << 20
_MB = 1 << 20


def unzip_folder() -> Path:
    """Where zipped bags are unpacked: a folder of this user's under ``tempfile.gettempdir()``."""
    user = os.getuid() if hasattr(os, "getuid") else "user"
    return Path(tempfile.gettempdir()) / f"lidarflow-unzipped-{user}"


@contextlib.contextmanager
def unzipped_bag(path: Path) -> Iterator[Path]:
    """The one ``.bag`` of the zip archive ``path``, unpacked to a temporary of
    :func:`lidarflow.atomic.temporary` in :func:`unzip_folder` for as long as the context lasts.

    Raises :class:`BagError`, naming ``path``, for a damaged archive, one with no or several
    bags, and one whose bag would unpack to more than the ratio cap or the free space less
    :data:`UNZIP_RESERVE` (checked before unpacking and while, should its headers lie).
    """
    try:
        with zipfile.ZipFile(path) as zf:
            members = [m for m in zf.infolist() if m.filename.lower().endswith(".bag")]
            if len(members) != 1:
                raise BagError(f"{path}: expected exactly one .bag inside, found {len(members)}")
            folder = unzip_folder()
            folder.mkdir(mode=0o700, exist_ok=True)  # this user's alone
            tmp = temporary(folder / path.name[: -len(".zip")])
            try:
                limit = _unzip_limit(path, members[0].file_size, folder)
                with zf.open(members[0]) as src, tmp.open("wb") as dst:
                    while chunk := src.read(_MB):
                        if dst.tell() + len(chunk) > limit:
                            _refuse_unzip(path, dst.tell() + len(chunk), folder)
                        dst.write(chunk)
            except BaseException:
                discard(tmp)
                raise
    except (zipfile.BadZipFile, EOFError) as err:
        raise BagError(f"{path}: corrupt zip archive ({err})") from err
    except OSError as err:
        raise BagError(f"{path}: cannot unpack ({err.strerror or err})") from err
    try:
        yield tmp
    finally:
        discard(tmp)


def _unzip_limit(path: Path, declared: int, folder: Path) -> int:
    """The most bytes the bag of ``path`` may unpack to in ``folder``; refuses one whose
    ``declared`` size is more."""
    room = shutil.disk_usage(folder).free - UNZIP_RESERVE
    limit = min(_ratio_cap(path), room)
    if declared > limit:
        _refuse_unzip(path, declared, folder)
    return limit


def _ratio_cap(path: Path) -> int:
    """What the bag of the archive ``path`` may unpack to, by the archive's size alone."""
    return max(UNZIP_RATIO * path.stat().st_size, UNZIP_FLOOR)


def _refuse_unzip(path: Path, size: int, folder: Path) -> None:
    """Raise the :class:`BagError` for a bag of ``path`` that unpacks to ``size`` bytes or more."""
    zipped = path.stat().st_size
    if size > _ratio_cap(path):
        raise BagError(
            f"{path}: its bag unpacks to {size_text(size)} or more, over {UNZIP_RATIO} times the "
            f"archive's {size_text(zipped)}: a zip bomb or a damaged archive; if it is a bag, "
            "unzip it yourself and give the .bag"
        )
    free = shutil.disk_usage(folder).free
    raise BagError(
        f"{path}: its bag unpacks to {size_text(size)} or more, and {folder} has {size_text(free)} "
        f"free (lidarflow leaves {size_text(UNZIP_RESERVE)}); free some space, or unzip it "
        "yourself and give the .bag"
    )
