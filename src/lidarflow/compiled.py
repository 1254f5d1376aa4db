"""Compiled loops for the per-scan hot spots, where numba is installed (``lidarflow[fast]``).

Each kernel is a plain Python loop that :func:`kernel` hands to numba; every caller keeps a
NumPy reference beside it and takes the kernel only where :func:`ready` says so, so an install
without numba gives the same outputs at NumPy's speed. The kernels do the reference's
arithmetic in its order (no fast-math, no fused multiply-add), so outputs are bit-identical
but for the last bits of point-to-line ICP's sums and of bearings (NumPy's SIMD builds round
``arctan2`` apart from the C library's ``atan2`` the kernels call); the tests compare each
against its reference.

Compiling takes seconds, and a robot wants its first prediction at once. So a kernel compiles
on a background thread when it is first asked for, for the types it was asked with, while its
caller takes the NumPy reference; from the next call after that it runs compiled. Compiled code
is cached on disk (numba's ``cache=True``: beside the module, or in the user's cache when that
is read-only; ``NUMBA_CACHE_DIR`` moves it), so later runs load it in milliseconds; a command
that ends while kernels compile finishes them first (:func:`finish`). While they
compile, some predictions are late: the compiling thread shares Python's lock.
:func:`wait` waits for the compiling to end (benchmarks, and before the process forks).

``LIDARFLOW_COMPILED=0`` turns the kernels off (the NumPy references run);
``LIDARFLOW_COMPILED=wait`` compiles on the first call instead, in the caller (:data:`background`
false).
"""

from __future__ import annotations

import os
import queue
import sys
import threading
from collections.abc import Callable
from typing import Any, TypeVar

__all__ = ["available", "background", "failed", "finish", "kernel", "ready", "wait"]

F = TypeVar("F", bound=Callable[..., Any])

_MODE = os.environ.get("LIDARFLOW_COMPILED", "1")
try:
    if _MODE == "0":
        raise ImportError("turned off by LIDARFLOW_COMPILED=0")
    import numba
except ImportError:
    numba = None

#: Whether a kernel compiles on a background thread (the default) or in its first caller.
background = _MODE != "wait"

# A kernel, or (kernel, variant) for one that callers run on several types (see ready).
_compiled: set[Any] = set()  # those compiled (or loaded from the cache)
_asked: set[Any] = set()  # those asked for: compiling, compiled or failed
_jobs: queue.Queue[tuple[Any, Any, tuple[Any, ...]]] = queue.Queue()
_worker: threading.Thread | None = None
_lock = threading.Lock()
#: The kernels that failed to compile in the background (name: why); their callers take the
#: NumPy reference.
failed: dict[str, str] = {}


def available() -> bool:
    """Whether the kernels can run compiled (numba importable and not turned off)."""
    return numba is not None


def kernel(function: F) -> F:
    """``function`` compiled by numba (no Python objects, the GIL released, cached on disk), or
    ``function`` itself where numba is not available: the callers then take their NumPy
    reference, never this loop, which in pure Python would be slow."""
    if numba is None:
        return function
    return numba.njit(cache=True, nogil=True)(function)  # type: ignore[no-any-return]


def ready(loop: Callable[..., Any], *args: Any, variant: Any = None) -> bool:
    """Whether the caller should run the kernel ``loop`` on ``args`` now. False without numba;
    in the background mode, false until ``loop`` is compiled: the first call starts compiling it
    for the types of ``args`` and the caller takes its NumPy reference meanwhile. A kernel that
    callers run on arrays of several types names the type as ``variant`` (a dtype, say), so
    that each compiles in the background; a later call with other types and the same variant
    compiles in the caller, as numba does."""
    if numba is None:
        return False
    key = loop if variant is None else (loop, variant)
    if key in _compiled or not background:
        return True
    with _lock:
        if key not in _asked:
            _asked.add(key)
            _jobs.put((key, loop, tuple(numba.typeof(a) for a in args)))
            _start_worker()
    return False


def wait() -> None:
    """Return when every kernel asked for so far is compiled (or failed to: its caller keeps
    taking the NumPy reference)."""
    _jobs.join()


def finish() -> None:
    """Wait for the kernels still compiling, so that they are cached for the next run: what a
    command that ran to its end calls before it exits (a machine's first runs only; a terminal
    is told why it waits). Without it a first run shorter than the compiling would leave every
    later one to start it again. Not on an interrupt: stopping stays prompt."""
    if _jobs.unfinished_tasks:
        if sys.stderr.isatty():
            sys.stderr.write(
                "lidarflow: compiling the fast loops for the next runs before exiting (a "
                "machine's first runs only; LIDARFLOW_COMPILED=0 turns them off)\n"
            )
        wait()


def _start_worker() -> None:
    global _worker
    if _worker is None or not _worker.is_alive():
        _worker = threading.Thread(target=_compile_jobs, name="lidarflow-compile", daemon=True)
        _worker.start()


def _compile_jobs() -> None:
    while True:
        key, loop, signature = _jobs.get()
        try:
            loop.compile(signature)
            _compiled.add(key)
        except Exception as err:  # one that cannot compile leaves its caller the reference
            failed[getattr(loop, "__name__", repr(loop))] = f"{type(err).__name__}: {err}"
        finally:
            _jobs.task_done()


def _after_fork_in_child() -> None:
    """A forked child has none of the parent's threads: its compiling starts afresh (what the
    parent had compiled is loaded from the cache on the child's first ask)."""
    global _worker, _jobs, _lock
    _worker, _jobs, _lock = None, queue.Queue(), threading.Lock()
    _asked.intersection_update(_compiled)


if numba is not None:
    # A fork while numba compiles would leave the child its compiler lock held by no thread.
    os.register_at_fork(before=wait, after_in_child=_after_fork_in_child)
