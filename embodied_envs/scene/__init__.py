"""Turn layout assets into SAPIEN/ManiSkill actors."""

from embodied_envs.scene.builder import asset_density, build_asset_actor
from embodied_envs.scene.layout_scene import (
    GoalRegion,
    LayoutScene,
    goal_candidates,
    load_layout_scene,
)

__all__ = [
    "GoalRegion",
    "LayoutScene",
    "asset_density",
    "build_asset_actor",
    "goal_candidates",
    "load_layout_scene",
]
