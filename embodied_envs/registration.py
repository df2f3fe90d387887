"""``PickEmbodiedGen-v1`` in gymnasium's registry, without importing the simulator.

``import embodied_envs`` runs :func:`register`; the first ``gym.make`` imports the env
(ManiSkill, SAPIEN, torch) through the string entry points (``embodied_envs.envs.entry``), so
commands that never make an env (``layout``, ``splat``) start without them. This module
imports nothing of the package.
"""

from __future__ import annotations

import gymnasium as gym
from gymnasium.envs.registration import WrapperSpec

ENV_ID = "PickEmbodiedGen-v1"
# the id with its module, as datasets store it: gymnasium imports the plugin on make
ENTRY_ID = f"embodied_envs:{ENV_ID}"
CONTROL_FREQ = 50  # Hz, control steps per second (the simulation runs at twice this)
# 500 control steps = 10 s at CONTROL_FREQ: at the speeds every controller follows (joint
# targets at most 1 rad/s, solvers/follow.py) the expert's pick and single-mover place
# episodes take about 130-300 steps and two movers about 400 (tools/bench/bench_solver.py)
MAX_EPISODE_STEPS = 500


def register() -> None:
    """Add the env to gymnasium's registry with the wrappers ManiSkill's own envs get."""
    if ENV_ID in gym.registry:
        return
    gym.register(
        ENV_ID,
        entry_point="embodied_envs.envs.entry:make",
        vector_entry_point="embodied_envs.envs.entry:make_vec",
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
