"""embodied_envs: layout-driven pick-and-place environments for ManiSkill 3.

Importing the package registers ``PickEmbodiedGen-v1`` with ManiSkill and gymnasium.
"""

from embodied_envs.envs import PickEmbodiedGenEnv

__all__ = ["PickEmbodiedGenEnv"]
__version__ = "0.1.0"
