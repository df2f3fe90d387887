"""Environments; importing this package registers ``PickEmbodiedGen-v1``."""

from embodied_envs.envs.pick_embodiedgen import PickEmbodiedGenEnv
from embodied_envs.envs.wrappers import CPUGymWrapper

__all__ = ["CPUGymWrapper", "PickEmbodiedGenEnv"]
