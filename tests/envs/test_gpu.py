"""The GPU path: ManiSkill's GPU simulation with several envs in one process.

Runs only where CUDA is present (``pytest -m cuda``); CI machines have none. The same module
also checks the CUDA splat backends against the CPU rasterizer.
"""

import gymnasium as gym
import numpy as np
import pytest
import torch
from placement_checks import check_constraints, episode_layout

import embodied_envs  # noqa: F401
from embodied_envs.envs.tasks import pick

pytestmark = [
    pytest.mark.cuda,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU"),
]
ENV_ID = "PickEmbodiedGen-v1"
N = 4


@pytest.fixture(scope="module")
def env():
    e = gym.make(
        ENV_ID, num_envs=N, sim_backend="physx_cuda", obs_mode="state_dict", render_mode="hybrid"
    )
    e.reset(seed=0)
    yield e
    e.close()


def test_per_env_layouts_differ(env):
    u = env.unwrapped
    assert u.device.type == "cuda"
    positions = [str(sorted(lay.position.items())) for lay in u.layouts]
    assert len(set(positions)) == N


def test_each_env_grades_its_own_target(env):
    u = env.unwrapped
    env.reset(seed=3)
    for k in range(N):
        own = u.env_actors[f"env{k}"][u.layouts[k].target_node]
        assert torch.allclose(u.obj.pose.p[k], own.pose.p[0])
    _, reward, _, _, info = env.step(torch.zeros(env.action_space.shape, device=u.device))
    # nothing grasped yet: the reward is the reaching term of each env's own object (the
    # default reward mode is ManiSkill's normalized_dense: over pick's maximum)
    dist = torch.linalg.norm(u.obj.pose.p - u.agent.tcp_pose.p, dim=1)
    assert not info["is_grasped"].any()
    reach = (1 - torch.tanh(5 * dist)) / pick.MAX_REWARD
    torch.testing.assert_close(reward, reach, atol=1e-4, rtol=0)


def test_partial_reset_leaves_other_envs_untouched(env):
    u = env.unwrapped
    env.reset(seed=5)
    rng = np.random.default_rng(0)
    for _ in range(10):
        a = torch.as_tensor(rng.uniform(-1, 1, env.action_space.shape), dtype=torch.float32)
        env.step(a.to(u.device))
    before_obj = u.obj.pose.raw_pose.clone()
    before_q = u.agent.robot.get_qpos().clone()
    env.reset(options=dict(env_idx=torch.tensor([1, 3], device=u.device)))
    after_obj, after_q = u.obj.pose.raw_pose, u.agent.robot.get_qpos()
    for k in (0, 2):
        assert torch.equal(after_obj[k], before_obj[k]) and torch.equal(after_q[k], before_q[k])
    for k in (1, 3):
        assert not torch.equal(after_q[k], before_q[k])


def test_hybrid_renders_every_env(env):
    frames = env.render()
    assert frames.shape == (N, 256, 256, 3) and frames.dtype == torch.uint8
    assert frames.float().std() > 5
    cached = env.unwrapped.hybrid.cached("render_camera")
    assert cached.rgb.device.type == "cuda" and cached.valid.all()
    assert not torch.equal(cached.rgb[0], cached.rgb[1]), "each env's background is its own"
    renders = env.unwrapped.hybrid.renders
    env.reset()
    env.render()
    assert env.unwrapped.hybrid.renders == renders, "episodes reuse the backgrounds"


@pytest.mark.parametrize("n", [16, 256])
def test_per_episode_placement_on_the_gpu(n):
    e = gym.make(ENV_ID, num_envs=n, sim_backend="physx_cuda", obs_mode="state")
    try:
        u = e.unwrapped
        nodes = [m for m in u.layout_scene.dynamic_nodes if m in u.layout_scene.episodes.fallback]

        def starts():
            return torch.stack([u.layout_scene.node_actors[m].pose.raw_pose for m in nodes], 1)

        _, info = e.reset(seed=0)
        assert not info["reconfigure"]
        a = starts().clone()
        assert a.device.type == "cuda"
        e.reset()
        b = starts().clone()
        assert (a[..., :2] != b[..., :2]).any(-1).all(), "every object of every env moved"
        for k in range(0, n, max(1, n // 8)):  # every rule holds, checked independently
            assert check_constraints(episode_layout(u, k)) == [], f"env {k}"
        e.reset(options=dict(env_idx=torch.tensor([1, 3], device=u.device)))
        c = starts()
        keep = torch.ones(n, dtype=torch.bool)
        keep[[1, 3]] = False
        assert torch.equal(c[keep.to(u.device)], b[keep.to(u.device)])
        assert (c[[1, 3], :, :2] != b[[1, 3], :, :2]).any(-1).all()
        e.reset(seed=0)
        torch.testing.assert_close(starts(), a, atol=1e-5, rtol=0)  # same seed, same starts
        assert u.layout_scene.episodes.fallbacks == 0
    finally:
        e.close()


def test_cuda_backends_match_the_cpu_rasterizer():
    from embodied_envs.paths import data_root
    from embodied_envs.splat import PinholeCamera, read_ply, render
    from embodied_envs.splat.backend import gsplat_available

    splat = read_ply(data_root() / "assets" / "background" / "gs_model.ply")
    cam = PinholeCamera.look_at((0.0, 1.3, 0.0), (2.0, 1.0, -1.0), up=(0, 1, 0))
    other = PinholeCamera.look_at((0.5, 1.2, 0.3), (-2.0, 1.0, 1.0), up=(0, 1, 0))
    cpu = [render(splat, c, backend="torch") for c in (cam, other)]
    backends = ["torch"] + (["gsplat"] if gsplat_available() else [])
    for backend in backends:
        gpu = render(splat.to("cuda"), cam, backend=backend)
        diff = (gpu.rgb.cpu() - cpu[0].rgb).abs()
        assert (diff > 2 / 255).float().mean() <= 0.01, backend
        both = render(splat.to("cuda"), [cam, other], backend=backend)  # one batched call
        assert both.rgb.shape[0] == 2
        for k in range(2):
            diff = (both.rgb[k].cpu() - cpu[k].rgb).abs()
            assert (diff > 2 / 255).float().mean() <= 0.01, (backend, k)


@pytest.mark.parametrize("obs_mode", ["rgbd", "pointcloud"])
def test_hybrid_depth_and_points_batched_on_cuda(obs_mode):
    """hybrid_obs on the GPU sim: every env's splat pixels carry segmentation 0 and a depth
    (rgbd) or a valid world point (pointcloud); the simulator's pixels keep theirs."""
    e = gym.make(ENV_ID, num_envs=N, sim_backend="physx_cuda", obs_mode=obs_mode, hybrid_obs=True)
    try:
        obs, _ = e.reset(seed=0)
        u = e.unwrapped
        splat = u.hybrid.splat_points["base_camera"]
        assert splat.shape == (N, 128, 128) and splat.device.type == "cuda"
        assert (splat.float().mean((1, 2)) > 0.2).all(), "every env sees its room"
        if obs_mode == "rgbd":
            depth = obs["sensor_data"]["base_camera"]["depth"][..., 0]
            assert (depth[splat] > 0).all()
            return
        pc = obs["pointcloud"]
        xyzw = pc["xyzw"].reshape(N, 128, 128, 4)
        seg = pc["segmentation"].reshape(N, 128, 128)
        assert (xyzw[splat][:, 3] == 1).all() and (seg[splat] == 0).all()
        # splat points are in the room, not at the camera or the origin
        eye = obs["sensor_param"]["base_camera"]["cam2world_gl"][:, :3, 3]
        dist = torch.linalg.norm(xyzw[..., :3] - eye[:, None, None], dim=-1)
        assert (dist[splat] > 0.05).all()
    finally:
        e.close()


def test_heterogeneous_sub_scenes_over_a_layout_set(tmp_path):
    """Eight GPU envs over three layouts with different targets, tables and node names: each
    env's sub-scene is the layout its seed draws, the merged target is each env's own, the
    state dict holds one entry per slot over all envs, starts meet each layout's rules,
    partial resets touch only their envs, and each env composites its own room."""
    from conftest import DATA
    from scene_sets import make_scene_set

    from embodied_envs.layout.sets import LayoutSet

    scenes = make_scene_set(tmp_path, DATA)
    n = 8
    layout_set = LayoutSet.load(scenes["four"])
    e = gym.make(ENV_ID, num_envs=n, sim_backend="physx_cuda", obs_mode="state",
                 layout_file=str(scenes["four"]), render_mode="hybrid")  # fmt: skip
    try:
        u = e.unwrapped
        e.reset(seed=0, options=dict(reconfigure=True))
        seeds = np.asarray(u._episode_seed).reshape(-1)
        for k in range(n):
            want = layout_set.draw(int(seeds[k]), k)
            assert u.layouts[k].source == want.source, k
            assert set(u.env_actors[f"env{k}"]) == set(want.object_nodes()), k
            own = u.env_actors[f"env{k}"][u.layouts[k].target_node]
            assert torch.allclose(u.obj.pose.p[k], own.pose.p[0]), k
            assert check_constraints(episode_layout(u, k)) == [], k
        assert len({x.source for x in u.layouts}) >= 2, "the draw mixes layouts"
        actors = u.get_state_dict()["actors"]
        assert {"target", "object1", "object2"} <= set(actors)
        assert all(v.shape[0] == n for v in actors.values())
        before = {s: u.layout_scene.node_actors[s].pose.raw_pose.clone() for s in actors}
        e.reset(options=dict(env_idx=torch.tensor([1, 6], device=u.device)))
        keep = torch.ones(n, dtype=torch.bool, device=u.device)
        keep[[1, 6]] = False
        for slot in ("target", "object1", "object2"):
            after = u.layout_scene.node_actors[slot].pose.raw_pose
            assert torch.equal(after[keep], before[slot][keep]), slot
            assert (after[[1, 6], :2] != before[slot][[1, 6], :2]).any(-1).all(), slot
        for k in range(n):
            own = u.env_actors[f"env{k}"][u.layouts[k].target_node]
            assert torch.allclose(u.obj.pose.p[k], own.pose.p[0]), "the merged target moved"
        frames = e.render()
        assert frames.shape[0] == n
        assert u.hybrid.rooms == [x.gs_model_path() for x in u.layouts]
    finally:
        e.close()
