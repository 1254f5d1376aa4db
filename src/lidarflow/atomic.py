"""Writing outputs whole or not at all, and never over what lidarflow did not write.

A writer gets a fresh temporary beside the target (:func:`atomic_path`, :func:`atomic_paths`),
named ``.NAME.PID[.N].partial`` + the target's suffix; only a finished writer's output is
moved onto the target (:func:`commit`), in one step (a folder by ``renameat2`` exchange on
Linux). A writer that fails or is interrupted leaves the target as it was; a temporary left by
a process killed outright is removed by the next write into its folder, never while its
process may still write it (:func:`clear_stale`). What may be replaced is
:mod:`lidarflow.overwrite`'s rule, kept by :func:`commit` at the last step.

>>> import tempfile
>>> folder = Path(tempfile.mkdtemp())
>>> with atomic_path(folder / "a.txt") as tmp:
...     _ = tmp.write_text("done")
>>> sorted(p.name for p in folder.iterdir())
['a.txt']
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import re
import shutil
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path

from lidarflow.errors import OutputError
from lidarflow.overwrite import (
    STAMP,
    check_kind,
    check_not_input,
    check_writable,
    is_ours,
    may_replace,
    stamp,
)

__all__ = [
    "STAMP",
    "atomic_path",
    "atomic_paths",
    "check_not_input",
    "check_writable",
    "clear_stale",
    "commit",
    "discard",
    "is_ours",
    "named_for",
    "stamp",
    "temporary",
    "write_bytes",
    "write_text",
]

_SUFFIX = ".partial"
#: The temporaries this process has handed out: the only ones named with its PID that are its.
_MINE: set[Path] = set()


def temporary(target: str | Path) -> Path:
    """A path beside ``target`` that does not exist, ending in ``target``'s suffix so that
    format-by-suffix writers still work; creates the parent and clears stale temporaries."""
    target = Path(target)
    if not target.name:
        raise OutputError(f"{target}: not a file name; name the output to write in it")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError) as err:  # a file where a folder should be
        folders = (target.parent, *target.parent.parents)
        file = next((f for f in folders if f.exists() and not f.is_dir()), None)
        if file is None:
            raise
        raise OutputError(f"{target}: {file} is a file, not a folder; name another output") from err
    clear_stale(target.parent)
    stem = f".{target.name}.{os.getpid()}"
    for n in range(1000):
        tmp = target.with_name(f"{stem}{'' if n == 0 else f'.{n}'}{_SUFFIX}{target.suffix}")
        if not (tmp.exists() or tmp.is_symlink()):
            _MINE.add(Path(os.path.abspath(tmp)))
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
    """Move the finished ``written`` (a file or a folder beside ``target``) onto ``target`` in
    one step, stamping a folder first; an :class:`OutputError` where the rule of
    :mod:`lidarflow.overwrite` refuses what is at ``target``. ``written`` is removed if the
    move fails or is refused."""
    written, target = Path(written), Path(target)
    try:
        if not (written.exists() or written.is_symlink()):
            raise FileNotFoundError(f"{target}: the writer wrote nothing")
        folder = written.is_dir() and not written.is_symlink()
        if folder:
            stamp(written)
        else:  # on disk before it carries the target's name
            with written.open("rb") as f:
                os.fsync(f.fileno())
        force = may_replace(target)
        if _rename(written, target, _NOREPLACE):
            return
        check_kind(target, folder)
        if not force:
            raise OutputError(
                f"{target} appeared while this run wrote it (another run writing the same "
                "output?); it was left as it is: rerun with --force to replace it"
            )
        if not folder:
            os.replace(written, target)
        elif _rename(written, target, _EXCHANGE):
            discard(written)  # the old folder, now under the temporary name
        else:  # no atomic exchange here: move the old one aside first
            aside = temporary(target.with_name(target.name + ".old"))
            os.replace(target, aside)
            os.replace(written, target)
            discard(aside)
    except BaseException:
        discard(written)
        raise


_NOREPLACE, _EXCHANGE = 1, 2  # renameat2's RENAME_NOREPLACE, RENAME_EXCHANGE (linux/fs.h)
_AT_FDCWD = -100
_libc = ctypes.CDLL(None, use_errno=True) if sys.platform.startswith("linux") else None
_renameat2 = getattr(_libc, "renameat2", None)


def _rename(src: Path, dst: Path, flag: int) -> bool:
    """Linux's ``renameat2(src, dst, flag)``: ``True`` where done; ``False`` where ``dst`` is
    there (``_NOREPLACE``) or is not (``_EXCHANGE``). Without it, portable calls do
    ``_NOREPLACE`` (a hard link, or a checked rename of a folder) and ``_EXCHANGE`` is
    ``False``."""
    if _renameat2 is not None:
        done = _renameat2(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), flag)
        if done == 0:
            return True
        code = ctypes.get_errno()
        if flag == _NOREPLACE and code == errno.EEXIST:
            return False
        if flag == _EXCHANGE and code == errno.ENOENT and src.exists():
            return False
        if code not in (errno.ENOSYS, errno.EINVAL, errno.EPERM, errno.EOPNOTSUPP):
            raise OSError(code, os.strerror(code), str(dst))
    if flag == _EXCHANGE:
        return False
    if dst.exists() or dst.is_symlink():
        return False
    if src.is_dir():
        os.rename(src, dst)
        return True
    try:
        os.link(src, dst)
    except FileExistsError:
        return False
    os.unlink(src)
    return True


def clear_stale(folder: str | Path) -> list[Path]:
    """Remove the temporaries in ``folder`` whose process is gone; returns them. One whose PID
    another live process has taken stays until that ends; one with this process's PID (PIDs
    repeat across container runs) goes unless this process made it."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    stale = []
    for entry in folder.iterdir():
        owners = _owners(entry.name)
        if owners and not any(_running(pid, entry) for pid in owners):
            discard(entry)
            stale.append(entry)
    return stale


_NUMBER = re.compile(r"[0-9]+")


def _owners(name: str) -> list[int]:
    """The PIDs a temporary named ``name`` may have been made by: none for a name
    :func:`temporary` does not make, two where it reads both ways (``.x.5.5.7.partial.5``)."""
    owners = []
    for found in re.finditer(re.escape(_SUFFIX), name):
        head, tail = name[: found.start()], name[found.end() :]
        parts = head.split(".")
        for numbers in (1, 2):  # .NAME.PID or .NAME.PID.N
            target = ".".join(parts[1:-numbers])
            if (
                parts[0] == ""
                and len(parts) > numbers + 1
                and all(_NUMBER.fullmatch(p) for p in parts[-numbers:])
                and target
                and Path(target).suffix == tail
            ):
                owners.append(int(parts[-numbers]))
    return owners


def _running(pid: int, entry: Path) -> bool:
    if pid == os.getpid():
        return Path(os.path.abspath(entry)) in _MINE
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


@contextlib.contextmanager
def atomic_path(target: str | Path) -> Iterator[Path]:
    """Yield a temporary path for the caller to write ``target`` to (a file or a folder),
    committed on a clean exit and removed on any exception (``KeyboardInterrupt`` too)."""
    with atomic_paths([target]) as (tmp,):
        yield tmp


@contextlib.contextmanager
def atomic_paths(targets: Sequence[str | Path]) -> Iterator[list[Path]]:
    """:func:`atomic_path` for outputs written together (a recording's chunks): committed in
    order once the caller finished; on any exception none is."""
    temps = [temporary(t) for t in targets]
    try:
        try:
            yield temps
        except OSError as err:
            named = named_for(err, temps, targets)
            if named is err:
                raise
            raise named from err
        for tmp, target in zip(temps, targets, strict=True):
            commit(tmp, target)
    except BaseException:
        for tmp in temps:  # those committed are gone already
            discard(tmp)
        raise


def named_for(
    err: OSError, temps: Sequence[Path], targets: Sequence[str | Path]
) -> OSError | OutputError:
    """``err`` as an :class:`OutputError` naming the target (of ``targets``) where it names
    one of ``temps`` (or a file in one) or is a disk's refusal naming no file; else ``err``."""
    named = Path(err.filename) if isinstance(err.filename, str | os.PathLike) else None
    if named is None and err.errno not in _DISK_ERRORS:
        return err
    for tmp, target in zip(temps, targets, strict=True):
        if named is None or named == tmp or tmp in named.parents:
            return OutputError(f"{target}: cannot be written there ({err.strerror or err})")
    return err


#: What a file system says of a write it cannot take, whether or not it names the file.
_DISK_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EIO}


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns ``path``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return path


def write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically; returns ``path``."""
    return write_bytes(path, text.encode("utf-8"))
