#!/usr/bin/env python
"""Benchmark: scripted pick-and-place success per shipped layout (CPU, seeded episodes).

Each episode resets with its seed (per-episode object placement and goal on the layout's
configuration), runs the solver within the env's registered episode limit, and counts success
by the env's own ``evaluate()`` at the end. Prints success rate, mean and max episode length
(control steps), failures by stage with the conditions of success each one missed
(``env.task_reader.unmet()``), and wall time.

``--diverse``: the former expert (``SolverConfig(consistent=False)``, ``collect --diverse``).
``--open-before N``: the hand opens N steps before a place's lowering ends (``SolverConfig``).

Usage: python tools/bench/bench_solver.py [--episodes 50] [--layout FILE ...] [--diverse]
"""

from __future__ import annotations

import argparse
import os
import time
from collections import Counter
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.paths import shipped_layouts  # noqa: E402
from embodied_envs.solvers import PickPlaceSolver  # noqa: E402
from embodied_envs.solvers.pick_place import SolverConfig  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--layout", type=Path, nargs="+", default=None)
    ap.add_argument("--diverse", action="store_true", help="the former expert")
    ap.add_argument("--open-before", type=int, default=SolverConfig.open_before,
                    help="steps before a lowering ends that the hand opens (SolverConfig)")
    args = ap.parse_args()
    config = SolverConfig(consistent=not args.diverse, open_before=args.open_before)
    for path in args.layout or shipped_layouts():
        env = gym.make("PickEmbodiedGen-v1", layout_file=str(path), control_mode="pd_joint_pos")
        limit = gym.spec("PickEmbodiedGen-v1").max_episode_steps
        ok, steps, stages, t0 = 0, [], Counter(), time.perf_counter()
        for seed in range(args.episodes):
            env.reset(seed=seed)
            result = PickPlaceSolver(env, config, seed=seed).solve()
            success = bool(env.unwrapped.evaluate()["success"][0])
            ok += success
            if success:
                steps.append(result.steps)
            else:
                failures = result.reports[0].plan_failures
                stage = failures[0].split(":")[0] if failures else "execution"
                unmet = "; ".join(env.unwrapped.task_reader.unmet()[0])  # as Episode.failure
                stages[f"{stage} (seed {seed}: {unmet})"] += 1
        env.close()
        wall = (time.perf_counter() - t0) / args.episodes
        print(
            f"{path.name:18s} success {ok}/{args.episodes} ({100 * ok / args.episodes:.0f}%), "
            f"episode length mean {np.mean(steps or [0]):.0f} max {max(steps or [0])} of {limit} "
            "steps, "
            f"{wall:.2f} s wall per episode; failures: {dict(stages) or 'none'}"
        )


if __name__ == "__main__":
    main()
