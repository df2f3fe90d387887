#!/usr/bin/env python
"""Benchmark: 256x256 splat renders with the PyTorch rasterizer on this machine's CPU.

Scene-like splats: the shipped room mesh sampled with ``mesh_to_splat`` at 100k and 1M
Gaussians (surface-aligned, overlapping, most of them in view), posed as the default layout
poses its background, seen from the env's default render camera and two room corners.
Reports the median of ``--repeats`` renders per view and the worst view against the targets.

Usage: python tools/bench/bench_splat.py [--repeats 5] [--threads N] [--backend torch]
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch
import trimesh

from embodied_envs.config import SPLAT_Y_UP_TO_Z_UP
from embodied_envs.layout import load_layout
from embodied_envs.layout.pose import quat_multiply_xyzw
from embodied_envs.splat import PinholeCamera, mesh_to_splat, pose_splat, render

ROOT = Path(__file__).resolve().parents[2]
TARGETS = {100_000: 0.3, 1_000_000: 1.0}  # seconds per 256x256 render
VIEWS = {
    "render_camera": ((0.9, 0.0, 1.1), (0.0, 0.0, 0.9)),
    "corner_a": ((1.8, 1.8, 1.6), (-1.0, -1.0, 0.6)),
    "corner_b": ((-1.8, -1.8, 1.4), (1.0, 1.0, 0.8)),
}


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--backend", default="torch")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    layout = load_layout(ROOT / "layouts" / "default.json")
    pose = layout.pose(layout.background)
    q = quat_multiply_xyzw(pose.q_xyzw, SPLAT_Y_UP_TO_Z_UP)
    mesh = trimesh.load(layout.asset_dir(layout.background) / "mesh_model.ply", force="mesh")
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, backend {args.backend}")
    print(f"{'gaussians':>10} {'view':>14} {'median s':>9} {'target s':>9}")
    for count, target in TARGETS.items():
        splat = mesh_to_splat(mesh, count, seed=0, visible_from=(0.0, 1.3, 0.0))
        splat = pose_splat(splat, torch.tensor(pose.p), torch.tensor(q[[3, 0, 1, 2]]))
        worst = 0.0
        for name, (eye, target_pt) in VIEWS.items():
            cam = PinholeCamera.look_at(eye, target_pt, width=256, height=256, fovy_deg=75.0)
            render(splat, cam, backend=args.backend)  # warm-up
            times = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                render(splat, cam, backend=args.backend)
                times.append(time.perf_counter() - start)
            med = statistics.median(times)
            worst = max(worst, med)
            print(f"{count:>10,} {name:>14} {med:>9.3f} {target:>9.2f}")
        verdict = "meets" if worst <= target else "MISSES"
        print(
            f"{count:>10,} {'worst view':>14} {worst:>9.3f} {target:>9.2f}  "
            f"{verdict} target (ratio {worst / target:.2f})"
        )


if __name__ == "__main__":
    main()
