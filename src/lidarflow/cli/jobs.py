"""``--jobs N``: the inputs of ``evaluate`` and ``predict`` run N at once, one worker process
per input, each on ``--threads`` threads and NumPy's BLAS and OpenMP on one.

Workers fork from a fork server, which holds no threads (a fork of a process that does can
deadlock) and imports lidarflow and PyTorch once for all of them. Outcomes come back in input
order; a failed task as one line naming its input. Ctrl-C or SIGTERM stops every worker, each
removing what it was writing (:mod:`lidarflow.atomic`); the parent waits for them, killing any
still running :data:`STOP_GRACE_S` later. What a worker does is :mod:`lidarflow.cli.worker`'s.
"""

from __future__ import annotations

import contextlib
import os
import select
import signal
import time
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, Annotated, Any

import typer

from lidarflow.cli.worker import Outcome, error_line, job_bar, pidfd, run_task, start_worker

if TYPE_CHECKING:
    from concurrent.futures import Future

__all__ = ["JobsOpt", "Outcome", "error_line", "job_bar", "resolve_jobs", "run_jobs"]

JobsOpt = Annotated[
    int,
    typer.Option(
        "--jobs",
        "-j",
        help="Inputs run at once, each in its own process on --threads threads (0: one per "
        "core); 1 runs them one after another in this process.",
        min=0,
    ),
]

#: The environment variables that size BLAS and OpenMP thread pools, read when those load.
_THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
#: Seconds a stopped worker has to remove what it was writing before it is killed.
STOP_GRACE_S = 30.0


def resolve_jobs(jobs: int, inputs: int) -> int:
    """The worker processes for ``inputs`` inputs: ``jobs`` (0: one per usable core), never
    more than the inputs."""
    if jobs == 0:
        jobs = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    return max(1, min(jobs or 1, inputs))


@contextlib.contextmanager
def _one_thread_libraries() -> Iterator[None]:
    """Spawned children inherit the environment: BLAS and OpenMP read these when they load."""
    saved = {k: os.environ.get(k) for k in _THREAD_VARIABLES}
    os.environ.update(dict.fromkeys(_THREAD_VARIABLES, "1"))
    try:
        yield
    finally:
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def run_jobs(
    work: Callable[[Any], Any],
    tasks: Sequence[Any],
    names: Sequence[str],
    jobs: int,
    threads: int,
    desc: str,
    on_outcome: Callable[[Outcome], None],
    stop_on_error: bool = False,
) -> list[Outcome]:
    """Run ``work(task)`` for each of ``tasks`` (inputs named ``names``), ``jobs`` at once in
    worker processes (1: in this process), handing each :class:`Outcome` to ``on_outcome`` in
    input order; returns those handed on. ``work`` must be module-level and ``tasks``
    picklable; ``stop_on_error``: the first failure stops the others."""
    done: list[Outcome] = []

    def hand_on(outcome: Outcome) -> bool:
        on_outcome(outcome)
        done.append(outcome)
        return stop_on_error and outcome.error is not None

    if jobs <= 1:
        for i, (name, task) in enumerate(zip(names, tasks, strict=True)):
            if hand_on(_run_here(work, i, name, task)):
                break
        return done
    _run_pool(work, tasks, names, jobs, threads, desc, hand_on)
    return done


def _run_here(work: Callable[[Any], Any], index: int, name: str, task: Any) -> Outcome:
    try:
        return Outcome(index, work(task))
    except Exception as err:
        if os.environ.get("LIDARFLOW_DEBUG") == "1":
            raise
        return Outcome(index, None, error_line(name, err))


def _run_pool(
    work: Callable[[Any], Any],
    tasks: Sequence[Any],
    names: Sequence[str],
    jobs: int,
    threads: int,
    desc: str,
    hand_on: Callable[[Outcome], bool],
) -> None:
    # imported here: one input in one process (the memory-bounded `predict`) never needs them
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    from tqdm import tqdm

    from lidarflow.extras import torch_available

    context = multiprocessing.get_context("forkserver")
    # Imported once in the fork server, not once per worker: PyTorch alone takes seconds.
    preload = ["lidarflow.cli.per_input", "lidarflow.evaluate.methods", "lidarflow.predict"]
    context.set_forkserver_preload(preload + (["torch"] if torch_available() else []))
    progress, stop = context.Queue(), context.Event()
    args = (progress, stop, threads, not torch_available(), os.getpid())
    executor = ProcessPoolExecutor(jobs, context, initializer=start_worker, initargs=args)
    bar = tqdm(total=0, desc=desc, unit="scan", disable=None, leave=False)
    ready: dict[int, Outcome] = {}
    finished = False
    try:
        with _one_thread_libraries():  # the workers start as the tasks are handed out
            pending: dict[Future[Outcome], int] = {
                executor.submit(run_task, work, i, names[i], task): i
                for i, task in enumerate(tasks)
            }
        following = 0
        while following < len(tasks):
            completed, _ = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            _drain(progress, bar)
            for future in completed:
                i = pending.pop(future)
                ready[i] = _outcome_of(future, i, names[i])
            while following in ready:
                with tqdm.external_write_mode():
                    if hand_on(ready.pop(following)):
                        return
                following += 1
            bar.set_postfix_str(f"{following}/{len(tasks)} inputs")
        finished = True
    finally:
        bar.close()
        if not finished:  # interrupted, failed, or stopped on an error: stop the workers
            stop.set()  # a task still handed out after this returns at once
            _stop_workers(list(getattr(executor, "_processes", {}).values()), progress)
        executor.shutdown(wait=True, cancel_futures=True)
        progress.close()


def _stop_workers(processes: list[Any], progress: Any) -> None:
    """SIGTERM each of ``processes``, wait up to :data:`STOP_GRACE_S` for them to end while
    draining their reports (a full pipe would stall them), then kill the rest.

    A worker's end is read from its pidfd where there are pidfds: the pool learns of it through
    the fork server, which a terminal's SIGTERM to the group kills while the worker still runs.
    """
    pidfds: dict[Any, int | None] = {}
    for process in processes:
        with contextlib.suppress(ProcessLookupError):  # not there: ended, and reaped
            os.kill(process.pid, signal.SIGTERM)
            pidfds[process] = pidfd(process.pid)

    def ended(process: Any) -> bool:
        fd = pidfds[process]
        if fd is None:
            return not process.is_alive()
        return bool(select.select([fd], [], [], 0)[0])  # readable once the process ends

    try:
        running = list(pidfds)
        deadline = time.monotonic() + STOP_GRACE_S
        while running and time.monotonic() < deadline:
            _drain(progress, None)
            time.sleep(0.05)
            running = [process for process in running if not ended(process)]
        for process in running:
            with contextlib.suppress(ProcessLookupError):
                os.kill(process.pid, signal.SIGKILL)
    finally:
        for fd in pidfds.values():
            if fd is not None:
                os.close(fd)


def _outcome_of(future: Future[Outcome], index: int, name: str) -> Outcome:
    from concurrent.futures.process import BrokenProcessPool

    try:
        return future.result()
    except BrokenProcessPool:
        return Outcome(
            index,
            None,
            f"{name}: not done: a worker process ended abruptly (killed, or out of "
            "memory?); rerun it, with fewer --jobs if memory is short",
        )


def _drain(progress: Any, bar: Any) -> None:
    """Move what the workers reported onto the parent's bar (``None``: drop it)."""
    import queue

    while True:
        try:
            kind, n = progress.get_nowait()
        except (queue.Empty, OSError, ValueError):
            return
        if bar is None:
            continue
        if kind == "total":
            bar.total += n
            bar.refresh()
        else:
            bar.update(n)
