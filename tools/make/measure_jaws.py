#!/usr/bin/env python
"""Measure a hand's jaws in its grasp frame: the numbers behind ``robots.Hand.fixed_jaw``.

For a layout's arm (its expert ``Hand``: the grasp frame in ``Hand.link``, the jaw that stands
still), the jaw joint (the last active joint) set to a series of angles, and the collision
hulls of both jaw links (ManiSkill's model) in the grasp frame (y: closing, z: approach):
per angle, the still jaw's inner face (its hull points' y nearest the origin, within 1 cm of
the frame's x = 0 plane), the moving jaw's (its points nearest the still jaw) and the deepest
z each jaw's hull reaches (its tip: positive is past the origin, toward the object).

Usage: python tools/make/measure_jaws.py tests/data/small_zoo/layouts/so100_marker.json
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import sapien  # noqa: E402

import embodied_envs  # noqa: E402,F401
from embodied_envs.robots import ROBOTS  # noqa: E402

SLAB = 0.01  # m: hull points within this of the grasp frame's x = 0 plane count as the face


def hull_points(link) -> np.ndarray:
    """The link's convex collision shapes' vertices in its own frame."""
    pts = []
    for shape in link._objs[0].collision_shapes:
        if hasattr(shape, "vertices"):
            local = shape.get_local_pose().to_transformation_matrix()
            v = np.asarray(shape.vertices) * np.asarray(shape.scale)
            pts.append(v @ local[:3, :3].T + local[:3, 3])
    return np.concatenate(pts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("layout")
    ap.add_argument("--angles", type=float, nargs="+", default=None, help="rad, jaw joint")
    args = ap.parse_args()
    env = gym.make("PickEmbodiedGen-v1", layout_file=args.layout, control_mode="pd_joint_pos")
    env.reset(seed=0)
    base = env.unwrapped
    uid = base.agent.uid
    hand, grip = ROBOTS[uid].hand, ROBOTS[uid].gripper
    robot = base.agent.robot
    links = {link.name: link for link in robot.get_links()}
    still = links[hand.link]
    moving = robot.get_active_joints()[-1].child_link
    in_link = sapien.Pose(hand.grasp_in_link[:3], hand.grasp_in_link[3:])
    angles = args.angles or np.linspace(grip.open_qpos, grip.closed_qpos, 7)
    qpos = robot.get_qpos()[0].cpu().numpy().copy()
    print(f"{uid}: still jaw {still.name}, moving jaw {moving.name}")
    for angle in angles:
        qpos[-1] = angle
        robot.set_qpos(qpos[None])
        to_grasp = (still._objs[0].entity_pose * in_link).inv()
        row = {}
        for name, link in (("still", still), ("moving", moving)):
            m = (to_grasp * link._objs[0].entity_pose).to_transformation_matrix()
            p = hull_points(link) @ m[:3, :3].T + m[:3, 3]
            row[name] = (p[np.abs(p[:, 0]) < SLAB], p[:, 2].max())
        face = row["still"][0][:, 1]
        side = np.sign(face.mean())
        still_face = side * np.abs(face).min()
        moving_face = (row["moving"][0][:, 1] * side).max() * side
        print(f"  jaw {angle:+.2f} rad: still face y {still_face:+.4f}, moving face y "
              f"{moving_face:+.4f} (gap {abs(still_face - moving_face):.4f}); tips z "
              f"{row['still'][1]:+.4f}, {row['moving'][1]:+.4f}")  # fmt: skip
    env.close()


if __name__ == "__main__":
    main()
