#!/usr/bin/env python
"""Benchmark: the normalised dense reward along expert episodes, per shipped layout (CPU).

Each episode resets with its seed and runs the scripted expert (``PickPlaceSolver``) with
``reward_mode="normalized_dense"``; a wrapper records every step's reward and success flag. Per
layout it prints: expert success at the end (the env's own ``evaluate()``); the largest
single-step fall of the reward over the episodes (with its seed and step, and whether success
was lost at that step), the median of the episodes' largest falls, the episodes that fall by
more than ``--tolerance`` at some step; the largest dip below the best reward reached before in
its episode (a fall spread over several steps); the reward at the end (min and mean); and the
reward's range over every step (it should stay in [0, 1] and reach 1 at success).

Usage: python tools/bench/bench_reward.py [--episodes 10] [--tolerance 0.05] [--layout FILE ...]
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.paths import shipped_layouts  # noqa: E402
from embodied_envs.solvers import PickPlaceSolver  # noqa: E402


class RewardTrace(gym.Wrapper):
    """Records each step's (first env's) reward and success flag."""

    def __init__(self, env):
        super().__init__(env)
        self.rewards: list[float] = []
        self.success: list[bool] = []

    def reset(self, **kwargs):
        self.rewards, self.success = [], []
        return self.env.reset(**kwargs)

    def step(self, action):
        out = self.env.step(action)
        self.rewards.append(float(np.asarray(out[1]).reshape(-1)[0]))
        self.success.append(bool(np.asarray(out[4]["success"]).reshape(-1)[0]))
        return out


@dataclass(frozen=True)
class Episode:
    seed: int
    success: bool
    rewards: np.ndarray  # (T,) the normalised reward per step
    flags: np.ndarray  # (T,) bool, success per step

    @property
    def falls(self) -> np.ndarray:
        """``(T - 1,)``: each step's fall of the reward (positive where it fell)."""
        return -np.diff(self.rewards) if len(self.rewards) > 1 else np.zeros(1)

    @property
    def undercut(self) -> float:
        """The largest fall below the best reward reached before (a dip over several steps)."""
        return float((np.maximum.accumulate(self.rewards) - self.rewards).max())


def run_layout(path: Path, episodes: int) -> list[Episode]:
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(path), obs_mode="state",
                   control_mode="pd_joint_pos", reward_mode="normalized_dense")  # fmt: skip
    env = RewardTrace(env)
    out = []
    try:
        for seed in range(episodes):
            env.reset(seed=seed)
            PickPlaceSolver(env, seed=seed).solve()
            success = bool(env.unwrapped.evaluate()["success"][0])
            out.append(Episode(seed, success, np.array(env.rewards), np.array(env.success)))
    finally:
        env.close()
    return out


def summary(name: str, eps: list[Episode], tol: float) -> str:
    worst = max(eps, key=lambda e: e.falls.max())
    at = int(worst.falls.argmax())
    lost = " (success lost)" if worst.flags[at] and not worst.flags[at + 1] else ""
    ends = np.array([e.rewards[-1] for e in eps])
    lo = min(e.rewards.min() for e in eps)
    hi = max(e.rewards.max() for e in eps)
    over = [e.seed for e in eps if e.falls.max() > tol]
    over = f"{len(over)} (seeds {', '.join(map(str, over))})" if over else "0"
    median = np.median([e.falls.max() for e in eps])
    ok = sum(e.success for e in eps)
    fall = f"{worst.falls.max():.3f} (seed {worst.seed}, step {at + 1}{lost})"
    dip = max(eps, key=lambda e: e.undercut)
    return (f"| {name} | {ok}/{len(eps)} | {fall} | {median:.3f} | {over} "
            f"| {dip.undercut:.3f} (seed {dip.seed}) "
            f"| {ends.min():.3f} / {ends.mean():.3f} | {lo:.3f} .. {hi:.3f} |")  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--tolerance", type=float, default=0.05)
    ap.add_argument("--layout", type=Path, nargs="+", default=None)
    args = ap.parse_args()
    print(f"| layout | success | largest fall | median largest fall | episodes with a fall > "
          f"{args.tolerance} | largest dip below the best so far | end reward min / mean "
          "| reward range |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for path in args.layout or shipped_layouts():
        t0 = time.perf_counter()
        eps = run_layout(path, args.episodes)
        wall = f" <!-- {time.perf_counter() - t0:.0f} s -->"
        print(summary(path.stem, eps, args.tolerance) + wall, flush=True)


if __name__ == "__main__":
    main()
