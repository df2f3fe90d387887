"""Demonstration datasets: the scripted solver recorded in ManiSkill's trajectory format.

One dataset per layout or layout set: ``<out>/<name>/trajectory.h5`` + ``trajectory.json`` as
ManiSkill's ``RecordEpisode`` writes them (``env_info`` with ``env_kwargs`` that re-create the
env from any working directory, per-episode seed, success and length, ``source_type``
``"motionplanning"``), readable by ``ManiSkillTrajectoryDataset`` and replayable by
``replay_trajectory``; plus ``summary.json``. Every episode records its ``instruction`` and
``layout_file``; over a layout set each episode is a reconfiguration (``reset_kwargs`` say so),
whose seed draws its layout again on replay. Each seed is one task of the episode executor
(``pipelines/runner.py``: this machine's processes or Ray), recorded into its own file in a worker
process that keeps one env; each episode is kept in ``OUT/.resume-<name>/`` as it arrives (a run
interrupted and started again keeps them), and the kept ones are merged in seed order with
ManiSkill's ``merge_trajectories``. Everything is written under a temporary name and renamed
when complete.
"""

from __future__ import annotations

import contextlib
import dataclasses
import fcntl
import functools
import json
import logging
import os
import shutil
import tempfile
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

import gymnasium as gym
from mani_skill.trajectory.merge_trajectory import merge_trajectories

from embodied_envs.datasets.recorder import EpisodeRecorder
from embodied_envs.datasets.records import RECORD_KEY, scene_record
from embodied_envs.paths import atomic_output
from embodied_envs.pipelines.episodes import Episode, expert, film_mode, run_episode
from embodied_envs.pipelines.executor import cached
from embodied_envs.pipelines.runner import executor_for, resume_store, run_episodes
from embodied_envs.registration import ENTRY_ID, ENV_ID
from embodied_envs.solvers.pick_place import SolverConfig
from embodied_envs.workers import started

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
        seed: first episode seed; the seeds run in order from it, whatever the workers.
        obs_mode: recorded observations (``none``: replay re-renders them).
        hybrid_obs: sensor RGB over the splat background (recorded in ``env_kwargs``).
        only_success: keep only successful episodes, trying up to ``max_attempts`` seeds.
        max_attempts: the bound on seeds tried for ``only_success``.
        workers: processes (1: this one); with ``ray``, the episodes running at once (0: the
            cluster's CPUs).
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
            started for the run), ``auto`` or a cluster's address.
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


def collect(plan: CollectPlan, out: Path, progress=None, on_resume=None) -> LayoutSummary:
    """Collect one layout's (or layout set's) dataset into ``out/<plan.dataset_name>/``.

    Args:
        plan: what to collect.
        out: the output folder.
        progress: optional callable taking each episode's record (for a progress bar).
        on_resume: optional callable taking the number of episodes an interrupted run of the
            same settings kept in ``out`` (``OUT/.resume-<name>/``) and that folder, when it
            kept any: this run keeps them and runs the rest.

    Returns:
        The summary (also written as ``summary.json``).

    Raises:
        CollectError: with ``only_success``, when the attempts run out before ``num``
            successes (nothing is written then); ``out`` is held by another run; or
            ``out/<name>`` exists already (a run never replaces a dataset it did not
            write).
        ResumeError: ``out`` holds an interrupted run of other settings.
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
        return _collect_into(plan, out, target, progress, on_resume)


def _collect_into(plan: CollectPlan, out: Path, target: Path, progress, on_resume):
    """``collect``'s work, with ``out`` held: the episodes by the run's executor, kept in its
    resume store; the dataset is made in a work folder and renamed to ``target`` when
    complete, and the store removed."""
    work = Path(tempfile.mkdtemp(prefix=f"{WORK_PREFIX}{plan.dataset_name}.", dir=out))
    t0 = time.perf_counter()
    try:
        store = resume_store(out, plan.dataset_name, plan, plan.files)
        executor = executor_for(plan.ray, plan.workers, plan.files)
        seeds = range(plan.seed, plan.seed + plan.attempts())
        walk = SeedWalk(plan)
        episodes = run_episodes(executor, store, _collect_seed,
                                [(seed_key(s), (plan, s)) for s in seeds], progress,
                                walk.enough, on_resume)  # fmt: skip
        ran = [episodes[seed_key(s)] for s in range(plan.seed, walk.next)]
        folders = [store.path(seed_key(r.seed)) for r in ran if r.kept]
        parts = [f / "part.h5" for f in folders]
        videos = [v for f in folders for v in sorted(f.glob("seed_*.mp4"))]
        places = (executor.ran.workers, executor.ran.nodes)
        try:
            summary = _write_dataset(plan, work, target, ran, parts, videos, t0, places)
        except CollectError:  # every attempt ran: nothing to resume
            store.remove()
            raise
        store.remove()
        return summary
    finally:
        shutil.rmtree(work, ignore_errors=True)


def seed_key(seed: int) -> str:
    """A seed's entry in the resume store."""
    return f"seed_{seed:06d}"


class SeedWalk:
    """The seeds that arrived, walked in seed order: enough once ``num`` are kept (or every
    attempt ran), as one worker running the seeds in order stops; ``next`` is the first seed
    past those."""

    def __init__(self, plan: CollectPlan):
        self.plan, self.next, self.kept = plan, plan.seed, 0

    def enough(self, episodes: dict[str, Episode]) -> bool:
        last = self.plan.seed + self.plan.attempts()
        while self.kept < self.plan.num and self.next < last and seed_key(self.next) in episodes:
            self.kept += episodes[seed_key(self.next)].kept
            self.next += 1
        return self.kept >= self.plan.num or self.next >= last


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


# --- the task ---------------------------------------------------------------------------
def _started_env(plan: CollectPlan):
    env = make_env(plan)
    started()  # this process's start-up is over: its env is built
    return env


def _collect_seed(plan: CollectPlan, seed: int):
    """In a worker process (of this machine or Ray's): the episode of ``seed`` recorded in the
    process's env, and its files: ``part.json``, ``part.h5`` (when kept) and its videos."""
    env = cached("collect", plan, lambda: _started_env(plan), lambda e: e.close())
    with tempfile.TemporaryDirectory(prefix="embodied-envs-seed-") as tmp:
        rec = recorder(env, plan, tmp, "part")
        try:
            episode = record_seed(rec, plan, seed)
        finally:
            rec.close_files()
        folder = Path(tmp)
        files: dict = {p.name: p.read_bytes() for p in folder.glob("seed_*.mp4")}
        files["part.json"] = json.loads((folder / "part.json").read_text())  # paths mapped
        if episode.kept:
            files["part.h5"] = (folder / "part.h5").read_bytes()
    return episode, files
