"""The one-pass grasp check (envs/contacts.py) gives ManiSkill's Panda ``is_grasping``
answer at every step of expert episodes on every shipped layout: before the grasp, holding
the object, and after a drop; and each other wheel arm's, by its entry's rule."""

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import per_layout_env
from mani_skill.utils.structs.pose import Pose

import embodied_envs  # noqa: F401
from embodied_envs import robots
from embodied_envs.envs import agents
from embodied_envs.envs.contacts import is_grasping
from embodied_envs.solvers import PickPlaceSolver

env = per_layout_env(control_mode="pd_joint_pos")  # the round table: more contacts


def test_agrees_with_maniskill_at_every_step(env):
    u = env.unwrapped
    evaluate = u.evaluate
    pairs = []

    def checked():
        pairs.append((bool(u.agent.is_grasping(u.obj)[0]), bool(is_grasping(u.agent, u.obj)[0])))
        return evaluate()

    u.evaluate = checked
    try:
        env.reset(seed=0)
        PickPlaceSolver(env, seed=0).solve()
        # drop it: the fingers open at the goal and the object falls out of the hand
        for _ in range(15):
            env.step(np.r_[u.agent.robot.get_qpos()[0, :7].cpu().numpy(), 1.0])
    finally:
        u.evaluate = evaluate
    ours = np.array([p[1] for p in pairs])
    theirs = np.array([p[0] for p in pairs])
    assert np.array_equal(ours, theirs)
    assert 30 < ours.sum() < len(ours) - 30  # both answers occur, many times
    assert theirs[0] == theirs[-1] == False  # noqa: E712  before the grasp, after the drop


# (robot, control steps the object is held between its open jaws while they close): the Koch's
# jaw only holds the can while it is pressed in (released sooner, PhysX pushes the can out),
# from ManiSkill's folded rest keyframe (its entry's rest, hand down, never grasps the can)
JAW_HOLDS = (("so100", 30), ("koch-v1.1", 8), ("fetch", 30))


@pytest.mark.parametrize("uid,hold", JAW_HOLDS, ids=[u for u, _ in JAW_HOLDS])
def test_each_arms_rule_agrees_with_its_maniskill_is_grasping(uid, hold):
    """The object held at the TCP (turned 90 deg about its z) while the jaws close, then let go,
    then the jaws open: at every step the entry's rule in one CPU pass answers as the agent's
    own ``is_grasping``; flipping the rule's opening signs would not, for the SO-100 and Fetch."""
    env = gym.make("PickEmbodiedGen-v1", robot_uids=uid, obs_mode="state")
    try:
        u, entry = env.unwrapped, robots.ROBOTS[uid]
        rule, grip = entry.grasp_check, entry.gripper
        flipped = dataclasses.replace(rule, opening=tuple(-o for o in rule.opening))
        turn = Pose.create_from_pq(q=torch.tensor([[0.5**0.5, 0.0, 0.0, 0.5**0.5]]))
        env.reset(seed=0)
        if uid == "koch-v1.1":
            u.agent.reset(torch.tensor([[0.0, 2.2, 3.017, -0.25, 0.0, 1.6]]))
        rows = []
        for k in range(75):
            action = torch.zeros(env.action_space.shape)
            action[grip.action_index] = grip.action_closed if k < 60 else grip.action_open
            if k < hold:
                u.obj.set_pose(agents.tcp_pose(u.agent, entry) * turn)
                u.obj.set_linear_velocity(torch.zeros(1, 3))
                u.obj.set_angular_velocity(torch.zeros(1, 3))
            env.step(action)
            rows.append([bool(u.agent.is_grasping(u.obj)[0])] + [
                bool(is_grasping(u.agent, u.obj, r)[0]) for r in (rule, flipped)
            ])  # fmt: skip
    finally:
        env.close()
    theirs, ours, wrong = np.array(rows).T
    assert np.array_equal(ours, theirs)
    assert theirs.sum() >= 4 and not theirs[-15:].any()  # grasped, and not after the opening
    if uid != "koch-v1.1":  # the Koch's 110 deg cone holds its forces either way
        assert (wrong != theirs).sum() >= 4
