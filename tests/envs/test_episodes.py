"""Episodes for learning: per-episode starts without rebuilding the scene, the three placement
regimes, and hybrid observations that survive ManiSkill's record-and-replay tools."""

import gymnasium as gym
import h5py
import numpy as np
import torch
from conftest import per_layout_env
from placement_checks import check_constraints, episode_layout, object_poses

import embodied_envs  # noqa: F401

ENV_ID = "PickEmbodiedGen-v1"


env = per_layout_env(obs_mode="state")


def test_default_resets_keep_the_scene_and_draw_valid_new_starts(env):
    u = env.unwrapped
    env.reset(seed=7, options=dict(reconfigure=True))  # a placed configuration
    scene, table, config = u.scene, u.layout_scene.node_actors[u.layouts[0].context], u.layouts
    starts, goals = [], []
    for _ in range(12):
        _, info = env.reset()
        assert not info["reconfigure"]
        assert u.scene is scene and u.layouts is config  # nothing rebuilt
        assert check_constraints(episode_layout(u)) == []
        starts.append(object_poses(u))
        goals.append(u.goal_site.pose.p[0].numpy().copy())
    assert u.layout_scene.node_actors[u.layouts[0].context] is table
    for node in starts[0]:  # every object moves between episodes
        assert len({tuple(s[node][:2].round(6)) for s in starts}) == len(starts), node
    assert len({tuple(g.round(6)) for g in goals}) == len(goals)
    assert u.layout_scene.episodes.fallbacks == 0


def test_same_seed_same_start_other_seed_other_start(env):
    u = env.unwrapped
    obs_a, _ = env.reset(seed=21)
    start_a, goal_a = object_poses(u), u.goal_site.pose.p.clone()
    env.reset()
    obs_b, _ = env.reset(seed=21)
    assert torch.equal(obs_a, obs_b) and torch.equal(goal_a, u.goal_site.pose.p)
    obs_c, _ = env.reset(seed=22)
    assert not torch.equal(obs_a, obs_c)
    target = u.layouts[0].target_node
    assert not np.array_equal(start_a[target], object_poses(u)[target])


def test_fixed_poses_regime_uses_the_file_every_episode():
    e = gym.make(ENV_ID, obs_mode="state", replace_objs=False)
    try:
        u = e.unwrapped
        file = u.base_layout
        for seed in (0, 1, None):
            e.reset(seed=seed)
            for node, raw in object_poses(u).items():
                want = file.pose(node).raised(u.objs_z_offset).to_raw()
                np.testing.assert_allclose(raw[:3], want[:3], atol=1e-5, err_msg=node)
                assert abs(abs(np.dot(raw[3:], want[3:])) - 1) < 1e-5, node
        e.reset(seed=3, options=dict(reconfigure=True))
        assert u.layouts[0].position == file.position
    finally:
        e.close()


def test_full_relayout_regime_redraws_table_robot_and_background():
    e = gym.make(ENV_ID, obs_mode="state", reconfiguration_freq=1)
    try:
        u = e.unwrapped
        seen = set()
        for seed in (1, 2):
            _, info = e.reset(seed=seed)
            assert info["reconfigure"]
            layout = u.layouts[0]
            seen.add(tuple(tuple(layout.position[n]) for n in (layout.context, layout.background)))
            assert check_constraints(episode_layout(u)) == []
        assert len(seen) == 2
    finally:
        e.close()


def test_hybrid_obs_survive_record_and_maniskill_replay(tmp_path, monkeypatch):
    """Record with ManiSkill's RecordEpisode (state obs), convert with ManiSkill's
    replay_trajectory to rgb from another working directory: the replayed observations are
    composited over the splat room, as a live env with hybrid_obs renders them."""
    from mani_skill.trajectory.replay_trajectory import main, parse_args
    from mani_skill.utils.wrappers.record import RecordEpisode

    env = gym.make(ENV_ID, obs_mode="state", hybrid_obs=True)
    env = RecordEpisode(env, str(tmp_path / "rec"), save_video=False, trajectory_name="traj")
    env.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(4):
        env.step(torch.as_tensor(rng.uniform(-1, 1, (1, 8)), dtype=torch.float32))
    env.close()
    work = tmp_path / "elsewhere"
    work.mkdir()
    monkeypatch.chdir(work)
    traj = tmp_path / "rec" / "traj.h5"
    main(
        parse_args(
            [
                "--traj-path",
                str(traj),
                "-o",
                "rgb",
                "--save-traj",
                "--use-env-states",
                "--allow-failure",
            ]
        )
    )
    out = next((tmp_path / "rec").glob("traj.rgb.*.h5"))
    with h5py.File(out) as f:
        replayed = f["traj_0/obs/sensor_data/base_camera/rgb"][:]
    assert replayed.shape == (5, 128, 128, 3)

    live = {}
    for hybrid in (True, False):
        e = gym.make(ENV_ID, obs_mode="rgb", hybrid_obs=hybrid)
        obs, _ = e.reset(seed=4)
        live[hybrid] = obs["sensor_data"]["base_camera"]["rgb"][0].numpy()
        e.close()
    same = (replayed[0] == live[True]).all(-1).mean()
    assert same > 0.99, f"only {same:.3f} of the replayed first frame matches the live one"
    splat = (live[True] != live[False]).any(-1)
    assert splat.mean() > 0.3, "the splat background covers much of the view"
    assert (replayed[0][splat] == live[True][splat]).all(-1).mean() > 0.99
