#!/usr/bin/env python
"""Measure a planar hand's reachable orientations: the table behind ``robots.Hand.tilt_reach``.

For a small-arm zoo layout (its arm, its table), a grasp frame 1.5 cm above the table top (a
small object's grasp centre), straight ahead of the base (and ``--bearing`` radians to the side)
at distances 0.08-0.36 m, approaching in the arm's vertical plane tilted 0-75 degrees from
straight down toward the far side, closing across the plane: ``x`` where the expert's seeded IK
(``solvers/motion.py``: collision-free against the table, within the hand's orientation
tolerance) finds a solution, ``.`` where not.

Usage: python tools/make/measure_tilts.py tests/data/small_zoo/layouts/koch_cube_22.json
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.solvers import PickPlaceSolver  # noqa: E402
from embodied_envs.solvers.grasp_choice import grasp_pose  # noqa: E402

TILTS = (0, 15, 30, 45, 60, 75)  # deg
DISTANCES = np.arange(0.08, 0.37, 0.02)  # m from the base


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("layout")
    ap.add_argument("--height", type=float, default=0.015, help="m above the table top")
    ap.add_argument("--bearing", type=float, nargs="+", default=[0.0, 0.6], help="rad")
    args = ap.parse_args()
    env = gym.make("PickEmbodiedGen-v1", layout_file=args.layout, control_mode="pd_joint_pos")
    env.reset(seed=0)
    solver = PickPlaceSolver(env, seed=0)
    base = solver.base.agent.robot.pose.raw_pose[0].cpu().numpy()
    w, x, y, z = base[3:]
    entry = solver.base.robot_entry
    ahead = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)) - entry.base_yaw
    top = float(solver.base.layout_scene.top_z[0])
    start = solver._qpos()[0]
    rng = np.random.default_rng(0)
    print(f"{entry.uid}: grasp {args.height} m above the table; tilts {TILTS} deg")
    for bearing in args.bearing:
        out = np.array([np.cos(ahead + bearing), np.sin(ahead + bearing), 0.0])
        across = np.array([-out[1], out[0], 0.0])
        print(f" bearing {bearing} rad")
        for r in DISTANCES:
            row = ""
            for tilt in np.deg2rad(TILTS):
                approach = np.cos(tilt) * np.array([0.0, 0.0, -1.0]) + np.sin(tilt) * out
                centre = np.array([*(base[:2] + r * out[:2]), top + args.height])
                link = grasp_pose(approach, across, centre) * solver.link_in_grasp
                goal = solver.planners[0].transform_goal_to_wrt_base(np.r_[link.p, link.q])
                row += "x" if solver.motion[0].ik(goal, start, rng)[0] else "."
            print(f"  {r:.2f} m {row}", flush=True)


if __name__ == "__main__":
    main()
