"""tools/recipes/train_policy.py: a chunking BC policy trained on collected demos, saved as
TorchScript with a reset hook, that `embodied-envs eval --policy FILE.pt` runs."""

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import DEFAULT_LAYOUT

from embodied_envs.cli.main import main
from embodied_envs.pipelines.collect import CollectPlan, collect
from embodied_envs.pipelines.policies import load_policy

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools" / "recipes"))
import train_policy  # noqa: E402

MODE = "pd_joint_delta_pos"
CHUNK, DECAY = 4, 0.5


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Two demos in the env's default controller and a policy trained on them for seconds."""
    root = tmp_path_factory.mktemp("policy")
    collect(CollectPlan(layout=str(DEFAULT_LAYOUT), num=2, seed=3, obs_mode="state",
                        control_mode=MODE), root / "demos")  # fmt: skip
    demos = root / "demos" / DEFAULT_LAYOUT.stem / "trajectory.h5"
    out = root / "run"
    args = ["--minutes", "0.05", "--chunk", str(CHUNK), "--decay", str(DECAY), "--hidden", "64"]
    train_policy.main(["--demos", str(demos), "--out", str(out), *args])
    return demos, out


def test_chunk_targets_past_the_episode_end_are_masked_or_held():
    acts = np.arange(6, dtype=np.float32).reshape(3, 2)  # 3 steps, 2 action values
    targets, valid = train_policy.chunk_targets([acts], 2, hold=False)
    assert targets.shape == (3, 2, 2) and valid.shape == (3, 2)
    np.testing.assert_array_equal(targets[0], acts[0:2])
    np.testing.assert_array_equal(targets[2], [acts[2], acts[2]])
    np.testing.assert_array_equal(valid, [[True, True], [True, True], [True, False]])
    held, valid = train_policy.chunk_targets([acts], 2, hold=True)
    np.testing.assert_array_equal(held, targets)
    assert valid.all()
    # relative to each step's anchor: the action a step ahead plus how far the anchor moved
    anchor = np.array([[0.0, 0.0], [1.0, 0.0], [3.0, 0.0]], np.float32)
    relative, _ = train_policy.chunk_targets([acts], 2, hold=False, anchors=[anchor])
    np.testing.assert_array_equal(relative[:, 0], acts)  # a step's own action is unchanged
    np.testing.assert_array_equal(relative[0, 1], acts[1] + [1.0, 0.0])
    np.testing.assert_array_equal(relative[1, 1], acts[2] + [2.0, 0.0])
    np.testing.assert_array_equal(relative[2, 1], acts[2])  # past the end: held, no motion


def test_training_writes_a_policy_that_eval_runs(trained, tmp_path, capsys):
    demos, out = trained
    info = json.loads((out / "train.json").read_text())
    observations, actions, _ = train_policy.load_episodes(demos, -1)
    assert info["control_mode"] == MODE and info["act_dim"] == 8 and info["episodes"] == 2
    assert info["pairs"] == sum(len(a) for a in actions) > 100 and info["iterations"] > 0
    assert info["chunk"] == CHUNK and info["drop"] == ["qvel"] and info["frame"] == "target"
    # the Panda's arm (pd_joint_delta_pos, 0.1 rad per unit action) is run as joint targets
    assert info["target_joints"] == list(range(7))
    policy = torch.jit.load(str(out / "policy.pt"))
    torch.testing.assert_close(policy.coef, torch.tensor([10.0] * 7 + [0.0]))
    code = main(["eval", "--policy", str(out / "policy.pt"), "--control-mode", MODE,
                 "--episodes", "1", "--seed", "3", "--max-episode-steps", "20", "--video", "none",
                 "--out", str(tmp_path / "ev")])  # fmt: skip
    assert code == 0, capsys.readouterr().out
    episodes = json.loads((tmp_path / "ev" / "episodes.json").read_text())
    assert episodes[0]["steps"] == 20 and episodes[0]["seed"] == 3


def test_the_dropped_group_does_not_change_the_action(trained):
    demos, out = trained
    policy = torch.jit.load(str(out / "policy.pt"))
    observations, _, _ = train_policy.load_episodes(demos, -1)
    qvel = train_policy.agent_groups(demos)["qvel"]
    assert qvel == slice(9, 18)  # the Panda's 9 joints: qpos, then qvel
    obs = torch.from_numpy(observations[0][5:6])
    moved = obs.clone()
    moved[:, qvel] += 1.0
    torch.testing.assert_close(policy.raw(obs), policy.raw(moved))


def test_temporal_ensembling_and_the_reset_hook(trained):
    demos, out = trained
    observations, _, _ = train_policy.load_episodes(demos, -1)
    obs = torch.from_numpy(observations[0][:2])
    first, second = obs[:1], obs[1:2]
    module = torch.jit.load(str(out / "policy.pt"))  # the TorchScript round trip
    low, high = module.act_low, module.act_high
    chunk_a, chunk_b = module.raw(first)[0], module.raw(second)[0]
    target_a, target_b = module.targets(first)[0], module.targets(second)[0]
    anchor_b = module.anchor(second)[0]  # the arm's joints as targets, in action units
    torch.testing.assert_close(target_b - chunk_b, anchor_b.expand_as(chunk_b))
    # step 2's action: its own prediction (weight 1) and step 1's (made a step ahead), as the
    # joint targets they set, less the joints at step 2
    w = math.exp(-DECAY)
    expected = torch.clamp((target_b[0] + w * target_a[1]) / (1 + w) - anchor_b, low, high)
    policy = load_policy(str(out / "policy.pt"), env=None)  # eval's loader
    with torch.no_grad():
        torch.testing.assert_close(policy.act(first)[0], torch.clamp(chunk_a[0], low, high))
        torch.testing.assert_close(policy.act(second)[0], expected)
        policy.reset(0)  # the episode starts again: nothing pending
        torch.testing.assert_close(policy.act(second)[0], torch.clamp(chunk_b[0], low, high))
