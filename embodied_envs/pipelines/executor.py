"""The one interface that runs episodes, whatever runs them: :class:`EpisodeExecutor`, in the
spirit of ``concurrent.futures.Executor`` (``submit`` gives a ``Future``, the executor is a
context manager that starts its backend and shuts it down).

Two backends: this machine's processes (``pipelines/processes.py``: ``--workers``) and a Ray
cluster (``pipelines/on_ray.py``: ``--ray``). What ``collect`` and ``eval`` do with the
episodes (progress, seed order, error lines, the resumable store) is written once above them,
in ``pipelines/runner.py``. A new backend is one file: a subclass that sends ``fn(*args)``
somewhere, gives back its result or its exception as it was raised, and notes where the task
ran (:class:`Ran`); ``runner.executor_for`` names it.

A task is a module-level function and its arguments; it runs in a worker process that keeps
what it builds (an env, a policy) for the next task (:func:`cached`).
"""

from __future__ import annotations

import dataclasses
from abc import ABC, abstractmethod
from collections.abc import Callable
from concurrent.futures import CancelledError, Future
from typing import Any

TASKS_AHEAD = 2  # tasks queued per worker: a worker starts its next episode at once, not after
# the driver has received and stored its last (one at a time cost ~0.2 s an episode of 0.6)


@dataclasses.dataclass
class Ran:
    """Where a run's tasks ran: the (node, process) pairs."""

    places: set = dataclasses.field(default_factory=set)

    @property
    def workers(self) -> int:
        return max(1, len(self.places))

    @property
    def nodes(self) -> int:
        return max(1, len({node for node, _ in self.places}))


class EpisodeExecutor(ABC):
    """Runs tasks (``fn(*args)``, one episode each) on a backend.

    Attributes:
        slots: the tasks to keep submitted at once so that every worker is busy.
        ran: where the tasks ran.
    """

    slots: int = 1

    def __init__(self) -> None:
        self.ran = Ran()

    @abstractmethod
    def submit(self, fn: Callable, /, *args) -> Future:
        """``fn(*args)`` on the backend: a future of its result, or of the exception it raised
        (as it raised it; a lost worker as the backend's own error)."""

    def start(self) -> None:  # noqa: B027 (a backend with nothing to start keeps it)
        """Starts the backend (its processes, its cluster connection)."""

    @abstractmethod
    def shutdown(self, cancel_futures: bool = False) -> None:
        """Ends the backend: after the submitted tasks, or with ``cancel_futures`` at once
        (those still running are stopped)."""

    def __enter__(self) -> EpisodeExecutor:
        self.start()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.shutdown(cancel_futures=exc_type is not None)


def chained(inner: Future, ran: Ran, error: Callable[[BaseException], BaseException]) -> Future:
    """The future of a task's own result, from ``inner``'s ``(result, node, process)`` (the
    place noted in ``ran``); ``inner``'s exception as ``error`` gives it."""
    outer: Future = Future()

    def done(f: Future) -> None:
        try:
            result, node, pid = f.result()
        except CancelledError:
            outer.cancel()
            return
        except BaseException as e:  # the task's, or the backend's (a lost worker)
            outer.set_exception(error(e))
            return
        ran.places.add((node, pid))
        outer.set_result(result)

    inner.add_done_callback(done)
    return outer


# --- what a worker process keeps between tasks ----------------------------------------------
_CACHED: dict[str, tuple[Any, Any, Callable[[Any], None]]] = {}  # kind -> (key, object, close)


def cached(kind: str, key: Any, make: Callable[[], Any], close: Callable[[Any], None]) -> Any:
    """In a worker process: the object of ``kind`` made for ``key`` (an env, a runner), made on
    first use and kept for the next tasks; one for another key replaces it (``close``)."""
    if kind in _CACHED and _CACHED[kind][0] == key:
        return _CACHED[kind][1]
    if kind in _CACHED:
        _, old, old_close = _CACHED.pop(kind)
        old_close(old)
    _CACHED[kind] = (key, make(), close)
    return _CACHED[kind][1]


def release_cached() -> None:
    """Closes what :func:`cached` keeps in this process (a run's tasks ran in it)."""
    while _CACHED:
        _, (_, obj, close) = _CACHED.popitem()
        close(obj)
