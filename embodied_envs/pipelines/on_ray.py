"""A Ray cluster behind the episode executor's interface (``--ray``): :class:`RayExecutor`,
one Ray task per submitted episode, at most ``in_flight`` at once; connecting
(:func:`session`, :func:`start`, :func:`check_address`) and the files a job sends.

Each task runs in a worker process that keeps its env (or its evaluation runner) for the next
task (``executor.cached``), reads the job's files from its node's copy (``cluster.Bundle``:
layouts, asset folders, splat, a policy file) and sends back what it recorded, its paths
mapped back onto the driver's. The tasks are the ones ``--workers`` runs (the env starts every
seed's episode from a new PhysX scene: nothing depends on what a worker ran before), so a
seed's episode is the same on either. A task whose worker process dies runs again, up to
``cluster.TASK_RETRIES`` times; a task's exception comes back as it was raised.
"""

from __future__ import annotations

import contextlib
import os
import socket
from collections.abc import Callable, Iterable
from concurrent.futures import Future
from pathlib import Path

from embodied_envs.cluster import (
    RAY_LOCAL,
    TASK_RETRIES,
    Bundle,
    CarriedError,
    ClusterError,
    TaskExit,
    cluster_cpus,
    named,
    ray_session,
    remote_task,
    start_early,
    starting,
)
from embodied_envs.layout import load_layout
from embodied_envs.layout.sets import layout_files
from embodied_envs.pipelines.executor import TASKS_AHEAD, EpisodeExecutor, chained
from embodied_envs.workers import started

CONNECT_SECONDS = 10.0  # a cluster address's TCP connection, tried before Ray's (which retries
# an address where nothing listens for minutes, printing its warnings)


@contextlib.contextmanager
def session(address: str | None, workers: int):
    """Ray for a run: none for ``address`` None; the caller's, if it connected already;
    otherwise ``address``'s (``RAY_LOCAL``: a Ray of this machine with ``workers`` CPUs, 0:
    all). The driver builds no env: its start-up ends here (``workers.started``)."""
    if address is None:
        yield
        return
    import ray  # only where a run asks for Ray

    args = _session_args(address, workers)
    if ray.is_initialized() and not starting(*args):
        yield
        return
    if not starting(*args):
        check_address(args[0])
    with ray_session(*args):
        started()
        yield


def start(address: str | None, workers: int, warm: str) -> None:
    """Begins the start of :func:`session`'s Ray (none for ``address`` None) while the command
    checks its inputs, its workers importing the module ``warm`` whose episodes they will
    run (``cluster.start_early``)."""
    if address is not None:
        args = _session_args(address, workers)
        check_address(args[0])
        start_early(*args, warm=(warm,))


def check_address(address: str | None) -> None:
    """Raises :class:`ClusterError` in one line, within :data:`CONNECT_SECONDS`, when nothing
    accepts a TCP connection at the cluster ``address`` names (None, or ``auto``:
    ``RAY_ADDRESS``'s, if set), or when it is not ``host:port`` (``ray://`` taken off: Ray's
    client; Ray's traceback said so seconds later). Another scheme's (``name://``) is left to
    Ray."""
    env = os.environ.get("RAY_ADDRESS")
    from_env = address in (None, "auto")
    target = env if from_env else address
    if not target or target in ("auto", RAY_LOCAL) or "://" in target.removeprefix("ray://"):
        return
    host, sep, port = target.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ClusterError(
            f"{named(address)}: {target!r} is not a Ray cluster's address (host:port, "
            "ray://host:port or auto). Fix: give its head's address, e.g. --ray 10.0.0.1:6379"
        )
    try:
        socket.create_connection((host.strip("[]"), int(port)), CONNECT_SECONDS).close()
    except OSError as e:
        why = (f"no answer within {CONNECT_SECONDS:.0f} s" if isinstance(e, TimeoutError)
               else (e.strerror or str(e)).lower())  # fmt: skip
        alone = "unset RAY_ADDRESS and give" if from_env else "give"
        raise ClusterError(
            f"{named(address)}: no Ray cluster reachable at {host}:{port} ({why}). Fix: start one "
            f"there (ray start --head), name a running one, or {alone} --ray without a value "
            "for a Ray of this machine alone"
        ) from None


def _session_args(address: str, workers: int) -> tuple[str | None, int | None]:
    return None if address == RAY_LOCAL else address, workers or None


def scene_paths(layout) -> list:
    """The layout files of ``layout`` (a file or a set) and their asset folders, each folder
    as (the name the layout gives it, ``..`` taken by name as on a node's copy; the folder it
    resolves to): ``cluster.Bundle.put``'s entries."""
    out: list = []
    for file in layout_files(layout):
        lay = load_layout(file, check_files=False)
        out.append(Path(file))
        for node in sorted(lay.assets):
            named = Path(os.path.normpath(os.path.abspath(lay.asset_base / lay.assets[node])))
            out.append((named, lay.asset_dir(node)))
    return out


def in_flight(plan) -> int:
    """The tasks a plan has on the cluster at once: its ``workers`` (else the cluster's CPUs),
    ``TASKS_AHEAD`` per worker where the cluster's CPUs run no more than that many (the
    further ones queue; on a larger cluster they would run: ``--workers`` caps the running)."""
    cpus = cluster_cpus()
    workers = plan.workers or cpus
    return TASKS_AHEAD * workers if workers >= cpus else workers


def _error(e: BaseException, fn: Callable, args: tuple) -> BaseException:
    """A Ray task's failure as the driver raises it: the task's own exception (its
    ``SystemExit`` too), without Ray's traceback; a worker lost more than ``TASK_RETRIES``
    times as :class:`ClusterError`."""
    from ray.exceptions import RayError, RayTaskError  # Ray is imported where a run uses it

    if isinstance(e, RayTaskError):
        cause = e.cause if isinstance(e.cause, Exception) else RuntimeError(str(e))
        return cause.rebuilt() if isinstance(cause, CarriedError | TaskExit) else cause
    if isinstance(e, RayError):
        text = " ".join(str(e).split())[:300]
        return ClusterError(
            f"a Ray task ({fn.__name__}{args[1:]}) was lost {TASK_RETRIES + 1} times: "
            f"{type(e).__name__}: {text}. Fix: see the worker logs (ray logs), or fewer tasks "
            "per node"
        )
    return e


class RayExecutor(EpisodeExecutor):
    """Ray tasks on the cluster ``address`` names (:func:`session`), with the files of
    ``layouts`` (files or sets) and ``files`` (a policy's) sent along (``cluster.Bundle``);
    ``workers`` caps the episodes running at once (0: the cluster's CPUs)."""

    def __init__(self, address: str, workers: int, layouts: Iterable, files: Iterable = ()):
        super().__init__()
        self.address, self.workers = address, workers
        self.groups = ([p for entry in layouts for p in scene_paths(entry)], list(files))
        self.stack = contextlib.ExitStack()
        self.refs: dict[Future, object] = {}

    def start(self) -> None:
        self.stack.enter_context(session(self.address, self.workers))
        try:
            self.bundle = Bundle.put(*self.groups)
        except BaseException:
            self.stack.close()
            raise
        self.slots = in_flight(self)
        self.remote = remote_task()

    def submit(self, fn: Callable, /, *args) -> Future:
        ref = self.remote.remote(fn, self.bundle, args)
        future = chained(ref.future(), self.ran, lambda e: _error(e, fn, args))
        self.refs[future] = ref
        future.add_done_callback(lambda f: self.refs.pop(f, None))
        return future

    def shutdown(self, cancel_futures: bool = False) -> None:
        import ray  # only where a run asks for Ray

        try:
            if cancel_futures:
                for ref in list(self.refs.values()):
                    ray.cancel(ref, force=True)
        finally:
            self.stack.close()
