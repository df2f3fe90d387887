"""The env's reads of ManiSkill and SAPIEN internals, for speed on the CPU simulation, in one place.

On the CPU simulation (one env per process) ManiSkill's public reads wrap every value in batched
torch tensors, one struct at a time; read every step, that costs as much as the physics. These
functions read the SAPIEN objects behind ManiSkill's ``Actor``, ``Link`` and ``Articulation``
structs directly and give the same values:

- :func:`cpu_state_dict`: ``BaseEnv.get_state_dict`` in one pass (``RecordEpisode`` records it
  every step; ManiSkill's pass cost 0.12 of 1.7 ms per recorded control step);
- :func:`positions`: an actor's position per env as a numpy array;
- :func:`restart_sleep_timers`: every moving body woken, as in a new scene.

They read ManiSkill's private fields through ``embodied_envs/internals.py`` (the one module
that reaches them; its ``PRIVATE_ATTRIBUTES``, ManiSkill 3.0.1), as ``envs/contacts.py``,
``envs/tasks/scene.py``, ``envs/agents.py`` and ``envs/fast_control.py`` do;
``tests/envs/test_fast_reads.py`` checks each on a real CPU env, so an upgrade that renames or
retypes one fails there, naming it.
"""

from __future__ import annotations

import numpy as np
import torch

from embodied_envs.internals import bodies, entities, link_components, px_articulations


def positions(actor) -> np.ndarray:
    """``actor.pose.p`` as a numpy array ``(num_envs, 3)``, read from its SAPIEN entities."""
    return np.array([entity.pose.p for entity in entities(actor)])


def cpu_state_dict(env) -> dict:
    """ManiSkill's state dict of a CPU-simulation ``env`` (what ``set_state_dict`` takes), read
    as ManiSkill's ``Actor.get_state`` and ``Articulation.get_state`` read it, with the same keys,
    order, shapes and values (``tests/envs/test_cpu_reads.py`` compares them at every step)."""
    zeros = np.zeros(3, dtype=np.float32)
    actors, articulations = {}, {}
    registry = env.scene.state_dict_registry
    # every value in one array (numpy's cost is per call), each state a view of it
    parts, rows = [], []  # rows: (the dict, its key, the state's length)
    for actor in registry.actors.values():
        if actor.px_body_type == "static":
            continue
        pose, body = entities(actor)[0].pose, bodies(actor)[0]
        moving = actor.px_body_type == "dynamic"
        vel = (body.linear_velocity, body.angular_velocity) if moving else (zeros, zeros)
        parts += (pose.p, pose.q, *vel)
        rows.append((actors, actor.name, 13))
    for art in registry.articulations.values():
        root, px = art.root, px_articulations(art)[0]
        pose, body = link_components(root)[0].entity_pose, bodies(root)[0]
        qpos, qvel = px.qpos, px.qvel
        parts += (pose.p, pose.q, body.linear_velocity, body.angular_velocity, qpos, qvel)
        rows.append((articulations, art.name, 13 + len(qpos) + len(qvel)))
    if parts:
        flat, start = np.concatenate(parts)[None], 0
        for into, name, size in rows:
            into[name] = torch.from_numpy(flat[:, start : start + size])
            start += size
    state = {}
    if actors:
        state["actors"] = actors
    if articulations:
        state["articulations"] = articulations
    controller = env.agent.get_controller_state()
    if isinstance(env.agent.controller, dict):
        controller = {k: v for k, v in controller.items() if len(v) > 0}
    if len(controller) > 0:
        state["controller"] = controller
    return state


def restart_sleep_timers(scene) -> None:
    """Wakes every moving body of a CPU-simulation ``scene``, as a new scene holds them. PhysX
    keeps each body's sleep timer across ``set_pose``: without this, when bodies settle and sleep
    depends on the episodes the process ran before, and one seed gives other states (and other
    expert actions) after another history, e.g. with another ``collect --workers``. Not for the
    GPU simulation, where all envs share one PhysX scene (untested there)."""
    px = scene.px
    for body in px.rigid_dynamic_components:
        if not body.kinematic:
            body.wake_up()
    for link in px.articulation_link_components:
        link.wake_up()
