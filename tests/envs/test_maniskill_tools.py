"""ManiSkill's own tools on this env: a ``RecordEpisode`` dataset that ManiSkill's
``replay_trajectory`` re-creates in a fresh process, ``CachedResetWrapper`` (``reset`` takes
every option ManiSkill's ``BaseEnv.reset`` reads) and ``agent.init_qpos`` as EmbodiedGen's env
sets it."""

import json
import os
import subprocess
import sys

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch
from conftest import ROOT

import embodied_envs  # noqa: F401
from embodied_envs.registration import ENTRY_ID, ENV_ID
from embodied_envs.robots import PANDA

REST_QPOS = np.array(PANDA.rest_qpos)


@pytest.fixture(scope="module")
def env():
    e = gym.make(ENV_ID, obs_mode="state")
    yield e
    e.close()


def test_a_record_episode_dataset_replays_with_maniskills_replay_trajectory(tmp_path):
    """20 random pd_joint_pos steps recorded by ManiSkill's RecordEpisode store the id with
    its package; ``python -m mani_skill.trajectory.replay_trajectory`` (which imports only
    mani_skill) re-creates the env from it, from a folder where ``embodied_envs`` is no module,
    and replaying the actions from the recorded seed gives the recorded states and state
    observations (every mover's slots, docs/tasks.md), which ManiSkill's dataset loads."""
    from mani_skill.trajectory.dataset import ManiSkillTrajectoryDataset
    from mani_skill.utils.wrappers.record import RecordEpisode

    e = gym.make(ENV_ID, obs_mode="state", control_mode="pd_joint_pos")
    assert e.spec.id == e.unwrapped.spec.id == ENTRY_ID == "embodied_envs:PickEmbodiedGen-v1"
    rec = RecordEpisode(e, str(tmp_path / "rec"), save_video=False, trajectory_name="traj")
    rec.reset(seed=3)
    rec.action_space.seed(0)
    for _ in range(20):
        rec.step(rec.action_space.sample())
    rec.close()
    meta = json.loads((tmp_path / "rec" / "traj.json").read_text())
    assert meta["env_info"]["env_id"] == ENTRY_ID
    work = tmp_path / "elsewhere"
    work.mkdir()
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    res = subprocess.run(
        [sys.executable, "-m", "mani_skill.trajectory.replay_trajectory",
         "--traj-path", str(tmp_path / "rec" / "traj.h5"), "--allow-failure", "--save-traj"],
        cwd=work, capture_output=True, text=True, timeout=300,
        env={**os.environ, "PYTHONPATH": path, "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"},
    )  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    assert "1/1=100.00% demos saved" in res.stdout + res.stderr
    out = tmp_path / "rec" / "traj.state.pd_joint_pos.physx_cpu.h5"
    with h5py.File(tmp_path / "rec" / "traj.h5") as a, h5py.File(out) as b:
        assert b["traj_0/actions"].shape == (20, 8)
        for name in a["traj_0/env_states/actors"]:
            want = a[f"traj_0/env_states/actors/{name}"][:]
            np.testing.assert_allclose(b[f"traj_0/env_states/actors/{name}"][:], want, atol=1e-5)
        width = e.observation_space.shape[-1]
        assert a["traj_0/obs"].shape == b["traj_0/obs"].shape == (21, width)
        np.testing.assert_allclose(b["traj_0/obs"][:], a["traj_0/obs"][:], atol=1e-4)
    data = ManiSkillTrajectoryDataset(str(out), load_count=-1, success_only=False)
    assert len(data) == 20 and data[0]["obs"].shape == (width,)


def test_cached_reset_wrapper_resets_to_its_cached_states(env):
    """ManiSkill's CachedResetWrapper resets with ``reset_to_env_states``: every reset puts the
    objects, the goal and the robot at one of its cached states, and the returned observation
    is the env's own at that state."""
    from mani_skill.utils.wrappers import CachedResetWrapper

    wrapped = CachedResetWrapper(env, config=dict(num_resets=3, seed=5))
    cached = wrapped._cached_resets_env_states
    objs = cached["actors"]
    assert set(objs) >= {"goal_site", "mug"} and objs["mug"].shape == (3, 13)
    assert not torch.allclose(objs["goal_site"][0], objs["goal_site"][1]), "distinct resets"
    u = env.unwrapped
    torch.manual_seed(0)  # the wrapper draws which cached state with torch
    hits = set()
    for _ in range(6):
        obs, _ = wrapped.reset()
        state = u.get_state_dict()
        match = [
            k for k in range(3)
            if all(torch.allclose(state["actors"][n][0], objs[n][k], atol=1e-6) for n in objs)
        ]  # fmt: skip
        assert len(match) == 1, "the reset state is one of the cached ones"
        k = match[0]
        robot = state["articulations"]["panda"][0]
        assert torch.allclose(robot, cached["articulations"]["panda"][k], atol=1e-6)
        assert torch.allclose(obs, u.get_obs(), atol=1e-6)
        assert torch.allclose(u.agent.init_qpos[0], robot[-18:-9]), "init_qpos: the state's"
        hits.add(k)
    assert len(hits) >= 2


def test_init_qpos_is_the_pose_each_episode_starts_from():
    """As EmbodiedGen's env: ``agent.init_qpos`` is ``(num_envs, 9)``, the arm's start pose
    (``REST_QPOS`` without noise, ``REST_QPOS`` plus the episode's noise with it), fingers
    open; it stays while the episode runs and follows the next reset."""
    e = gym.make(ENV_ID, obs_mode="state", robot_init_qpos_noise=0.0)
    try:
        e.reset(seed=0)
        agent = e.unwrapped.agent
        assert agent.init_qpos.shape == (1, 9)
        np.testing.assert_allclose(agent.init_qpos[0].numpy(), REST_QPOS, atol=1e-6)
    finally:
        e.close()
    e = gym.make(ENV_ID, obs_mode="state")  # the default noise, 0.02 rad
    try:
        e.reset(seed=1)
        agent = e.unwrapped.agent
        start = agent.init_qpos.clone()
        assert torch.equal(start, agent.robot.get_qpos())
        assert 1e-4 < np.abs(start[0, :7].numpy() - REST_QPOS[:7]).max() < 0.1
        np.testing.assert_allclose(start[0, 7:].numpy(), [0.04, 0.04], atol=1e-6)
        for _ in range(3):
            e.step(torch.ones(1, 8))
        assert torch.equal(agent.init_qpos, start)
        assert not torch.equal(agent.robot.get_qpos(), start), "the arm moved"
        e.reset(seed=2)
        assert not torch.equal(agent.init_qpos, start)
        assert torch.equal(agent.init_qpos, agent.robot.get_qpos())
    finally:
        e.close()
