"""Every tunable limit of placement and goals, in one place.

:class:`PlacementLimits` rules where :func:`~embodied_envs.layout.placement.place` and the
per-episode sampler put objects; :class:`GoalRegion` where goals are drawn. The robot's reach
(distance band and heading cone) is defined once, in :class:`PlacementLimits`; goals use the
same reach, kept :attr:`GoalRegion.inset` away from its edges. Both are set through ``gym.make``
(``placement_limits=dict(...)``, ``goal_region=dict(...)``) or a config file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from embodied_envs.layout.errors import check_number
from embodied_envs.layout.placement.rules import array_module
from embodied_envs.robots import PANDA


@dataclass(frozen=True)
class PlacementLimits:
    """Tunable limits of placement (per configuration and per episode); each field's range
    follows its comment and is checked on construction."""

    # the reach band, m from the layout's robot spot, exclusive: reach_min in [0, 2), reach_max
    # in (reach_min, 2]; the env's default is its robot's (robots.py), these the Panda's
    reach_min: float = PANDA.reach[0]
    reach_max: float = PANDA.reach[1]
    # m in [-0.5, 0.5]: the band and the heading cone are centred this far ahead of the spot,
    # along its heading: the arm's pan axis, about which it turns (the env's default is its
    # robot's, robots.py; the Panda's 0: its axis stands over the spot)
    reach_origin: float = 0.0
    max_heading_deg: float = 60.0  # in (0, 180]: manipulated objects within this of the heading
    hull_margin: float = 0.02  # m in [0, 0.5], the parent's top hull is shrunk by this much
    clearance: float = 0.01  # m in [0, 0.5], minimum gap between footprints
    # m in [0, 0.5] or None: the least gap between a task's mover and any other object, room
    # for the hand's jaws beside it (the env's default is its robot's, robots.py; None: clearance)
    mover_clearance: float | None = None
    robot_footprint: float = 0.12  # m in (0, 1], side of the robot base's square footprint
    # the arm at rest, a box per link: ((x_lo, x_hi, y_lo, y_hi, z_lo), ...) m in the robot spot's
    # frame (x to the table), z_lo its lowest point above the table top; an object whose top
    # comes within rest_clearance of z_lo keeps rest_clearance from the box (``rest_links``; the
    # env's default is its robot's, robots.py, this the Panda's; None: the base's square only)
    rest_arm: tuple[tuple[float, float, float, float, float], ...] | None = PANDA.rest_arm
    rest_clearance: float = 0.02  # m in [0, 0.5]: the expert's 1 cm obstacle spheres and 1 cm
    top_band: float = 0.05  # m in (0, 0.5], vertices this close to the highest point: the top
    bottom_percentile: float = 1.0  # in [0, 100]: the context's lowest point, a z percentile
    floor_radius: float = 1.5  # m in (0, 20], FLOOR objects stand this close to the origin
    max_attempts: int = 4096  # in [1, 1e6], candidates per object before giving up
    batch: int = 96  # in [1, 1e5], candidates drawn per vectorised batch
    episode_candidates: int = 128  # in [1, 4096], per object and env in each episode's draw

    def gap(self, node: str, other: str | None, movers) -> float:
        """The least gap (m) between the footprints of ``node`` and ``other`` (None: the
        robot base, kept ``clearance`` from all): ``mover_clearance`` where either is one of
        the task's ``movers``, at least ``clearance``."""
        if self.mover_clearance is None or other is None:
            return self.clearance
        if node in movers or other in movers:
            return max(self.clearance, self.mover_clearance)
        return self.clearance

    def reach_centre(self, xy, yaw):
        """Where the reach band and heading cone are centred for a robot spot at ``xy (..., 2)``
        facing ``yaw (...)`` (numpy or torch arrays)."""
        if not self.reach_origin:
            return xy
        xp = array_module(yaw)
        return xy + self.reach_origin * xp.stack([xp.cos(yaw), xp.sin(yaw)], -1)

    def rest_links(self, top: float) -> tuple[int, ...]:
        """The rows of ``rest_arm`` an object whose top stands ``top`` m above the table keeps
        ``rest_clearance`` from: the links whose lowest point is within that of its top."""
        rows = self.rest_arm or ()
        return tuple(k for k, box in enumerate(rows) if top + self.rest_clearance > box[4])

    def rest_polygons(self) -> list[np.ndarray]:
        """``rest_arm``'s boxes as counter-clockwise ``(4, 2)`` polygons in the spot's frame."""
        return [np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)
                for x0, x1, y0, y1, _ in self.rest_arm or ()]  # fmt: skip

    def __post_init__(self):
        w = "placement_limits."
        if self.rest_arm is not None:
            rows = self.rest_arm
            if not isinstance(rows, tuple | list) or not all(
                isinstance(r, tuple | list) and len(r) == 5 for r in rows
            ):
                raise ValueError(
                    f"{w}rest_arm={rows!r} must be a list of [x_lo, x_hi, y_lo, y_hi, z_lo] "
                    "boxes in metres (the arm at rest, a row per link), or null"
                )
            for k, (x0, x1, y0, y1, z0) in enumerate(rows):
                check_number(f"{w}rest_arm[{k}][0]", x0, -2.0, 2.0)
                check_number(f"{w}rest_arm[{k}][1]", x1, float(x0), 2.0, lo_open=True)
                check_number(f"{w}rest_arm[{k}][2]", y0, -2.0, 2.0)
                check_number(f"{w}rest_arm[{k}][3]", y1, float(y0), 2.0, lo_open=True)
                check_number(f"{w}rest_arm[{k}][4]", z0, -2.0, 2.0)
            object.__setattr__(self, "rest_arm", tuple(tuple(float(v) for v in r) for r in rows))
        check_number(w + "rest_clearance", self.rest_clearance, 0.0, 0.5)
        check_number(w + "reach_min", self.reach_min, 0.0, 2.0, hi_open=True)
        check_number(w + "reach_max", self.reach_max, float(self.reach_min), 2.0, lo_open=True)
        check_number(w + "reach_origin", self.reach_origin, -0.5, 0.5)
        check_number(w + "max_heading_deg", self.max_heading_deg, 0.0, 180.0, lo_open=True)
        check_number(w + "hull_margin", self.hull_margin, 0.0, 0.5)
        check_number(w + "clearance", self.clearance, 0.0, 0.5)
        if self.mover_clearance is not None:
            check_number(w + "mover_clearance", self.mover_clearance, 0.0, 0.5)
        check_number(w + "robot_footprint", self.robot_footprint, 0.0, 1.0, lo_open=True)
        check_number(w + "top_band", self.top_band, 0.0, 0.5, lo_open=True)
        check_number(w + "bottom_percentile", self.bottom_percentile, 0.0, 100.0)
        check_number(w + "floor_radius", self.floor_radius, 0.0, 20.0, lo_open=True)
        check_number(w + "max_attempts", self.max_attempts, 1, 1_000_000, integer=True)
        check_number(w + "batch", self.batch, 1, 100_000, integer=True)
        check_number(w + "episode_candidates", self.episode_candidates, 1, 4096, integer=True)


@dataclass(frozen=True)
class GoalRegion:
    """Where goals are drawn: above the table top, inside the robot's reach."""

    # inset: m in [0, 1), kept from both ends of the reach band; height: m above the table top,
    # 0 <= low <= high <= 1. The env's defaults are its robot's (robots.py), these the Panda's
    inset: float = PANDA.goal_inset
    margin: float = 0.05  # m in [0, 0.5], inside the table top's hull
    height: tuple[float, float] = PANDA.goal_height
    candidates: int = 64  # in [1, 1e5], per env in each draw (the region fills >= ~20%)

    def __post_init__(self):
        check_number("goal_region.inset", self.inset, 0.0, 1.0, hi_open=True)
        check_number("goal_region.margin", self.margin, 0.0, 0.5)
        check_number("goal_region.candidates", self.candidates, 1, 100_000, integer=True)
        h = self.height
        if not isinstance(h, tuple | list) or len(h) != 2:
            raise ValueError(f"goal_region.height={h!r} must be [low, high] in metres")
        check_number("goal_region.height[0]", h[0], 0.0, 1.0)
        check_number("goal_region.height[1]", h[1], float(h[0]), 1.0)

    def check_reach(self, limits: PlacementLimits) -> None:
        """The goal band (the reach band shrunk by ``inset``) must be non-empty.

        Raises:
            ValueError: naming both settings.
        """
        lo, hi = self.distance_band(limits)
        if lo >= hi:
            raise ValueError(
                f"goal_region.inset={self.inset} leaves no goal band of the reach "
                f"[{limits.reach_min}, {limits.reach_max}] m ({lo:.3f} >= {hi:.3f}). Fix: a "
                "smaller inset, or a wider placement_limits reach"
            )

    def distance_band(self, limits: PlacementLimits) -> tuple[float, float]:
        """Goal distances from the robot base: the reach band shrunk by ``inset`` at both ends."""
        return limits.reach_min + self.inset, limits.reach_max - self.inset
