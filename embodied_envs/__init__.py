"""embodied_envs: layout-driven pick-and-place environments for ManiSkill 3.

Importing the package registers ``PickEmbodiedGen-v1`` for ``gym.make``; the simulator (ManiSkill,
SAPIEN, torch) is imported by the first ``gym.make`` or the first use of
:class:`PickEmbodiedGenEnv`, not by ``import embodied_envs``.
"""

from embodied_envs.registration import ENV_ID, register

register()

__all__ = ["ENV_ID", "PickEmbodiedGenEnv"]
__version__ = "0.1.0"


def __getattr__(name: str):
    if name == "PickEmbodiedGenEnv":
        # the simulator loads on first use, not on `import embodied_envs`
        from embodied_envs.envs import PickEmbodiedGenEnv

        return PickEmbodiedGenEnv
    raise AttributeError(f"module 'embodied_envs' has no attribute {name!r}")
