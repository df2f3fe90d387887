"""Conversion of an SO-100 dataset, an arm with one controller, to its other joint modes
(``datasets/joint_actions.py``): ManiSkill 3.0.1's converter stops on it with AttributeError."""

import json
import os
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest
from conftest import DATA

import embodied_envs  # noqa: F401
from embodied_envs.datasets.joint_actions import mode_action, one_controller

SO100_LAYOUT = DATA / "layouts" / "so100_block.json"
CLI = [sys.executable, "-m", "embodied_envs.cli.main"]
ENV = {**os.environ, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}


@pytest.mark.parametrize("mode", ["pd_joint_delta_pos", "pd_joint_target_delta_pos"])
def test_a_target_becomes_the_modes_action_for_every_joint(mode):
    """A target half of each joint's bound past it: the action is 0.5 on every joint, the jaw
    included, and stepping it moves the controller's targets there."""
    env = gym.make("PickEmbodiedGen-v1", layout_file=str(SO100_LAYOUT), control_mode=mode)
    try:
        env.reset(seed=0)
        controller = env.unwrapped.agent.controller
        assert one_controller(env)
        high = np.asarray(controller.config.upper, np.float32)
        base = (controller._target_qpos if "target" in mode else controller.qpos).numpy()[0]
        action = mode_action(controller, base + 0.5 * high, mode)
        np.testing.assert_allclose(action, np.full(6, 0.5), atol=1e-5)
        env.step(action)
        np.testing.assert_allclose(controller._target_qpos.numpy()[0], base + 0.5 * high, atol=1e-5)
    finally:
        env.close()


def test_replay_converts_an_so100_demo_to_target_delta_control(tmp_path):
    """`collect` then `replay -c pd_joint_target_delta_pos` on the SO-100's layout: the converted
    demo succeeds again (seed 100; 3 of the 4 demos of seeds 100-104 convert, 2026-11-25)."""
    run = lambda *a: subprocess.run([*CLI, *a], cwd=tmp_path, env=ENV, capture_output=True,  # noqa: E731
                                    text=True, timeout=600)  # fmt: skip
    res = run("collect", "--layout", str(SO100_LAYOUT), "--num", "1", "--seed", "100",
              "--only-success", "--out", "out")  # fmt: skip
    assert "1 demonstrations (1/1 successful" in res.stdout, res.stdout[-2000:] + res.stderr[-2000:]
    traj = tmp_path / "out" / "so100_block" / "trajectory.h5"
    res = run("replay", "--traj-path", str(traj), "-c", "pd_joint_target_delta_pos", "--save-traj")
    assert "1/1=" in res.stdout, res.stdout[-2000:] + res.stderr[-2000:]
    out = json.loads(next(traj.parent.glob("*.pd_joint_target_delta_pos.*.json")).read_text())
    assert [e["control_mode"] for e in out["episodes"]] == ["pd_joint_target_delta_pos"]
