"""Turn layout assets into SAPIEN/ManiSkill actors; per-episode randomisation of each env."""

from embodied_envs.layout.placement.episode import EpisodeSampler
from embodied_envs.scene.builder import asset_density, build_asset_actor
from embodied_envs.scene.layout_scene import LayoutScene, load_layout_scene

__all__ = [
    "EpisodeSampler",
    "LayoutScene",
    "asset_density",
    "build_asset_actor",
    "load_layout_scene",
]
