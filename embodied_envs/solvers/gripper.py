"""The Panda's parallel-jaw gripper as boxes, and how far points stay outside them.

The grasp synthesis (``grasps.py``) and the check of annotated grasps (``annotated.py``) measure
with these: a grasp is a TCP position with a closing (TCP y) and an approach (TCP z) direction,
as ManiSkill's ``panda_hand_tcp`` frame has them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GripperModel:
    """The Panda hand as boxes in the ``panda_hand_tcp`` frame (m), fingers open: the
    bounding boxes of ManiSkill's Panda finger and hand collision meshes.

    ``x``: across the fingers' width; ``y``: the closing direction; ``z``: the approach (the
    TCP sits between the fingertips; the palm is behind it, at negative z).
    """

    opening: float = 0.08  # finger gap when open
    finger_width: float = 0.022  # along x
    finger_thickness: float = 0.026  # along y, outside the gap
    finger_tip: float = 0.009  # the fingertips reach this far past the TCP (+z)
    finger_length: float = 0.054  # from the tips back to the palm
    palm_size: tuple[float, float] = (0.064, 0.208)  # x, y extents
    palm_z: tuple[float, float] = (-0.129, -0.037)  # z extent

    def boxes(self, sweep: float = 0.0, opening: np.ndarray | float | None = None) -> np.ndarray:
        """``(..., 3, 2, 3)`` boxes (min corner, max corner): two fingers and the palm, each
        stretched back along -z by ``sweep`` (the way in from the pre-grasp), the fingers
        ``opening`` apart (default: fully open; an array gives one set per opening)."""
        gap = np.asarray(self.opening if opening is None else opening, dtype=np.float64)
        half = gap[..., None] / 2
        t, w = self.finger_thickness, self.finger_width / 2
        z_top, z_base = self.finger_tip, self.finger_tip - self.finger_length
        (px, py), (z0, z1) = self.palm_size, self.palm_z
        one = np.ones_like(half)
        left = np.stack(
            [
                np.concatenate([-w * one, half, (z_base - sweep) * one], -1),
                np.concatenate([w * one, half + t, z_top * one], -1),
            ],
            -2,
        )
        right = np.stack(
            [
                np.concatenate([-w * one, -half - t, (z_base - sweep) * one], -1),
                np.concatenate([w * one, -half, z_top * one], -1),
            ],
            -2,
        )
        palm = np.broadcast_to(
            np.array([[-px / 2, -py / 2, z0 - sweep], [px / 2, py / 2, z1]]), left.shape
        )
        return np.stack([left, right, palm], -3)  # fmt: skip

    def between(self, points: np.ndarray) -> np.ndarray:
        """Which of ``points`` (..., 3; the grasp frame) stand between the jaws: within the
        fingers' width and their length back from the tips, at any gap; every point where
        none does (the jaws close on the whole object)."""
        x, z = points[..., 0], points[..., 2]
        inside = (np.abs(x) <= self.finger_width / 2) & (z <= self.finger_tip)
        inside &= z >= self.finger_tip - self.finger_length
        return inside if inside.any() else np.ones_like(inside)


def to_tcp(points: np.ndarray, centre, closing, approach) -> np.ndarray:
    """World (or object) points in the TCP frames of grasps: ``(g, p, 3)``."""
    ortho = np.cross(closing, approach)
    rot = np.stack([ortho, closing, approach], -1)  # (g, 3, 3): columns x, y, z
    return np.einsum("gpk,gkj->gpj", points[None] - centre[:, None], rot)


def box_clearance(
    points: np.ndarray,
    centre: np.ndarray,
    closing: np.ndarray,
    approach: np.ndarray,
    boxes: np.ndarray,
    bound: float | None = None,
) -> np.ndarray:
    """``(g,)``: how far ``points (p, 3)`` stay outside the gripper boxes of each grasp (TCP
    at ``centre``, axes from ``closing`` and ``approach``, all ``(g, 3)`` in the points' frame;
    ``boxes (g, b, 2, 3)`` in each TCP frame): the least over points and boxes of the largest
    per-axis distance outside (a point lies in a box grown by ``m`` exactly when its clearance
    is at most ``m``; inside, it is negative; no points: infinite).

    With ``bound`` (for points mostly far from the grasps: the other objects), exact up to
    ``bound`` and some value above it for a grasp whose clearance is larger: a point within
    ``m`` of a box lies in the box's bounding box (in the points' frame) grown by
    ``m * sqrt(3)``, so only the (grasp, point) pairs there are measured and a far point costs
    one comparison. Without, every pair is measured (the object's own points, near them all).
    """
    gap = np.full(len(centre), np.inf, dtype=np.float32)
    if not len(points) or not len(centre):
        return gap
    if bound is None:
        return point_clearance(points, centre, closing, approach, boxes).min(1)
    rot = tcp_axes(closing, approach)
    world = box_corners(centre, rot, boxes)  # (g, 8 b, 3)
    grow = max(bound, 0.0) * np.sqrt(3.0)
    lo, hi = world.min(1) - grow, world.max(1) + grow
    near = points[((points >= lo.min(0)) & (points <= hi.max(0))).all(1)]
    g, k = np.nonzero(((near[None] >= lo[:, None]) & (near[None] <= hi[:, None])).all(-1))
    if len(g):  # g ascends: each grasp's pairs are one run
        out = pair_clearance(near, centre, rot, boxes, g, k)
        starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
        gap[g[starts]] = np.minimum.reduceat(out, starts)
    return gap


def point_clearance(
    points: np.ndarray,
    centre: np.ndarray,
    closing: np.ndarray,
    approach: np.ndarray,
    boxes: np.ndarray,
) -> np.ndarray:
    """``(g, p)``: how far each point stays outside each grasp's gripper boxes (the least over
    the boxes; arguments as :func:`box_clearance`'s)."""
    local = to_tcp(points, centre, closing, approach).astype(np.float32)
    return _clearance(local, boxes, None)


def pair_clearance(points, centre, rot, boxes, g, k) -> np.ndarray:
    """Per pair j, how far point ``k[j]`` stays outside the boxes of grasp ``g[j]`` (``rot``
    from :func:`tcp_axes`)."""
    local = np.einsum("pk,pjk->pj", points[k] - centre[g], rot[g]).astype(np.float32)
    return _clearance(local, boxes, g)


def _clearance(local: np.ndarray, boxes: np.ndarray, rows: np.ndarray | None) -> np.ndarray:
    """:func:`outside` of float32 points ``local`` (``(g, p, 3)`` with ``rows`` None, each
    grasp's points; else ``(n, 3)``, point j in grasp ``rows[j]``'s frame) and each grasp's
    ``boxes (g, b, 2, 3)``, the least over the boxes: the same float32 values, one box bound
    at a time. A bound the grasps share (every box's x and z, the palm's y: only the fingers'
    gap differs) is one number, not an array gathered per point: a million pairs cost 9x less
    memory traffic than gathering every box of every pair."""
    bounds = boxes.astype(np.float32)
    axes = np.moveaxis(local, -1, 0).copy()  # each axis's values contiguous
    best = None
    for b in range(bounds.shape[1]):
        worst = None
        for a, x in enumerate(axes):
            lo, hi = (_bound(bounds[:, b, s, a], rows, local.ndim) for s in (0, 1))
            far = np.maximum(lo - x, x - hi)
            worst = far if worst is None else np.maximum(worst, far)
        best = worst if best is None else np.minimum(best, worst)
    return best


def _bound(column: np.ndarray, rows: np.ndarray | None, ndim: int):
    """One box bound per grasp ``column (g,)`` for :func:`_clearance`'s points: a float32
    scalar when every grasp has the same, else per point (``rows``) or per grasp."""
    if len(column) and (column == column[0]).all():
        return column[0]
    if rows is not None:
        return column[rows]
    return column.reshape(-1, *[1] * (ndim - 2))


def tcp_axes(closing: np.ndarray, approach: np.ndarray) -> np.ndarray:
    """``(g, 3, 3)``: rows the TCP's x, y (closing) and z (approach) axes."""
    return np.stack([np.cross(closing, approach), closing, approach], 1)


def box_corners(centre: np.ndarray, rot: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """``(g, 8 b, 3)``: the corners of each grasp's boxes ``(g, b, 2, 3)`` (TCP frames) in the
    frame of ``centre (g, 3)`` and ``rot`` (:func:`tcp_axes`)."""
    corners = np.stack(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij"), -1).reshape(-1, 3)
    local = np.where(corners[None, None], boxes[:, :, 1][:, :, None], boxes[:, :, 0][:, :, None])
    return centre[:, None] + np.einsum("gpk,gkj->gpj", local.reshape(len(boxes), -1, 3), rot)


def outside(x: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """How far points ``x (..., 3)`` lie outside boxes ``(..., 2, 3)`` (broadcast), per axis
    the largest (negative inside), in float32."""
    x = x.astype(np.float32)
    lo, hi = boxes[..., 0, :].astype(np.float32), boxes[..., 1, :].astype(np.float32)
    return np.maximum(lo - x, x - hi).max(-1)
