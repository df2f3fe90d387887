"""Environments; importing this package registers ``PickEmbodiedGen-v1``."""

from embodied_envs.envs.pick_embodiedgen import PickEmbodiedGenEnv

__all__ = ["PickEmbodiedGenEnv"]
