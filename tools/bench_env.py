#!/usr/bin/env python
"""Benchmark: PickEmbodiedGen-v1 stepping and rendering.

1. State-only steps/s vs ManiSkill's PickCube-v1 (same run), with and without resets.
2. Per-frame render time of ``hybrid`` vs ``rgb_array`` (same layout, camera and actions;
   render calls only), and the one-off background pre-render time per (camera, env).

Usage: python tools/bench_env.py [--steps 2000] [--frames 100]
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import statistics  # noqa: E402

import gymnasium as gym  # noqa: E402
import mani_skill.envs  # noqa: E402,F401
import numpy as np  # noqa: E402

import embodied_envs  # noqa: E402,F401


def steps_per_second(env_id: str, steps: int, reset_every: int | None, **kwargs) -> float:
    env = gym.make(env_id, obs_mode="state", **kwargs)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (steps, *env.action_space.shape)).astype(np.float32)
    for a in actions[:50]:  # warm-up
        env.step(a)
    t = time.perf_counter()
    for i, a in enumerate(actions):
        _, _, term, trunc, _ = env.step(a)
        if reset_every and (i + 1) % reset_every == 0:
            env.reset()
    elapsed = time.perf_counter() - t
    env.close()
    return steps / elapsed


def render_seconds(render_mode: str, frames: int) -> tuple[float, object]:
    """Median seconds per ``render()`` over random-action steps, and the env's unwrapped."""
    env = gym.make("PickEmbodiedGen-v1", obs_mode="state", render_mode=render_mode)
    env.reset(seed=0)
    env.render()  # warm-up (first render; hybrid pre-renders its background here)
    rng = np.random.default_rng(0)
    times = []
    for _ in range(frames):
        env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32))
        t = time.perf_counter()
        env.render()
        times.append(time.perf_counter() - t)
    env.close()
    return statistics.median(times), env.unwrapped


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--frames", type=int, default=100)
    args = ap.parse_args()
    rgb, _ = render_seconds("rgb_array", args.frames)
    hyb, u = render_seconds("hybrid", args.frames)
    print(
        f"render per frame (256x256):    hybrid {hyb * 1e3:6.1f} ms, rgb_array {rgb * 1e3:6.1f} ms,"
        f" ratio {hyb / rgb:.2f}"
    )
    print(
        f"background pre-render:         {u.hybrid.render_seconds / u.hybrid.renders:.2f} s per "
        f"(camera, env), {u.hybrid.renders} in the run ({len(u.hybrid.splat):,} Gaussians)"
    )
    # episodes of 100 steps (our registry limit); one env reconfigures on every reset
    ours = steps_per_second("PickEmbodiedGen-v1", args.steps, 100, replace_objs=False)
    base = steps_per_second("PickCube-v1", args.steps, 100)
    print(
        f"with a reset every 100 steps:  PickEmbodiedGen-v1 {ours:7.1f} steps/s, "
        f"PickCube-v1 {base:7.1f} steps/s, ratio {ours / base:.2f}"
    )
    ours = steps_per_second("PickEmbodiedGen-v1", args.steps, None, replace_objs=False)
    base = steps_per_second("PickCube-v1", args.steps, None)
    print(
        f"stepping only (no resets):     PickEmbodiedGen-v1 {ours:7.1f} steps/s, "
        f"PickCube-v1 {base:7.1f} steps/s, ratio {ours / base:.2f}"
    )


if __name__ == "__main__":
    main()
