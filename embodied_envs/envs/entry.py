"""gymnasium's entry points of ``PickEmbodiedGen-v1`` (named in ``registration.register``):
importing this module registers the env with ManiSkill."""

from __future__ import annotations

from mani_skill.utils.registration import make as make_maniskill
from mani_skill.utils.registration import make_vec as make_vec_maniskill

from embodied_envs.envs.pick_embodiedgen import PickEmbodiedGenEnv
from embodied_envs.registration import ENV_ID


def make(**kwargs):
    """``gym.make``: ManiSkill's ``make``, with ``config`` files merged under the keywords."""
    return make_maniskill(ENV_ID, **PickEmbodiedGenEnv.env_kwargs(**kwargs))


def make_vec(**kwargs):
    """``gym.make_vec``: ManiSkill's batched vector env over ``num_envs``."""
    return make_vec_maniskill(ENV_ID, **kwargs)
