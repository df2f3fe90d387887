"""``robot_init_qpos``: the rest joints an episode starts from instead of the robot entry's,
checked before anything is simulated, recorded in the env's spec, taken from config files and
the CLI's ``--config``, and re-created by ManiSkill's ``replay_trajectory``."""

import json
import os
import subprocess
import sys
import time

import gymnasium as gym
import h5py
import numpy as np
import pytest
from conftest import DEFAULT_LAYOUT, ROOT

import embodied_envs  # noqa: F401
from embodied_envs.config import ConfigError
from embodied_envs.envs import PickEmbodiedGenEnv, agents
from embodied_envs.registration import ENV_ID
from embodied_envs.robots import PANDA_REST, ROBOTS

# ManiSkill's own Panda rest keyframe: panda_joint4 at -5pi/8, the hand straight down
HAND_DOWN = [0, 0.3927, 0, -1.9635, 0, 2.3562, 0.7854, 0.04, 0.04]


def hand_down_angle(env) -> float:
    """Degrees between the TCP's approach axis (its z) and straight down."""
    u = env.unwrapped
    rot = agents.tcp_pose(u.main_agent, u.robot_entry).to_transformation_matrix()
    z = rot[0, :3, 2].cpu().numpy()
    return float(np.degrees(np.arccos(np.clip(-z[2], -1, 1))))


def test_the_keyword_sets_the_start_joints_and_the_noise_applies_on_top():
    e = gym.make(ENV_ID, obs_mode="state", robot_init_qpos=np.array(HAND_DOWN),
                 robot_init_qpos_noise=0.0)  # fmt: skip
    try:
        u = e.unwrapped
        for seed in (0, 7):
            e.reset(seed=seed)
            qpos = u.agent.robot.get_qpos()[0].numpy()
            np.testing.assert_allclose(qpos, HAND_DOWN, atol=1e-5)
            np.testing.assert_allclose(u.agent.init_qpos[0].numpy(), HAND_DOWN, atol=1e-5)
            assert hand_down_angle(e) < 1.0  # the hand straight down
        # recorded as a list (an array given directly is spelled out for the JSON file)
        assert e.unwrapped.spec.kwargs["robot_init_qpos"] == HAND_DOWN
        assert u.robot_init_qpos == HAND_DOWN
    finally:
        e.close()
    e = gym.make(ENV_ID, obs_mode="state", robot_init_qpos=tuple(HAND_DOWN))  # noise 0.02
    try:
        e.reset(seed=3)
        qpos = e.unwrapped.agent.robot.get_qpos()[0].numpy()
        assert 0 < np.abs(qpos[:7] - HAND_DOWN[:7]).max() < 0.02 * 6
        np.testing.assert_allclose(qpos[7:], HAND_DOWN[7:], atol=1e-6)  # fingers open
    finally:
        e.close()
    # default: the entry's rest, EmbodiedGen's pose with the hand pitched 45 degrees
    e = gym.make(ENV_ID, obs_mode="state", robot_init_qpos_noise=0.0)
    try:
        e.reset(seed=0)
        np.testing.assert_allclose(e.unwrapped.agent.robot.get_qpos()[0], PANDA_REST, atol=1e-5)
        assert 40 < hand_down_angle(e) < 50
        assert "robot_init_qpos" not in e.unwrapped.spec.kwargs
    finally:
        e.close()


LENGTH = ["robot_init_qpos has 8 values", "robot 'panda' has 9 active joints", "Fix: give 9"]
TYPE = ["robot 'panda' (9 active joints) must be a list of 9 finite numbers", "hand-down rest"]
LIMIT = ["robot 'panda'", "(its articulation's joint limits)", "Fix: give every joint a value"]


@pytest.mark.parametrize(
    "value, words",
    [
        (HAND_DOWN[:8], LENGTH),
        ([*HAND_DOWN, 0.0], ["has 10 values", "e.g. its rest [0.0, 0.3927, 0.0, -1.1781"]),
        ("0 0.39 0", ["robot_init_qpos='0 0.39 0'", *TYPE]),
        ([True] * 9, TYPE),
        ([None] * 9, TYPE),
        ([0.0] * 8 + [float("nan")], TYPE),
        (np.zeros((1, 9)), TYPE),
        ([], TYPE),
        ([0, 0, 0, 0.5, 0, 0, 0, 0.04, 0.04],
         [*LIMIT, "joint 3 (panda_joint4) = 0.5000 is outside [-3.0718, -0.0698]"]),
        ([*HAND_DOWN[:7], 0.08, 0.04],
         [*LIMIT, "joint 7 (panda_finger_joint1) = 0.0800 is outside [0.0000, 0.0400]"]),
    ],
)  # fmt: skip
def test_bad_values_are_refused_in_one_message_before_simulation(value, words):
    t = time.perf_counter()
    with pytest.raises(ValueError) as e:
        gym.make(ENV_ID, robot_init_qpos=value)
    for w in words:
        assert w in str(e.value), str(e.value)
    assert "\n" not in str(e.value)
    assert time.perf_counter() - t < 5, "refused before the scene is built"


def test_other_robots_are_checked_against_their_own_joints():
    with pytest.raises(ValueError, match="robot 'so100' has 6 active joints") as e:
        gym.make(ENV_ID, robot_uids="so100", robot_init_qpos=HAND_DOWN)
    assert str([round(v, 4) for v in ROBOTS["so100"].rest_qpos]) in str(e.value)


def test_placement_warns_that_its_rest_boxes_are_the_arms_own_rest():
    """Placement keeps tall objects clear of the arm's links at its entry's rest
    (``Robot.rest_arm``): started elsewhere, the env says so and how to measure the arm there;
    not where the start is the rest, nor where the user set ``rest_arm``."""
    import warnings

    from embodied_envs.envs.keywords import limits_and_goals

    entry = ROBOTS["panda"]
    with pytest.warns(UserWarning, match=r"panda's links at its own rest .* --qpos .*rest_arm"):
        limits, _ = limits_and_goals(entry, None, None, np.array(HAND_DOWN))
    assert limits.rest_arm == entry.rest_arm  # kept: objects still avoid where the rest is
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for user, rest in ((None, PANDA_REST), (dict(rest_arm=None), HAND_DOWN)):
            limits, _ = limits_and_goals(entry, user, None, np.array(rest))
        assert limits.rest_arm is None
        with pytest.raises(ValueError, match=r"rest_arm\[0\]\[1\]=0.1 is outside \(0.2, 2.0\]"):
            limits_and_goals(entry, dict(rest_arm=[[0.2, 0.1, 0, 1, 0]]), None)


def test_two_arms_the_first_takes_it_the_second_keeps_its_rest():
    e = gym.make(ENV_ID, obs_mode="state", robot_uids=("panda", "panda"),
                 robot_init_qpos=HAND_DOWN, robot_init_qpos_noise=0.0)  # fmt: skip
    try:
        e.reset(seed=0)
        first, second = agents.all_agents(e.unwrapped)
        np.testing.assert_allclose(first.robot.get_qpos()[0], HAND_DOWN, atol=1e-5)
        np.testing.assert_allclose(second.robot.get_qpos()[0], PANDA_REST, atol=1e-5)
    finally:
        e.close()
    with pytest.raises(ValueError, match="the first arm's; the second keeps its rest"):
        gym.make(ENV_ID, robot_uids=("panda", "panda"), robot_init_qpos=HAND_DOWN[:7])


def test_config_files_take_it_and_refuse_a_wrong_type(tmp_path):
    good = tmp_path / "hand_down.yaml"
    good.write_text(f"robot_init_qpos: {HAND_DOWN}\n")
    assert PickEmbodiedGenEnv.env_kwargs(config=[good])["robot_init_qpos"] == HAND_DOWN
    bad = tmp_path / "bad.yaml"
    bad.write_text("robot_init_qpos: [0, 0.39, .nan]\n")
    with pytest.raises(ConfigError) as e:
        PickEmbodiedGenEnv.env_kwargs(config=[bad])
    assert str(e.value).startswith(str(bad)) and "must be a list of finite numbers" in str(e.value)
    bad.write_text("robot_init_qpos: down\n")
    with pytest.raises(ConfigError, match="robot_init_qpos='down' must be list"):
        PickEmbodiedGenEnv.env_kwargs(config=[bad])


def test_a_collected_dataset_records_it_and_maniskill_replays_it(tmp_path):
    """``collect --config`` with the hand-down rest: the dataset's env_kwargs hold it, each
    episode's first recorded joints are it (plus the noise), and ManiSkill's replay_trajectory
    re-creates that env and reproduces the demo's success."""
    (tmp_path / "hand_down.yaml").write_text(f"robot_init_qpos: {HAND_DOWN}\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MS_SKIP_ASSET_DOWNLOAD_PROMPT": "1"}
    res = subprocess.run(
        [sys.executable, "-m", "embodied_envs.cli.main", "collect", "--layout",
         str(DEFAULT_LAYOUT), "--num", "1", "--seed", "5", "--out", "out",
         "--config", "hand_down.yaml"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert res.returncode == 0, res.stdout + res.stderr
    assert "default.json: 1 demonstrations (1/1 successful" in res.stdout, res.stdout
    traj = tmp_path / "out" / "default" / "trajectory.h5"
    meta = json.loads(traj.with_suffix(".json").read_text())
    assert meta["env_info"]["env_kwargs"]["robot_init_qpos"] == HAND_DOWN
    with h5py.File(traj) as f:  # the articulation's state: pose, velocities, qpos, qvel
        qpos = f["traj_0"]["env_states"]["articulations"]["panda"][0, 13:22]
    assert np.abs(qpos - HAND_DOWN).max() < 0.02 * 6
    res = subprocess.run(
        [sys.executable, "-m", "mani_skill.trajectory.replay_trajectory", "--traj-path",
         str(traj), "--save-traj"],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert "1/1=100.00% demos saved" in res.stdout + res.stderr, res.stdout + res.stderr
    out = traj.with_name("trajectory.none.pd_joint_pos.physx_cpu.h5")
    with h5py.File(out) as f:  # re-created from the seed and env_kwargs: the same start
        replayed = f["traj_0"]["env_states"]["articulations"]["panda"][0, 13:22]
    np.testing.assert_allclose(replayed, qpos, atol=1e-6)
