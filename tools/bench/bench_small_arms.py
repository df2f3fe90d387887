#!/usr/bin/env python
"""Benchmark: the expert on the small-arm zoo (``tools/make/make_small_zoo.py``), per arm and
object, with each failed episode's stage.

Each layout runs ``--episodes`` seeded episodes as ``embodied-envs collect`` runs them (reset
with the seed, the solver seeded by it, ``--control-mode``, default ``pd_joint_pos``). A
failure is named by its first unplanned stage, else by its misses (``grasp``: the object did
not rise with the hand; ``carry``: it left the hand), else ``execution`` (everything ran, the
task did not succeed: ``place``/``held`` say where the object ended). Prints a line per layout,
then a table per arm.

Usage: python tools/bench/bench_small_arms.py [--episodes 6] [--layout FILE ...]
       [--control-mode pd_joint_pos]
"""

from __future__ import annotations

import argparse
import os
import time
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.solvers import PickPlaceSolver  # noqa: E402

ZOO = Path(__file__).resolve().parents[2] / "tests" / "data" / "small_zoo" / "layouts"


def why(result, env) -> str:
    """One word for a failed episode (see the module's docstring)."""
    report = result.reports[0]
    if report.plan_failures:
        return report.plan_failures[0].split(":")[0]
    if report.misses:
        return "miss " + ",".join(m.split(" ")[0] for m in report.misses)
    info = env.unwrapped.evaluate()
    held = bool(np.asarray(info["is_grasped"]).reshape(-1)[0])
    return f"execution (held {int(held)})"


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--episodes", type=int, default=6)
    ap.add_argument("--seed", type=int, default=0, help="first episode seed")
    ap.add_argument("--layout", type=Path, nargs="+", default=None)
    ap.add_argument("--control-mode", default="pd_joint_pos", help="the env's control mode")
    args = ap.parse_args()
    table = defaultdict(dict)
    for path in args.layout or sorted(ZOO.glob("*.json")):
        env = gym.make("PickEmbodiedGen-v1", layout_file=str(path), control_mode=args.control_mode)
        ok, fails, t0 = 0, [], time.perf_counter()
        for seed in range(args.seed, args.seed + args.episodes):
            env.reset(seed=seed)
            result = PickPlaceSolver(env, seed=seed).solve()
            success = bool(env.unwrapped.evaluate()["success"][0])
            ok += success
            if not success:
                fails.append(f"{seed}: {why(result, env)}")
        env.close()
        wall = (time.perf_counter() - t0) / args.episodes
        arm, _, obj = path.stem.partition("_")
        table[arm][obj] = f"{ok}/{args.episodes}"
        print(f"{path.stem:22s} {ok}/{args.episodes}  {wall:.1f} s/episode  {'; '.join(fails)}",
              flush=True)  # fmt: skip
    objs = sorted({o for row in table.values() for o in row})
    print("\n| arm | " + " | ".join(objs) + " |\n|" + " --- |" * (len(objs) + 1))
    for arm, row in table.items():
        print(f"| {arm} | " + " | ".join(row.get(o, "") for o in objs) + " |")


if __name__ == "__main__":
    main()
