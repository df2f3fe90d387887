"""collect's recorder writes ManiSkill's RecordEpisode files, array for array."""

from __future__ import annotations

import json

import gymnasium as gym
import h5py
import numpy as np
import pytest
from mani_skill.utils.wrappers.record import RecordEpisode

from embodied_envs.datasets.recorder import EpisodeRecorder
from embodied_envs.registration import ENV_ID


def _record(cls, out, obs_mode: str, control_mode: str) -> tuple[dict, dict]:
    """Three seeded episodes of fixed pseudo-random actions (the second not saved, the third
    cut by the next reset), recorded by ``cls``; the .h5 as {path: array} and the .json."""
    env = gym.make(ENV_ID, obs_mode=obs_mode, control_mode=control_mode, sim_backend="physx_cpu")
    env = cls(
        env, output_dir=str(out), trajectory_name="t", save_video=False, save_on_reset=False,
        record_reward=True, source_type="x", source_desc="y",
    )  # fmt: skip
    rng = np.random.default_rng(0)
    try:
        for seed, steps, save in ((3, 25, True), (4, 10, False), (5, 30, True)):
            env.reset(seed=seed)
            for _ in range(steps):
                action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
                env.step(action)
                action[:] = 7.0  # a caller reusing its action array changes no record
            env.flush_trajectory(save=save)
        env.reset(seed=6)
        for _ in range(5):
            env.step(env.action_space.sample() * 0)
    finally:
        env.close()
    arrays = {}

    def keep(name, item):  # visititems stops at the first value that is not None
        if isinstance(item, h5py.Dataset):
            arrays[name] = item[()]

    with h5py.File(out / "t.h5", "r") as f:
        f.visititems(keep)
    return arrays, json.loads((out / "t.json").read_text())


@pytest.mark.parametrize(
    "obs_mode, control_mode",
    [
        ("none", "pd_joint_pos"),
        ("state_dict", "pd_joint_target_delta_pos"),
        ("rgb", "pd_joint_pos"),
    ],
)
def test_same_files_as_record_episode(tmp_path, obs_mode, control_mode):
    ours, ours_json = _record(EpisodeRecorder, tmp_path / "ours", obs_mode, control_mode)
    theirs, theirs_json = _record(RecordEpisode, tmp_path / "theirs", obs_mode, control_mode)
    assert sorted(ours) == sorted(theirs)
    for key in ("actions", "rewards", "success", "fail", "terminated", "truncated"):
        assert f"traj_1/{key}" in theirs, key
    assert any(k.startswith("traj_1/env_states/articulations/") for k in theirs)
    for name, value in theirs.items():
        assert ours[name].dtype == value.dtype, name
        np.testing.assert_array_equal(ours[name], value, err_msg=name)
    assert len(ours["traj_0/actions"]) == 25 and len(ours["traj_1/actions"]) == 30
    assert not (ours["traj_0/actions"] == 7.0).any()
    if obs_mode == "rgb":  # every step's own image, not the last one's
        frames = ours["traj_1/obs/sensor_data/base_camera/rgb"]
        assert len(frames) == 31 and (frames[0] != frames[-1]).any()
    if control_mode == "pd_joint_target_delta_pos":  # the controller's targets are recorded
        assert any("controller" in k for k in ours)
    assert ours_json["episodes"] == theirs_json["episodes"]
    assert [e["elapsed_steps"] for e in ours_json["episodes"]] == [25, 30]
