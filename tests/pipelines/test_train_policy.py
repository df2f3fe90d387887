"""tools/recipes/train_policy.py: a chunking BC policy trained on collected demos, saved as
TorchScript with a reset hook, that `embodied-envs eval --policy FILE.pt` runs."""

import json
import math
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import torch
from conftest import DEFAULT_LAYOUT
from mani_skill.trajectory import utils as trajectory_utils
from mani_skill.trajectory.dataset import load_h5_data

from embodied_envs.cli.main import main
from embodied_envs.pipelines.collect import CollectPlan, collect
from embodied_envs.pipelines.policies import load_policy

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools" / "recipes"))
import perturb  # noqa: E402
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
    observations, actions, _, _ = train_policy.load_episodes(demos, -1)
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
    observations, _, _, _ = train_policy.load_episodes(demos, -1)
    qvel = train_policy.agent_groups(demos)[0]["qvel"]
    assert qvel == slice(9, 18)  # the Panda's 9 joints: qpos, then qvel
    obs = torch.from_numpy(observations[0][5:6])
    moved = obs.clone()
    moved[:, qvel] += 1.0
    torch.testing.assert_close(policy.raw(obs), policy.raw(moved))


def test_temporal_ensembling_and_the_reset_hook(trained):
    demos, out = trained
    observations, _, _, _ = train_policy.load_episodes(demos, -1)
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


POS_TOL = 1e-4  # m: float32 observations of poses ~1 m from the origin, pinocchio against PhysX


def test_corrective_copies_observe_what_the_env_observes_with_the_arm_moved(trained):
    """A copy's observation equals the env's own with its arm set to the moved joints (its TCP,
    the TCP-to-mover vector); with no offset it is the demonstrated step."""
    demos, _ = trained
    observations, _, bases, env_info = train_policy.load_episodes(demos, -1)
    obs, base = observations[0][:40:8], bases[0][:40:8]  # steps before the grasp
    env = train_policy.dataset_env(env_info)
    try:
        slices, kin = perturb.obs_slices(env), perturb.Kinematics(env)
        same, _, _ = perturb.corrective_copies(obs, base, np.arange(7), kin, slices, 0.0, 1,
                                               np.random.default_rng(0))  # fmt: skip
        np.testing.assert_allclose(same, obs, atol=POS_TOL)
        copies, index, offset = perturb.corrective_copies(
            obs, base, np.arange(7), kin, slices, 0.05, 2, np.random.default_rng(1))
        assert copies.shape == (10, obs.shape[1]) and list(index) == [0, 1, 2, 3, 4] * 2
        moved_by = np.linalg.norm(copies[:, 19:22] - obs[index, 19:22], axis=1)
        assert np.median(moved_by) > 0.01  # 0.05 rad moves the TCP by centimetres
        env.reset(seed=3)  # the demos' first seed: the same scene as episode 0
        with h5py.File(demos, "r") as f:  # the recorded scene at each step (ManiSkill's replay)
            states = trajectory_utils.dict_to_list_of_dicts(load_h5_data(f["traj_0"]["env_states"]))
        robot = env.unwrapped.agent.robot
        for row in range(len(copies)):
            env.unwrapped.set_state_dict(states[0:40:8][index[row]])
            robot.set_qpos(torch.from_numpy(copies[row : row + 1, slices["qpos"]]))
            seen = env.unwrapped.get_obs()
            for group in ("qpos", "tcp_pose", "tcp_to_mover_pos"):
                got = np.asarray(seen["extra" if group != "qpos" else "agent"][group])[0]
                want = copies[row, slices[group]]
                if group == "tcp_pose" and np.dot(got[3:], want[3:]) < 0:
                    got[3:] *= -1  # q and -q are the same turn
                np.testing.assert_allclose(got, want, atol=POS_TOL, err_msg=group)
    finally:
        env.close()


def test_corrective_copies_keep_the_targets_and_move_the_labels(trained, tmp_path):
    """Trained with copies, the pairs double and train.json says so; a copy's label is the
    demonstrated joint targets less its moved joints."""
    demos, _ = trained
    observations, actions, bases, env_info = train_policy.load_episodes(demos, -1)
    env = train_policy.dataset_env(env_info)
    try:
        frame = train_policy.target_frame(env, observations[0].shape[1], 8)
        anchors = [o[:, frame[1]] * frame[0] for o in observations]
        targets, valid = train_policy.chunk_targets(actions, CHUNK, False, anchors)
        obs = np.concatenate([o[: len(a)] for o, a in zip(observations, actions, strict=True)])
        args = train_policy.parse_args(["--demos", str(demos), "--out", str(tmp_path),
                                        "--perturb", "0.03", "--perturb-copies", "1"])  # fmt: skip
        big, labels, mask = train_policy.with_corrective_copies(
            args, env, (observations, actions, bases), obs, targets, valid, frame)
    finally:
        env.close()
    n = len(obs)
    assert len(big) == len(labels) == len(mask) == 2 * n
    coef = frame[0][:7]  # 10 per radian: the Panda's 0.1 rad per unit action
    moved = (big[n:, :7] - obs[:, :7]) * coef  # the copies' joint offsets, in action units
    # the joint targets (label + anchor) are the demonstrated ones, for every step of the chunk
    np.testing.assert_allclose(labels[n:, :, :7] + (big[n:, None, :7] * coef),
                               targets[:, :, :7] + (obs[:, None, :7] * coef), atol=1e-4)
    # the gripper's where the TCP moved off while nothing is held: open (as at the start); as
    # demonstrated elsewhere (the copies of held steps keep the release ahead)
    reopen = np.linalg.norm(big[n:, 19:22] - obs[:, 19:22], axis=1) > perturb.GRASP_TOL
    reopen &= obs[:, 18] < 0.5
    assert 0 < reopen.sum() < n and (targets[~reopen, :, 7] < 0).any()  # some closing kept
    np.testing.assert_array_equal(labels[n:][~reopen, :, 7], targets[~reopen, :, 7])
    np.testing.assert_array_equal(labels[n:][reopen, :, 7], actions[0][0, 7])
    assert np.abs(moved).max() > 0.1 and (mask[n:] == valid).all()


def test_a_dataset_whose_layout_moved_names_the_field_and_the_fix(trained, tmp_path):
    """A dataset copied from another machine names a layout file not here: one line naming
    the dataset, the field and --layout; with --layout the env is made."""
    demos, _ = trained
    moved = tmp_path / "trajectory.h5"
    moved.write_bytes(demos.read_bytes())
    meta = json.loads(demos.with_suffix(".json").read_text())
    meta["env_info"]["env_kwargs"]["layout_file"] = "/elsewhere/default.json"
    moved.with_suffix(".json").write_text(json.dumps(meta))
    with pytest.raises(SystemExit) as e:
        train_policy.main(["--demos", str(moved), "--out", str(tmp_path / "run")])
    assert str(e.value) == (f"{moved}: env_info.env_kwargs.layout_file /elsewhere/default.json "
                            "does not exist here. Fix: --layout FILE, the layout the "
                            "demonstrations were collected on")  # fmt: skip
    env = train_policy.dataset_env(meta["env_info"], DEFAULT_LAYOUT, moved)
    try:
        assert Path(env.unwrapped.layout_set.files[0]) == DEFAULT_LAYOUT
    finally:
        env.close()


def test_a_held_mover_moves_with_the_hand_in_its_copies(trained):
    """In a copy of a step that holds the can, the can keeps its pose in the hand's frame and
    its vector to the goal moves with it; the goal stays."""
    demos, _ = trained
    observations, _, bases, env_info = train_policy.load_episodes(demos, -1)
    held = observations[0][:, 18] > 0.5
    assert held.sum() > 10  # the demo lifts the can
    obs, base = observations[0][held][::5], bases[0][held][::5]
    env = train_policy.dataset_env(env_info)
    try:
        slices, kin = perturb.obs_slices(env), perturb.Kinematics(env)
        copies, index, _ = perturb.corrective_copies(obs, base, np.arange(7), kin, slices, 0.05,
                                                     1, np.random.default_rng(2))  # fmt: skip
    finally:
        env.close()

    def in_hand(rows):  # the can's position in the TCP's frame
        tcp, can = rows[:, 19:26].astype(np.float64), rows[:, 32:35].astype(np.float64)
        return perturb.quat_rotate(perturb.conj(tcp[:, 3:]), can - tcp[:, :3])

    assert np.abs(copies[:, 32:35] - obs[index, 32:35]).max() > 0.01  # the can moved
    np.testing.assert_allclose(in_hand(copies), in_hand(obs[index]), atol=POS_TOL)
    goal = copies[:, 62:65] + copies[:, 32:35]  # mover_to_goal + mover
    np.testing.assert_allclose(goal, obs[index, 62:65] + obs[index, 32:35], atol=POS_TOL)
    np.testing.assert_allclose(copies[:, 53:56], copies[:, 32:35] - copies[:, 19:22], atol=POS_TOL)
