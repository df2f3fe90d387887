#!/usr/bin/env python
"""Benchmark: seeded and unseeded default resets against ManiSkill's PickCube-v1, same process.

Evaluation loops, ``collect``, ``RecordEpisode`` replays and ManiSkill's seeded eval envs reset
with a new seed every episode; training loops reset without one. Each layout's env and
PickCube-v1 are timed in alternating rounds (state observations, CPU): the median per-round
ratio of mean ms per ``reset()``, robust to the machine's drift. ``--clock cpu`` times them in
this thread's CPU time (``time.thread_time``), which leaves out the time other jobs hold the
cores.

Usage: python tools/bench/bench_reset.py [--resets 200] [--rounds 10] [--clock wall|cpu]
    [--layout L ...]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import mani_skill.envs  # noqa: E402,F401

import embodied_envs  # noqa: E402,F401
from embodied_envs.paths import shipped_layouts  # noqa: E402

SEEDED_TARGET = 1.2  # a seeded reset against PickCube-v1's (issue 46)


def reset_ms(env, resets: int, seeded: bool, first_seed: int, clock=time.perf_counter) -> float:
    t = clock()
    for k in range(resets):
        env.reset(seed=first_seed + k) if seeded else env.reset()
    return (clock() - t) / resets * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--resets", type=int, default=200, help="per env and kind, in all rounds")
    ap.add_argument("--rounds", type=int, default=10, help="interleaved rounds (median ratio)")
    ap.add_argument("--layout", nargs="+", default=None, help="default: the shipped layouts")
    ap.add_argument("--clock", choices=("wall", "cpu"), default="wall")
    args = ap.parse_args()
    clock = time.thread_time if args.clock == "cpu" else time.perf_counter
    base = gym.make("PickCube-v1", obs_mode="state")
    base.reset(seed=0)
    per_round = max(1, args.resets // args.rounds)
    for layout in args.layout or [str(p) for p in shipped_layouts()]:
        env = gym.make("PickEmbodiedGen-v1", layout_file=layout, obs_mode="state")
        env.reset(seed=0)
        for seeded in (True, False):
            ours, cube = [], []
            for r in range(args.rounds):  # alternate short rounds: the machine drifts
                first = 1000 + r * per_round
                ours.append(reset_ms(env, per_round, seeded, first, clock))
                cube.append(reset_ms(base, per_round, seeded, first, clock))
            ratio = statistics.median(o / c for o, c in zip(ours, cube, strict=True))
            kind = "seeded" if seeded else "unseeded"
            print(
                f"{os.path.basename(layout):18s} {kind:8s} reset: {statistics.median(ours):6.2f}"
                f" ms, PickCube-v1 {statistics.median(cube):6.2f} ms (medians of {args.rounds} "
                f"interleaved rounds), median ratio {ratio:.2f}"
                + (f" (target <= {SEEDED_TARGET})" if seeded else "")
            )
        env.close()
    base.close()


if __name__ == "__main__":
    main()
