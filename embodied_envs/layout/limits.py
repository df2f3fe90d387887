"""Every tunable limit of placement and goals, in one place.

:class:`PlacementLimits` rules where :func:`~embodied_envs.layout.placement.place` and the
per-episode sampler put objects; :class:`GoalRegion` where goals are drawn. The robot's reach
(distance band and heading cone) is defined once, in :class:`PlacementLimits`; goals use the
same reach, kept :attr:`GoalRegion.inset` away from its edges. Both are set through ``gym.make``
(``placement_limits=dict(...)``, ``goal_region=dict(...)``) or a config file.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PlacementLimits:
    """Tunable limits of placement (per configuration and per episode)."""

    reach_min: float = 0.20  # m, manipulated object centre to robot base, exclusive
    reach_max: float = 0.78  # m, exclusive: the Panda's top-down grasps fail from ~0.80 m
    max_heading_deg: float = 60.0  # manipulated objects within this angle of the robot heading
    hull_margin: float = 0.02  # m, the parent's top hull is shrunk by this much
    clearance: float = 0.01  # m, minimum gap between footprints
    robot_footprint: float = 0.12  # m, side of the robot base's square footprint
    top_band: float = 0.05  # m, vertices this close to the highest point form the top
    bottom_percentile: float = 1.0  # the context's lowest point is this percentile of its z
    floor_radius: float = 1.5  # m, FLOOR objects are placed within this distance of the origin
    max_attempts: int = 4096  # candidates per object before giving up
    batch: int = 96  # candidates drawn per vectorised batch
    episode_candidates: int = 128  # per object and env in each per-episode draw (one batch)


@dataclass(frozen=True)
class GoalRegion:
    """Where goals are drawn: above the table top, inside the robot's reach."""

    inset: float = 0.10  # m kept from both ends of the reach band (a held object reaches past)
    margin: float = 0.05  # m inside the table top's hull
    height: tuple[float, float] = (0.05, 0.25)  # m above the table top
    candidates: int = 64  # per env in each draw; the region fills >= ~20% of their box

    def distance_band(self, limits: PlacementLimits) -> tuple[float, float]:
        """Goal distances from the robot base: the reach band shrunk by ``inset`` at both ends."""
        return limits.reach_min + self.inset, limits.reach_max - self.inset
