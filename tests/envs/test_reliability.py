"""Gymnasium compliance, determinism, numerical safety and action checks."""

import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import LAYOUTS, per_layout_env
from gymnasium.utils.env_checker import check_env
from gymnasium.utils.passive_env_checker import env_render_passive_checker
from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

import embodied_envs  # noqa: F401
from embodied_envs.envs import PickEmbodiedGenEnv

ENV_ID = "PickEmbodiedGen-v1"


@pytest.mark.parametrize("obs_mode, render_mode", [("state", "rgb_array"), ("rgb", "hybrid")])
def test_gymnasium_check_env_passes(obs_mode, render_mode):
    env = CPUGymWrapper(gym.make(ENV_ID, obs_mode=obs_mode, render_mode=render_mode))
    try:
        # every check of check_env, with the render check of this mode; the checker's
        # re-creation of the env from its spec is done below for every declared mode, because
        # ManiSkill's TimeLimitWrapper and CPUGymWrapper do not record constructor arguments
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env, skip_render_check=True, skip_close_check=True)
            env_render_passive_checker(env)
        messages = [str(w.message) for w in caught]
        assert not any("determinis" in m or "not equal" in m for m in messages), messages
        frame = env.render()
        assert frame.shape == (256, 256, 3) and frame.dtype == np.uint8
    finally:
        env.close()
    env.close()  # closing twice is allowed


def test_every_declared_render_mode_renders_frames():
    for mode in PickEmbodiedGenEnv.SUPPORTED_RENDER_MODES:
        env = gym.make(ENV_ID, render_mode=mode)
        try:
            env.reset(seed=0)
            env_render_passive_checker(CPUGymWrapper(env))
            frame = env.render()  # headless "human" returns the render camera's frames
            assert frame.ndim == 4 and frame.shape[0] == 1 and frame.shape[-1] == 3, mode
            assert frame.dtype == torch.uint8 and frame.float().std() > 5, mode
        finally:
            env.close()


def rollout(env, seed: int, steps: int, reconfigure: bool = False):
    obs, info = env.reset(seed=seed, options=dict(reconfigure=reconfigure))
    rng = np.random.default_rng(seed)
    frames = [(obs, None, info)]
    for _ in range(steps):
        action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
        obs, reward, term, trunc, info = env.step(action)
        frames.append((obs, reward, info))
    return frames


def flat(x):
    if isinstance(x, dict):
        return {k: flat(v) for k, v in x.items()}
    return np.asarray(x.cpu() if isinstance(x, torch.Tensor) else x)


def assert_identical(a, b):
    a, b = flat(a), flat(b)
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for k in a:
            assert_identical(a[k], b[k])
    else:
        assert np.array_equal(a, b, equal_nan=False), "values differ"


state_env = per_layout_env(obs_mode="state_dict")


def test_same_seed_is_bit_identical_over_50_steps_including_reconfigure(state_env):
    first = rollout(state_env, 11, 50, reconfigure=True)
    layout_a = state_env.unwrapped.layouts[0].position
    again = rollout(state_env, 11, 50, reconfigure=True)
    assert state_env.unwrapped.layouts[0].position == layout_a
    third = rollout(state_env, 11, 50)  # a plain reset keeps the configuration
    assert state_env.unwrapped.layouts[0].position == layout_a
    for (o1, r1, i1), (o2, r2, i2), (o3, r3, i3) in zip(first, again, third, strict=True):
        assert_identical(o1, o2)
        assert_identical(o1, o3)
        if r1 is not None:
            assert_identical(r1, r2)
            assert_identical(r1, r3)
            assert_identical(i1, i2)
            assert_identical(i1, i3)


def test_different_seeds_give_different_start_states(state_env):
    a = flat(state_env.reset(seed=1)[0])
    b = flat(state_env.reset(seed=2)[0])
    assert not np.array_equal(a["extra"]["mover_pose"], b["extra"]["mover_pose"])
    assert not np.array_equal(a["agent"]["qpos"], b["agent"]["qpos"])


def test_state_dict_round_trip(state_env):
    u = state_env.unwrapped
    rollout(state_env, 5, 10)
    saved = u.get_state_dict()
    obs_then = flat(u.get_obs())
    rng = np.random.default_rng(0)
    for _ in range(15):
        state_env.step(rng.uniform(-1, 1, state_env.action_space.shape).astype(np.float32))
    moved, kept = flat(u.get_state_dict()), flat(saved)
    robot = next(iter(kept["articulations"]))
    assert not np.array_equal(moved["articulations"][robot], kept["articulations"][robot])
    u.set_state_dict(saved)
    restored, kept = flat(u.get_state_dict()), flat(saved)
    for group in ("actors", "articulations"):
        for name in kept[group]:  # PhysX renormalises quaternions: equal to float rounding
            np.testing.assert_allclose(restored[group][name], kept[group][name], atol=1e-6)
    now = flat(u.get_obs())
    np.testing.assert_allclose(
        now["extra"]["mover_pose"], obs_then["extra"]["mover_pose"], atol=1e-6
    )
    np.testing.assert_allclose(now["agent"]["qpos"], obs_then["agent"]["qpos"], atol=1e-6)


@pytest.mark.parametrize("layout", LAYOUTS, ids=[p.stem for p in LAYOUTS])
def test_1000_random_steps_stay_finite_with_normalised_reward_in_unit_interval(layout):
    env = gym.make(
        ENV_ID, layout_file=str(layout), obs_mode="state", reward_mode="normalized_dense"
    )
    try:
        obs, _ = env.reset(seed=0)
        rng = np.random.default_rng(0)
        rewards = []
        for _ in range(1000):
            action = rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            obs, reward, term, trunc, info = env.step(action)
            assert torch.isfinite(obs).all(), "observation has NaN or inf"
            rewards.append(float(reward))
            if bool(term) or bool(trunc):
                obs, _ = env.reset()
                assert torch.isfinite(obs).all()
        r = np.asarray(rewards)
        assert np.isfinite(r).all() and r.min() >= 0.0 and r.max() <= 1.0
    finally:
        env.close()


@pytest.mark.parametrize(
    "action, words",
    [
        (np.full(7, 0.1, np.float32), ["shape (7,)", "takes (8,)"]),
        (np.zeros((2, 8), np.float32), ["shape (2, 8)", "(1, 8)"]),
        (np.array([0.1] * 7 + [np.nan], np.float32), ["NaN or inf", "env [0]"]),
        (np.array([np.inf] + [0.0] * 7, np.float32), ["NaN or inf"]),
    ],
)
def test_bad_actions_raise_a_clear_error_and_leave_the_state_alone(state_env, action, words):
    u = state_env.unwrapped
    state_env.reset(seed=0)
    before = flat(u.get_state_dict())
    with pytest.raises(ValueError) as e:
        state_env.step(action)
    for w in words:
        assert w in str(e.value), str(e.value)
    assert_identical(u.get_state_dict(), before)
