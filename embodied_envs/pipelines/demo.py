"""The demo: the scripted solver on a layout, its episodes tiled into MP4 videos + a summary.

On CPU each env runs in its own process (ManiSkill's CPU simulation holds one env per process).
Env 0 uses the layout file's poses; env k > 0 uses ``place(layout, derive_seed(seed, k))``,
written under the output folder (never beside the input), as on the GPU simulation. Over a
layout set, env k shows the layout it draws (``LayoutSet.draw(seed, k)``).
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import gymnasium as gym
import numpy as np

from embodied_envs.layout.placement import derive_seed, place
from embodied_envs.layout.sets import LayoutSet
from embodied_envs.paths import atomic_output
from embodied_envs.pipelines.episodes import Episode, expert, run_episode, write_video
from embodied_envs.registration import CONTROL_FREQ, ENV_ID
from embodied_envs.workers import run, started


@dataclass(frozen=True)
class DemoPlan:
    """What the demo runs.

    Attributes:
        layout: the layout file (absolute), or a layout set's files (env k draws its own).
        num_envs: envs shown side by side, each in its own process on CPU.
        episodes: episodes per env; env k's episode e has seed ``seed + e * num_envs + k``.
        seed: the first seed (and the placement seed of envs k > 0).
        render_mode: ``hybrid`` or ``rgb_array``.
        env_kwargs: further ``gym.make`` keywords (camera, config files).
        frame_every: record every k-th control step.
        workers: processes (None: min(envs, cores)).
    """

    layout: str | tuple[str, ...]
    num_envs: int = 1
    episodes: int = 1
    seed: int = 0
    render_mode: str = "hybrid"
    env_kwargs: dict = field(default_factory=dict)
    frame_every: int = 2
    workers: int | None = None


def _run_env(job: dict) -> tuple[str | list, list[Episode]]:
    """The robot uid of one env (two uids: two arms) and all its episodes (a process of its
    own when there are several)."""
    env = gym.make(
        ENV_ID,
        **job["env_kwargs"],
        layout_file=job["layout"],
        replace_objs=False,
        render_mode=job["render_mode"],
        control_mode="pd_joint_pos",
    )
    started()
    try:
        uids = env.unwrapped.robot_uids  # the layout's relation.robot, or the config's uid
        return uids if isinstance(uids, str) else list(uids), [
            run_episode(env, seed, expert, film_every=job["frame_every"], closing_frame=True)
            for seed in job["seeds"]
        ]
    finally:
        env.close()


def tile(frames: list[np.ndarray]) -> np.ndarray:
    """Tile equally sized frames into a near-square grid."""
    n = len(frames)
    cols = math.ceil(math.sqrt(n))
    rows = math.ceil(n / cols)
    h, w, c = frames[0].shape
    grid = np.zeros((rows * h, cols * w, c), np.uint8)
    for i, f in enumerate(frames):
        r, col = divmod(i, cols)
        grid[r * h : (r + 1) * h, col * w : (col + 1) * w] = f
    return grid


def tiled(per_env_frames: list[list[np.ndarray]]) -> Iterator[np.ndarray]:
    """The envs' frames tiled over time (shorter episodes hold their last frame)."""
    for t in range(max(len(f) for f in per_env_frames)):
        yield tile([f[min(t, len(f) - 1)] for f in per_env_frames])


def env_layouts(layout: str | tuple[str, ...], num_envs: int, seed: int, out: Path) -> list[str]:
    """Env k's layout file: the one env k draws from the layout set (``LayoutSet.draw(seed,
    k)``; a single layout draws itself); env 0 keeps the file's poses, env k > 0 (and env 0
    when the drawn layout has asset pools) gets a placed variant written under ``out``."""
    layout_set = LayoutSet.load(layout)
    paths = []
    for k in range(num_envs):
        drawn = layout_set.draw(seed, k)
        if k == 0 and drawn in layout_set.layouts:  # nothing from a pool: the file as it is
            paths.append(str(drawn.source))
            continue
        placed = place(drawn, derive_seed(seed, k))
        paths.append(str(placed.save(out / "layouts" / f"env{k}.json")))
    return paths


def run_demo(plan: DemoPlan, out: Path, progress: Callable[[int], None] | None = None) -> dict:
    """Run the demo, write ``out/episode_XXX.mp4`` and ``out/summary.json``; the summary.

    ``progress`` is called with the number of episodes each finished env ran.
    """
    out.mkdir(parents=True, exist_ok=True)
    layouts = env_layouts(plan.layout, plan.num_envs, plan.seed, out)
    jobs = [
        dict(
            layout=layouts[k],
            render_mode=plan.render_mode,
            env_kwargs=plan.env_kwargs,
            frame_every=plan.frame_every,
            seeds=[plan.seed + e * plan.num_envs + k for e in range(plan.episodes)],
        )
        for k in range(plan.num_envs)
    ]
    t0 = time.perf_counter()
    workers = 1 if plan.num_envs == 1 else plan.workers or min(plan.num_envs, os.cpu_count() or 1)
    results = run(
        _run_env,
        [(job,) for job in jobs],
        workers,
        on_result=None if progress is None else lambda r: progress(len(r[1])),
    )
    robots, per_env = zip(*results, strict=True)  # env k's robot uid and its episodes
    fps = max(1, int(round(CONTROL_FREQ / plan.frame_every)))
    summary = dict(
        layout=plan.layout if isinstance(plan.layout, str) else list(plan.layout),
        layouts=layouts,
        num_envs=plan.num_envs,
        seed=plan.seed,
        render_mode=plan.render_mode,
        fps=fps,
        episodes=[],
    )
    for e in range(plan.episodes):
        eps = [per_env[k][e] for k in range(plan.num_envs)]
        video = out / f"episode_{e:03d}.mp4"
        n_frames = write_video(video, tiled([ep.frames for ep in eps]), fps, quality=7)
        envs = [
            dict(episode=e, env=k, seed=ep.seed, layout=layouts[k], robot=robots[k],
                 success=ep.success, failure=ep.failure, steps=ep.steps,
                 plan_failures=ep.plan_failures,
                 wall_time_s=round(ep.wall_time_s, 3))
            for k, ep in enumerate(eps)
        ]  # fmt: skip
        summary["episodes"].append(
            dict(
                episode=e,
                video=str(video),
                frames=n_frames,
                success_rate=float(np.mean([ep.success for ep in eps])),
                envs=envs,
            )
        )
    summary["wall_time_s"] = round(time.perf_counter() - t0, 2)
    with atomic_output(out / "summary.json") as tmp:
        tmp.write_text(json.dumps(summary, indent=2) + "\n")
    return summary
