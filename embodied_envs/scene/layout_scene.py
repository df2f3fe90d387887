"""Load per-env layouts into one ManiSkill scene: actors per env, merged per node and role."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from mani_skill.utils.structs import Actor
from mani_skill.utils.structs.pose import Pose

from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.placement import derive_seed, floor_height, place
from embodied_envs.layout.placement.batch import Region
from embodied_envs.layout.placement.episode import NOISE_DIMS, EpisodeSampler, EpisodeStart
from embodied_envs.layout.placement.limits import GoalRegion, PlacementLimits
from embodied_envs.layout.schema import (
    CONTEXT_SLOT,
    OBJECT_SLOT,
    TARGET_ACTOR,
    TARGET_SLOT,
    LayoutInfo,
    label,
)
from embodied_envs.layout.sets import LayoutSet
from embodied_envs.scene.builder import build_asset_actor

if TYPE_CHECKING:
    from mani_skill.envs.scene import ManiSkillScene


@dataclass
class SceneEpisodes:
    """Per-episode starts of every env: one :class:`EpisodeSampler` per group of envs that
    hold the same layout (a loop over layouts, never over envs), their starts keyed by slot.

    Attributes:
        samplers: per group, its sampler (over the group's envs, ascending).
        slots: per group, each node's slot name.
        top: the whole table top of every env (``Region``, edges padded).
        robot_xy, top_z: per env, its robot base's XY and its table top's height.
    """

    samplers: list[EpisodeSampler]
    slots: list[dict[str, str]]
    top: Region
    robot_xy: torch.Tensor
    top_z: torch.Tensor

    @classmethod
    def of(cls, samplers: list[EpisodeSampler], slots: list[dict[str, str]], num_envs: int):
        device = samplers[0].device

        def tensor(x):  # the samplers' arrays (numpy on the CPU) as tensors for the env
            return torch.as_tensor(x, device=device)

        if len(samplers) == 1:
            only = samplers[0]
            return cls(samplers, slots, only.top.map(tensor), tensor(only.robot_xy),
                       tensor(only.top_z))  # fmt: skip
        edges = max(s.top.normals.shape[1] for s in samplers)
        normals = torch.zeros((num_envs, edges, 2), device=device)
        offsets = torch.zeros((num_envs, edges), device=device)  # padded edges: 0 >= 0 holds
        lo, hi, robot_xy = (torch.zeros((num_envs, 2), device=device) for _ in range(3))
        z = torch.zeros(num_envs, device=device)
        for s in samplers:
            top, rows = s.top.map(tensor), s.env_ids
            e = top.normals.shape[1]
            normals[rows, :e], offsets[rows, :e] = top.normals, top.offsets
            lo[rows], hi[rows], z[rows], robot_xy[rows] = top.lo, top.hi, top.z, tensor(s.robot_xy)
        return cls(samplers, slots, Region(normals, offsets, lo, hi, z), robot_xy, z)

    @functools.cached_property
    def top_arrays(self) -> Region:
        """``top`` as numpy arrays (on a CPU env the same memory), for numpy points."""
        return self.top.map(lambda x: x.cpu().numpy())

    @property
    def fallbacks(self) -> int:
        return sum(s.fallbacks for s in self.samplers)

    @property
    def fallback(self) -> dict[str, torch.Tensor]:
        """The configuration's pose of each slot's objects, ``(num_envs, 7)`` (one group)."""
        if len(self.samplers) == 1:
            device = self.top_z.device
            fallback = self.samplers[0].fallback.items()
            return {self.slots[0][n]: torch.as_tensor(p, device=device) for n, p in fallback}
        raise AttributeError("fallback poses are per group: see samplers[g].fallback")

    def reseeded(self, seed, env_idx, enhanced_determinism: bool) -> None:
        """After ManiSkill's ``_set_episode_rng(seed, env_idx)`` (``EpisodeSampler.reseeded``)."""
        if seed is not None:  # every env's episode RNG is new
            for s in self.samplers:
                s.invalidate()
        elif enhanced_determinism:
            for s, rows in self._rows(torch.as_tensor(env_idx, device=self.top_z.device)):
                s.invalidate(rows)

    def draw(self, env_idx: torch.Tensor, rngs) -> EpisodeStart:
        """The next episode start of each env in ``env_idx``, objects keyed by slot."""
        if len(self.samplers) == 1:
            start = self.samplers[0].draw(env_idx, rngs)
            names = self.slots[0]
            return EpisodeStart({names[n]: p for n, p in start.objects.items()}, start.goal,
                                start.joint_noise)  # fmt: skip
        b, device = len(env_idx), self.top_z.device
        objects: dict[str, torch.Tensor] = {}
        goal = torch.zeros((b, 3), device=device)
        noise = torch.zeros((b, NOISE_DIMS), device=device)
        for s, names in zip(self.samplers, self.slots, strict=True):
            where = torch.isin(env_idx, s.env_ids).nonzero().reshape(-1)
            if not len(where):
                continue
            rows = torch.searchsorted(s.env_ids, env_idx[where])
            start = s.draw(rows, rngs)
            for node, pose in start.objects.items():
                objects.setdefault(names[node], torch.zeros((b, 7), device=device))[where] = pose
            goal[where], noise[where] = start.goal, start.joint_noise
        return EpisodeStart(objects, goal, noise)

    def _rows(self, env_idx: torch.Tensor):
        """Per sampler, the rows of the envs of ``env_idx`` it holds (samplers with none
        left out)."""
        for s in self.samplers:
            mine = env_idx[torch.isin(env_idx, s.env_ids)]
            if len(mine):
                yield s, torch.searchsorted(s.env_ids, mine)


@dataclass
class LayoutScene:
    """The loaded actors of all envs.

    Envs may hold different layouts (a layout set or asset pools): their actors are merged
    into **slots**, one ManiSkill ``Actor`` over all envs per slot, as ManiSkill's
    ``PickSingleYCB`` merges its per-env objects. When every env holds the same nodes, each
    node is its own slot, named after it. Otherwise the slots are ``context``, ``target``
    (the graded object) and ``object1``, ``object2``, ... (the other objects, in each layout's
    order), and every layout must have as many objects.

    Attributes:
        env_actors: ``env_actors[f"env{i}"][node]``, the actor of each node in env i.
        node_actors: each slot's actors merged over envs.
        dynamic_nodes: the slots whose pose is reset each episode (all but the context).
        node_poses: each slot's configuration raw pose per env, ``(num_envs, 7)`` (the
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
    episodes: SceneEpisodes
    floor_z: float

    def register_state(self, env) -> None:
        """Make each dynamic slot one entry of ``env``'s state dict, over all envs (its per-env
        actors are views of the merged one and leave the registry)."""
        for actor in (a for actors in self.env_actors.values() for a in actors.values()):
            env.remove_from_state_dict_registry(actor)
        for node in self.dynamic_nodes:
            env.add_to_state_dict_registry(self.node_actors[node])

    def set_episode_poses(self, env_idx: torch.Tensor, objects: dict[str, torch.Tensor]) -> None:
        """Pose every dynamic slot of ``env_idx`` at rest: at ``objects[slot]`` (raw poses
        ``(b, 7)``) when given, else at its configuration's pose."""
        zeros = torch.zeros((len(env_idx), 3), device=env_idx.device)
        for node in self.dynamic_nodes:
            pose = objects[node] if node in objects else self.node_poses[node][env_idx]
            actor = self.node_actors[node]
            actor.set_pose(Pose.create(pose))
            actor.set_linear_velocity(zeros)
            actor.set_angular_velocity(zeros)

    def off_table(self, points: torch.Tensor, drop: float) -> torch.Tensor:
        """``(n, ...)`` bool: each env's points (``points (n, ..., 3)``, a tensor or a numpy
        array) are more than ``drop`` below its table's top or outside the top's footprint (the
        whole top hull, seen from above)."""
        top = self.episodes.top if isinstance(points, torch.Tensor) else self.episodes.top_arrays
        low = (top.z - drop).reshape(-1, *[1] * (points.ndim - 2))
        return (points[..., 2] < low) | ~top.contains(points[..., :2])

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
    layout_set: LayoutSet, seeds: np.ndarray, limits: PlacementLimits, first: bool, replace: bool
) -> list[LayoutInfo]:
    """The layout of each env for a configuration: env k draws its scene from the set
    (``LayoutSet.draw(seeds[k], k)``); with ``replace``, it is placed by
    ``derive_seed(seeds[k], k)``, except env 0 on the ``first`` configuration of a set without
    asset pools, which keeps the file's poses; without ``replace``, the file's poses."""
    seeds = np.asarray(seeds).reshape(-1)
    drawn = [layout_set.draw(s, k) for k, s in enumerate(seeds)]
    if not replace:
        return drawn
    keep_file = first and not any(layout_set.pools)
    return [
        layout if (keep_file and k == 0) else place(layout, derive_seed(s, k), limits)
        for k, (s, layout) in enumerate(zip(seeds, drawn, strict=True))
    ]


def scene_slots(layouts: list[LayoutInfo]) -> list[dict[str, str]]:
    """Each env's slot name per node (``LayoutScene``): the node names when every env holds
    the same nodes, else ``context``, ``target``, ``object1``, ...

    Raises:
        LayoutError: the layouts differ in how many objects they hold.
    """
    nodes = layouts[0].object_nodes()
    if all(x.object_nodes() == nodes for x in layouts):
        return [{n: n for n in nodes} for _ in layouts]
    counts = {label(x.source): len(x.object_nodes()) for x in layouts}
    if len(set(counts.values())) > 1:
        raise LayoutError(
            f"layouts held by parallel envs must hold as many objects each (each object is one"
            f" actor merged over envs), and these differ: {counts}. Fix: give every layout of "
            "the set as many objects (add or drop distractors), or use num_envs=1."
        )
    slots = []
    for x in layouts:
        others = [n for n in x.object_nodes() if n not in (x.context, x.target_node)]
        names = {x.context: CONTEXT_SLOT, x.target_node: TARGET_SLOT}
        slots.append(names | {n: f"{OBJECT_SLOT}{j + 1}" for j, n in enumerate(others)})
    return slots


def load_layout_scene(
    scene: ManiSkillScene,
    layouts: list[LayoutInfo],
    objs_z_offset: float,
    robot_z_offset: float,
    limits: PlacementLimits,
    goal_region: GoalRegion,
    device: torch.device,
) -> LayoutScene:
    """Build every env's layout actors, merged into slots, and the per-env tensors the task
    needs; one episode sampler per group of envs holding the same layout."""
    num_envs = len(layouts)
    slots = scene_slots(layouts)
    names = list(slots[0].values())
    env_actors: dict[str, dict[str, Actor]] = {}
    node_poses = {name: np.zeros((num_envs, 7), np.float32) for name in names}
    robot_poses = np.zeros((num_envs, 7), np.float32)
    specs: dict[tuple[Path, str], object] = {}  # (asset folder, node) -> parsed asset, once
    for i, layout in enumerate(layouts):
        actors = {}
        for node in layout.object_nodes():
            static = layout.objs_mapping[node] == "context"
            pose = layout.pose(node).raised(0.0 if static else objs_z_offset)
            node_poses[slots[i][node]][i] = pose.to_raw()
            key = (layout.asset_dir(node), node)
            if key not in specs:
                specs[key] = layout.asset_spec(node)
            actors[node] = build_asset_actor(scene, specs[key], pose, f"env{i}/{node}", [i], static)
        env_actors[f"env{i}"] = actors
        robot_poses[i] = layout.pose(layout.robot).raised(robot_z_offset).to_raw()
    node_actors = {}
    for name in names:
        per_env = [
            env_actors[f"env{i}"][next(n for n, s in slots[i].items() if s == name)]
            for i in range(num_envs)
        ]
        node_actors[name] = Actor.merge(per_env, name=name)
    target_actor = Actor.merge(
        [env_actors[f"env{i}"][layouts[i].target_node] for i in range(num_envs)], name=TARGET_ACTOR
    )
    groups: dict[tuple, list[int]] = {}  # envs holding the same layout and assets
    for i, layout in enumerate(layouts):
        groups.setdefault((layout.source, tuple(sorted(layout.assets.items()))), []).append(i)
    samplers, group_slots = [], []
    for envs in groups.values():
        samplers.append(
            EpisodeSampler(
                [layouts[i] for i in envs], limits, goal_region, objs_z_offset, device,
                env_ids=torch.tensor(envs, device=device),
            )
        )  # fmt: skip
        group_slots.append(slots[envs[0]])

    def t(x):
        return torch.as_tensor(x, device=device)

    context = slots[0][layouts[0].context]
    return LayoutScene(
        env_actors=env_actors,
        node_actors=node_actors,
        dynamic_nodes=[n for n in names if n != context],
        node_poses={n: t(p) for n, p in node_poses.items()},
        target_actor=target_actor,
        robot_poses=t(robot_poses),
        episodes=SceneEpisodes.of(samplers, group_slots, num_envs),
        floor_z=min(floor_height(layout) for layout in layouts),
    )
