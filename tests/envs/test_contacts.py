"""The one-pass grasp check (envs/contacts.py) gives ManiSkill's Panda ``is_grasping``
answer at every step of expert episodes on every shipped layout: before the grasp, holding
the object, and after a drop."""

import numpy as np
from conftest import per_layout_env

import embodied_envs  # noqa: F401
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
