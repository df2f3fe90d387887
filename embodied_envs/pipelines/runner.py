"""What ``collect`` and ``eval`` do with their episodes, whichever executor runs them
(``pipelines/executor.py``): :func:`run_episodes` hands the tasks to the executor in order, a
few ahead of its workers, keeps each episode in the run's :class:`ResumeStore` as it arrives,
reports it to the progress bar, stops once the run has enough, and raises a task's error as
the task raised it. A run started again with the same ``--out`` and settings keeps what the
store holds and runs the rest (:func:`resume_store`), with ``--workers`` or ``--ray``.

A task returns its episode and the files it recorded (name -> bytes, or a JSON-able value
written as JSON); the store keeps them with ``episode.json`` under the task's key.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, wait
from dataclasses import asdict
from pathlib import Path

from embodied_envs.datasets.records import layout_content_hash
from embodied_envs.pipelines.episodes import Episode
from embodied_envs.pipelines.executor import EpisodeExecutor
from embodied_envs.pipelines.on_ray import RayExecutor
from embodied_envs.pipelines.processes import ProcessExecutor
from embodied_envs.pipelines.resume import RESUME_PREFIX, ResumeStore

POLL_SECONDS = 0.1  # how often the driver looks at arrivals (and at Ctrl-C)
RUN_KEYS = ("workers", "ray")  # plan fields that do not change the episodes (not in resume)
EPISODE_FILE = "episode.json"  # a store entry's episode


def executor_for(ray: str | None, workers: int, layouts: Iterable, files: Iterable = ()):
    """The executor of a run: ``workers`` processes of this machine (``ray`` None), or Ray
    tasks on the cluster ``ray`` names, sent the files of ``layouts`` and ``files``."""
    if ray is None:
        return ProcessExecutor(workers)
    return RayExecutor(ray, workers, layouts, files)


def resume_store(out: Path, name: str, plan, layouts: Iterable, files: Iterable = ()):
    """The store of a run of ``plan`` named ``name`` in ``out``: what an interrupted run of the
    same settings (``plan`` but ``RUN_KEYS``) over the same bytes (of ``layouts``, their
    assets, and ``files``) received is kept."""
    digest = hashlib.sha256()
    for entry in layouts:
        digest.update(layout_content_hash(entry).encode())
    for file in files:
        digest.update(Path(file).read_bytes())
    settings = {k: v for k, v in asdict(plan).items() if k not in RUN_KEYS}
    fingerprint = {"plan": settings, "files_sha256": digest.hexdigest()}
    return ResumeStore(out / f"{RESUME_PREFIX}{name}", fingerprint)


def stored_episode(store: ResumeStore, key: str) -> Episode:
    """The episode a store entry holds."""
    return Episode(**json.loads((store.path(key) / EPISODE_FILE).read_text()))


def _save(store: ResumeStore, key: str, episode: Episode, files: dict) -> None:
    data = {n: v if isinstance(v, bytes) else json.dumps(v).encode() for n, v in files.items()}
    store.save(key, {EPISODE_FILE: json.dumps(asdict(episode)).encode(), **data})


def run_episodes(
    executor: EpisodeExecutor,
    store: ResumeStore,
    fn: Callable,
    tasks: Sequence[tuple[str, tuple]],
    progress: Callable[[Episode], None] | None = None,
    enough: Callable[[dict[str, Episode]], bool] | None = None,
    on_resume: Callable[[int, Path], None] | None = None,
) -> dict[str, Episode]:
    """``fn(*args)`` for each task ``(key, args)`` not in ``store``, submitted in order to
    ``executor`` (started and shut down here), each result kept in ``store`` as it arrives.

    Args:
        executor: the backend.
        store: what this run (or an interrupted one of the same settings) received.
        fn: a module-level function returning ``(episode, files)``.
        tasks: the keys and arguments, in the order they are wanted.
        progress: called with each episode: the stored ones first, then as they arrive.
        enough: whether the episodes so far are all the run needs (the tasks still running
            are stopped); None: every task.
        on_resume: called with the number of episodes the store holds and its folder, when
            it holds any.

    Returns:
        The episodes by key (stored and new; with ``enough``, possibly some past it).

    Raises:
        Exception: what a task raised, as it raised it (what arrived is kept in ``store``).
    """
    order = {key: k for k, (key, _) in enumerate(tasks)}
    results = {key: stored_episode(store, key) for key in store.keys() if key in order}
    if results and on_resume is not None:
        on_resume(len(results), store.folder)
    if progress is not None:
        for key in sorted(results, key=order.__getitem__):
            progress(results[key])
    if enough is not None and enough(results):
        return results
    todo = iter([(key, args) for key, args in tasks if key not in results])
    with executor:
        pending: dict = {}

        def fill() -> None:
            while len(pending) < executor.slots and (task := next(todo, None)) is not None:
                pending[executor.submit(fn, *task[1])] = task[0]

        fill()
        while pending:
            done, _ = wait(pending, timeout=POLL_SECONDS, return_when=FIRST_COMPLETED)
            # the episodes that arrived are kept before an error among them is raised
            for future in sorted(done, key=lambda f: (f.exception() is not None,
                                                      order[pending[f]])):  # fmt: skip
                key = pending.pop(future)
                episode, files = future.result()
                _save(store, key, episode, files)
                results[key] = episode
                if progress is not None:
                    progress(episode)
            if enough is not None and enough(results):
                break
            fill()
        if pending:  # enough: the tasks still running are stopped
            executor.shutdown(cancel_futures=True)
    return results
