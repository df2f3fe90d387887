"""Conversion of ``pd_joint_pos`` demos to ``pd_joint_vel`` (``datasets/joint_actions.py``,
``follow_recorded``): the converted arm follows the recorded run's joints, not its targets,
which lead the joints by the PD drive's lag."""

import functools
import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import DATA
from mani_skill.trajectory.utils.actions import conversion

import embodied_envs  # noqa: F401
from embodied_envs.datasets.joint_actions import joint_pos_to_joint

# round_table --fixed-hand episode 5 (seed 108), one of the 7 of 50 that ManiSkill's converter
# lost (measured 2026-11-25): its banana ends 3.1 cm below the goal
DEMO = Path(__file__).parent.parent / "data" / "demos" / "round_table_seed108_fixed_hand.json"
# the dataset's env_kwargs
KWARGS = {"obs_mode": "none", "hybrid_obs": False, "sim_backend": "physx_cpu"}


@pytest.fixture(scope="module")
def demo() -> tuple[np.ndarray, int]:
    record = json.loads(DEMO.read_text())
    return np.asarray(record["actions"], np.float32), int(record["seed"])


def convert(converter, actions: np.ndarray, seed: int) -> tuple[dict, int]:
    """The last info and the step count of ``converter``'s ``pd_joint_vel`` replay of
    ``actions``, in fresh envs."""
    layout = str(DATA / "layouts" / "round_table.json")
    make = lambda mode: gym.make("PickEmbodiedGen-v1", layout_file=layout, control_mode=mode,  # noqa: E731
                                 **KWARGS)  # fmt: skip
    env, ori = make("pd_joint_vel"), make("pd_joint_pos")
    try:
        env.reset(seed=seed)
        ori.reset(seed=seed)
        info = converter("pd_joint_vel", actions, ori, env)
        return info, int(env.unwrapped.elapsed_steps[0])
    finally:
        env.close()
        ori.close()


def to_goal(info: dict) -> float:
    return float(torch.linalg.norm(torch.as_tensor(info["obj_to_goal_pos"][0])))


def test_the_converted_arm_follows_the_recorded_joints_and_keeps_the_demo(demo):
    """ManiSkill's converter asks each recorded target of the velocity controller in one step:
    its arm runs ahead of the recorded one and the banana slips in the hand, 3 cm below the
    goal at the end (outside its 2.5 cm). Following the recorded joints, the demo succeeds
    with the banana within 1 cm, in as many steps as recorded (no action clipped twice)."""
    actions, seed = demo
    theirs, _ = convert(conversion.from_pd_joint_pos, actions, seed)
    assert not bool(theirs["success"][0])
    assert to_goal(theirs) > 0.025
    ours_converter = functools.partial(joint_pos_to_joint, combined=conversion.from_pd_joint_pos)
    ours, steps = convert(ours_converter, actions, seed)  # as `replay` sets it
    assert bool(ours["success"][0])
    assert to_goal(ours) < 0.01
    assert len(actions) <= steps < len(actions) + 10
