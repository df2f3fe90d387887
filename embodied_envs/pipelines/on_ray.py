"""``collect`` and ``eval`` on a Ray cluster (``--ray``): one Ray task per episode seed, the
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
import dataclasses
import json
import tempfile
from dataclasses import asdict
from pathlib import Path

from embodied_envs.cluster import (
    RAY_LOCAL,
    Bundle,
    Ran,
    ResumeStore,
    cached,
    cluster_cpus,
    ray_session,
)
from embodied_envs.cluster import run_tasks as run_on_ray
from embodied_envs.datasets.records import scene_folders
from embodied_envs.paths import atomic_output
from embodied_envs.pipelines.collect import CollectPlan, make_env, record_seed, recorder
from embodied_envs.pipelines.episodes import Episode
from embodied_envs.pipelines.evaluate import EpisodeRunner, EvalPlan
from embodied_envs.workers import started

RESUME_PREFIX = ".resume-"  # in --out: what an interrupted --ray run received
RUN_KEYS = ("workers", "ray")  # plan fields that do not change the episodes (not in resume)


@contextlib.contextmanager
def session(address: str | None, workers: int):
    """Ray for a run: none for ``address`` None; the caller's, if it connected already;
    otherwise ``address``'s (``RAY_LOCAL``: a Ray of this machine with ``workers`` CPUs, 0:
    all). The driver builds no env: its start-up ends here (``workers.started``)."""
    if address is None:
        yield
        return
    import ray  # only where a run asks for Ray

    if ray.is_initialized():
        yield
        return
    with ray_session(None if address == RAY_LOCAL else address, workers or None):
        started()
        yield


def scene_paths(layout) -> list[Path]:
    """The layout files of ``layout`` (a file or a set) and their asset folders."""
    return [p for file, folders in scene_folders(layout) for p in (file, *folders.values())]


def fingerprint(plan, bundle: Bundle) -> dict:
    """What a resumed run must share with the run it resumes: the plan's episode settings
    and the bytes of the files they read."""
    settings = {k: v for k, v in asdict(plan).items() if k not in RUN_KEYS}
    return {"plan": settings, "files_sha256": bundle.digest}


def in_flight(plan) -> int:
    return plan.workers or cluster_cpus()


# --- collect -------------------------------------------------------------------------------
def _collect_seed(plan: CollectPlan, seed: int):
    """On a worker: the episode of ``seed`` recorded as the local workers record it; the
    episode, its ``.h5`` bytes (None when not kept), its ``.json`` and its videos."""
    env = cached("collect", plan, lambda: make_env(plan), lambda e: e.close())
    with tempfile.TemporaryDirectory(prefix="embodied-envs-seed-") as tmp:
        rec = recorder(env, plan, tmp, "part")
        try:
            episode = record_seed(rec, plan, seed)
        finally:
            rec.close_files()
        folder = Path(tmp)
        h5 = (folder / "part.h5").read_bytes() if episode.kept else None
        meta = json.loads((folder / "part.json").read_text())
        videos = {p.name: p.read_bytes() for p in folder.glob("seed_*.mp4")}
    return episode, h5, meta, videos


def _episode_of(folder: Path) -> Episode:
    return Episode(**json.loads((folder / "episode.json").read_text()))


def collect_on_ray(plan: CollectPlan, out: Path, progress):
    """``plan``'s episodes on Ray: the records of the seeds one local worker would run (seed
    order), the ``.h5`` files of the kept ones, their videos, the resume store and (workers,
    nodes)."""
    with session(plan.ray, plan.workers):
        bundle = Bundle.put([p for f in plan.files for p in scene_paths(f)])
        store = ResumeStore(out / f"{RESUME_PREFIX}{plan.dataset_name}", fingerprint(plan, bundle))
        records = {int(k.split("_")[1]): _episode_of(store.path(k)) for k in store.keys()}
        last = plan.seed + plan.attempts()
        walk = {"next": plan.seed, "kept": 0, "done": False}

        def settled() -> bool:
            """Walks the seeds that arrived in order: done once ``num`` are kept (or all
            attempts ran), as one local worker stops."""
            while not walk["done"] and walk["next"] < last and walk["next"] in records:
                walk["kept"] += records[walk["next"]].kept
                walk["next"] += 1
                walk["done"] = walk["kept"] >= plan.num
            return walk["done"] or walk["next"] >= last

        def arrived(task, result) -> bool:
            (_, seed), (episode, h5, meta, videos) = task, result
            files = {"episode.json": json.dumps(asdict(episode)).encode(), **videos,
                     "part.json": json.dumps(meta).encode()}  # fmt: skip
            if h5 is not None:
                files["part.h5"] = h5
            store.save(f"seed_{seed:06d}", files)
            records[seed] = episode
            if progress is not None:
                progress(episode)
            return settled()

        if progress is not None:
            for seed in sorted(records):
                progress(records[seed])
        ran = Ran()
        if not settled():
            todo = ((plan, s) for s in range(plan.seed, last) if s not in records)
            run_on_ray(_collect_seed, bundle, todo, in_flight(plan), arrived, ran)
        ran_seeds = [records[s] for s in range(plan.seed, walk["next"])]
        folders = [store.path(f"seed_{r.seed:06d}") for r in ran_seeds if r.kept]
        parts = [f / "part.h5" for f in folders]
        videos = [v for f in folders for v in sorted(f.glob("seed_*.mp4"))]
    return ran_seeds, parts, videos, store, (max(ran.workers, 1), max(ran.nodes, 1))


# --- eval ----------------------------------------------------------------------------------
def _eval_episode(plan: EvalPlan, layout, seed: int):
    """On a worker: the episode of ``seed`` in ``layout`` as a local worker runs it; the
    episode and its video's bytes (None when none was kept)."""
    runner = cached("eval", plan, lambda: EpisodeRunner(plan), EpisodeRunner.close)
    with tempfile.TemporaryDirectory(prefix="embodied-envs-seed-") as tmp:
        episode = runner.run(layout, seed, Path(tmp))
        video = (Path(tmp) / episode.video).read_bytes() if episode.video else None
    return episode, video


def policy_file(spec: str) -> Path | None:
    """The file a ``--policy`` value names (``file.py:factory``, a TorchScript file), if any."""
    name = spec.rpartition(":")[0] if ":" in spec else spec
    path = Path(name)
    return path.resolve() if name.endswith((".py", ".pt", ".ts")) and path.is_file() else None


def evaluate_on_ray(plan: EvalPlan, out: Path, progress):
    """``plan``'s episodes on Ray, each video written under ``out/videos`` as it arrives: the
    episodes (in task order), the resume store and (workers, nodes).

    Raises:
        Exception: what an episode raised on a worker, naming the driver's files and the
            ``--policy`` value as given.
    """
    with session(plan.ray, plan.workers):
        file = policy_file(plan.policy)
        sent = plan
        if file is not None:  # the policy's file travels with the job, named absolutely
            sent = dataclasses.replace(plan, policy=plan.policy.replace(
                plan.policy.rpartition(":")[0] or plan.policy, str(file), 1))  # fmt: skip
        paths = [p for entry in plan.layouts for p in scene_paths(entry)]
        bundle = Bundle.put(paths, [file] if file is not None else [])
        store = ResumeStore(out / f"{RESUME_PREFIX}eval", fingerprint(plan, bundle))
        tasks = plan.tasks()
        keys = [f"{k:06d}" for k in range(len(tasks))]
        key_of = dict(zip(tasks, keys, strict=True))
        results = {k: _episode_of(store.path(k)) for k in store.keys() if k in keys}
        if progress is not None:
            for key in sorted(results):
                progress(results[key])

        def arrived(task, result) -> bool:
            episode, video = result
            key = key_of[task[1:]]
            if video is not None:
                (out / "videos").mkdir(exist_ok=True)
                with atomic_output(out / "videos" / episode.video) as tmp:
                    tmp.write_bytes(video)
            store.save(key, {"episode.json": json.dumps(asdict(episode)).encode()})
            results[key] = episode
            if progress is not None:
                progress(episode)
            return False

        ran = Ran()
        todo = ((sent, *task) for k, task in zip(keys, tasks, strict=True) if k not in results)
        try:
            run_on_ray(_eval_episode, bundle, todo, in_flight(plan), arrived, ran)
        except Exception as e:  # the policy named as the user gave it, as a local run does
            if sent is not plan:
                e.args = tuple(a.replace(sent.policy, plan.policy) if isinstance(a, str) else a
                               for a in e.args)  # fmt: skip
            raise
    return [results[k] for k in keys], store, (max(ran.workers, 1), max(ran.nodes, 1))

