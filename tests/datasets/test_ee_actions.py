"""Conversion of ``pd_joint_pos`` demos to end-effector control (``datasets/ee_actions.py``): a
demo that ends at the first step its task succeeds, the arm still slowing down (as ManiSkill's
``RecordEpisode`` datasets of other experts, and this expert's time-optimal ones, do); the
converted arm lags a little, so it holds the last target until the task succeeds too."""

import gymnasium as gym
import numpy as np
import pytest
import torch

import embodied_envs  # noqa: F401
from embodied_envs.datasets.ee_actions import SETTLE_STEPS, joint_pos_to_ee
from embodied_envs.paths import default_layout
from embodied_envs.solvers import PickPlaceSolver
from embodied_envs.solvers.pick_place import SolverConfig

ENV_ID = "PickEmbodiedGen-v1"


def demo(seed: int) -> np.ndarray:
    """The time-optimal expert's actions for ``seed`` on the default layout (``convertible``
    off: the Panda's datasheet speeds), up to the first step its task succeeds."""
    env = gym.make(ENV_ID, layout_file=str(default_layout()), control_mode="pd_joint_pos")
    actions, success = [], []
    step = env.step

    def recorded(a):
        out = step(a)
        actions.append(np.asarray(a, np.float32).copy())
        success.append(bool(out[4]["success"][0]))
        return out

    env.step = recorded
    try:
        env.reset(seed=seed)
        result = PickPlaceSolver(env, SolverConfig(convertible=False), seed=seed).solve()
        assert bool(result.success[0])
    finally:
        env.close()
    return np.array(actions[: success.index(True) + 1])


def convert(actions: np.ndarray, seed: int, **kwargs):
    """The converted replay in fresh envs: its last info and its number of steps."""
    make = lambda mode: gym.make(ENV_ID, layout_file=str(default_layout()), control_mode=mode)  # noqa: E731
    env, ori = make("pd_ee_delta_pose"), make("pd_joint_pos")
    try:
        env.reset(seed=seed)
        ori.reset(seed=seed)
        info = joint_pos_to_ee("pd_ee_delta_pose", actions, ori, env, **kwargs)
        return info, int(env.unwrapped.elapsed_steps[0])
    finally:
        env.close()
        ori.close()


# seeds whose demos the converted arm finishes short of success (found among seeds 200-220:
# 4 of the 19 that converted at all needed 1-7 more steps)
# (217 was one until the reach's minimum moved to 0.30 m: 203 is, found among 200-203)
@pytest.mark.parametrize("seed", [216, 203])
def test_the_converted_arm_holds_the_last_target_until_success(seed):
    actions = demo(seed)
    cut, cut_steps = convert(actions, seed, settle=0)
    assert not bool(cut["success"][0]), "the case needs no settling: pick another seed"
    done, steps = convert(actions, seed)
    assert bool(done["success"][0])
    assert torch.linalg.norm(done["obj_to_goal_pos"][0]) <= 0.025
    assert cut_steps < steps <= cut_steps + SETTLE_STEPS  # the same replay, then held
