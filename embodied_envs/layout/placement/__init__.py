"""Placement: where the table, the robot and every object stand, per configuration and per episode.

- ``limits.py``: every tunable limit (:class:`PlacementLimits`, :class:`GoalRegion`);
- ``rules.py``: the placement rules, defined once, on numpy or torch arrays;
- ``geometry.py``: footprints, tops and bottoms read from assets, plane polygons;
- ``tree.py``: the one walk of the support tree both placements follow;
- ``configuration.py``: :func:`place`, a seeded placement of every node (per configuration);
- ``episode.py``: ``EpisodeSampler``, the per-episode object starts and goals over a batch of
  envs (with ``batch.py``, its arrays); it needs torch, so it is imported from its module:
  ``from embodied_envs.layout.placement.episode import EpisodeSampler``;
- ``file_poses.py``: the checks of a layout file's own poses, and the floor's height.
"""

from embodied_envs.layout.placement.configuration import derive_seed, place
from embodied_envs.layout.placement.file_poses import check_file_poses, floor_height
from embodied_envs.layout.placement.geometry import (
    local_top,
    node_footprint,
    node_geometry,
    polygon_area,
    square,
    top_surface,
    world_vertices,
)
from embodied_envs.layout.placement.limits import GoalRegion, PlacementLimits
from embodied_envs.layout.placement.tree import support_order, support_tree

__all__ = [
    "GoalRegion",
    "PlacementLimits",
    "check_file_poses",
    "derive_seed",
    "floor_height",
    "local_top",
    "node_footprint",
    "node_geometry",
    "place",
    "polygon_area",
    "square",
    "support_order",
    "support_tree",
    "top_surface",
    "world_vertices",
]
