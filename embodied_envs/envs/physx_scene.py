"""A new PhysX scene at each reset on the CPU simulation, so that a seed's episode does not depend
on the episodes the env ran before it.

PhysX keeps, across ``set_pose`` and across removing and re-adding actors, the pools it numbers
its contact pairs and their island edges from; the solver visits an island's contacts in that
order, and a body resting on several contact pairs at once (a bowl's convex pieces on the
table) then takes other impulses after another history: up to 5e-4 in the distractors' states
within 10 control steps (docs/reliability.md, "Determinism"). A fresh PhysX scene has fresh
pools. :func:`renew_physx_system` moves every entity, as it stands, into a new
``PhysxCpuSystem``: the assets, shapes, joints and render bodies stay the same objects, so
ManiSkill's structs and the env's references keep working, and the reset then sets the state
as in a new env. Not for the GPU simulation (its system holds every sub-scene).
"""

from __future__ import annotations

import sapien
from sapien import physx


def renew_physx_system(scene) -> None:
    """Moves every entity of a CPU-simulation ManiSkill ``scene`` (one sub-scene) into a new
    ``PhysxCpuSystem`` with the old one's scene config and timestep; the render system stays.
    ``scene.sub_scenes[0]`` and ``scene.px`` then name the new ones."""
    old = scene.sub_scenes[0]
    px = old.physx_system
    default = physx.get_scene_config()  # the process-wide default a new system takes
    physx.set_scene_config(px.config)
    try:
        new_px = physx.PhysxCpuSystem()
    finally:
        physx.set_scene_config(default)
    new_px.timestep = px.timestep
    systems = [new_px]
    try:
        systems.append(old.render_system)
    except RuntimeError:  # a scene built without rendering has no render system
        pass
    new = sapien.Scene(systems)
    entities = list(old.entities)
    for entity in reversed(entities):  # joints and drives before the bodies they join
        old.remove_entity(entity)
    for entity in entities:  # the order a new env adds them in
        new.add_entity(entity)
    scene.sub_scenes[0] = new
    scene.px = new_px
