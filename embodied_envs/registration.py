"""``PickEmbodiedGen-v1`` in gymnasium's registry, without importing the simulator.

``import embodied_envs`` runs :func:`register`; the first ``gym.make`` imports the env module
(ManiSkill, SAPIEN, torch) through the string entry points below, which register the class with
ManiSkill, so commands that never make an env (``layout``, ``splat``) start without them.
"""

from __future__ import annotations

import gymnasium as gym
from gymnasium.envs.registration import WrapperSpec

ENV_ID = "PickEmbodiedGen-v1"
CONTROL_FREQ = 50  # Hz, control steps per second (the simulation runs at twice this)
# 300 control steps = 6 s at CONTROL_FREQ: the scripted expert's longest successful
# episode over 50 seeded episodes per shipped layout was 297 steps (mean ~150;
# tools/bench_solver.py), so every demonstration fits in one episode
MAX_EPISODE_STEPS = 300


def env_kwargs(config=None, **kwargs) -> dict:
    """The env's keywords: the ``config`` files merged in order, then ``kwargs`` over them.

    Raises:
        embodied_envs.config.ConfigError: a file that cannot be read, or an unknown key.
    """
    from embodied_envs.config import load_config, merge_config

    return merge_config(load_config(config), kwargs)


def make(**kwargs):
    """gymnasium's entry point: ManiSkill's ``make`` for the env (registered on import)."""
    from mani_skill.utils.registration import make as make_maniskill

    import embodied_envs.envs.pick_embodiedgen  # noqa: F401  (registers with ManiSkill)

    return make_maniskill(ENV_ID, **env_kwargs(**kwargs))


def make_vec(**kwargs):
    """gymnasium's vector entry point: ManiSkill's batched vector env over ``num_envs``."""
    from mani_skill.utils.registration import make_vec as make_vec_maniskill

    return make_vec_maniskill(ENV_ID, **kwargs)


def register() -> None:
    """Add the env to gymnasium's registry with the wrappers ManiSkill's own envs get."""
    if ENV_ID in gym.registry:
        return
    gym.register(
        ENV_ID,
        entry_point=f"{__name__}:make",
        vector_entry_point=f"{__name__}:make_vec",
        max_episode_steps=MAX_EPISODE_STEPS,
        disable_env_checker=True,  # as ManiSkill registers its envs
        additional_wrappers=(
            WrapperSpec(
                "MSTimeLimit",
                entry_point="mani_skill.utils.registration:TimeLimitWrapper",
                kwargs=dict(max_episode_steps=MAX_EPISODE_STEPS),
            ),
        ),
    )
