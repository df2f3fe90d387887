"""Grasps a planar hand can make: an arm of five joints (base turn, three pitches, wrist roll;
``robots.Hand.planar``) points its hand only within its vertical plane through the base joint, and
turns it freely about the approach (the wrist roll).

So a grasp's approach is fixed by its closing line: perpendicular to the closing direction and
within the plane, ``closing x across`` (``across`` the plane's normal); or, at the hand's
``planar_tilts``, the closing turned square to the approach as long as it stays within the
friction cone of the pair's line (a line across the plane: any tilt). Of the asset's
antipodal contact pairs (``grasps.py``: the same pairs, not the approaches it turned about each
line for a six- or seven-joint arm), those whose approach is tilted from straight down toward
the far side by no more than the arm reaches are posed with that approach and checked as the
synthesised grasps are: the open hand swept along the approach clear of the object, the table
and the other objects. Ranked as ``grasps.posed_grasps`` ranks (roomy first, the grip near the
centre of mass, the width mid-opening), then by the tilt's distance from the hand's first
``planar_tilts`` (the approach its arm reaches at most distances).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from embodied_envs.solvers.grasp_types import GraspConfig, Grasps
from embodied_envs.solvers.grasps import posed_clearance
from embodied_envs.solvers.gripper import GripperModel, box_clearance, box_corners, tcp_axes
from embodied_envs.solvers.screw import SCREW_END_TOLERANCE

DOWN = np.array([0.0, 0.0, -1.0])
BACK_TILT = np.deg2rad(5.0)  # rad: an approach tilted back toward the base by at most this
# (a closing line nearly along the plane) still counts as straight down
EPS = 1e-4  # m: rounding kept off the clearance checks
REACH_STEP = 15.0  # deg: the reach table's resolution (a tilt this far out ranks one step lower)
TIP_HOLD = -0.002  # m: a grasp held back along its approach keeps its contacts at least 2 mm
# inside the fingers' tips


def table_gap(cfg: GraspConfig) -> float:
    """How far (m) the open fingers of a grasp held back from the table stay above it: the
    grasps' clearance of the support surface and of the obstacle points (the table's own
    surface points are obstacles too)."""
    return cfg.clearance + cfg.obstacle_margin + EPS


def tip_floor(cfg: GraspConfig, height: float) -> float:
    """How far (m) above the table the open fingers of a grasp held back from it stay, for
    an object ``height`` tall: ``table_gap``; where that leaves the tips less than half its
    height (a flat object), the five-joint arm's descent error (its screw walk ends up to
    ``SCREW_END_TOLERANCE`` off), at least the grasps' clearance of the support surface. At 5
    mm the Koch's tips reached the top 3 mm of a 0.8 cm domino and its moving jaw's slanted
    tip rode over the domino's edge (held-out seeds 0 and 2: three misses each)."""
    gap = table_gap(cfg)
    if height - gap >= height / 2:
        return gap
    return max(cfg.clearance, SCREW_END_TOLERANCE) + EPS


def off_reach(tilt: np.ndarray, reach: tuple[float, float]) -> np.ndarray:
    """A rank penalty for approach tilts (rad) outside the arm's reach (deg, lowest and
    highest): 1 per ``REACH_STEP`` outside (0 inside: any tilt the arm reaches will do)."""
    lo, hi = np.deg2rad(reach)
    return np.maximum(np.maximum(lo - tilt, tilt - hi), 0.0) / np.deg2rad(REACH_STEP)


def contact_pairs(grasps: Grasps) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The asset's distinct antipodal pairs in its frame: centres, closing lines (one sign),
    widths. ``grasps`` repeats each pair once per approach it turned about the line."""
    sign = np.where(grasps.closing[np.arange(len(grasps)),
                                   np.abs(grasps.closing).argmax(1)] < 0, -1.0, 1.0)  # fmt: skip
    closing = grasps.closing * sign[:, None]
    key = np.round(np.concatenate([grasps.centre, closing], 1), 4)
    _, first = np.unique(key, axis=0, return_index=True)
    first = np.sort(first)  # the best-ranked row of each pair
    return grasps.centre[first], closing[first], grasps.width[first]


def lowest_centre(
    gripper: GripperModel, closing: np.ndarray, approach: np.ndarray, opening: float
) -> np.ndarray:
    """``(n,)``: how far below the grasp centre the open fingers reach (m) when the hand
    approaches along ``approach (n, 3)`` closing along ``closing (n, 3)``: a grasp centre
    lower than the support surface plus this puts a finger into it."""
    boxes = np.broadcast_to(gripper.boxes(0.0, opening)[:2], (len(closing), 2, 2, 3))
    corners = box_corners(np.zeros((len(closing), 3)), tcp_axes(closing, approach), boxes)
    return -corners[..., 2].min(1)


def planar_grasps(
    grasps: Grasps,
    object_to_world: np.ndarray,
    base_xy: np.ndarray,
    support_z: float,
    obstacles: np.ndarray | None,
    tilts: tuple[float, ...],
    reach: Callable,
    cfg: GraspConfig,
    gripper: GripperModel,
    limit: int,
) -> list[tuple]:
    """A planar hand's grasps of an object posed at ``object_to_world`` (see the module's
    docstring), best first, at most ``limit``: world ``(centre, closing, approach, opening)``.
    ``base_xy``: the arm's base in the world; ``tilts``: the approach tilts (deg) from
    straight down toward the far side tried for a closing line across the plane; ``reach``:
    the tilts (deg, lowest and highest) its arm reaches per grasp centre,
    ``reach(xy (n, 2)) -> (lo, hi)`` (``robots.Hand.tilts_at`` at each centre's distance: an
    L block's far leg lay 2 cm further out than its centre, where only tilted grasps reach):
    grasps tilted outside rank after the others, by how far; an empty list when none passes.
    The ``limit`` best, then each with its closing the other way (the same grasp at the wrist
    roll's other half-turn)."""
    rot, t = object_to_world[:3, :3], object_to_world[:3, 3]
    centre_o, closing_o, width = contact_pairs(grasps)
    centre, closing = centre_o @ rot.T + t, closing_o @ rot.T
    out = centre[:, :2] - np.asarray(base_xy)[None, :2]
    out = np.concatenate([out / np.maximum(np.linalg.norm(out, axis=1, keepdims=True), 1e-9),
                          np.zeros((len(out), 1))], 1)  # fmt: skip
    across = np.stack([-out[:, 1], out[:, 0], np.zeros(len(out))], 1)
    rows, approach, tilt = [], [], []
    cone = np.sin(np.deg2rad(cfg.cone_deg))
    for a in np.deg2rad(tilts):  # each of the hand's tilts, closing within the friction cone
        at = np.cos(a) * DOWN[None] + np.sin(a) * out  # of the pair's line (a faceted body's
        k = np.flatnonzero(np.abs(np.einsum("ij,ij->i", closing, at)) <= cone)  # lines lean)
        rows.append(k)
        approach.append(at[k])
        tilt.append(np.full(len(k), a))
    # and the one approach in the plane square to the closing line (where it is not across)
    k = np.flatnonzero(np.linalg.norm(np.cross(closing, across), axis=1) > cone)
    a = np.cross(closing[k], across[k])
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    a[a[:, 2] > 0] *= -1.0
    rows.append(k)
    approach.append(a)
    tilt.append(np.arctan2(np.einsum("ij,ij->i", a, out[k]), -a[:, 2]))
    rows, approach, tilt = np.concatenate(rows), np.concatenate(approach), np.concatenate(tilt)
    lo, hi = reach(centre[rows, :2])
    reach_deg = np.stack(np.broadcast_arrays(lo, hi, tilt)[:2], 1)  # per row: (lo, hi) deg
    highest = np.deg2rad(np.maximum(max(tilts), reach_deg[:, 1])) + 1e-9
    keep = (tilt >= -BACK_TILT) & (tilt <= highest)
    rows, approach, tilt, reach_deg = rows[keep], approach[keep], tilt[keep], reach_deg[keep]
    if not len(rows):
        return []
    lean = np.abs(np.einsum("ij,ij->i", closing[rows], approach))  # sine of the turn
    close = closing[rows] - np.einsum("ij,ij->i", closing[rows], approach)[:, None] * approach
    close /= np.linalg.norm(close, axis=1, keepdims=True)
    opening = np.minimum(gripper.opening, width[rows] + 2 * cfg.preshape)
    # held back along the approach as far as the open fingers need to clear the table (the
    # jaws' faces, not their tips, then meet the contacts: a short object, a lying marker;
    # a flat one's tips as low as the descent allows)
    low = lowest_centre(gripper, close, approach, gripper.opening)
    height = float((grasps.points @ rot.T + t)[:, 2].max()) - support_z
    rise = support_z + tip_floor(cfg, height) + low - centre[rows, 2]
    back = np.maximum(rise, 0.0) / np.maximum(-approach[:, 2], 1e-9)
    within = back <= gripper.finger_tip + TIP_HOLD
    rows, approach, tilt, close, opening, back, lean, reach_deg = (
        x[within] for x in (rows, approach, tilt, close, opening, back, lean, reach_deg))
    at = centre[rows] - back[:, None] * approach
    at_o = (at - t) @ rot
    boxes = gripper.boxes(cfg.sweep, opening)
    # the object's own points: the open hand swept in along the approach holds none
    gap = box_clearance(grasps.points, at_o, close @ rot, approach @ rot, boxes)
    ok = gap > cfg.margin
    if not ok.any():
        return []
    clear, roomy = posed_clearance(at[ok], close[ok], approach[ok], boxes[ok],
                                   support_z, obstacles, cfg)  # fmt: skip
    keep = np.flatnonzero(ok)[clear]
    roomy = roomy[clear] & (gap[keep] > cfg.wide_margin)
    score = (
        np.linalg.norm(centre_o[rows[keep]] - grasps.com, axis=1) / 0.05
        + np.abs(width[rows[keep]] - gripper.opening / 2) / 0.08
        + off_reach(tilt[keep], reach_deg[keep].T) + 2.0 * ~roomy
        + lean[keep] / cone  # the closing turned off the pair's line: up to one step
    )
    best = keep[np.argsort(score, kind="stable")][:limit]
    # then each the other way the wrist roll takes it (its range may hold only one: the Koch
    # took a flat eraser 0.24 m out closing one way only, IK failing the other)
    return [(at[j], way * close[j], approach[j], float(opening[j])) for way in (1.0, -1.0)
            for j in best]  # fmt: skip
