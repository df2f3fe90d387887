"""What ``collect`` and ``eval`` share on a Ray cluster (``--ray``; their own parts are in
``collect.py`` and ``evaluate.py``): one Ray task per episode seed, the
same per-seed episode function as the local workers, so a seed's episode is the same on
either (the env starts every seed's episode from a new PhysX scene: nothing depends on what a
worker ran before).

Each task runs in a worker process that keeps its env (or its evaluation runner) for the next
task, reads the job's files from its node's copy (``cluster.Bundle``: layouts, asset folders,
splat, a policy file) and sends back what it recorded: the episode, its ``.h5`` and ``.json``,
its video. The driver keeps each arrival in ``OUT/.resume-<name>/`` (``cluster.ResumeStore``)
and writes the dataset or the evaluation from them in seed order, as the local run does; a run
interrupted and started again with the same ``--out`` and flags keeps what arrived and runs the
rest. ``collect --only-success`` runs seeds in order, a few ahead, and keeps the first ``num``
successes in seed order: the seeds one local worker keeps.
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
from dataclasses import asdict
from pathlib import Path

from embodied_envs.cluster import (
    RAY_LOCAL,
    Bundle,
    ClusterError,
    ResumeStore,
    cluster_cpus,
    ray_session,
    start_early,
    starting,
)
from embodied_envs.layout import load_layout
from embodied_envs.layout.sets import layout_files
from embodied_envs.pipelines.episodes import Episode
from embodied_envs.workers import started

RESUME_PREFIX = ".resume-"  # in --out: what an interrupted --ray run received
TASKS_AHEAD = 2  # tasks queued per worker: a worker starts its next episode at once, not after
# the driver has received and stored its last (one at a time cost ~0.2 s an episode of 0.6)
RUN_KEYS = ("workers", "ray")  # plan fields that do not change the episodes (not in resume)
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
    ``RAY_ADDRESS``'s, if set). An address that is not ``host:port`` (``ray://`` taken off:
    Ray's client) is left to Ray."""
    env = os.environ.get("RAY_ADDRESS")
    from_env = address in (None, "auto")
    target = env if from_env else address
    if not target:
        return
    named = f"--ray {address}" if address is not None else "--ray"
    named += f" (RAY_ADDRESS={env})" if from_env else ""
    host, sep, port = target.removeprefix("ray://").rpartition(":")
    if not sep or not host or not port.isdigit():
        return
    try:
        socket.create_connection((host.strip("[]"), int(port)), CONNECT_SECONDS).close()
    except OSError as e:
        why = (f"no answer within {CONNECT_SECONDS:.0f} s" if isinstance(e, TimeoutError)
               else (e.strerror or str(e)).lower())  # fmt: skip
        alone = "unset RAY_ADDRESS and give" if from_env else "give"
        raise ClusterError(
            f"{named}: no Ray cluster reachable at {host}:{port} ({why}). Fix: start one "
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


def fingerprint(plan, bundle: Bundle) -> dict:
    """What a resumed run must share with the run it resumes: the plan's episode settings
    and the bytes of the files they read."""
    settings = {k: v for k, v in asdict(plan).items() if k not in RUN_KEYS}
    return {"plan": settings, "files_sha256": bundle.digest}


def resume_store(out: Path, name: str, plan, bundle: Bundle) -> ResumeStore:
    """The store of a run of ``plan`` named ``name`` in ``out`` (what an interrupted run of the
    same plan and files received is kept)."""
    return ResumeStore(out / f"{RESUME_PREFIX}{name}", fingerprint(plan, bundle))


def in_flight(plan) -> int:
    """The tasks a plan has on the cluster at once: its ``workers`` (else the cluster's CPUs),
    ``TASKS_AHEAD`` per worker where the cluster's CPUs run no more than that many (the
    further ones queue; on a larger cluster they would run: ``--workers`` caps the running)."""
    cpus = cluster_cpus()
    workers = plan.workers or cpus
    return TASKS_AHEAD * workers if workers >= cpus else workers


def episode_of(folder: Path) -> Episode:
    """The episode a :class:`ResumeStore` entry holds."""
    return Episode(**json.loads((folder / "episode.json").read_text()))


def save_episode(store: ResumeStore, key: str, episode: Episode, **files: bytes) -> None:
    store.save(key, {"episode.json": json.dumps(asdict(episode)).encode(), **files})
