"""One env per process on CPU: gymnasium's async vector env with forkserver workers."""

import gymnasium as gym
import numpy as np
import pytest
from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper

import embodied_envs  # noqa: F401

ENV_ID = "PickEmbodiedGen-v1"


@pytest.fixture(scope="module")
def vec():
    envs = gym.make_vec(
        ENV_ID,
        num_envs=2,
        vectorization_mode="async",
        wrappers=[CPUGymWrapper],
        vector_kwargs=dict(context="forkserver"),
        obs_mode="state",
    )
    yield envs
    envs.close()


def worker_layouts(vec) -> list[dict]:
    """Each worker's (single) env configuration poses."""
    return [layouts[0].position for layouts in vec.get_attr("layouts")]


def test_each_worker_gets_its_own_reproducible_start(vec):
    configured = worker_layouts(vec)
    obs_a, info = vec.reset(seed=[10, 11])
    assert not info["reconfigure"].any(), "a default reset does not rebuild the scene"
    obs_b, _ = vec.reset(seed=[10, 11])
    np.testing.assert_array_equal(obs_a, obs_b)
    assert not np.array_equal(obs_a[0], obs_a[1]), "workers with different seeds share a start"
    assert worker_layouts(vec) == configured

    # a worker's start is the one a single in-process env draws for the same seed
    single = gym.make(ENV_ID, obs_mode="state")
    try:
        obs, _ = single.reset(seed=11)
        assert single.unwrapped.layouts[0].position == configured[1]
        np.testing.assert_array_equal(obs.numpy()[0], obs_a[1])
    finally:
        single.close()

    obs_c, _ = vec.reset(seed=[12, 13])
    assert not np.array_equal(obs_c[0], obs_a[0])
    obs_d, _ = vec.reset()  # unseeded: the next episode of each worker's stream
    assert not np.array_equal(obs_d[0], obs_c[0])


def test_workers_step_independently(vec):
    vec.reset(seed=[1, 2])
    rng = np.random.default_rng(0)
    for _ in range(20):
        obs, reward, term, trunc, info = vec.step(
            rng.uniform(-1, 1, vec.action_space.shape).astype(np.float32)
        )
    assert obs.shape[0] == 2 and np.isfinite(obs).all() and reward.shape == (2,)


def test_maniskill_eval_env_recipe_runs_hybrid(tmp_path):
    """ManiSkill's baselines' CPU evaluation envs (FrameStack, CPUGymWrapper with metrics,
    RecordEpisode, an async forkserver vector env), unchanged, with render_mode="hybrid"."""
    from mani_skill.utils.wrappers.frame_stack import FrameStack
    from mani_skill.utils.wrappers.record import RecordEpisode

    def thunk(seed, video_dir):
        def make():
            # the module-qualified id: the forkserver worker imports the plugin itself
            env = gym.make(
                f"embodied_envs:{ENV_ID}", obs_mode="state", render_mode="hybrid",
                reconfiguration_freq=1, max_episode_steps=6,
            )  # fmt: skip
            env = FrameStack(env, num_stack=2)
            env = CPUGymWrapper(env, ignore_terminations=True, record_metrics=True)
            if video_dir:
                env = RecordEpisode(env, output_dir=video_dir, save_trajectory=False,
                                    info_on_video=True)  # fmt: skip
            env.action_space.seed(seed)
            return env

        return make

    envs = gym.vector.AsyncVectorEnv(
        [thunk(0, str(tmp_path)), thunk(1, None)], context="forkserver"
    )
    try:
        obs, _ = envs.reset(seed=[0, 1])
        assert obs.shape[:2] == (2, 2)  # two envs, two stacked frames
        for _ in range(6):
            obs, rew, term, trunc, info = envs.step(envs.action_space.sample())
        assert trunc.all() and not term.any()
        assert info["fail"].shape == (2,) and not info["success"].any()
    finally:
        envs.close()
    videos = sorted(tmp_path.glob("*.mp4"))
    assert len(videos) == 1
    import imageio.v3 as iio

    frame = iio.imread(videos[0], index=0)
    assert frame.shape[:2] == (256, 256) and frame.mean() > 60, "the room is in the video"
