"""The grasp check every step pays for: ManiSkill's Panda ``is_grasping``, in one pass on CPU.

ManiSkill's ``Panda.is_grasping(obj)`` asks the scene for the contact impulses between each
finger and the object. On the GPU simulation that is one batched query. On the CPU simulation
each call walks every contact of the scene in Python, once per finger, and then makes a dozen
one-env torch tensors; ``evaluate()`` runs it on every step, where it cost more than the physics
(0.5 ms of 1.5 ms per control step on the shipped default layout). :func:`is_grasping` gives the
same answer with the same rule (both fingers press on the object with at least ``min_force``
newtons, each within ``max_angle`` degrees of its opening direction): on GPU it calls
ManiSkill's; on CPU it walks the contacts once, for both fingers, in numpy.
"""

from __future__ import annotations

import numpy as np
import torch

MIN_FORCE = 0.5  # N, ManiSkill's Panda.is_grasping default
MAX_ANGLE = 85.0  # degrees, likewise


def is_grasping(agent, obj, min_force: float = MIN_FORCE, max_angle: float = MAX_ANGLE):
    """Per env (bool tensor, shape (num_envs,)): the Panda ``agent`` grasps the actor ``obj``,
    as ``agent.is_grasping(obj, min_force, max_angle)`` decides."""
    scene = agent.scene
    if scene.gpu_sim_enabled:
        return agent.is_grasping(obj, min_force, max_angle)
    # the rigid-body components (comparing them costs a third of comparing their entities)
    left, right = agent.finger1_link._bodies[0], agent.finger2_link._bodies[0]
    target = obj._bodies[0]
    impulses, rows = [], []  # every contact point's impulse on a finger; (finger, sign)
    for contact in scene.px.get_contacts():
        a, b = contact.bodies
        if b == target:
            finger, sign = a, 1.0  # impulses act on the contact's first body
        elif a == target:
            finger, sign = b, -1.0
        else:
            continue
        if finger == left or finger == right:
            points = [point.impulse for point in contact.points]
            impulses.extend(points)
            rows.extend([(0 if finger == left else 1, sign)] * len(points))
    impulse = np.zeros((2, 3))
    if impulses:
        side, sign = np.array(rows).T
        np.add.at(impulse, side.astype(int), np.array(impulses) * sign[:, None])
    force = impulse / scene.px.timestep
    # the directions that open the fingers: the left finger's y axis, minus the right one's
    opening = np.stack(
        [
            agent.finger1_link._objs[0].entity_pose.to_transformation_matrix()[:3, 1],
            -agent.finger2_link._objs[0].entity_pose.to_transformation_matrix()[:3, 1],
        ]
    )
    magnitude = np.linalg.norm(force, axis=1)
    unit = force / np.where(magnitude < 1e-6, 1.0, magnitude)[:, None]
    angle = np.rad2deg(np.arccos(np.clip(np.sum(unit * opening, axis=1), -1, 1)))
    grasped = bool(np.all((magnitude >= min_force) & (angle <= max_angle)))
    return torch.tensor([grasped], device=scene.device)
