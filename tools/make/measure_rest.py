#!/usr/bin/env python
"""Measure an arm at rest: the numbers behind ``robots.Robot.rest_arm``.

For a layout's arm set to its rest joints (``robots.Robot.rest_qpos``, no start noise), each link
but the base's (ManiSkill's model, its convex collision shapes) as a box in the frame of the
layout's robot spot (x to the table, y to its left, z up from the table top): ``(x_lo, x_hi,
y_lo, y_hi, z_lo)``, the box widened and its lowest point lowered to whole millimetres. Prints
the rows as ``robots.py`` holds them; placement keeps objects that come near a link's lowest
point out of its box (``PlacementLimits.rest_links``).

Usage: python tools/make/measure_rest.py layouts/so100_block.json layouts/koch_block.json
       python tools/make/measure_rest.py layouts/so100_block.json --qpos 0 0 0 1.57 1.57 0
       (an arm whose robot_init_qpos is not its rest: pass the rows as placement_limits's
       rest_arm)
"""

from __future__ import annotations

import argparse
import math
import os

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
from mani_skill.utils.geometry.trimesh_utils import get_component_mesh  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.layout.pose import LayoutPose  # noqa: E402
from embodied_envs.robots import ROBOTS  # noqa: E402

MM = 1000.0


def rest_boxes(layout: str, qpos=None) -> tuple[str, list[tuple[str, tuple[float, ...]]]]:
    """The arm's uid and, per link but its base, its box at rest (``qpos``, every active
    joint; default its ``rest_qpos``) in the spot's frame."""
    env = gym.make("PickEmbodiedGen-v1", layout_file=layout, control_mode="pd_joint_pos")
    env.reset(seed=0)
    base = env.unwrapped
    entry = ROBOTS[base.agent.uid]
    robot = base.agent.robot
    rest = entry.rest_qpos if qpos is None else qpos
    robot.set_qpos(np.asarray(rest, np.float32)[None])
    spot = base.layouts[0].pose(base.layouts[0].robot)  # placement reads its xy and yaw only
    to_spot = LayoutPose.from_xyz_yaw(spot.p, spot.yaw).to_sapien().inv().to_transformation_matrix()
    rows = []
    for link in robot.get_links()[1:]:  # the first is the base, kept out by its square
        mesh = get_component_mesh(link._objs[0], to_world_frame=True)
        if mesh is None:  # no collision shape
            continue
        p = mesh.vertices @ to_spot[:3, :3].T + to_spot[:3, 3]
        lo, hi = p.min(0), p.max(0)
        box = (math.floor(lo[0] * MM) / MM, math.ceil(hi[0] * MM) / MM,
               math.floor(lo[1] * MM) / MM, math.ceil(hi[1] * MM) / MM,
               math.floor(lo[2] * MM) / MM)  # fmt: skip
        rows.append((link.name, box))
    env.close()
    return entry.uid, rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("layouts", nargs="+")
    ap.add_argument("--qpos", type=float, nargs="+", default=None,
                    help="rad, every active joint (as robot_init_qpos); default its rest_qpos")
    args = ap.parse_args()
    for layout in args.layouts:
        uid, rows = rest_boxes(layout, args.qpos)
        print(f"{uid} ({layout}): rest_arm=(")
        for name, box in rows:
            print(f"    ({', '.join(f'{v:.3f}' for v in box)}),  # {name}")
        print(")")


if __name__ == "__main__":
    main()
