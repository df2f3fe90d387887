"""The grasp check every step pays for: an arm's ManiSkill ``is_grasping``, in one pass on CPU.

ManiSkill's ``is_grasping(obj)`` of the Panda, SO-100, Koch and Fetch asks the scene for the
contact impulses between each finger and the object. On the GPU simulation that is one batched
query. On the CPU simulation each call walks every contact of the scene in Python, once per
finger, and then makes a dozen one-env torch tensors; ``evaluate()`` runs it on every step, where
it cost more than the physics (0.5 ms of 1.5 ms per control step on the shipped default layout,
Panda; 1-2 ms of the others' steps, ``tools/bench/bench_robots.py``). :func:`is_grasping` gives the
same answer with the same rule (``robots.FingerGrasp``: both fingers press on the object with at
least ``min_force`` newtons, each within ``max_angle`` degrees of its opening direction): on GPU
it calls the agent's; on CPU it walks the contacts once, for both fingers, in numpy.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from embodied_envs.robots import PANDA_GRASP, FingerGrasp


def is_grasping(agent, obj, rule: FingerGrasp = PANDA_GRASP):
    """Per env (bool tensor, shape (num_envs,)): ``agent`` (an arm whose ``is_grasping`` follows
    ``rule``, the Panda's by default) grasps the actor ``obj``, as
    ``agent.is_grasping(obj, rule.min_force, rule.max_angle)`` decides."""
    scene = agent.scene
    min_force, max_angle = rule.min_force, rule.max_angle
    if scene.gpu_sim_enabled:
        return agent.is_grasping(obj, min_force, max_angle)
    # the rigid-body components (comparing them costs a third of comparing their entities)
    fingers = agent.finger1_link._bodies[0], agent.finger2_link._bodies[0]
    target = obj._bodies[0]
    # per finger, the impulses of its contact points with the target: those acting on the
    # finger (it is the contact's first body) and those acting on the target
    on_finger, on_target = ([], []), ([], [])
    for contact in scene.px.get_contacts():
        a, b = contact.bodies
        if b == target:
            finger, into = a, on_finger
        elif a == target:
            finger, into = b, on_target
        else:
            continue
        side = 0 if finger == fingers[0] else 1 if finger == fingers[1] else None
        if side is not None:
            into[side].extend([point.impulse for point in contact.points])
    # the opening directions: each finger's y axis, signed by the rule
    links = agent.finger1_link._objs[0], agent.finger2_link._objs[0]
    for side, opens in enumerate(rule.opening):
        impulse = np.zeros(3)
        if on_finger[side]:
            impulse += np.sum(on_finger[side], axis=0, dtype=np.float64)
        if on_target[side]:
            impulse -= np.sum(on_target[side], axis=0, dtype=np.float64)
        force = impulse / scene.px.timestep
        magnitude = float(np.linalg.norm(force))
        if magnitude < min_force:
            return torch.tensor([False], device=scene.device)
        opening = opens * links[side].entity_pose.to_transformation_matrix()[:3, 1]
        cos = float(np.dot(force, opening)) / magnitude
        if math.degrees(math.acos(min(max(cos, -1.0), 1.0))) > max_angle:
            return torch.tensor([False], device=scene.device)
    return torch.tensor([True], device=scene.device)
