"""The commands' worker processes: :func:`run` (``layout generate``, ``demo``) and the pool
under ``collect`` and ``eval``'s episode executor (:func:`process_pool`,
``pipelines/processes.py``).

Tasks run in this process (``workers=1``) or in a pool of worker processes (forkserver by
default: safe with torch and SAPIEN). A worker exits as soon as the command that started it is
gone, even after SIGKILL, so no orphan keeps writing outputs, and leaves Ctrl-C to the
command. A worker that dies (killed, out of memory) is noticed within ``POLL_SECONDS``:
:func:`run` stops the others and raises :class:`WorkerError`; an exception raised by a task
stops the run the same way and is raised again in the parent as it was. Tasks send progress
with :func:`report`.
"""

from __future__ import annotations

import gc
import multiprocessing as mp
import os
import signal
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

PARENT_CHECK_SECONDS = 0.5  # how often a worker looks whether its parent is still there
POLL_SECONDS = 0.1  # how often the parent looks at results, progress and dead workers


class WorkerError(RuntimeError):
    """A worker process died without finishing its task."""


DIED = (  # WorkerError's message
    "a worker process died (killed, or out of memory). Fix: fewer --workers, or see the system "
    "log for the killer"
)


_report: Callable[[Any], None] | None = None  # where report() sends progress


def report(message: Any) -> None:
    """From inside a task: hand ``message`` to the parent's ``on_progress`` (picklable)."""
    if _report is not None:
        _report(message)


_starting = False  # the garbage collector is off for a command's start-up (start_up)


def start_up() -> None:
    """A command's start-up begins: the garbage collector is off until :func:`started`.
    Importing ManiSkill, torch and SAPIEN and building the first env makes ~300,000 objects
    that live as long as the process; each full collection among them walks them all (0.3 s
    of a command's 2 s start-up). A collection forced meanwhile (ManiSkill forces one when it
    builds a scene) finds every object alive then set aside first (:func:`_set_aside`): it
    walks none of them (0.2 s less)."""
    global _starting
    gc.disable()
    if _set_aside not in gc.callbacks:
        gc.callbacks.append(_set_aside)
    _starting = True


def _set_aside(phase: str, info: dict) -> None:
    """A collection starts during a start-up: what is alive is set aside (``gc.freeze``),
    as :func:`started` sets it aside at the start-up's end."""
    if phase == "start":
        gc.freeze()


def started() -> None:
    """The start-up is over (a task built its env): when :func:`start_up` turned the collector
    off, every object alive now is set aside from its walks (``gc.freeze``) and it runs
    again; otherwise nothing changes (library use, worker processes)."""
    global _starting
    if _starting:
        _starting = False
        if _set_aside in gc.callbacks:
            gc.callbacks.remove(_set_aside)
        gc.freeze()
        gc.enable()


def exit_with_parent(parent_pid: int) -> None:
    """Start a daemon thread that ends this process as soon as ``parent_pid`` is no longer its
    parent (the parent was killed, even by SIGKILL): no orphan keeps writing outputs."""

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_CHECK_SECONDS)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def _init_worker(progress, initializer, initargs) -> None:
    global _report
    os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")
    # Ctrl-C reaches every process of the terminal's group: the command alone decides (it
    # keeps what it received and stops the workers), no worker prints a traceback of its own
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # the parent here is the command itself (fork) or its forkserver, which ends with it
    exit_with_parent(os.getppid())
    _report = None if progress is None else progress.put
    if initializer is not None:
        initializer(*initargs)


def run(
    fn: Callable,
    tasks: Sequence[tuple],
    workers: int = 1,
    *,
    initializer: Callable | None = None,
    initargs: tuple = (),
    on_result: Callable[[Any], None] | None = None,
    on_progress: Callable[[Any], None] | None = None,
    context: str = "forkserver",
) -> list:
    """``fn(*task)`` for every task; the results in task order.

    Args:
        fn: a module-level function (pickled by name for worker processes).
        tasks: argument tuples.
        workers: processes; 1 runs every task here, in order.
        initializer: called with ``initargs`` once per process before its first task.
        on_result: called in the parent with each result as it arrives.
        on_progress: called in the parent with each :func:`report` message.
        context: the multiprocessing start method of the workers.

    Raises:
        WorkerError: a worker process died.
        Exception: whatever a task raised, as it raised it.
    """
    global _report
    if workers <= 1:
        previous, _report = _report, on_progress
        try:
            if initializer is not None:
                initializer(*initargs)
            results = []
            for task in tasks:
                results.append(fn(*task))
                if on_result is not None:
                    on_result(results[-1])
            return results
        finally:
            _report = previous
    ctx = mp.get_context(context)
    # a SimpleQueue writes in the task's own thread: a task's reports are in the pipe before
    # its result is sent, so the last drain sees them all (a Queue's feeder thread may lag)
    progress = ctx.SimpleQueue() if on_progress is not None else None

    def drain() -> None:
        while progress is not None and not progress.empty():
            on_progress(progress.get())

    pool = process_pool(min(workers, max(1, len(tasks))), initializer, initargs, context, progress)
    ok = False
    try:
        futures = {pool.submit(fn, *task): k for k, task in enumerate(tasks)}
        results: list = [None] * len(tasks)
        pending = set(futures)
        while pending:
            done, pending = wait(pending, timeout=POLL_SECONDS, return_when=FIRST_COMPLETED)
            drain()
            for fut in done:
                results[futures[fut]] = fut.result()
                if on_result is not None:
                    on_result(results[futures[fut]])
        drain()
        ok = True
        return results
    except BrokenProcessPool:
        raise WorkerError(DIED) from None
    finally:
        stop_pool(pool, now=not ok)


def process_pool(
    workers: int,
    initializer: Callable | None = None,
    initargs: tuple = (),
    context: str = "forkserver",
    progress=None,
) -> ProcessPoolExecutor:
    """A pool of ``workers`` processes that end with the command (even after its SIGKILL) and
    ignore Ctrl-C (the command stops them: :func:`stop_pool`); each runs
    ``initializer(*initargs)`` first.

    Args:
        workers: processes.
        initializer: called with ``initargs`` once per process before its first task.
        initargs: its arguments.
        context: the multiprocessing start method.
        progress: a queue that :func:`report` puts the tasks' messages in (None: dropped).
    """
    return ProcessPoolExecutor(
        workers,
        mp_context=mp.get_context(context),
        initializer=_init_worker,
        initargs=(progress, initializer, initargs),
    )


def stop_pool(pool: ProcessPoolExecutor, now: bool) -> None:
    """Ends ``pool``: after its tasks, or ``now`` (a task's error, a dead worker, Ctrl-C): its
    processes are stopped at once, not when their tasks end."""
    if not now:
        pool.shutdown(wait=True)
        return
    processes = list((pool._processes or {}).values())  # the stdlib keeps no public list
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        p.terminate()
