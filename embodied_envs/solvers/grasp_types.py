"""The value types of grasp synthesis (``grasps.py``): its numbers, an asset's grasps and the
error for an asset the gripper takes nowhere; shared by the synthesis, the annotations merged
into it (``annotated.py``) and the planar hands' grasps (``planar.py``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class GraspError(RuntimeError):
    """An asset the gripper cannot take anywhere (names the asset and why)."""


@dataclass(frozen=True)
class GraspConfig:
    """The numbers of grasp synthesis."""

    surface_samples: int = 1500  # points sampled on the outer surface
    check_points: int = 3000  # object points the gripper boxes are checked against
    cone_deg: float = 15.0  # friction cone half-angle kept (mu 0.6 allows 31)
    tilted_cone_deg: float = 0.0  # where no pair is within cone_deg, pairs on rays tilted from
    # the inward normal, both normals within this of the closing line (a triangular prism
    # lying: its faces 120 degrees apart, each 30 off the line across; 0: none). The solver
    # sets it from the jaws' and the object's friction (``GraspChoice.asset_config``)
    tilted_too: bool = False  # the tilted pairs besides the others (a planar arm that takes
    # none of the others: a hex pencil lying on a face, its pairs closing 30 degrees off
    # vertical or vertically)
    width_margin: float = 0.012  # m, contact width at most opening - margin
    min_width: float = 0.004  # m
    approaches: int = 12  # approach directions around each closing line
    max_tilt_deg: float = 65.0  # approach at most this far from straight down (posed)
    sweep: float = 0.08  # m, approach distance checked (the solver's pre-grasp offset)
    clearance: float = 0.002  # m, gripper boxes keep this far from the table top
    margin: float = 0.006  # m, gripper boxes keep this far from the object (arm precision)
    wide_margin: float = 0.015  # m, grasps this clear of the object (posed: of the other
    # objects too) rank first
    obstacle_margin: float = 0.003  # m, posed gripper boxes keep this far from other objects
    posed_scan: int = 512  # posed grasps searched for roomy ones (further only for clear ones)
    max_pairs: int = 500  # contact pairs kept (a seeded sample over the surface)
    preshape: float = 0.015  # m per side: the fingers open to the contact width plus this


@dataclass(frozen=True)
class Grasps:
    """Grasps of one asset in its own frame, best first.

    Attributes:
        centre: ``(n, 3)`` TCP positions.
        closing: ``(n, 3)`` unit closing directions (TCP y).
        approach: ``(n, 3)`` unit approach directions (TCP z).
        width: ``(n,)`` contact width.
        opening: ``(n,)`` finger gap to approach with (pre-shaped: width plus margin).
        score: ``(n,)`` rank before posing (lower is better).
        com: ``(3,)`` the centre of mass used.
        points: ``(m, 3)`` surface points of the object the gripper boxes were checked against.
        planes: per convex part, its face planes ``(f, 4)``: ``n . x + d <= 0`` inside.
    """

    centre: np.ndarray
    closing: np.ndarray
    approach: np.ndarray
    width: np.ndarray
    opening: np.ndarray
    score: np.ndarray
    com: np.ndarray
    points: np.ndarray
    planes: tuple[np.ndarray, ...]
    annotated: np.ndarray | None = None  # (n,) bool: from the asset's affordance_annot.json

    def __len__(self) -> int:
        return len(self.centre)
