"""Writing files whole or not at all: a temporary name beside the target, then a rename.

Every file lidarflow writes (recordings, reports, pictures, ONNX files, bags) goes through
:func:`atomic_path`: the writer gets a fresh path in the target's folder that does not exist yet
(bag writers insist on that), with the target's suffix (writers that pick the format by it keep
working), and only a writer that finished sees its output renamed onto the target with
``os.replace`` (atomic on one file system). A writer that fails, or is interrupted
(``KeyboardInterrupt``; the CLI turns SIGTERM into one too), leaves the target as it was, and its
temporary is removed. A run killed outright (SIGKILL, power loss) can leave a temporary, never
a half-written target: the temporaries are named ``.NAME.PID.partial`` (+ the suffix), and
the next write into that folder, of any target, removes those whose process is gone. A
temporary is never removed while its process runs: one whose PID another live process has
since taken stays until that process ends too; one whose PID is this process's own (a
container's PIDs repeat from run to run) goes unless this process made it.

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
from collections.abc import Iterable, Iterator
from pathlib import Path

from lidarflow.errors import OutputError

__all__ = [
    "atomic_path",
    "check_not_input",
    "check_writable",
    "clear_stale",
    "commit",
    "discard",
    "temporary",
    "write_bytes",
    "write_text",
]

_SUFFIX = ".partial"
#: The temporaries this process has handed out: the only ones named with its PID that are its.
_MINE: set[Path] = set()


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


def check_not_input(output: str | Path, inputs: Iterable[str | Path | None]) -> None:
    """Refuse an ``output`` that would replace one of ``inputs``, whatever ``--force`` says:
    the same file (by its resolved path, through symbolic links, or by inode: a hard link), a
    folder that holds an input, or a path inside an input ROS 2 bag folder. Inputs that are
    not there (``bundled``, a glob pattern) are skipped: there is nothing to destroy."""
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
        if (source / "metadata.yaml").is_file() and (
            source in out.parents or any(_same_file(out, f) for f in source.rglob("*"))
        ):
            raise OutputError(
                f"{output} is inside the input bag {given}: writing it would change that bag; "
                "name an output outside it"
            )


def _same_file(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` are one file on disk (hard links too); ``False`` where one is
    not there."""
    try:
        return a.samefile(b)
    except OSError:
        return False


def temporary(target: str | Path) -> Path:
    """A path beside ``target`` that does not exist: ``.NAME.PID[.N].partial`` + its suffix
    (``.x.npz.123.partial.npz``), so that format-by-suffix writers still see ``.npz``. The
    temporaries in its folder that processes killed outright left are removed first
    (:func:`clear_stale`); the parent is created."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
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


def clear_stale(folder: str | Path) -> list[Path]:
    """Remove the temporaries in ``folder`` (files, or folders with what was staged in them)
    that processes killed outright left: those whose process is gone (see the module's
    docstring for PIDs taken again); returns them."""
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
    """The PIDs a temporary named ``name`` (``.NAME.PID[.N].partial`` + NAME's suffix) may have
    been made by: none for a name :func:`temporary` does not make, two where it reads both
    ways (``.x.5.5.7.partial.5``)."""
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
    """Whether the temporary ``entry`` named with ``pid`` may still be written."""
    if pid == os.getpid():
        return Path(os.path.abspath(entry)) in _MINE
    return _alive(pid)


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
