import gymnasium as gym
import numpy as np
import pytest
import torch

import embodied_envs  # noqa: F401
from embodied_envs.solvers import PickPlaceSolver


@pytest.fixture(scope="module")
def env():
    e = gym.make("PickEmbodiedGen-v1", control_mode="pd_joint_pos")
    yield e
    e.close()


def test_solver_succeeds_on_default_layout(env):
    env.reset(seed=0)
    result = PickPlaceSolver(env, seed=0).solve()
    assert result.reports[0].planned, result.reports[0].plan_failures
    info = env.unwrapped.evaluate()  # the env's own judgement, not the solver's
    assert bool(info["success"][0]) and bool(info["is_grasped"][0])
    assert float(torch.linalg.norm(info["obj_to_goal_pos"][0])) < 0.025


def test_unreachable_goal_is_reported_not_raised(env):
    env.reset(seed=1)
    u = env.unwrapped
    far = u.goal_site.pose.p.clone()
    far[:, 2] += 3.0  # three metres up: no IK solution
    u.goal_site.set_pose(type(u.goal_site.pose).create_from_pq(far))
    result = PickPlaceSolver(env, seed=1).solve()
    failures = result.reports[0].plan_failures
    assert failures and failures[0].startswith("carry:"), failures
    assert not bool(np.asarray(result.success)[0])
