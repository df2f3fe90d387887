"""Load per-env layouts into one ManiSkill scene: actors per env, merged per node and role."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.placement import (
    half_planes,
    node_geometry,
    shrink_polygon,
    top_surface,
    world_vertices,
)
from embodied_envs.layout.schema import LayoutInfo
from embodied_envs.scene.builder import build_asset_actor

if TYPE_CHECKING:
    from mani_skill.envs.scene import ManiSkillScene
    from mani_skill.utils.structs import Actor


@dataclass(frozen=True)
class GoalRegion:
    """Where goals may be drawn: above the table top, within the robot's reach."""

    reach: tuple[float, float] = (0.30, 0.65)  # m from the robot base
    max_heading_deg: float = 50.0  # within this angle of the robot heading
    margin: float = 0.05  # m inside the table top's hull
    height: tuple[float, float] = (0.05, 0.25)  # m above the table top
    grid: int = 48  # candidate grid resolution per axis


@dataclass
class LayoutScene:
    """The loaded actors of all envs.

    Attributes:
        env_actors: ``env_actors[f"env{i}"][node]``, the actor of each node in env i.
        node_actors: each node's actors merged over envs (one ManiSkill ``Actor`` per node).
        dynamic_nodes: nodes whose pose is reset each episode (all but the context).
        node_poses: each node's initial raw pose per env, ``(num_envs, 7)``.
        target: the graded object of each env merged over envs.
        robot_poses: robot base raw pose per env, ``(num_envs, 7)``.
        goal_xy: candidate goal positions per env, ``(num_envs, K, 2)``.
        top_z: height of the context's top per env, ``(num_envs,)``.
    """

    env_actors: dict[str, dict[str, Actor]]
    node_actors: dict[str, Actor]
    dynamic_nodes: list[str]
    node_poses: dict[str, torch.Tensor]
    target: Actor
    robot_poses: torch.Tensor
    goal_xy: torch.Tensor
    top_z: torch.Tensor


def goal_candidates(layout: LayoutInfo, region: GoalRegion) -> tuple[np.ndarray, float]:
    """Grid points over the table top that lie within the robot's reach.

    Returns:
        ``(K, 2)`` candidate XY positions and the table top height.

    Raises:
        LayoutError: when no point of the table top is within reach of the robot.
    """
    ctx = layout.context
    surface = top_surface(world_vertices(node_geometry(layout, ctx), layout.pose(ctx)), 0.05)
    try:
        hull = shrink_polygon(surface.hull, region.margin)
    except ValueError:
        hull = surface.hull
    normals, offsets = half_planes(hull)
    lo, hi = hull.min(0), hull.max(0)
    g = region.grid
    xs, ys = np.meshgrid(np.linspace(lo[0], hi[0], g), np.linspace(lo[1], hi[1], g))
    pts = np.stack([xs.ravel(), ys.ravel()], 1)
    robot = layout.pose(layout.robot)
    rel = pts - np.array(robot.p[:2])
    d = np.linalg.norm(rel, axis=1)
    bearing = np.arctan2(rel[:, 1], rel[:, 0])
    dyaw = np.abs((bearing - robot.yaw + np.pi) % (2 * np.pi) - np.pi)
    ok = (
        np.all(pts @ normals.T >= offsets, axis=1)
        & (d >= region.reach[0])
        & (d <= region.reach[1])
        & (dyaw <= math.radians(region.max_heading_deg))
    )
    if not ok.any():
        src = layout.source or "<layout>"
        raise LayoutError(
            f'{src}: position["{layout.robot}"]: no point of the "{ctx}" top lies within '
            f"{region.reach} m of the robot base and {region.max_heading_deg} deg of its heading."
            " Fix: put the robot at the table's edge, facing the table."
        )
    return pts[ok], surface.z


def load_layout_scene(
    scene: ManiSkillScene,
    layouts: list[LayoutInfo],
    objs_z_offset: float,
    robot_z_offset: float,
    goal_region: GoalRegion,
    device: torch.device,
    num_goal_candidates: int = 256,
) -> LayoutScene:
    """Build every env's layout actors and the per-env tensors the task needs."""
    from mani_skill.utils.structs import Actor

    num_envs = len(layouts)
    nodes = layouts[0].object_nodes()
    for i, layout in enumerate(layouts):
        if layout.object_nodes() != nodes:
            raise LayoutError(
                f"env {i}: layout nodes {layout.object_nodes()} differ from env 0's {nodes}"
            )
    specs = {node: layouts[0].asset_spec(node) for node in nodes}
    env_actors: dict[str, dict[str, Actor]] = {}
    node_poses = {node: np.zeros((num_envs, 7), np.float32) for node in nodes}
    robot_poses = np.zeros((num_envs, 7), np.float32)
    goal_xy = np.zeros((num_envs, num_goal_candidates, 2), np.float32)
    top_z = np.zeros(num_envs, np.float32)
    for i, layout in enumerate(layouts):
        actors = {}
        for node in nodes:
            static = layout.objs_mapping[node] == "context"
            pose = layout.pose(node).translated(0.0 if static else objs_z_offset)
            node_poses[node][i] = pose.to_raw()
            actors[node] = build_asset_actor(
                scene, specs[node], pose, f"env{i}/{node}", [i], static
            )
        env_actors[f"env{i}"] = actors
        robot_poses[i] = layout.pose(layout.robot).translated(robot_z_offset).to_raw()
        candidates, top_z[i] = goal_candidates(layout, goal_region)
        goal_xy[i] = np.resize(candidates, (num_goal_candidates, 2))
    node_actors = {}
    for node in nodes:
        per_env = [env_actors[f"env{i}"][node] for i in range(num_envs)]
        node_actors[node] = Actor.merge(per_env, name=node)
    target = Actor.merge(
        [env_actors[f"env{i}"][layouts[i].target] for i in range(num_envs)], name="target_obj"
    )

    def t(x):
        return torch.as_tensor(x, device=device)

    return LayoutScene(
        env_actors=env_actors,
        node_actors=node_actors,
        dynamic_nodes=[n for n in nodes if layouts[0].objs_mapping[n] != "context"],
        node_poses={n: t(p) for n, p in node_poses.items()},
        target=target,
        robot_poses=t(robot_poses),
        goal_xy=t(goal_xy),
        top_z=t(top_z),
    )
