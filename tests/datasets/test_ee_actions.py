"""Conversion of ``pd_joint_pos`` demos to end-effector control (``datasets/ee_actions.py``): a
demo that ends at the first step its task succeeds, the arm still slowing down (as ManiSkill's
``RecordEpisode`` datasets of other experts, and this expert's time-optimal ones, do); the
converted arm lags a little, so it holds the last target until the task succeeds too."""

import gymnasium as gym
import numpy as np
import pytest
import torch

import embodied_envs  # noqa: F401
from embodied_envs.datasets import ee_actions
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


ROUND_TABLE = default_layout().parent / "round_table.json"


def test_a_fixed_hand_demo_converts_to_position_only_control():
    """``pd_ee_delta_pos`` keeps the hand's orientation: the expert's demo of round_table seed
    115 turns the hand to the banana and converts to no success (measured, 2026-11-25). With
    ``SolverConfig(fixed_hand=True)`` the hand keeps its closing direction within 20 degrees
    all episode, and the converted replay (the held banana following its recorded path)
    succeeds with the banana within the goal's 2.5 cm."""
    seed = 115
    make = lambda mode: gym.make(ENV_ID, layout_file=str(ROUND_TABLE), control_mode=mode)  # noqa: E731
    env = make("pd_joint_pos")
    u, actions, turns = env.unwrapped, [], []
    step = env.step

    def recorded(a):
        out = step(a)
        actions.append(np.asarray(a, np.float32).copy())
        y = u.agent.tcp.pose.to_transformation_matrix()[0, :3, 1].numpy()
        turns.append(np.degrees(np.arccos(min(1.0, abs(float(y @ y0))))))
        return out

    try:
        env.reset(seed=seed)
        y0 = u.agent.tcp.pose.to_transformation_matrix()[0, :3, 1].numpy()
        env.step = recorded
        solver = PickPlaceSolver(env, SolverConfig(fixed_hand=True), seed=seed)
        assert bool(solver.solve().success[0])
    finally:
        env.close()
    assert max(turns) <= 20.0, max(turns)
    conv, ori = make("pd_ee_delta_pos"), make("pd_joint_pos")
    try:
        conv.reset(seed=seed)
        ori.reset(seed=seed)
        info = joint_pos_to_ee("pd_ee_delta_pos", np.array(actions), ori, conv)
    finally:
        conv.close()
        ori.close()
    assert bool(info["success"][0])
    assert torch.linalg.norm(info["obj_to_goal_pos"][0]) <= 0.025


def test_the_settle_holds_the_arm_where_chasing_the_target_stalls(monkeypatch):
    """Default seed 114 (``collect --fixed-hand``): ``pd_ee_delta_pos`` keeps the hand 45
    degrees off the recorded top-down one (the rest pose's pitch), and at the goal a wrist joint
    sits at its limit with the hand 8 mm short of the last target. Chasing that target all the
    settle phase keeps the arm turning (never static: no success, measured 2026-11-25); holding
    the measured pose once the gap stops shrinking (``ee_actions.STALL``) stops the arm with
    the can within the goal's 2.5 cm, a few steps after the demo's end."""
    seed = 114
    make = lambda mode: gym.make(ENV_ID, layout_file=str(default_layout()), control_mode=mode)  # noqa: E731
    env = make("pd_joint_pos")
    actions, step = [], env.step

    def recorded(a):
        actions.append(np.asarray(a, np.float32).copy())
        return step(a)

    try:
        env.reset(seed=seed)
        env.step = recorded
        solver = PickPlaceSolver(env, SolverConfig(fixed_hand=True), seed=seed)
        assert bool(solver.solve().success[0])
    finally:
        env.close()

    def converted():
        conv, ori = make("pd_ee_delta_pos"), make("pd_joint_pos")
        try:
            conv.reset(seed=seed)
            ori.reset(seed=seed)
            info = joint_pos_to_ee("pd_ee_delta_pos", np.array(actions), ori, conv)
            return info, int(conv.unwrapped.elapsed_steps[0])
        finally:
            conv.close()
            ori.close()

    held, steps = converted()
    assert bool(held["success"][0]) and bool(held["is_robot_static"][0])
    assert torch.linalg.norm(held["obj_to_goal_pos"][0]) <= 0.025
    assert len(actions) < steps <= len(actions) + SETTLE_STEPS
    monkeypatch.setattr(ee_actions, "STALL", np.inf)  # chase the last target all the settle
    chased, chased_steps = converted()
    assert not bool(chased["success"][0]) and not bool(chased["is_robot_static"][0])
    assert chased_steps == len(actions) + SETTLE_STEPS
