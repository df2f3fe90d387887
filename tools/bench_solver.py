#!/usr/bin/env python
"""Benchmark: scripted pick-and-place success rate per shipped layout (CPU, seeded).

Each episode resets with its seed (one env reconfigures every reset, so the layout is re-placed
per seed); success is the env's own ``evaluate()`` at the end of the solver's run.

Usage: python tools/bench_solver.py [--episodes 20]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.paths import shipped_layouts  # noqa: E402
from embodied_envs.solvers import PickPlaceSolver  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--episodes", type=int, default=20)
    args = ap.parse_args()
    for path in shipped_layouts():
        env = gym.make(
            "PickEmbodiedGen-v1",
            layout_file=str(path),
            control_mode="pd_joint_pos",
            max_episode_steps=600,
        )
        ok, times, failures = 0, [], []
        for seed in range(args.episodes):
            t = time.perf_counter()
            env.reset(seed=seed)
            result = PickPlaceSolver(env, seed=seed).solve()
            success = bool(env.unwrapped.evaluate()["success"][0])
            times.append(time.perf_counter() - t)
            ok += success
            if not success:
                failures.append((seed, result.reports[0].plan_failures))
        env.close()
        print(
            f"{path.name:18s} success {ok}/{args.episodes} ({100 * ok / args.episodes:.0f}%), "
            f"mean episode wall time {sum(times) / len(times):.2f} s; failures: {failures}"
        )


if __name__ == "__main__":
    main()
