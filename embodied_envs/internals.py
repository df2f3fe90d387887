"""ManiSkill's and SAPIEN's private fields: the package reads (and writes) them here and nowhere
else, each behind a named function, so that a ManiSkill release that renames or retypes one
breaks this module alone.

Why they are read at all: on the CPU simulation (one env per process) ManiSkill's public reads
wrap every value in batched torch tensors, one struct at a time; the env's per-step reads
(``envs/fast_reads.py``, ``envs/tasks/scene.py``, ``envs/contacts.py``, ``envs/agents.py``) and
its numpy ``set_action`` (``envs/fast_control.py``) go to the SAPIEN objects behind ManiSkill's
structs instead; the expert and the dataset converters read a few controller and agent fields
that ManiSkill exposes no other way.

``tests/envs/test_fast_reads.py`` checks each field on a real CPU env (with ManiSkill 3.0.1);
``tests/test_structure.py`` fails when another module of the package reaches a private
attribute of an object other than its own. This module imports nothing: the dataset converters,
which load no simulator, use it too.
"""

from __future__ import annotations

# (ManiSkill struct, private attribute, what each item of it is): the per-env lists behind
# ManiSkill's structs (mani_skill.utils.structs) that the functions below return
PRIVATE_ATTRIBUTES = (
    ("Actor", "_objs", "sapien.Entity"),  # its pose
    ("Actor", "_bodies", "PhysxRigidBodyComponent"),  # velocities, contacts
    ("Link", "_objs", "PhysxArticulationLinkComponent"),  # entity_pose, collision shapes
    ("Link", "_bodies", "PhysxArticulationLinkComponent"),  # velocities, contacts
    ("Articulation", "_objs", "PhysxArticulation"),  # qpos, qvel
    ("ArticulationJoint", "_objs", "PhysxArticulationJoint"),  # drive targets (fast_control)
)


def entities(actor) -> list:
    """``Actor._objs``: the actor's SAPIEN entity per env."""
    return actor._objs


def bodies(struct) -> list:
    """``Actor._bodies`` or ``Link._bodies``: its PhysX rigid-body component per env (velocities,
    contacts: compared by identity)."""
    return struct._bodies


def link_components(link) -> list:
    """``Link._objs``: the link's ``PhysxArticulationLinkComponent`` per env."""
    return link._objs


def px_articulations(articulation) -> list:
    """``Articulation._objs``: its ``PhysxArticulation`` per env (qpos, qvel)."""
    return articulation._objs


def px_joints(joint) -> list:
    """``ArticulationJoint._objs``: its ``PhysxArticulationJoint`` per env (drive targets)."""
    return joint._objs


def controller_configs(agent) -> dict:
    """``BaseAgent._controller_configs``: control mode -> its controller configs (ManiSkill
    builds them anew on each read)."""
    return agent._controller_configs


def viewer(env):
    """``BaseEnv._viewer``: the env's open SAPIEN viewer, or None."""
    return env._viewer


def _field(name: str, doc: str) -> property:
    return property(
        lambda s: getattr(s.controller, name),
        lambda s, value: setattr(s.controller, name, value),
        doc=f"``{name}``: {doc}",
    )


class ControllerState:
    """A ManiSkill controller's private fields, read and set by these names (the joint
    controllers' state that ``envs/fast_control.py`` keeps as ManiSkill keeps it, and what the
    dataset converters read)."""

    __slots__ = ("controller",)

    def __init__(self, controller):
        self.controller = controller

    normalize_action = _field("_normalize_action", "whether actions are clipped and scaled")
    step = _field("_step", "sub-steps interpolated since the last action")
    start_qpos = _field("_start_qpos", "the joints' positions at the last action")
    target_qpos = _field("_target_qpos", "the joints' position targets")
    target_qvel = _field("_target_qvel", "the joints' velocity targets")
    step_size = _field("_step_size", "the interpolation's step per sub-step")
    sim_steps = _field("_sim_steps", "simulation steps per control step")
    multiplier = _field("_multiplier", "a mimic controller's joint multipliers")
    offset = _field("_offset", "a mimic controller's joint offsets")
    control_freq = _field("_control_freq", "control steps per second")
    target_pose = _field("_target_pose", "an end-effector controller's pose target")
