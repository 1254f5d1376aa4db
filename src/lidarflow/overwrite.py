"""What an output may replace: the rule every command keeps, decided here and nowhere else.

A file is replaced only by a file, a folder only by a folder that lidarflow wrote (it holds
:data:`STAMP`); a named output that exists only with ``force``, and never one that appeared
while the command ran; inputs are never outputs. How an output is written so that the rule
holds to the end is :mod:`lidarflow.atomic`'s.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path

from lidarflow.errors import OutputError

__all__ = [
    "STAMP",
    "check_kind",
    "check_not_input",
    "check_writable",
    "is_ours",
    "may_replace",
    "stamp",
]

#: The file in every folder lidarflow wrote: what makes the folder one it may replace.
STAMP = ".lidarflow"
#: The outputs the user named (:func:`check_writable`), each with its ``force``. A target not
#: named here (a checkpoint in a run folder) may replace a file of its kind.
_NAMED: dict[Path, bool] = {}


def _key(path: str | Path) -> Path:
    return Path(os.path.abspath(path))


def check_writable(path: str | Path, force: bool = False, folder: bool = False) -> None:
    """Claim ``path`` as an output (a ``folder`` or a file); an :class:`OutputError` where it
    exists, unless ``force``, or where :func:`check_kind` refuses it even with ``force``."""
    path = Path(path)
    _NAMED[_key(path)] = force
    if not (path.exists() or path.is_symlink()):
        return
    check_kind(path, folder)
    if not force:
        raise OutputError(f"{path} already exists; use --force to overwrite it")


def check_kind(path: Path, folder: bool) -> None:
    """An :class:`OutputError` where the existing ``path`` may not be replaced by a ``folder``
    (or a file), whatever ``--force`` says: it is the other kind, or a folder not ours."""
    is_dir = path.is_dir() and not path.is_symlink()
    if is_dir and not folder:
        raise OutputError(
            f"{path} is a folder; name a file to write (not even --force replaces a folder "
            "with a file)"
        )
    if folder and not is_dir:
        raise OutputError(f"{path} exists and is not a folder; name a new folder")
    if is_dir and not is_ours(path):
        raise OutputError(
            f"{path} exists and is not a folder lidarflow wrote (no {STAMP} in it); name a new "
            "folder, or remove it yourself (not even --force replaces it)"
        )


def may_replace(target: str | Path) -> bool:
    """Whether the existing ``target`` may be replaced: a named output only where named with
    ``force``; a target not named always."""
    return _NAMED.get(_key(target), True)


def is_ours(folder: str | Path, ignoring: Callable[[str], bool] | None = None) -> bool:
    """Whether ``folder`` may be replaced or emptied: it holds :data:`STAMP`, or nothing but
    entries whose names ``ignoring`` accepts."""
    folder = Path(folder)
    if (folder / STAMP).is_file():
        return True
    return all(ignoring is not None and ignoring(e.name) for e in folder.iterdir())


def stamp(folder: str | Path) -> None:
    """Mark ``folder`` as written by lidarflow (:data:`STAMP`: the command that wrote it)."""
    (Path(folder) / STAMP).write_text(
        json.dumps({"written_by": "lidarflow", "command": sys.argv}) + "\n"
    )


def check_not_input(output: str | Path, inputs: Iterable[str | Path | None]) -> None:
    """An :class:`OutputError` where ``output`` would replace one of ``inputs``, whatever
    ``--force`` says: the same file (through symbolic or hard links), a folder holding an
    input, a file inside an input folder, or any path inside an input ROS 2 bag. Inputs not on
    disk (``bundled``, a glob pattern) are skipped."""
    out = Path(os.path.abspath(output)).resolve()
    for given in inputs:
        if given is None or not Path(given).exists():
            continue
        source = Path(os.path.abspath(given)).resolve()
        if out == source or _same_file(out, source):
            raise OutputError(
                f"{output} is the input {given}: name another output (not even --force "
                "overwrites an input)"
            )
        if out in source.parents:
            raise OutputError(
                f"{output} holds the input {given}: writing it would remove that; name "
                "another output"
            )
        if source.is_dir() and (
            (out.exists() and any(_same_file(out, f) for f in source.rglob("*")))
            or ((source / "metadata.yaml").is_file() and source in out.parents)
        ):
            raise OutputError(
                f"{output} is inside the input {given}: writing it would change that input; "
                "name an output outside it"
            )


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.samefile(b)
    except OSError:  # one of them is not there
        return False
