"""Load per-env layouts into one ManiSkill scene: actors per env, merged per node and role."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from mani_skill.utils.structs import Actor
from mani_skill.utils.structs.pose import Pose

from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.limits import GoalRegion, PlacementLimits
from embodied_envs.layout.placement import derive_seed, floor_height, place
from embodied_envs.layout.schema import LayoutInfo
from embodied_envs.scene.builder import build_asset_actor
from embodied_envs.scene.episode import EpisodeSampler

if TYPE_CHECKING:
    from mani_skill.envs.scene import ManiSkillScene


@dataclass
class LayoutScene:
    """The loaded actors of all envs.

    Attributes:
        env_actors: ``env_actors[f"env{i}"][node]``, the actor of each node in env i.
        node_actors: each node's actors merged over envs (one ManiSkill ``Actor`` per node).
        dynamic_nodes: nodes whose pose is reset each episode (all but the context).
        node_poses: each node's configuration raw pose per env, ``(num_envs, 7)`` (the
            layouts' poses, objects raised by ``objs_z_offset``).
        target_actor: the graded object of each env merged over envs.
        robot_poses: robot base raw pose per env, ``(num_envs, 7)``.
        episodes: per-episode object starts, goals and joint noise of every env.
        floor_z: height of the floor (``placement.floor_height`` of the lowest env).
    """

    env_actors: dict[str, dict[str, Actor]]
    node_actors: dict[str, Actor]
    dynamic_nodes: list[str]
    node_poses: dict[str, torch.Tensor]
    target_actor: Actor
    robot_poses: torch.Tensor
    episodes: EpisodeSampler
    floor_z: float

    def register_state(self, env) -> None:
        """Make each dynamic node one entry of ``env``'s state dict, over all envs (its per-env
        actors are views of the merged one and leave the registry)."""
        for actor in (a for actors in self.env_actors.values() for a in actors.values()):
            env.remove_from_state_dict_registry(actor)
        for node in self.dynamic_nodes:
            env.add_to_state_dict_registry(self.node_actors[node])

    def set_episode_poses(self, env_idx: torch.Tensor, objects: dict[str, torch.Tensor]) -> None:
        """Pose every dynamic node of ``env_idx`` at rest: at ``objects[node]`` (raw poses
        ``(b, 7)``) when given, else at its configuration's pose."""
        zeros = torch.zeros((len(env_idx), 3), device=env_idx.device)
        for node in self.dynamic_nodes:
            pose = objects[node] if node in objects else self.node_poses[node][env_idx]
            actor = self.node_actors[node]
            actor.set_pose(Pose.create(pose))
            actor.set_linear_velocity(zeros)
            actor.set_angular_velocity(zeros)

    def off_table(self, points: torch.Tensor, drop: float) -> torch.Tensor:
        """``(n,)`` bool: each env's point (``points (n, 3)``) is more than ``drop`` below its
        table's top or outside the top's footprint (the whole top hull, seen from above)."""
        top = self.episodes.top
        inside = top.contains(points[:, None, :2])[:, 0]
        return (points[:, 2] < top.z - drop) | ~inside

    def framing(
        self, back: float, eye_rise: float, target_rise: float, env: int = 0
    ) -> tuple[list[float], list[float]]:
        """A render camera's eye and target framed on env ``env``'s robot and table: the eye
        ``back`` metres past the centre of the table's top, away from the robot, ``eye_rise``
        above the top; the target over the top's centre, ``target_rise`` above it."""
        top = self.episodes.top
        centre = ((top.lo[env] + top.hi[env]) / 2).tolist()
        away = np.asarray(centre) - self.episodes.robot_xy[env].tolist()
        away = away / max(float(np.linalg.norm(away)), 1e-6)
        z = float(self.top_z[env])
        eye = [centre[0] + back * away[0], centre[1] + back * away[1], z + eye_rise]
        return eye, [centre[0], centre[1], z + target_rise]

    @property
    def top_z(self) -> torch.Tensor:
        """Height of the context's top per env, ``(num_envs,)``."""
        return self.episodes.top_z


def configuration_layouts(
    base: LayoutInfo, seeds: np.ndarray, limits: PlacementLimits, first: bool, replace: bool
) -> list[LayoutInfo]:
    """The layout of each env for a configuration: with ``replace``, env k placed by
    ``derive_seed(seeds[k], k)``, except env 0 on the ``first`` configuration, which keeps the
    file's poses; without ``replace``, the file's poses everywhere."""
    seeds = np.asarray(seeds).reshape(-1)
    if not replace:
        return [base] * len(seeds)
    return [
        base if (first and k == 0) else place(base, derive_seed(s, k), limits)
        for k, s in enumerate(seeds)
    ]


def load_layout_scene(
    scene: ManiSkillScene,
    layouts: list[LayoutInfo],
    objs_z_offset: float,
    robot_z_offset: float,
    limits: PlacementLimits,
    goal_region: GoalRegion,
    device: torch.device,
) -> LayoutScene:
    """Build every env's layout actors and the per-env tensors the task needs."""
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
    for i, layout in enumerate(layouts):
        actors = {}
        for node in nodes:
            static = layout.objs_mapping[node] == "context"
            pose = layout.pose(node).raised(0.0 if static else objs_z_offset)
            node_poses[node][i] = pose.to_raw()
            actors[node] = build_asset_actor(
                scene, specs[node], pose, f"env{i}/{node}", [i], static
            )
        env_actors[f"env{i}"] = actors
        robot_poses[i] = layout.pose(layout.robot).raised(robot_z_offset).to_raw()
    node_actors = {}
    for node in nodes:
        per_env = [env_actors[f"env{i}"][node] for i in range(num_envs)]
        node_actors[node] = Actor.merge(per_env, name=node)
    target_actor = Actor.merge(
        [env_actors[f"env{i}"][layouts[i].target_node] for i in range(num_envs)], name="target_obj"
    )

    def t(x):
        return torch.as_tensor(x, device=device)

    node_poses = {n: t(p) for n, p in node_poses.items()}
    return LayoutScene(
        env_actors=env_actors,
        node_actors=node_actors,
        dynamic_nodes=[n for n in nodes if layouts[0].objs_mapping[n] != "context"],
        node_poses=node_poses,
        target_actor=target_actor,
        robot_poses=t(robot_poses),
        episodes=EpisodeSampler(layouts, limits, goal_region, objs_z_offset, device),
        floor_z=min(floor_height(layout) for layout in layouts),
    )
