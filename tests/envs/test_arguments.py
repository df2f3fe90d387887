"""Runtime arguments (seeds, env_idx, actions, num_envs, a closed env) fail with messages that
name the argument and what is accepted, before the simulator sees them."""

import time

import gymnasium as gym
import numpy as np
import pytest
import torch

import embodied_envs  # noqa: F401

ENV_ID = "PickEmbodiedGen-v1"


@pytest.fixture(scope="module")
def env():
    e = gym.make(ENV_ID, obs_mode="state")
    yield e
    e.close()


@pytest.mark.parametrize(
    "seed, words",
    [
        (2**40, "a seed is an int in [0, 4294967295]"),
        (-1, "got -1"),
        (1.5, "got 1.5"),
        (True, "got True"),
        ("3", "got '3'"),
        ([1, 2], "2 seeds for 1 envs"),
    ],
)
def test_bad_seeds_are_refused_naming_the_range(env, seed, words):
    obs_before = env.reset(seed=0)[0]
    with pytest.raises(ValueError, match="reset\\(seed=") as e:
        env.reset(seed=seed)
    assert words in str(e.value)
    assert torch.equal(env.unwrapped.get_obs(), obs_before), "nothing was reset"


def test_good_seeds_of_every_integer_kind_are_equal(env):
    a = env.reset(seed=7)[0]
    for seed in (np.int64(7), [7], np.array([7]), torch.tensor([7])):
        assert torch.equal(env.reset(seed=seed)[0], a)


@pytest.mark.parametrize("env_idx", [[1], [-1], [0.0], [], [0, 0], [[0]], "0"])
def test_bad_env_idx_is_refused(env, env_idx):
    with pytest.raises(ValueError, match=r"env_idx is a non-empty 1-D list or tensor .* \[0, 0\]"):
        env.reset(options=dict(env_idx=env_idx))


def test_env_idx_as_a_list_resets_like_a_tensor(env):
    env.reset(seed=3)
    a = env.reset(seed=3, options=dict(env_idx=[0]))[0]
    b = env.reset(seed=3, options=dict(env_idx=torch.tensor([0])))[0]
    assert torch.equal(a, b)


def test_list_actions_step_like_tensors(env):
    env.reset(seed=1)
    action = [0.1, -0.1, 0.0, 0.05, 0.0, 0.0, 0.0, 1.0]
    obs_list = env.step(action)[0]
    env.reset(seed=1)
    obs_tensor = env.step(torch.tensor(action))[0]
    assert torch.equal(obs_list, obs_tensor)
    with pytest.raises(ValueError, match=r"action has shape \(3,\); .* takes \(8,\) or \(1, 8\)"):
        env.step([0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="action must be numbers of shape"):
        env.step(["a"] * 8)


def test_step_and_reset_after_close_say_so():
    e = gym.make(ENV_ID, obs_mode="state")
    e.reset(seed=0)
    e.close()
    for call in (lambda: e.step(np.zeros(8)), lambda: e.reset(seed=0)):
        with pytest.raises(RuntimeError, match="on a closed PickEmbodiedGen-v1 env"):
            call()


@pytest.mark.skipif(torch.cuda.is_available(), reason="the message is for machines without CUDA")
def test_several_envs_without_cuda_point_to_the_async_vector_env():
    with pytest.raises(ValueError) as e:
        gym.make(ENV_ID, num_envs=4)
    msg = str(e.value)
    assert "num_envs=4 needs ManiSkill's GPU simulation" in msg and "no CUDA device" in msg
    assert "vectorization_mode='async'" in msg and "CPUGymWrapper" in msg
    with pytest.raises(ValueError, match="sim_backend='physx_cpu'"):
        gym.make(ENV_ID, num_envs=2, sim_backend="physx_cpu")
    with pytest.raises(ValueError, match="num_envs=0 must be a positive integer"):
        gym.make(ENV_ID, num_envs=0)


@pytest.mark.skipif(torch.cuda.is_available(), reason="the message is for machines without CUDA")
def test_one_gpu_env_without_cuda_says_so():
    for backend in ("physx_cuda", "gpu", "cuda:0"):
        with pytest.raises(ValueError) as e:
            gym.make(ENV_ID, sim_backend=backend)
        msg = str(e.value)
        assert f"sim_backend={backend!r} runs PhysX on the GPU" in msg and "no CUDA device" in msg
        assert "sim_backend='physx_cpu'" in msg


def test_gpu_sim_without_physx_gpu_library_names_file_url_and_fix(monkeypatch):
    """A CUDA machine that cannot reach GitHub (SAPIEN fetches PhysX's GPU library there on first
    use) gets one line naming the library, the URL and the fix, not a requests traceback."""
    import requests
    import sapien.physx

    from embodied_envs.envs.arguments import check_gpu_physics, gpu_sim_requested

    def offline():
        raise requests.exceptions.ConnectionError("Failed to resolve 'github.com'\nmore")

    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(sapien.physx, "is_gpu_enabled", lambda: False)
    monkeypatch.setattr(sapien.physx, "enable_gpu", offline)
    with pytest.raises(RuntimeError) as e:
        check_gpu_physics(16, "auto")
    msg = str(e.value)
    version = sapien.physx.version()
    assert f".sapien/physx/{version}/libPhysXGpu_64.so" in msg
    assert f"physx-precompiled/releases/download/{version}/linux-so.zip" in msg
    assert "ConnectionError: Failed to resolve 'github.com'" in msg and "more" not in msg
    assert "on a machine with internet and unzip it into" in msg
    assert isinstance(e.value.__cause__, requests.exceptions.ConnectionError)
    # the CPU simulation never asks for the library
    check_gpu_physics(1, "auto")
    check_gpu_physics(1, "physx_cpu")
    assert [gpu_sim_requested(n, b) for n, b in [(1, "auto"), (2, "auto"), (1, "gpu"),
            (1, "physx_cuda:1"), (4, "physx_cpu")]] == [False, True, True, True, False]  # fmt: skip


@pytest.mark.parametrize(
    "kwargs, words",
    [
        (dict(placement_limits=dict(batch=0)), ["placement_limits.batch=0", "[1, 100000]"]),
        (dict(placement_limits=dict(reach_min=0.7, reach_max=0.4)), ["reach_max=0.4"]),
        (dict(placement_limits=dict(episode_candidates=2.5)), ["must be an integer"]),
        (dict(goal_region=dict(height=[50, 51])), ["goal_region.height[0]=50", "[0.0, 1.0]"]),
        (dict(goal_region=dict(height=[0.2, 0.1])), ["goal_region.height[1]=0.1"]),
        (dict(goal_region=dict(inset=-0.1)), ["goal_region.inset=-0.1"]),
        (dict(goal_region=dict(inset=0.4)), ["leaves no goal band"]),
        (dict(robot_init_qpos_noise=1000), ["robot_init_qpos_noise=1000", "[0.0, 0.5]"]),
        (dict(objs_z_offset=-1.0), ["objs_z_offset=-1.0"]),
        (dict(robot_z_offset=float("nan")), ["robot_z_offset=nan"]),
        (dict(init_3dgs_quat=(0, 0, 0, 0)), ["init_3dgs_quat", "unit quaternion"]),
        (dict(init_3dgs_quat=(float("nan"), 0, 0, 1)), ["init_3dgs_quat", "unit quaternion"]),
        (dict(replace_objs="false"), ["replace_objs='false'", "True or False"]),
        (dict(hybrid_obs="no"), ["hybrid_obs='no'"]),
        (dict(enable_grasp=[1] * 10), ["enable_grasp="]),
        (
            dict(camera_cfg=dict(image_hw=[16384, 16384])),
            ["image_hw=[16384, 16384]", "at most 8192 px"],
        ),
    ],
)
def test_numeric_and_flag_keywords_are_range_checked_before_simulation(kwargs, words):
    t = time.perf_counter()
    with pytest.raises(ValueError) as e:
        gym.make(ENV_ID, **kwargs)
    for w in words:
        assert w in str(e.value), str(e.value)
    assert time.perf_counter() - t < 5, "refused before the scene is built"


@pytest.mark.parametrize(
    "options, words",
    [
        (dict(reconfigure="no"), ["reconfigure='no'", "True or False"]),
        ("reconfigure", ["options is a dict"]),
        (dict(reset_to_env_states=[0.0]), ["reset_to_env_states is a dict with 'env_states'",
                                          "got list"]),
        (dict(reset_to_env_states=dict(states={})), ["optionally 'obs'", "got keys ['states']"]),
    ],
)  # fmt: skip
def test_reset_options_are_checked(env, options, words):
    with pytest.raises(ValueError) as e:
        env.reset(seed=0, options=options)
    for w in words:
        assert w in str(e.value), str(e.value)


def test_options_maniskill_passes_on_are_ignored_with_a_warning(env):
    """ManiSkill's BaseEnv.reset hands keys it does not read to the task, which reads none:
    they are ignored (the same reset as without them), with a warning naming them."""
    want = env.reset(seed=4)[0]
    with pytest.warns(UserWarning, match=r"ignored keys \['reconfig', 'x'\]; this env reads "):
        got = env.reset(seed=4, options=dict(reconfig=True, x=1, env_idx=[0]))[0]
    assert torch.equal(got, want)


def test_reset_to_env_states_takes_a_state_dict_or_a_flat_state(env):
    """ManiSkill's reset option: the env's state (and its observation) as recorded."""
    u = env.unwrapped
    env.reset(seed=5)
    state, flat, obs = u.get_state_dict(), u.get_state(), u.get_obs()
    env.reset(seed=6)
    assert not torch.equal(u.get_obs(), obs)
    got = env.reset(options=dict(reset_to_env_states=dict(env_states=state)))[0]
    assert torch.allclose(got, obs, atol=1e-6) and torch.allclose(u.get_state(), flat, atol=1e-6)
    env.reset(seed=6)
    got = env.reset(options=dict(reset_to_env_states=dict(env_states=flat, obs=obs)))[0]
    assert torch.equal(got, obs) and torch.allclose(u.get_state(), flat, atol=1e-6)


def test_enable_grasp_is_accepted_and_changes_nothing():
    """EmbodiedGen passes ``enable_grasp``: taken (a flag, checked as such), and the same seeded
    episode runs to the same observations, rewards, flags and states with it on as off (two
    fresh envs: PhysX keeps contact state across resets, so an env with a history differs in
    the last digits)."""
    env = gym.make(ENV_ID, obs_mode="state")
    other = gym.make(ENV_ID, obs_mode="state", enable_grasp=True)
    try:
        runs = []
        for e in (env, other):
            obs, _ = e.reset(seed=3)
            steps = [(obs, None, None, e.unwrapped.get_state_dict())]
            rng = np.random.default_rng(0)
            for _ in range(5):
                obs, reward, terminated, truncated, info = e.step(
                    rng.uniform(-1, 1, e.action_space.shape).astype(np.float32)
                )
                flags = {k: v for k, v in info.items() if isinstance(v, torch.Tensor)}
                steps.append((obs, reward, flags, e.unwrapped.get_state_dict()))
            runs.append(steps)
        for (a, ra, fa, sa), (b, rb, fb, sb) in zip(*runs, strict=True):
            assert torch.equal(a, b)
            assert (ra is None and rb is None) or torch.equal(ra, rb)
            assert fa is None or list(fa) == list(fb)
            assert fa is None or all(torch.equal(fa[k], fb[k]) for k in fa)
            for group in sa:
                assert list(sa[group]) == list(sb[group])
                for name in sa[group]:
                    assert torch.equal(sa[group][name], sb[group][name]), (group, name)
        assert not hasattr(other.unwrapped, "enable_grasp")  # nothing of it is kept
    finally:
        env.close()
        other.close()


def test_a_float32_array_action_is_shared_as_the_general_path_makes_it():
    """The usual action (a float32 array of the single or batched shape) is checked in numpy
    and shared with torch, the tensor ``torch.as_tensor`` makes of it (as before); a
    non-finite one is refused with the same message."""
    from embodied_envs.envs.arguments import check_action

    action = np.linspace(-1, 1, 8, dtype=np.float32)
    for a in (action, action[None]):
        fast = check_action(a, (8,), 1, "pd_joint_pos")
        want = torch.as_tensor(a)
        assert fast.dtype == want.dtype == torch.float32 and torch.equal(fast, want)
        assert fast.shape == a.shape
        assert np.shares_memory(fast.numpy(), a), "shared, as torch.as_tensor shares it"
    bad = action.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match=r"action contains NaN or inf \(env \[0\]\)"):
        check_action(bad, (8,), 1, "pd_joint_pos")
