#!/usr/bin/env python
"""Benchmark: what a layout set costs, against the same layouts one at a time, same process.

- **Configuration**: a seeded ``reset(options=dict(reconfigure=True))`` of an env over the set
  (each draws one layout and builds it) against the same reconfiguration of an env holding
  just the layout drawn; the target is a ratio <= 1 (no more than building that layout once).
- **Episodes**: seeded and unseeded resets (no reconfiguration) of the set env against the
  single-layout env of the layout it holds; the target is a ratio of about 1.

Timings are interleaved, state observations, CPU (one env per process), mean ms per reset.
On a GPU the set's envs hold different layouts at once; that path is not timed here.

Usage: python tools/bench/bench_sets.py [--configs 20] [--resets 200] [--layout L ...]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.paths import shipped_layouts  # noqa: E402

RECONFIGURE = dict(reconfigure=True)


def timed(fn) -> float:
    t = time.perf_counter()
    fn()
    return (time.perf_counter() - t) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--configs", type=int, default=20, help="reconfigurations timed per env")
    ap.add_argument("--resets", type=int, default=200, help="episode resets timed per env")
    ap.add_argument("--layout", nargs="+", default=None, help="default: the shipped layouts")
    args = ap.parse_args()
    files = args.layout or [str(p) for p in shipped_layouts()]
    many = gym.make("PickEmbodiedGen-v1", layout_file=files, obs_mode="state")
    one = {f: gym.make("PickEmbodiedGen-v1", layout_file=f, obs_mode="state") for f in files}
    layout_set = many.unwrapped.layout_set
    # configuration: the set env and the env of the layout its seed draws, interleaved
    ratios = []
    for seed in range(args.configs):
        drawn = str(layout_set.draw(seed, 0).source)
        set_ms = timed(lambda s=seed: many.reset(seed=s, options=RECONFIGURE))
        one_ms = timed(lambda s=seed, d=drawn: one[d].reset(seed=s, options=RECONFIGURE))
        ratios.append(set_ms / one_ms)
    print(
        f"configuration over {len(files)} layouts: median ratio {statistics.median(ratios):.2f} "
        f"(set / its drawn layout alone, {args.configs} seeds; target <= 1)"
    )
    # episodes: the set env holding each layout against that layout's own env
    for f in files:
        seed = next(s for s in range(1000) if str(layout_set.draw(s, 0).source) == f)
        many.reset(seed=seed, options=dict(reconfigure=True))
        one[f].reset(seed=seed, options=dict(reconfigure=True))
        for seeded in (True, False):
            times = {"set": 0.0, "one": 0.0}
            for k in range(args.resets):
                for name, env in (("set", many), ("one", one[f])):
                    times[name] += timed(
                        lambda e=env, s=(5000 + k if seeded else None): e.reset(seed=s)
                    )
            kind = "seeded" if seeded else "unseeded"
            a, b = times["set"] / args.resets, times["one"] / args.resets
            print(
                f"{os.path.basename(f):18s} {kind:8s} reset: set {a:6.2f} ms, alone {b:6.2f} "
                f"ms, ratio {a / b:.2f} (target ~1)"
            )
    many.close()
    for env in one.values():
        env.close()


if __name__ == "__main__":
    main()
