"""What every input file must be before lidarflow opens it: a regular file.

A named pipe blocks its reader and a character device (``/dev/zero``) never ends; both readers
of inputs refuse them by what ``stat`` says, which opens nothing.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from lidarflow.errors import LidarflowError

__all__ = ["check_regular"]

_KINDS = (
    (stat.S_ISFIFO, "a named pipe"),
    (stat.S_ISCHR, "a character device"),
    (stat.S_ISBLK, "a block device"),
    (stat.S_ISSOCK, "a socket"),
)


def check_regular(path: str | Path, error: type[LidarflowError], folder: bool = False) -> None:
    """Raise ``error`` (one line naming ``path``) unless ``path`` is a regular file, through
    symbolic links; or, where ``folder``, a folder whose top-level files (a ROS 2 bag's) are.
    A path that is not there passes: the reader says so in its own words."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if folder and stat.S_ISDIR(mode):
        with os.scandir(path) as entries:
            for entry in entries:
                check_regular(entry.path, error)
        return
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):  # a folder where a file is due: the reader
        return  # says what it expected
    kind = next((name for test, name in _KINDS if test(mode)), "a special file")
    shown = f"{path}" if not path.is_symlink() else f"{path} (-> {os.path.realpath(path)})"
    raise error(
        f"{shown}: {kind}, not a file; lidarflow reads recordings and bags from regular files "
        "(copy the data to one)"
    )
