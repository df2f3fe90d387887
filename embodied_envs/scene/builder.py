"""Build EmbodiedGen assets as ManiSkill actors: the context static, everything else dynamic;
friction from the URDF (clipped), restitution 0.05, mass from the URDF or 1000 kg/m^3."""

from __future__ import annotations

from typing import TYPE_CHECKING

import sapien

from embodied_envs.layout.assets import DEFAULT_DENSITY, AssetSpec, asset_geometry
from embodied_envs.layout.pose import LayoutPose

if TYPE_CHECKING:
    from mani_skill.envs.scene import ManiSkillScene
    from mani_skill.utils.structs import Actor


def asset_density(spec: AssetSpec) -> float:
    """Density that gives the URDF's mass over the collision parts' volume (else 1000 kg/m^3)."""
    if spec.mass is None:
        return DEFAULT_DENSITY
    volume = asset_geometry(spec).volume
    return spec.mass / volume if volume > 0 else DEFAULT_DENSITY


def build_asset_actor(
    scene: ManiSkillScene,
    spec: AssetSpec,
    pose: LayoutPose,
    name: str,
    scene_idxs: list[int],
    static: bool,
) -> Actor:
    """Build one asset in the given sub-scenes.

    Args:
        scene: the ManiSkill scene.
        spec: the parsed asset.
        pose: initial pose of the actor.
        name: unique actor name.
        scene_idxs: sub-scenes (parallel envs) this actor lives in.
        static: True for the context (table), False for dynamic objects.

    Returns:
        The ManiSkill actor.
    """
    material = sapien.physx.PhysxMaterial(
        static_friction=spec.static_friction,
        dynamic_friction=spec.dynamic_friction,
        restitution=spec.restitution,
    )
    builder = scene.create_actor_builder()
    builder.add_visual_from_file(
        str(spec.visual.path), pose=spec.visual.sapien_pose(), scale=spec.visual.scale
    )
    # EmbodiedGen collision meshes: each connected component is one convex part
    builder.add_multiple_convex_collisions_from_file(
        str(spec.collision.path),
        pose=spec.collision.sapien_pose(),
        scale=spec.collision.scale,
        material=material,
        density=asset_density(spec),
        decomposition="none",
    )
    builder.set_scene_idxs(scene_idxs)
    builder.initial_pose = pose.to_sapien()
    return builder.build_static(name=name) if static else builder.build(name=name)
