"""A new PhysX scene at each reset on the CPU simulation, so that a seed's episode does not depend
on the episodes the env ran before it (docs/reliability.md, "Determinism").

A PhysX scene keeps its contact-pair bookkeeping across ``set_pose``, and across removing and
re-adding every actor: after another history, the solver meets a body's contact pairs in
another order, and a body resting on several at once (the default layout's bowl: convex pieces
on the table) takes other impulses, its angular velocity 2.4e-3 rad/s apart after one control
step. A new scene has none of it. :func:`renew_physx_system` moves every entity, as it stands,
into a new ``PhysxCpuSystem`` (0.6 ms; 1.1 ms with a camera): shapes, joints, drives and render
bodies stay the same objects, so ManiSkill's structs and the env's references keep working, and
the reset then sets the state as in a new env. Not for the GPU simulation, whose one system
holds every sub-scene.
"""

from __future__ import annotations

import sapien
from sapien import physx

from embodied_envs.envs.fast_reads import restart_sleep_timers
from embodied_envs.internals import viewer


def renew_physx_system(scene) -> None:
    """Moves every entity of a CPU-simulation ManiSkill ``scene`` (one sub-scene) into a new
    ``PhysxCpuSystem`` with the old one's scene config and timestep; the render system stays.
    ``scene.sub_scenes[0]`` and ``scene.px`` then name the new ones.

    Every moving body is woken before the move, so that each enters the new scene awake, as
    in a new env. One that enters it asleep and is woken there (the reset wakes every body)
    gives other states: on the default layout, the expert's seed 4 after its seed 3 (whose end
    left the bowl awake, the box and the mug asleep) grasped the can at step 53 with the can's
    angular velocity 0.81 rad/s apart from seed 4 alone, and its actions differed from step 54
    (``tests/envs/test_physx_scene.py``)."""
    restart_sleep_timers(scene)
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
    ids = [entity.per_scene_id for entity in entities]
    for entity in reversed(entities):  # joints and drives before the bodies they join
        old.remove_entity(entity)
    _add_keeping_ids(new, entities, ids)
    scene.sub_scenes[0] = new
    scene.px = new_px


def _add_keeping_ids(scene, entities: list, ids: list[int]) -> None:
    """Adds ``entities`` to ``scene`` in their order (the order a new env adds them in), each
    with its old ``per_scene_id`` (``ids``; a scene numbers entities 1, 2, ... as they are
    added): an id left free by an entity removed earlier (ManiSkill's CPU-only
    ``Actor.remove_from_scene``) is taken by an empty entity, removed after. ManiSkill caches
    the ids (``Actor.per_scene_id``, ``segmentation_id_map``; the hybrid renderer's foreground)
    and the camera's segmentation draws the live ones."""
    fillers, expected = [], 1
    for entity, want in zip(entities, ids, strict=True):
        for _ in range(want - expected):
            fillers.append(sapien.Entity())
            scene.add_entity(fillers[-1])
        scene.add_entity(entity)
        expected = entity.per_scene_id + 1
    for filler in fillers:  # no components: nothing in the PhysX scene
        scene.remove_entity(filler)


def before_reset(env) -> None:
    """The env's reset (CPU simulation): a new PhysX scene, unless the scene is new since the
    last reset (the first reset of a configuration); the viewer, if open, shows the new scene.
    Nothing on the GPU simulation."""
    if env.gpu_sim_enabled:
        return
    # marked on the ManiSkill scene, which a reconfiguration replaces (the env holds no PhysX
    # system: after close() none stays alive with its bodies)
    if getattr(env.scene, "reset_before", False):
        renew_physx_system(env.scene)
        if viewer(env) is not None:
            viewer(env).set_scene(env.scene.sub_scenes[0])
    env.scene.reset_before = True
