#!/usr/bin/env python
"""Check: the grading's values (``evaluate()``'s info and the dense and normalised rewards)
along seeded episodes on every shipped layout, saved to a file or compared with one saved
before a change, bit for bit (``--atol`` to allow float rounding from a changed op order).

Each layout (``embodied_envs/data/layouts/*.json`` but ``so100_block``, another robot's)
gets one CPU env (``obs_mode="state"``, ``control_mode="pd_joint_pos"``); per seed a reset, then
``--steps`` steps of uniform random actions in the action space (a seeded numpy generator),
then the scripted expert's episode (``PickPlaceSolver``, its first ``--expert`` steps; 0: all)
from a new reset and ``--steps`` random steps after it (a placed mover knocked). At every step:
``evaluate()``'s info, ``compute_dense_reward`` and ``compute_normalized_dense_reward``.

``--tensors``: the rules on tensors (the GPU simulation's path, here on the CPU).

Usage: python tools/bench/grading_values.py --save before.npz
       python tools/bench/grading_values.py --compare before.npz [--atol 1e-6]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.envs.tasks.scene import TaskReader  # noqa: E402
from embodied_envs.paths import default_layout  # noqa: E402
from embodied_envs.solvers import PickPlaceSolver  # noqa: E402


def grades(env) -> dict[str, np.ndarray]:
    u = env.unwrapped
    info = type(u).evaluate(u)  # the env's own, not a wrapper set on the instance
    out = {k: v.cpu().numpy() for k, v in info.items()}
    out["dense"] = u.compute_dense_reward(None, None, info).cpu().numpy()
    out["normalized"] = u.compute_normalized_dense_reward(None, None, info).cpu().numpy()
    return out


def record(path: Path, seeds: int, steps: int, expert: int, tensors: bool) -> dict:
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(path), obs_mode="state",
                   control_mode="pd_joint_pos")  # fmt: skip
    u, rows = env.unwrapped, {}
    if tensors:  # the rules on tensors read through ManiSkill's structs, as on the GPU
        u.task_reader = TaskReader(u, u.task_scene, u.layout_scene.top_z, tensors=True)

    def add(tag: str) -> None:
        for key, value in grades(env).items():
            rows.setdefault(f"{path.stem}/{key}", []).append(value)
        rows.setdefault(f"{path.stem}/step", []).append(np.array([tag]))

    low, high = env.action_space.low, env.action_space.high
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        env.reset(seed=seed)
        add(f"s{seed} reset")
        for t in range(steps):
            env.step(torch.as_tensor(rng.uniform(low, high), dtype=torch.float32))
            add(f"s{seed} random {t}")
        if expert >= 0:
            env.reset(seed=seed)
            own, count = u.evaluate, [0]

            def evaluate(own=own, count=count, seed=seed):  # the expert's steps (0: all)
                info = own()
                if not expert or count[0] < expert:
                    count[0] += 1
                    add(f"s{seed} expert {count[0]}")
                return info

            u.evaluate = evaluate
            try:
                PickPlaceSolver(env, seed=seed).solve()
            except Exception as e:  # noqa: BLE001 - a failed plan still graded its steps
                print(f"{path.stem} seed {seed}: expert stopped: {e}", file=sys.stderr)
            finally:
                u.evaluate = own
            for t in range(steps):
                env.step(torch.as_tensor(rng.uniform(low, high), dtype=torch.float32))
                add(f"s{seed} after expert {t}")
    env.close()
    return {k: np.stack(v) for k, v in rows.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    group = ap.add_mutually_exclusive_group(required=True)
    group.add_argument("--save", type=Path)
    group.add_argument("--compare", type=Path)
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--expert", type=int, default=0, help="0: all; -1: none")
    ap.add_argument("--atol", type=float, default=0.0)
    ap.add_argument("--tensors", action="store_true", help="grade torch tensors (the GPU path)")
    args = ap.parse_args()
    layouts = sorted(p for p in default_layout().parent.glob("*.json") if p.stem != "so100_block")
    values = {}
    for path in layouts:
        values.update(record(path, args.seeds, args.steps, args.expert, args.tensors))
    if args.save:
        np.savez(args.save, **values)
        print(f"saved {len(values)} arrays from {len(layouts)} layouts to {args.save}")
        return
    before = np.load(args.compare)
    bad = sorted(set(before.files) ^ set(values))
    for key in sorted(set(before.files) & set(values)):
        a, b = before[key], values[key]
        if a.shape != b.shape or a.dtype != b.dtype:
            bad.append(f"{key}: {a.dtype}{a.shape} vs {b.dtype}{b.shape}")
        elif a.dtype.kind in "fc":
            diff = np.abs(a - b).max(initial=0.0)
            if diff > args.atol or not np.array_equal(np.isnan(a), np.isnan(b)):
                bad.append(f"{key}: max difference {diff:.3g}")
            elif diff:
                print(f"{key}: max difference {diff:.3g} (within --atol)")
        elif not np.array_equal(a, b):
            bad.append(f"{key}: {int((a != b).sum())} values differ")
    steps = sum(len(values[k]) for k in values if k.endswith("/step"))
    print(f"{len(values)} arrays, {steps} graded steps over {len(layouts)} layouts: "
          + ("all equal" if not bad else f"{len(bad)} differ"))  # fmt: skip
    for line in bad:
        print("  " + line)
    sys.exit(1 if bad else 0)


if __name__ == "__main__":
    main()
