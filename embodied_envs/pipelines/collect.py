"""Demonstration datasets: the scripted solver recorded in ManiSkill's trajectory format.

One dataset per layout or layout set: ``<out>/<name>/trajectory.h5`` + ``trajectory.json`` as
ManiSkill's ``RecordEpisode`` writes them (``env_info`` with ``env_kwargs`` that re-create the
env from any working directory, per-episode seed, success and length, ``source_type``
``"motionplanning"``), readable by ``ManiSkillTrajectoryDataset`` and replayable by
``replay_trajectory``; plus ``summary.json``. Every episode records its ``instruction`` and
``layout_file``; over a layout set each episode is a reconfiguration (``reset_kwargs`` say so),
whose seed draws its layout again on replay. On CPU each worker is one process with one env; it
collects a disjoint block of seeds into its own file, and the blocks are merged with ManiSkill's
``merge_trajectories``. Everything is written under a temporary name and renamed when complete.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import functools
import json
import logging
import math
import os
import shutil
import tempfile
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

import gymnasium as gym
from mani_skill.trajectory.merge_trajectory import merge_trajectories

from embodied_envs.cluster import Ran, cached, run_tasks
from embodied_envs.datasets.recorder import EpisodeRecorder
from embodied_envs.datasets.records import RECORD_KEY, scene_record
from embodied_envs.paths import atomic_output
from embodied_envs.pipelines import on_ray
from embodied_envs.pipelines.episodes import Episode, expert, film_mode, run_episode
from embodied_envs.registration import ENTRY_ID, ENV_ID
from embodied_envs.solvers.pick_place import SolverConfig
from embodied_envs.workers import report, run, started

SOURCE_DESC = (
    "embodied_envs PickPlaceSolver (embodied_envs/solvers/pick_place.py) with the robot's hand "
    "entry (embodied_envs/robots.py): antipodal parallel-jaw grasps synthesised from each mover's "
    "collision mesh (embodied_envs/solvers/grasps.py) and the asset's annotated grasps where it "
    "has them, posed where it lies within 65 degrees of straight down (the top-down grasp across "
    "its footprint's narrow side first; a five-joint arm's tilted in its arm's plane) and kept "
    "when the gripper clears the object, the table and the other objects; the arm takes the one "
    "it reaches soonest (IK and a collision-free plan, lower ranks "
    "costing steps); seeded plans (straight joint lines, screw motions, RRT-Connect) approach, "
    "grasp, lift and carry it: to the goal and hold still (pick), or over its destination, "
    "lowered and released (place, move); a missed or slipped grasp is made again; its joint "
    "targets recorded as the dataset's control mode's actions (embodied_envs/solvers/modes.py)"
)
FIXED_HAND_DESC = (
    "; every grasp top-down at the hand's start orientation, carried without turning it "
    "(collect --fixed-hand: demos for pd_ee_delta_pos)"
)
DIVERSE_DESC = (
    "; the former, diverse expert (collect --diverse): grasp and IK branch chosen afresh per "
    "start, so nearby starts may give distant paths"
)
OBS_MODES = ("none", "state", "rgb", "rgbd")
MANISKILL_LOGGER = "mani_skill "  # ManiSkill's logger's name (mani_skill/utils/logging_utils.py)


class CollectError(RuntimeError):
    """A collection that cannot give what was asked (names the numbers and the fix)."""


@dataclass(frozen=True)
class CollectPlan:
    """What to collect for one layout or layout set.

    Attributes:
        layout: the layout file (absolute), or a set's files.
        name: the dataset's folder name (default: the layout file's stem).
        num: demonstrations wanted.
        seed: first episode seed; worker k uses the block ``seed + k * block`` onwards.
        obs_mode: recorded observations (``none``: replay re-renders them).
        hybrid_obs: sensor RGB over the splat background (recorded in ``env_kwargs``).
        only_success: keep only successful episodes, trying up to ``max_attempts`` seeds.
        max_attempts: the bound on seeds tried for ``only_success``.
        workers: processes.
        video: also write one MP4 per kept episode.
        fixed_hand: the expert keeps the hand's orientation (``SolverConfig.fixed_hand``): demos
            that ``pd_ee_delta_pos`` replays.
        diverse: the former expert (``SolverConfig.consistent=False``): nearby starts may take
            other grasps and arm branches (docs/expert.md, "Consistent demonstrations").
        control_mode: the mode the expert's actions are recorded in (``solvers/modes.py``):
            each step's joint targets as that mode's action, graded on the run they make.
        env_kwargs: further ``gym.make`` keywords (from ``--config`` files), recorded with the
            dataset's ``env_kwargs``.
        ray: None: on this machine; else on Ray (``pipelines/on_ray.py``): ``local`` (a Ray
            started for the run), ``auto`` or a cluster's address; ``workers`` then caps the
            episodes running at once (default: the cluster's CPUs).
    """

    layout: str | tuple[str, ...]
    num: int
    name: str | None = None
    seed: int = 0
    obs_mode: str = "none"
    hybrid_obs: bool = False
    only_success: bool = False
    max_attempts: int | None = None
    workers: int = 1
    video: bool = False
    fixed_hand: bool = False
    diverse: bool = False
    control_mode: str = "pd_joint_pos"
    env_kwargs: dict = field(default_factory=dict)
    ray: str | None = None

    @property
    def files(self) -> list[str]:
        return [self.layout] if isinstance(self.layout, str) else list(self.layout)

    @property
    def env_layout(self) -> str | list[str]:
        """The env's ``layout_file``."""
        return self.layout if isinstance(self.layout, str) else list(self.layout)

    @property
    def dataset_name(self) -> str:
        return self.name or Path(self.files[0]).stem

    def attempts(self) -> int:
        return (self.max_attempts or 2 * self.num) if self.only_success else self.num

    def blocks(self) -> list[tuple[list[int], int]]:
        """Per worker: its seeds and how many demonstrations it must keep."""
        w = max(1, min(self.workers, self.num))
        quota = [self.num // w + (k < self.num % w) for k in range(w)]
        tries = [math.ceil(self.attempts() * q / self.num) for q in quota]
        starts = [self.seed + sum(tries[:k]) for k in range(w)]
        return [(list(range(s, s + t)), q) for s, t, q in zip(starts, tries, quota, strict=True)]


@dataclass
class LayoutSummary:
    layout: str | list[str]
    env_id: str
    attempted: int
    kept: int
    successes: int
    success_rate: float
    failures_by_stage: dict[str, int]
    steps_mean: float
    steps_max: int
    wall_time_s: float
    seeds: list[int]
    workers: int = 1  # processes that ran episodes
    nodes: int = 1  # machines they ran on
    files: list[str] = field(default_factory=list)


def make_env(plan: CollectPlan):
    """The env a worker collects ``plan`` in (one CPU env, not yet recorded)."""
    return gym.make(
        ENV_ID,
        **plan.env_kwargs
        | dict(
            layout_file=plan.env_layout,
            obs_mode=plan.obs_mode,
            hybrid_obs=plan.hybrid_obs,
            control_mode=plan.control_mode,
            render_mode=film_mode(plan.files) if plan.video else None,
            sim_backend="physx_cpu",
        ),
    )


def recorder(env, plan: CollectPlan, out_dir: str, name: str) -> EpisodeRecorder:
    """``env`` recorded by ManiSkill's RecordEpisode (``datasets/recorder.py``: its files,
    cheaper per step) into ``out_dir/name.h5``."""
    return EpisodeRecorder(
        env,
        output_dir=out_dir,
        trajectory_name=name,
        save_video=plan.video,
        save_on_reset=False,
        record_reward=True,
        source_type="motionplanning",
        source_desc=SOURCE_DESC + (FIXED_HAND_DESC if plan.fixed_hand else "")
        + (DIVERSE_DESC if plan.diverse else ""),
        video_fps=int(round(1 / env.unwrapped.control_timestep)),
    )


def record_seed(env: EpisodeRecorder, plan: CollectPlan, seed: int) -> Episode:
    """The episode of ``seed``, by the expert, recorded by ``env`` (kept in its file when it
    succeeded or ``plan`` keeps every episode; with its video when filming): what every worker,
    local or on Ray, does per seed."""
    config = SolverConfig(fixed_hand=plan.fixed_hand, consistent=not plan.diverse)
    drive = functools.partial(expert, config=config)
    episode = run_episode(env, seed, drive)
    episode.kept = episode.success or not plan.only_success
    env.flush_trajectory(save=episode.kept)
    if plan.video:
        env.flush_video(name=f"seed_{seed:06d}", save=episode.kept)
    return episode


def _worker(plan: CollectPlan, seeds: list[int], quota: int, out_dir: str, name: str) -> list:
    """One worker's block of seeds: one env recorded into ``out_dir/name.h5``; a record per
    episode is reported (the parent's progress bar) and all are returned."""
    env = recorder(make_env(plan), plan, out_dir, name)
    started()
    kept, records = 0, []
    try:
        for seed in seeds:
            episode = record_seed(env, plan, seed)
            kept += episode.kept
            records.append(episode)
            report(asdict(episode))
            if kept >= quota:
                break
    finally:
        env.close()
    return records


@contextlib.contextmanager
def _quiet(logger: logging.Logger):
    """``logger`` at WARNING within the block."""
    level = logger.level
    logger.setLevel(logging.WARNING)
    try:
        yield
    finally:
        logger.setLevel(level)


WORK_PREFIX = ".collect-"  # work folders in --out while a dataset is being made
_HELD: dict[str, tuple[int, int]] = {}  # folders this process holds: path -> (fd, depth)


@contextlib.contextmanager
def owned_output(out: Path):
    """Hold ``out`` for this process: an exclusive ``flock`` on the folder itself, refused at
    once while another run holds it (re-entrant within a process). Once held, the work folders
    of runs that were killed (``WORK_PREFIX``) are removed.

    Raises:
        CollectError: another run is writing to ``out``.
    """
    out.mkdir(parents=True, exist_ok=True)
    key = str(out.resolve())
    if key in _HELD:
        fd, depth = _HELD[key]
        _HELD[key] = (fd, depth + 1)
        try:
            yield
        finally:
            _HELD[key] = (fd, depth)
        return
    fd = os.open(out, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise CollectError(
                f"{out} is being written by another embodied-envs collect. Fix: wait for it to "
                "end, or give this run its own --out"
            ) from None
        for stale in out.glob(f"{WORK_PREFIX}*"):  # no run holds them: killed runs' leftovers
            shutil.rmtree(stale, ignore_errors=True)
        _HELD[key] = (fd, 1)
        try:
            yield
        finally:
            del _HELD[key]
    finally:
        os.close(fd)  # releases the lock


def describe_dataset(folder: Path) -> str:
    """A dataset folder in words: its layouts and episode seeds, as far as they can be read."""
    try:
        meta = json.loads((folder / "trajectory.json").read_text())
        seeds = [e["episode_seed"] for e in meta["episodes"]]
        layout = meta["env_info"]["env_kwargs"].get("layout_file")
        return f"a dataset of {layout} (episode seeds {min(seeds)}-{max(seeds)})"
    except (OSError, ValueError, KeyError, TypeError):
        return "files this run did not write"


def collect(plan: CollectPlan, out: Path, progress=None) -> LayoutSummary:
    """Collect one layout's (or layout set's) dataset into ``out/<plan.dataset_name>/``.

    Args:
        plan: what to collect.
        out: the output folder.
        progress: optional callable taking each episode's record (for a progress bar).

    Returns:
        The summary (also written as ``summary.json``).

    Raises:
        CollectError: with ``only_success``, when the attempts run out before ``num``
            successes (nothing is written then); ``out`` is held by another run; or
            ``out/<name>`` exists already (a run never replaces a dataset it did not
            write).
    """
    plan = dataclasses.replace(
        plan,
        layout=str(Path(plan.layout).resolve())
        if isinstance(plan.layout, str)
        else tuple(str(Path(f).resolve()) for f in plan.layout),
    )
    target = out / plan.dataset_name
    out.mkdir(parents=True, exist_ok=True)
    with owned_output(out):
        if target.exists():
            raise CollectError(
                f"{target} already holds {describe_dataset(target)}; this run would replace it. "
                "Fix: collect each shard (--seed range) into its own --out and join them with "
                "python -m mani_skill.trajectory.merge_trajectory, or remove that folder."
            )
        return _collect_into(plan, out, target, progress)


def _collect_into(plan: CollectPlan, out: Path, target: Path, progress):
    """``collect``'s work, with ``out`` held: the dataset is made in a work folder and renamed
    to ``target`` when complete."""
    work = Path(tempfile.mkdtemp(prefix=f"{WORK_PREFIX}{plan.dataset_name}.", dir=out))
    t0 = time.perf_counter()
    try:
        if plan.ray is not None:
            records, parts, videos, store, ran = collect_on_ray(plan, out, progress)
        else:
            records, ran = _collect_here(plan, work, progress)
            parts, videos = sorted(work.glob("part*.h5")), sorted(work.glob("seed_*.mp4"))
            store = None
        summary = _write_dataset(plan, work, target, records, parts, videos, t0, ran)
        if store is not None:
            store.remove()
        return summary
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _collect_here(plan: CollectPlan, work: Path, progress) -> tuple[list[Episode], tuple]:
    """The episodes on this machine (``workers`` processes), recorded into ``work``: their
    records in seed order and (workers, nodes)."""
    tasks = [
        (plan, seeds, quota, str(work), f"part{k:03d}")
        for k, (seeds, quota) in enumerate(plan.blocks())
    ]
    parts = run(
        _worker,
        tasks,
        len(tasks) if plan.workers > 1 else 1,
        on_progress=None if progress is None else lambda rec: progress(Episode(**rec)),
    )
    records = sorted((r for part in parts for r in part), key=lambda r: r.seed)
    return records, (len(tasks), 1)


def _write_dataset(plan, work, target, records, parts, videos, t0, ran) -> LayoutSummary:
    """The dataset of the episodes ``records`` (seed order; ``parts``: the files their kept
    ones were recorded in, in seed order; ``videos``) made in ``work`` and renamed to
    ``target``; ``ran``: (workers, nodes)."""
    layout = plan.layout if isinstance(plan.layout, str) else f"{plan.dataset_name} (a layout set)"
    kept = [r for r in records if r.kept]
    successes = sum(r.success for r in records)
    if plan.only_success and len(kept) < plan.num:
        raise CollectError(
            f"{layout}: {len(kept)} of {plan.num} successful demonstrations after "
            f"{len(records)} attempts (success rate {successes / max(len(records), 1):.0%})."
            " Fix: raise --max-attempts, or check the layout with `embodied-envs demo`."
        )
    staged = work / "trajectory.h5"
    with _quiet(logging.getLogger(MANISKILL_LOGGER)):  # its INFO line per part: one per seed
        merge_trajectories(str(staged), [str(p) for p in parts])
    meta_path = staged.with_suffix(".json")
    meta = json.loads(meta_path.read_text())
    meta[RECORD_KEY] = scene_record(plan.files)  # replay checks the scene is unchanged
    # gymnasium's module:id form: ManiSkill's replay_trajectory and baselines import the
    # plugin themselves
    meta["env_info"]["env_id"] = ENTRY_ID
    drawn = {r.seed: r for r in kept}
    for episode in meta["episodes"]:  # what each episode was asked, and where
        r = drawn[episode["episode_seed"]]
        episode.update(instruction=r.instruction, layout_file=r.layout)
    with atomic_output(meta_path) as tmp:
        tmp.write_text(json.dumps(meta, indent=2))
    steps = [r.steps for r in kept] or [0]
    summary = LayoutSummary(
        layout=plan.env_layout,
        env_id=ENV_ID,
        attempted=len(records),
        kept=len(kept),
        successes=successes,
        success_rate=successes / max(len(records), 1),
        failures_by_stage=dict(Counter(r.failure for r in records if r.failure)),
        steps_mean=sum(steps) / len(steps),
        steps_max=max(steps),
        wall_time_s=round(time.perf_counter() - t0, 2),
        seeds=[r.seed for r in kept],
        workers=ran[0],
        nodes=ran[1],
        files=["trajectory.h5", "trajectory.json", "summary.json"],
    )
    (work / "summary.json").write_text(json.dumps(asdict(summary), indent=2))
    staging = work / "dataset"
    staging.mkdir()
    for name in summary.files:
        (work / name).replace(staging / name)
    for video in videos:
        shutil.copyfile(video, staging / video.name)
    staging.rename(target)  # a folder that appeared meanwhile is not replaced
    return summary


# --- on Ray (pipelines/on_ray.py) ------------------------------------------------------------
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


def collect_on_ray(plan: CollectPlan, out: Path, progress):
    """``plan``'s episodes on Ray: the records of the seeds one local worker would run (seed
    order), the ``.h5`` files of the kept ones, their videos, the resume store and (workers,
    nodes)."""
    with on_ray.session(plan.ray, plan.workers):
        bundle = on_ray.Bundle.put([p for f in plan.files for p in on_ray.scene_paths(f)])
        store = on_ray.resume_store(out, plan.dataset_name, plan, bundle)
        records = {int(k.split("_")[1]): on_ray.episode_of(store.path(k)) for k in store.keys()}
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
            files = {**videos, "part.json": json.dumps(meta).encode()}
            if h5 is not None:
                files["part.h5"] = h5
            on_ray.save_episode(store, f"seed_{seed:06d}", episode, **files)
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
            run_tasks(_collect_seed, bundle, todo, on_ray.in_flight(plan), arrived, ran)
        ran_seeds = [records[s] for s in range(plan.seed, walk["next"])]
        folders = [store.path(f"seed_{r.seed:06d}") for r in ran_seeds if r.kept]
        parts = [f / "part.h5" for f in folders]
        videos = [v for f in folders for v in sorted(f.glob("seed_*.mp4"))]
    return ran_seeds, parts, videos, store, (max(ran.workers, 1), max(ran.nodes, 1))
