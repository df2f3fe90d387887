#!/usr/bin/env python
"""Benchmark: the cost of an episode of ``embodied-envs eval`` against a bare gym loop.

One env (CPU, ``obs_mode="state"``, the env's default controller, no render mode: an episode
``eval`` does not film), in this process. Episodes alternate: a bare loop (``reset(seed)``, then
``step(zero action)`` for the steps the eval episode took) and an eval episode of the ``zero``
policy (``EpisodeRunner.run``: the policy call, the action check, the step tally), on the same
seeds. Prints the median seconds per episode of each and their ratio (eval / bare), and the
cost of a filmed episode (the first ``--video-episodes`` of an eval) once.

Usage: python tools/bench/bench_eval.py [--episodes 5] [--steps 300] [--layout FILE]
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.paths import default_layout  # noqa: E402
from embodied_envs.pipelines.evaluate import EpisodeRunner, EvalPlan  # noqa: E402
from embodied_envs.pipelines.policies import load_policy  # noqa: E402
from embodied_envs.registration import ENV_ID  # noqa: E402


def bare_episode(env, seed: int, steps: int) -> float:
    action = np.zeros(env.action_space.shape, np.float32)
    t0 = time.perf_counter()
    env.reset(seed=seed)
    for _ in range(steps):
        env.step(action)
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--episodes", type=int, default=5, help="episodes of each kind")
    ap.add_argument("--steps", type=int, default=300, help="episode limit (control steps)")
    ap.add_argument("--layout", type=Path, default=default_layout())
    args = ap.parse_args()
    layout = str(Path(args.layout).resolve())
    plan = EvalPlan(
        policy="zero", layouts=(layout,), episodes=args.episodes, video="none",
        env_kwargs=dict(max_episode_steps=args.steps),
    )  # fmt: skip
    env = gym.make(ENV_ID, **plan.env_make_kwargs(layout, render=False))
    runner = EpisodeRunner(plan)
    runner.envs[layout], runner.policies[layout] = env, load_policy("zero", env)
    bare_episode(env, 0, 10)  # warm up both paths once
    runner.run(layout, 0, None)
    bare, evaluated = [], []
    for seed in range(args.episodes):
        t0 = time.perf_counter()
        result = runner.run(layout, seed, None)
        evaluated.append(time.perf_counter() - t0)
        bare.append(bare_episode(env, seed, result.steps))
    b, e = statistics.median(bare), statistics.median(evaluated)
    print(
        f"{Path(layout).name}: {args.episodes} episodes of {result.steps} steps each way; median "
        f"bare loop {b:.3f} s, eval {e:.3f} s per episode: eval / bare = {e / b:.3f}"
    )
    runner.close()
    filmed = replace(plan, video="all", video_episodes=1, episodes=1)
    runner = EpisodeRunner(filmed)
    runner.env(layout)  # made (and its splat loaded) outside the timing
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        runner.run(layout, 0, Path(tmp))
        f = time.perf_counter() - t0
    runner.close()
    print(f"a filmed episode (the first --video-episodes of an eval): {f:.2f} s, {f / b:.1f}x bare")


if __name__ == "__main__":
    main()
