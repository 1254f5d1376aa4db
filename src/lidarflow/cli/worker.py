"""What runs in a ``--jobs`` worker process (:mod:`lidarflow.cli.jobs`): its set-up, its stop
signal (the first only: the task's outputs are removed, then the worker exits), its watch on
the parent, one task with its progress; and the :class:`Outcome` a task comes back as."""

from __future__ import annotations

import atexit
import contextlib
import io
import os
import select
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["Outcome", "error_line", "job_bar", "on_signal", "pidfd", "run_task", "start_worker"]


@dataclass(frozen=True)
class Outcome:
    """One input's result: ``value`` or the one-line ``error`` naming the input, and what its
    task wrote on stderr (``notes``)."""

    index: int
    value: Any = None
    error: str | None = None
    notes: str = ""


def error_line(name: str, err: BaseException) -> str:
    """``err`` as one line naming the input ``name``, as the CLI would print it."""
    from lidarflow.cli.app import error_text

    text = error_text(err)
    if text is None:
        text = (
            f"internal error: {type(err).__name__}: {err} (rerun it with --jobs 1 and "
            "LIDARFLOW_DEBUG=1 for the traceback, and please report it)"
        )
    return text if name in text else f"{name}: {text}"


# What a worker process holds (set by start_worker); None in the parent.
_PROGRESS: Any = None
_STOP: Any = None
_BUSY = False
_SIGNALLED = 0  # the stop signal a worker took (0: none yet)


class _QueueBar:
    """A worker's progress bar: its total and its steps go to the parent's one bar."""

    def __init__(self, total: int | None) -> None:
        self.total = total

    def __enter__(self) -> _QueueBar:
        if self.total:
            _PROGRESS.put(("total", self.total))
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def update(self, n: int = 1) -> None:
        _PROGRESS.put(("done", n))


def job_bar(total: int | None, desc: str) -> Any:
    """A progress bar for one input (a context manager with ``update``): its own in the
    parent process, a share of the parent's one bar in a worker."""
    if _PROGRESS is not None:
        return _QueueBar(total)
    from lidarflow.cli.app import progress_bar

    return progress_bar(total, desc)


def on_signal(signum: int, frame: object) -> None:
    global _SIGNALLED
    first = not _SIGNALLED
    _SIGNALLED = _SIGNALLED or signum
    if not _BUSY:  # idle: nothing to clean up
        _exit(128 + _SIGNALLED)
    if first:  # stop the task, whose outputs go through lidarflow.atomic; _run_task then exits
        raise KeyboardInterrupt(f"stopped by signal {signal.Signals(signum).name}")
    # a later one (the parent's SIGTERM after a terminal's SIGINT): the clean-up goes on


def _exit(code: int) -> None:
    """End this worker now, its exit handlers run (they release the semaphores made here),
    without going back to the pool's loop, which would wait for another task."""
    for signum in (signal.SIGINT, signal.SIGTERM):  # one raised in the exit handlers would
        signal.signal(signum, signal.SIG_IGN)  # print a traceback
    atexit._run_exitfuncs()
    os._exit(code)


def _watch_parent(parent: int) -> None:
    """SIGTERM this worker every second once the process ``parent`` has ended, watched from a
    thread (a pidfd on Linux, else a check every half second)."""

    def watch() -> None:
        fd = pidfd(parent)
        if fd is not None:
            select.select([fd], [], [])  # readable once the process ends
        else:  # no pidfds here, or the parent is gone already
            with contextlib.suppress(ProcessLookupError):
                while True:
                    os.kill(parent, 0)
                    time.sleep(0.5)
        while True:  # again: one taken as a task ends stops that task, not the worker
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(1.0)

    threading.Thread(target=watch, name="lidarflow-parent-watch", daemon=True).start()


def start_worker(progress: Any, stop: Any, threads: int, block_torch: bool, parent: int) -> None:
    """A worker's set-up, before its first task (see the module)."""
    global _PROGRESS, _STOP
    _PROGRESS, _STOP = progress, stop
    progress.cancel_join_thread()  # exit without waiting for the parent to read the progress
    if block_torch:
        from lidarflow.extras import TORCH_EXTRA_MODULES

        for name in TORCH_EXTRA_MODULES:
            sys.modules[name] = None  # type: ignore[assignment]
    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    _watch_parent(parent)
    from lidarflow.cli.app import use_threads

    use_threads(threads)


def run_task(work: Callable[[Any], Any], index: int, name: str, task: Any) -> Outcome:
    """Run ``work(task)`` in a worker: its result, or its error as one line."""
    global _BUSY
    notes = io.StringIO()
    _BUSY = True
    try:
        if _SIGNALLED or (_STOP is not None and _STOP.is_set()):  # handed out as it stopped
            raise KeyboardInterrupt("stopped")
        with contextlib.redirect_stderr(notes):
            value = work(task)
        return Outcome(index, value, None, notes.getvalue())
    except Exception as err:
        if os.environ.get("LIDARFLOW_DEBUG") == "1":
            notes.write(traceback.format_exc())
        return Outcome(index, None, error_line(name, err), notes.getvalue())
    finally:
        if _SIGNALLED:  # the task's clean-up is done: this worker stops with it
            _exit(128 + _SIGNALLED)
        _BUSY = False


def pidfd(pid: int) -> int | None:
    """A pidfd of the process ``pid`` (Linux), ``None`` where there is none."""
    try:
        return os.pidfd_open(pid)
    except (AttributeError, OSError):
        return None
