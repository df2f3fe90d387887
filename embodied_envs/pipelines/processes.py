"""This machine's processes behind the episode executor's interface (``--workers``).

``workers=1`` runs each task in this process, in order, at once (no process to start; what
the tasks keep, :func:`executor.cached`, is closed at the end). More run in a pool of worker
processes (``workers.process_pool``: forkserver, ending with the command, Ctrl-C left to the
command), each keeping its env between tasks. A dead worker is ``workers.WorkerError``; a
task's exception comes back as it was raised, also one that pickle cannot rebuild
(``cluster.CarriedError``, as on Ray).
"""

from __future__ import annotations

import os
import pickle
from collections.abc import Callable
from concurrent.futures import Future
from concurrent.futures.process import BrokenProcessPool

from embodied_envs.cluster import CarriedError
from embodied_envs.pipelines.executor import (
    TASKS_AHEAD,
    EpisodeExecutor,
    chained,
    release_cached,
)
from embodied_envs.workers import DIED, WorkerError, process_pool, stop_pool

NODE = "this machine"  # the node every task runs on


def _call(fn: Callable, args: tuple):
    """In a worker process: ``fn(*args)``, this machine and this process's id; an exception
    that pickle cannot rebuild is carried (:class:`CarriedError`)."""
    try:
        return fn(*args), NODE, os.getpid()
    except Exception as e:
        try:
            pickle.loads(pickle.dumps(e))
        except Exception:
            raise CarriedError.of(e) from None
        raise


def _error(e: BaseException) -> BaseException:
    """A task's exception as the driver raises it."""
    if isinstance(e, CarriedError):
        return e.rebuilt()
    if isinstance(e, BrokenProcessPool):
        return WorkerError(DIED)
    return e


class ProcessExecutor(EpisodeExecutor):
    """``workers`` processes of this machine (1: this process)."""

    def __init__(self, workers: int):
        super().__init__()
        self.workers = max(1, workers)
        self.slots = 1 if self.workers == 1 else TASKS_AHEAD * self.workers
        self.pool = None

    def start(self) -> None:
        if self.workers > 1:
            self.pool = process_pool(self.workers)

    def submit(self, fn: Callable, /, *args) -> Future:
        if self.pool is not None:
            return chained(self.pool.submit(_call, fn, args), self.ran, _error)
        done: Future = Future()
        try:  # here and now; Ctrl-C and the like go up at once
            done.set_result((fn(*args), NODE, os.getpid()))
        except Exception as e:
            done.set_exception(e)
        return chained(done, self.ran, _error)

    def shutdown(self, cancel_futures: bool = False) -> None:
        if self.pool is not None:
            stop_pool(self.pool, now=cancel_futures)
            self.pool = None
        else:
            release_cached()
