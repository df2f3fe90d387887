#!/usr/bin/env python
"""Benchmark: what camera observations cost, and where a camera step's time goes.

1. Whole ``collect`` commands, interleaved in each round, on the same seeds (``--num N
   --seed 0 --only-success --control-mode pd_joint_delta_pos --workers 1``):
   ``--obs-mode state`` (the baseline) against ``--obs-mode rgb --hybrid-obs --rooms shipped``
   at the recipe's camera (the commands' defaults: 64x64, the robot's visual meshes decimated to
   500 triangles a part), and, with ``--full``, the same at ManiSkill's 128x128 with the robot
   as shipped (``--camera-size 128 --robot-visual-faces 0``). Prints seconds and the ratio to
   the state command of the same round (the target: at most 5x).
2. One env, zero actions, milliseconds per ``env.step`` and its parts, by ``cProfile`` of
   ``--steps`` steps: SAPIEN's render (``take_picture`` + ``get_picture``), the composite over
   the splat (``HybridRenderer.composite_sensors``), the rest (physics, task, observation).

Usage: OMP_NUM_THREADS=1 PYTHONPATH=$PWD python tools/bench/bench_camera.py [--num 20]
       [--rounds 2] [--steps 200] [--full]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

from embodied_envs.paths import default_layout  # noqa: E402

CAMERA = ["--obs-mode", "rgb", "--hybrid-obs", "--rooms", "shipped"]
VARIANTS = {
    "state": ["--obs-mode", "state"],
    "rgb hybrid 64, robot 500/part": CAMERA,
    "rgb hybrid 128, robot as shipped": [
        *CAMERA, "--camera-size", "128", "--robot-visual-faces", "0"
    ],
}  # fmt: skip


def collect_seconds(num: int, flags: list[str]) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "embodied_envs.cli.main", "collect", "--layout",
               str(default_layout()), "--num", str(num), "--seed", "0", "--only-success",
               "--control-mode", "pd_joint_delta_pos", "--workers", "1", "--out", tmp,
               *flags]  # fmt: skip
        t = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True)
        return time.perf_counter() - t


def step_parts(steps: int, **kwargs) -> dict[str, float]:
    """Milliseconds per step: total, SAPIEN's render, the composite, the rest."""
    import gymnasium as gym
    import numpy as np

    import embodied_envs  # noqa: F401

    env = gym.make("PickEmbodiedGen-v1", control_mode="pd_joint_delta_pos", **kwargs)
    env.reset(seed=0)
    action = np.zeros(env.action_space.shape, np.float32)
    for _ in range(5):
        env.step(action)
    profile = cProfile.Profile()
    t = time.perf_counter()
    profile.enable()
    for _ in range(steps):
        env.step(action)
    profile.disable()
    total = (time.perf_counter() - t) / steps * 1000
    env.close()
    stats = pstats.Stats(profile).stats  # (file, line, name) -> (cc, nc, tt, ct, callers)

    def cumulative(name: str) -> float:
        return sum(v[3] for k, v in stats.items() if k[2] == name) / steps * 1000

    render = cumulative("take_picture") + cumulative("get_picture")
    # the composite's own fetch of depth and segmentation is a copy (the render was waited on
    # by the colour's fetch): counted in both, under 0.1 ms
    composite = cumulative("composite_sensors")
    return dict(total=total, render=render, composite=composite, rest=total - render - composite)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--num", type=int, default=20, help="demonstrations per command")
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--steps", type=int, default=200, help="env steps profiled per variant")
    ap.add_argument("--full", action="store_true", help="also 128x128 with the robot as shipped")
    args = ap.parse_args(argv)
    variants = dict(VARIANTS) if args.full else {k: VARIANTS[k] for k in list(VARIANTS)[:2]}
    print(f"collect --num {args.num} --workers 1, whole command (s), ratio to state")
    for r in range(args.rounds):
        times = {name: collect_seconds(args.num, flags) for name, flags in variants.items()}
        line = ", ".join(f"{n} {t:.1f} s ({t / times['state']:.2f}x)" for n, t in times.items())
        print(f"round {r + 1}: {line}", flush=True)
    print(f"\nenv.step, zero actions, ms per step over {args.steps} steps")
    sensors = [
        ("state", dict(obs_mode="state")),
        ("rgb 64, robot 500/part, hybrid", dict(obs_mode="rgb", hybrid_obs=True,
         robot_visual_faces=500, sensor_configs=dict(width=64, height=64))),
        ("rgb 64, robot as shipped, hybrid", dict(obs_mode="rgb", hybrid_obs=True,
         sensor_configs=dict(width=64, height=64))),
        ("rgb 128, robot as shipped, hybrid", dict(obs_mode="rgb", hybrid_obs=True)),
        ("rgb 128, robot as shipped", dict(obs_mode="rgb")),
    ]  # fmt: skip
    for name, kwargs in sensors:
        parts = step_parts(args.steps, **kwargs)
        print(f"{name}: " + ", ".join(f"{k} {v:.1f}" for k, v in parts.items()), flush=True)


if __name__ == "__main__":
    main()
