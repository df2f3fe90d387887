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
:func:`grasped_cpu` answers for several objects (a task's movers) from that one walk.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from embodied_envs.internals import bodies, link_components
from embodied_envs.robots import PANDA_GRASP, FingerGrasp


def is_grasping(agent, obj, rule: FingerGrasp = PANDA_GRASP):
    """Per env (bool tensor, shape (num_envs,)): ``agent`` (an arm whose ``is_grasping`` follows
    ``rule``, the Panda's by default) grasps the actor ``obj``, as
    ``agent.is_grasping(obj, rule.min_force, rule.max_angle)`` decides."""
    scene = agent.scene
    if scene.gpu_sim_enabled:
        return agent.is_grasping(obj, rule.min_force, rule.max_angle)
    return torch.tensor([bool(grasped_cpu(agent, [obj], rule)[0])], device=scene.device)


def grasped_cpu(agent, objs, rule: FingerGrasp = PANDA_GRASP) -> np.ndarray:
    """``(len(objs),)`` bool: on the CPU simulation's one env, :func:`is_grasping` of each actor
    of ``objs``, from one walk over the scene's contacts for all of them. A contact point's
    impulse (a SAPIEN object, then an array, per point) is read only where both fingers touch
    the target (with ``min_force`` > 0, one finger alone decides nothing else)."""
    scene = agent.scene
    # the rigid-body components (compared by identity, as ``==`` compares them)
    fingers = bodies(agent.finger1_link)[0], bodies(agent.finger2_link)[0]
    targets = [bodies(obj)[0] for obj in objs]
    slot = {body: k for k, body in enumerate(dict.fromkeys(targets))}
    # per target and finger, its contacts with the target and whether the finger is the
    # contact's first body (the impulses act on it) or the target is (they act on the target)
    touching = [([], []) for _ in slot]
    for contact in scene.px.get_contacts():
        a, b = contact.bodies
        if b in slot:
            finger, k, on_finger = a, slot[b], True
        elif a in slot:
            finger, k, on_finger = b, slot[a], False
        else:
            continue
        side = 0 if finger == fingers[0] else 1 if finger == fingers[1] else None
        if side is not None:
            touching[k][side].append((contact, on_finger))
    links = link_components(agent.finger1_link)[0], link_components(agent.finger2_link)[0]
    step = scene.px.timestep
    held = [
        (all(touching[k]) or rule.min_force <= 0)
        and _presses([_impulses(c) for c in touching[k]], links, rule, step)
        for k in slot.values()
    ]
    return np.array([held[slot[body]] for body in targets], dtype=bool)


def _impulses(contacts: list) -> tuple[list[float] | None, list[float] | None]:
    """A finger's summed contact impulses with the target, in float64: those acting on the
    finger and those acting on the target (None where none), each point's in the contacts'
    order, added one after another (``np.sum`` over the points' rows adds them so)."""
    sums: list = [None, None]
    for contact, on_finger in contacts:
        k = 0 if on_finger else 1
        for point in contact.points:
            x, y, z = point.impulse.tolist()
            if sums[k] is None:
                sums[k] = [0.0, 0.0, 0.0]
            acc = sums[k]
            acc[0] += x
            acc[1] += y
            acc[2] += z
    return sums[0], sums[1]


def _presses(impulses, links, rule: FingerGrasp, timestep: float) -> bool:
    """Both fingers press on the target (per finger, its summed contact impulses with it
    acting on the finger and on the target, :func:`_impulses`) with ``rule.min_force``, within
    ``rule.max_angle`` of opening."""
    for side, opens in enumerate(rule.opening):  # the opening: each finger's y axis, signed
        on_finger, on_target = impulses[side]
        if on_finger is None and on_target is None and rule.min_force > 0:
            return False  # no force
        impulse = np.zeros(3)
        if on_finger is not None:
            impulse += on_finger
        if on_target is not None:
            impulse -= on_target
        force = impulse / timestep
        magnitude = float(np.linalg.norm(force))
        if magnitude < rule.min_force:
            return False
        opening = opens * links[side].entity_pose.to_transformation_matrix()[:3, 1]
        cos = float(np.dot(force, opening)) / magnitude
        if math.degrees(math.acos(min(max(cos, -1.0), 1.0))) > rule.max_angle:
            return False
    return True
