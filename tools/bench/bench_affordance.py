#!/usr/bin/env python
"""Benchmark: the expert with and without grasp annotations on a layout's mover.

No asset annotated by EmbodiedGen's ``affordance-cli`` ships (it needs GraspGen's model and a
GPU), so this writes an ``affordance_annot.json`` the way it would for a part-restricted grasp:
the mover's own synthesised grasps on one part, a mug's handle: those whose TCP lies farther
than ``--radius`` from the vertical line through the centre of mass, confidence by rank. It
copies the layout and its assets to a temporary folder, adds the file beside the mover's URDF,
and runs the same seeded episodes on both within the registered limit. Prints success, mean
steps and failures.

Usage: python tools/bench/bench_affordance.py [--layout FILE] [--episodes 20] [--radius 0.045]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from scipy.spatial.transform import Rotation  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.layout import load_layout, parse_urdf  # noqa: E402
from embodied_envs.layout.affordance import ANNOT_NAME, GRASPGEN_TCP_DEPTH  # noqa: E402
from embodied_envs.paths import data_root  # noqa: E402
from embodied_envs.solvers import PickPlaceSolver  # noqa: E402
from embodied_envs.solvers.grasps import asset_grasps  # noqa: E402


def annotation(urdf: Path, radius: float) -> dict:
    g = asset_grasps(parse_urdf(urdf))
    keep = np.flatnonzero(np.linalg.norm(g.centre[:, :2] - g.com[:2], axis=1) > radius)
    group = {}
    for rank, i in enumerate(keep):
        x, z = g.closing[i], g.approach[i]
        qx, qy, qz, qw = Rotation.from_matrix(np.stack([x, np.cross(z, x), z], 1)).as_quat()
        group[f"grasp_{i}"] = {
            "confidence": float(0.99 - 0.5 * rank / max(len(keep), 1)),
            "position": (g.centre[i] - GRASPGEN_TCP_DEPTH * z).tolist(),
            "orientation": {"w": float(qw), "xyz": [float(qx), float(qy), float(qz)]},
        }
    return {"affordances": [{"part_name": "handle", "graspable": True, "id": 0,
                             "grasp_group": group}]}


def run(layout: Path, episodes: int) -> tuple[int, float, list[int]]:
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(layout), control_mode="pd_joint_pos")
    limit = gym.spec("PickEmbodiedGen-v1").max_episode_steps
    ok, steps, failed = 0, [], []
    for seed in range(episodes):
        env.reset(seed=seed)
        result = PickPlaceSolver(env, seed=seed).solve()
        good = bool(result.success[0]) and result.steps <= limit
        ok += good
        steps.append(result.steps)
        if not good:
            failed.append(seed)
    env.close()
    return ok, float(np.mean(steps)), failed


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--layout", type=Path, default=data_root() / "layouts" / "place_tray.json")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--radius", type=float, default=0.045, help="m, off the axis: the handle")
    args = ap.parse_args()
    layout = load_layout(args.layout)
    mover = layout.manipulated_objs[0]
    with tempfile.TemporaryDirectory() as tmp:
        copy = Path(tmp) / "layout.json"
        data = json.loads(args.layout.read_text())
        for node in data["assets"]:
            src = layout.asset_dir(node)
            shutil.copytree(src, Path(tmp) / "assets" / node)
            data["assets"][node] = f"assets/{node}"
        copy.write_text(json.dumps(data))
        urdf = next((Path(tmp) / "assets" / mover).glob("*.urdf"))
        plain = run(copy, args.episodes)
        annot = annotation(urdf, args.radius)
        (urdf.parent / ANNOT_NAME).write_text(json.dumps(annot))
        count = len(annot["affordances"][0]["grasp_group"])
        start = time.perf_counter()
        annotated = run(copy, args.episodes)
    print(f"{args.layout.name}, mover {mover!r}, {args.episodes} seeded episodes")
    print(f"{'grasps':>28} {'success':>8} {'mean steps':>11}  failed seeds")
    for name, (ok, mean, failed) in (
        ("synthesised", plain),
        (f"+ {count} annotated (handle)", annotated),
    ):
        print(f"{name:>28} {ok:>4}/{args.episodes:<3} {mean:>11.0f}  {failed}")
    print(f"(annotated run {time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
