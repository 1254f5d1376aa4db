"""Writing files whole or not at all: a temporary name beside the target, then a rename.

Every file lidarflow writes (recordings, reports, pictures, ONNX files, bags) goes through
:func:`atomic_path`: the writer gets a fresh path in the target's folder that does not exist yet
(bag writers insist on that), with the target's suffix (writers that pick the format by it keep
working), and only a writer that finished sees its output renamed onto the target with
``os.replace`` (atomic on one file system). A writer that fails, or is interrupted
(``KeyboardInterrupt``; the CLI turns SIGTERM into one too), leaves the target as it was, and its
temporary is removed. A run killed outright (SIGKILL, power loss) can leave a temporary, never
a half-written target: the temporaries are named ``.NAME.PID.partial`` and the next write of
that target clears those of processes that are gone.

>>> import tempfile
>>> folder = Path(tempfile.mkdtemp())
>>> with atomic_path(folder / "a.txt") as tmp:
...     _ = tmp.write_text("done")
>>> sorted(p.name for p in folder.iterdir())
['a.txt']
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
from collections.abc import Iterator
from pathlib import Path

from lidarflow.errors import OutputError

__all__ = [
    "atomic_path",
    "check_writable",
    "commit",
    "discard",
    "temporary",
    "write_bytes",
    "write_text",
]

_SUFFIX = ".partial"


def check_writable(path: str | Path, force: bool = False, marker: str | None = None) -> None:
    """Refuse an existing ``path`` unless ``force``: one line saying what to do. For an output
    that is a folder, ``marker`` names a file that such a folder holds: a folder without it
    (or a file) is not replaced even with ``force``, since replacing a folder removes all it
    holds (``--report .``)."""
    path = Path(path)
    if not (path.exists() or path.is_symlink()):
        return
    if not force:
        raise OutputError(f"{path} already exists; use --force to overwrite it")
    if marker is not None and not (path / marker).is_file():
        raise OutputError(
            f"{path} exists and is not a folder lidarflow wrote (no {marker} in it); "
            "name a new folder"
        )


def temporary(target: str | Path) -> Path:
    """A path beside ``target`` that does not exist: ``.NAME.PID[.N].partial`` + its suffix
    (``.x.npz.123.partial.npz``), so that format-by-suffix writers still see ``.npz``. Temporaries
    of ``target`` left by processes killed outright are removed first; the parent is created."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    _clear_stale(target)
    stem = f".{target.name}.{os.getpid()}"
    for n in range(1000):
        tmp = target.with_name(f"{stem}{'' if n == 0 else f'.{n}'}{_SUFFIX}{target.suffix}")
        if not (tmp.exists() or tmp.is_symlink()):
            return tmp
    raise FileExistsError(f"{target}: no free temporary name beside it")


def discard(path: str | Path) -> None:
    """Remove ``path`` (a file or a folder) if it is there."""
    path = Path(path)
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def commit(written: str | Path, target: str | Path) -> None:
    """Move the finished ``written`` (a file or a folder, beside ``target``) onto ``target``: one
    rename, or for a folder over an existing folder two (the old one moved aside, then removed).
    ``written`` is removed if the move fails."""
    written, target = Path(written), Path(target)
    try:
        if not (written.exists() or written.is_symlink()):
            raise FileNotFoundError(f"{target}: the writer wrote nothing")
        if written.is_file():  # on disk before it carries the target's name
            with written.open("rb") as f:
                os.fsync(f.fileno())
        if target.is_dir() and not target.is_symlink():
            aside = temporary(target.with_name(target.name + ".old"))
            os.replace(target, aside)
            os.replace(written, target)
            discard(aside)
        else:
            os.replace(written, target)
    except BaseException:
        discard(written)
        raise


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def _clear_stale(target: Path) -> None:
    """Remove temporaries of ``target`` (and what was staged beside them) that processes killed
    outright left."""
    pattern = re.compile(rf"\.{re.escape(target.name)}\.(\d+)(\.\d+)?{re.escape(_SUFFIX)}.*")
    if not target.parent.is_dir():
        return
    for entry in target.parent.iterdir():
        match = pattern.fullmatch(entry.name)
        if match and int(match.group(1)) != os.getpid() and not _alive(int(match.group(1))):
            discard(entry)


@contextlib.contextmanager
def atomic_path(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``target`` for the caller to write (a file or a folder);
    on a clean exit it replaces ``target`` (:func:`commit`), on any exception
    (``KeyboardInterrupt`` too) it is removed and ``target`` stays as it was."""
    tmp = temporary(target)
    try:
        yield tmp
    except OSError as err:
        discard(tmp)
        raise _named_for(err, tmp, target) from err
    except BaseException:
        discard(tmp)
        raise
    commit(tmp, target)


def _named_for(err: OSError, tmp: Path, target: str | Path) -> OSError | OutputError:
    """``err`` as the user should read it: where it names the temporary (or a file inside a
    temporary folder), a refusal naming ``target``, which the user asked for."""
    named = Path(err.filename) if isinstance(err.filename, str | os.PathLike) else None
    if named is None or not (named == tmp or tmp in named.parents):
        return err
    return OutputError(f"{target}: cannot be written there ({err.strerror or err})")


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    return write_bytes(path, text.encode("utf-8"))
