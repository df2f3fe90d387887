"""The ManiSkill and SAPIEN internals ``embodied_envs/internals.py`` reads for the package
(``envs/fast_reads.py``, ``envs/contacts.py``, ``envs/tasks/scene.py``, ``envs/fast_control.py``,
the expert and the dataset converters) exist, with the types those reads expect, on a real CPU
env: a ManiSkill upgrade that renames or retypes one fails here, naming it and the
installed version, rather than as a wrong value or an AttributeError mid-episode."""

import gymnasium as gym
import mani_skill
import numpy as np
import pytest
import sapien
import torch
from mani_skill.agents.controllers.passive_controller import PassiveController
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.utils.structs import Actor, Articulation, ArticulationJoint, Link

import embodied_envs  # noqa: F401
from embodied_envs import internals
from embodied_envs.envs import fast_control, fast_reads

PHYSX = sapien.physx
ITEM_TYPES = {  # the names internals.PRIVATE_ATTRIBUTES gives, as classes
    "sapien.Entity": sapien.Entity,
    "PhysxRigidBodyComponent": PHYSX.PhysxRigidBodyComponent,
    "PhysxArticulationLinkComponent": PHYSX.PhysxArticulationLinkComponent,
    "PhysxArticulation": PHYSX.PhysxArticulation,
    "PhysxArticulationJoint": PHYSX.PhysxArticulationJoint,
}
STRUCTS = {
    "Actor": Actor, "Link": Link, "Articulation": Articulation,
    "ArticulationJoint": ArticulationJoint,
}  # fmt: skip


def relied_on(what: str) -> str:
    return (
        f"{what}: embodied_envs/internals.py relies on it, and ManiSkill "
        f"{mani_skill.__version__} lacks it or changed its type; update the reads there (and "
        "what uses them) to this version"
    )


@pytest.fixture(scope="module")
def env():
    e = gym.make("PickEmbodiedGen-v1", obs_mode="state", sim_backend="physx_cpu")
    e.reset(seed=0)
    yield e
    e.close()


def structs(env):
    """One of each ManiSkill struct the reads meet: the target object, a robot link, the robot."""
    u = env.unwrapped
    return {
        "Actor": u.obj, "Link": u.agent.finger1_link, "Articulation": u.agent.robot,
        "ArticulationJoint": u.agent.controller.controllers["arm"].joints[0],
    }  # fmt: skip


@pytest.mark.parametrize("struct,name,item", internals.PRIVATE_ATTRIBUTES)
def test_each_private_attribute_exists_with_its_type(env, struct, name, item):
    obj = structs(env)[struct]
    assert isinstance(obj, STRUCTS[struct])
    value = getattr(obj, name, None)
    assert isinstance(value, list) and len(value) == env.unwrapped.num_envs, relied_on(
        f"{struct}.{name} (a list, one item per env)"
    )
    assert all(isinstance(x, ITEM_TYPES[item]) for x in value), relied_on(
        f"{struct}.{name} items of type {item}, got {[type(x).__name__ for x in value]}"
    )


def test_what_the_reads_call_on_those_objects_exists(env):
    u = env.unwrapped
    checks = {
        "sapien.Entity.pose": lambda: u.obj._objs[0].pose.p,
        "PhysxRigidBodyComponent.linear_velocity": lambda: u.obj._bodies[0].linear_velocity,
        "PhysxRigidBodyComponent.angular_velocity": lambda: u.obj._bodies[0].angular_velocity,
        "PhysxArticulationLinkComponent.entity_pose": lambda: u.agent.tcp._objs[0].entity_pose.p,
        "PhysxArticulation.qpos": lambda: u.agent.robot._objs[0].qpos,
        "PhysxArticulation.qvel": lambda: u.agent.robot._objs[0].qvel,
        "Articulation.root": lambda: u.agent.robot.root._bodies[0].linear_velocity,
        "Actor.px_body_type": lambda: np.array([len(u.obj.px_body_type)], float),
        "ManiSkillScene.state_dict_registry.actors": lambda: np.array(
            [len(u.scene.state_dict_registry.actors)], float),
        "ManiSkillScene.state_dict_registry.articulations": lambda: np.array(
            [len(u.scene.state_dict_registry.articulations)], float),
    }  # fmt: skip
    for what, read in checks.items():
        try:
            value = np.asarray(read())
        except AttributeError as err:
            pytest.fail(relied_on(f"{what} ({err})"))
        assert value.size > 0 and np.isfinite(value).all(), relied_on(what)
    assert u.obj.px_body_type == "dynamic", relied_on("Actor.px_body_type ('dynamic')")
    px = u.scene.px
    for name in ("rigid_dynamic_components", "articulation_link_components"):
        bodies = getattr(px, name, None)
        assert bodies, relied_on(f"PhysxCpuSystem.{name} (a non-empty list)")
        assert all(callable(getattr(b, "wake_up", None)) for b in bodies), relied_on(
            f"PhysxCpuSystem.{name}[i].wake_up()"
        )
    assert all(isinstance(b.kinematic, bool) for b in px.rigid_dynamic_components), relied_on(
        "PhysxRigidDynamicComponent.kinematic (a bool)"
    )


def test_the_agent_and_env_fields_exist(env):
    """``internals.controller_configs``, ``viewer`` and the ``ControllerState`` fields the
    expert and the dataset converters read, on the default Panda in ``pd_joint_pos`` (and its
    ``pd_ee_delta_pose`` arm for ``target_pose``)."""
    u = env.unwrapped
    configs = internals.controller_configs(u.agent)
    assert isinstance(configs, dict) and "pd_joint_pos" in configs, relied_on(
        "BaseAgent._controller_configs (a dict by control mode)")
    assert internals.viewer(u) is None, relied_on("BaseEnv._viewer (None with no viewer)")
    arm = u.agent.controller.controllers["arm"]
    state = internals.ControllerState(arm)
    assert state.control_freq == u.control_freq, relied_on("BaseController._control_freq")
    assert isinstance(state.target_qpos, torch.Tensor), relied_on("_target_qpos (a tensor)")
    e = gym.make("PickEmbodiedGen-v1", obs_mode="none", control_mode="pd_ee_delta_pose")
    try:
        e.reset(seed=0)
        e.step(np.zeros(e.action_space.shape, np.float32))
        ee = internals.ControllerState(e.unwrapped.agent.controller.controllers["arm"])
        assert isinstance(ee.target_pose.p, torch.Tensor), relied_on("_target_pose (a Pose)")
    finally:
        e.close()


def test_the_controller_attributes_fast_control_reads_exist():
    """Each controller class ``fast_control`` does the ``set_action`` of, met in the Fetch's
    joint control modes (all but the passive one), has the attributes it reads and sets."""
    e = gym.make("PickEmbodiedGen-v1", obs_mode="none", robot_uids="fetch")
    agent, met = e.unwrapped.agent, set()
    for mode in [m for m in agent.supported_control_modes if "joint" in m]:
        agent.set_control_mode(mode)
        agent.controller.reset()
        for c in agent.controller.controllers.values():
            names = fast_control.CONTROLLER_ATTRIBUTES.get(type(c))
            if names is None:
                continue
            met.add(type(c))
            for name in names:
                assert hasattr(c, name), relied_on(f"{type(c).__name__}.{name}")
            if internals.ControllerState(c).normalize_action:
                for name in fast_control.NORMALIZED_ATTRIBUTES:
                    assert isinstance(getattr(c, name, None), torch.Tensor), relied_on(name)
            if "_target_qpos" in names:
                target = internals.ControllerState(c).target_qpos
                assert isinstance(target, torch.Tensor), relied_on("_target_qpos")
                for flag in fast_control.CONFIG_FLAGS:
                    assert isinstance(getattr(c.config, flag), bool), relied_on(flag)
    e.close()
    assert set(fast_control.CONTROLLER_ATTRIBUTES) - met == {PassiveController}


def test_the_reads_give_what_maniskill_gives(env):
    """Each read against the public ManiSkill call it replaces, after some steps."""
    u = env.unwrapped
    for _ in range(3):
        env.step(env.action_space.sample())
    np.testing.assert_array_equal(fast_reads.positions(u.goal_site), u.goal_site.pose.p.numpy())
    ours, theirs = fast_reads.cpu_state_dict(u), BaseEnv.get_state_dict(u)
    assert list(ours) == list(theirs)
    for group in ("actors", "articulations"):
        assert list(ours[group]) == list(theirs[group]), relied_on(f"state_dict_registry {group}")
        for name, value in theirs[group].items():
            assert torch.equal(ours[group][name], value), relied_on(f"the state of {name}")


def test_restart_sleep_timers_wakes_every_moving_body(env):
    u = env.unwrapped
    bodies = [b for b in u.scene.px.rigid_dynamic_components if not b.kinematic]
    for b in bodies:
        b.put_to_sleep()
    assert all(b.is_sleeping for b in bodies)
    fast_reads.restart_sleep_timers(u.scene)
    assert bodies and not any(b.is_sleeping for b in bodies)
