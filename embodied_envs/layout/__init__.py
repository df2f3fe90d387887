"""Layout files: schema, poses, asset specs and placement."""

from embodied_envs.layout.assets import AssetGeometry, AssetSpec, asset_geometry, parse_urdf
from embodied_envs.layout.errors import LayoutError, PlacementError
from embodied_envs.layout.loader import check_asset_files, load_layout
from embodied_envs.layout.placement.limits import GoalRegion, PlacementLimits
from embodied_envs.layout.pose import LayoutPose
from embodied_envs.layout.schema import LayoutInfo

__all__ = [
    "AssetGeometry",
    "AssetSpec",
    "GoalRegion",
    "LayoutError",
    "LayoutInfo",
    "LayoutPose",
    "PlacementError",
    "PlacementLimits",
    "asset_geometry",
    "check_asset_files",
    "load_layout",
    "parse_urdf",
]
