"""``place``: every mover ends in or on the receptacle (another object, or the table).

**Success**, for every mover: at rest (``state.REST_LIN``, ``REST_ANG``), released (not
grasped; fingers open or the hand away, ``state.released``) and in its pose:

- its centre over the receptacle's footprint (in the receptacle's frame);
- a receptacle object: its lowest point off the table (``OFF_TABLE``: it rests on the
  receptacle, not leaning on its outer wall from the table), and

  - "on": at most ``TOUCH`` above the receptacle's top (not hovering);
  - "in": more than ``TOUCH`` below the receptacle's top (its rim), or half its depth where
    that is less (its floor, the lowest surface under its opening, less than ``2 TOUCH`` under
    the rim: a tray): it stands or lies on the inner floor or walls, however tall it is, not
    on the rim (a mover on the rim touches the rim); a receptacle whose floor lies less than
    ``MIN_DEPTH`` under its top has no inside;

  or resting on another mover in its pose (:func:`stacked`);
- the table: its lowest point within ``TOUCH`` of the top.

Held above the receptacle, dropped and still bouncing, next to it on the table, leaning on
its side, standing on its rim (for "in"): not success. **Reward**: ``state.staged_dense``,
``MAX_REWARD`` at success only; a mover let go over the footprint with its lowest point within
``state.DROP_GAP`` of the receptacle's top (or the table's) keeps its carry credit while it
falls into its pose. :func:`conditions` names each condition, for the summaries' reasons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from embodied_envs.envs.tasks.state import (
    DROP_GAP,
    OFF_TABLE,
    STAGES,
    TaskState,
    every,
    norm,
    number_set,
    released_and_still,
    some,
    staged_dense,
    staged_evaluate,
    total,
)
from embodied_envs.layout.placement.rules import array_module

TOUCH = 0.01  # m: a lowest point this close above a support surface touches it
MIN_DEPTH = 0.005  # m: a floor less deep under the top is no inside (resting contacts sink ~1 mm)
MAX_REWARD = STAGES  # the dense reward on success (its staged reward's maximum)
EDGE_TOLERANCE = 1e-9  # m: a centre this close outside the footprint's edge is over it
numbers = number_set(GAPS=(TOUCH, DROP_GAP), TOUCH=TOUCH, HALF=0.5)


@dataclass(frozen=True)
class Bounds:
    """What :func:`in_pose` compares with that stays the same over a configuration, per env
    (``TaskReader`` makes it once; ``TaskState.bounds``), from the state's receptacle fields.

    Attributes:
        normals: ``(n, 1, E, 2)``, ``offsets``: ``(n, 1, E)``: the footprint's half planes,
            the offsets less ``EDGE_TOLERANCE``.
        low: ``(n, 1)`` the lowest a mover's lowest point rests on a receptacle object
            (``OFF_TABLE`` over the table's top); ``-inf`` where the receptacle is the table.
        high: ``(n, 1)`` the highest a mover's lowest point rests above the support's top:
            ``TOUCH``; for "in" on an object, ``-TOUCH`` or minus half its depth, whichever is
            nearer the top (``-inf`` where it has none: ``MIN_DEPTH``).
    """

    normals: Any
    offsets: Any
    low: Any
    high: Any

    @classmethod
    def of(cls, footprint: tuple, rim, floor, is_in, rec_is_table, table_z) -> Bounds:
        """From those fields of a :class:`TaskState` (numpy arrays or tensors)."""
        (normals, offsets), xp = footprint, array_module(rim)
        low = xp.where(rec_is_table, -math.inf, table_z + OFF_TABLE)
        depth = rim - floor
        below = xp.minimum(depth / 2, xp.full_like(depth, TOUCH))  # under the rim, at least
        inside = xp.where(depth >= MIN_DEPTH, -below, -math.inf)
        high = xp.where(is_in & ~rec_is_table, inside, TOUCH)
        return cls(normals[:, None], offsets[:, None] - EDGE_TOLERANCE, low[:, None],
                   high[:, None])  # fmt: skip


def _bounds(s: TaskState) -> Bounds:
    if s.bounds is not None:
        return s.bounds
    return Bounds.of(s.footprint, s.rim, s.floor, s.is_in, s.rec_is_table, s.table_z)


def _parts(s: TaskState) -> dict:
    """``(n, m)`` each, the parts of a mover's pose: ``over`` the footprint, ``off`` the table
    (or on it: the table receptacle), ``under`` the height its lowest point may rest at
    (:class:`Bounds`' ``high``), ``near`` (within ``DROP_GAP`` of the support's top)."""
    xp, c, b = s.xp, numbers(s.bottom), _bounds(s)
    xy = s.in_receptacle[..., :2]
    over = every(total(xy[:, :, None, :] * b.normals) >= b.offsets)
    top = xp.where(s.rec_is_table, s.table_z, s.rec_top)[:, None]  # the support's height
    return dict(over=over, off=s.bottom >= b.low, under=s.bottom <= top + b.high,
                near=s.bottom <= top + c.GAPS[1])  # fmt: skip


def stacked(s: TaskState, pose, free):
    """``(n, m)``: ``pose`` (each mover resting in its pose), and each mover ``free`` (over the
    footprint, off the table) resting on a mover in its pose: its lowest point in the upper
    half of that one's height, at most ``TOUCH`` above its top, its centre within that one's
    reach (the farthest of its collision points from its centre) horizontally. Chains (a mover
    on one on another) count, to the number of movers. The movers' ``top`` and ``reach``
    unread (``None``: one mover): ``pose``."""
    if s.top is None or pose.shape[1] < 2:
        return pose
    if isinstance(pose, np.ndarray) and not some(free & ~pose, None):
        return pose  # no mover could rest on another (numpy: on tensors a branch on values
        # would wait for the GPU): most steps, the movers on the table or in their pose
    c = numbers(s.bottom)
    bottom, top = s.bottom[:, :, None], s.top[:, None, :]  # (n, j, k): j on k
    mid = (s.bottom + s.top)[:, None, :] * c.HALF
    gap = (s.movers[:, :, None, :] - s.movers[:, None, :, :])[..., :2]
    on = (bottom >= mid) & (bottom <= top + c.TOUCH) & (norm(gap) <= s.reach[:, None, :])
    for _ in range(pose.shape[1] - 1):
        pose = pose | (free & some(on & pose[:, None, :], 2))
    return pose


def in_pose(s: TaskState):
    """``(n, m)`` each: each mover rests where the task wants it (released or not); near it
    (over the footprint, lowest point within ``DROP_GAP`` of the surface there)."""
    p = _parts(s)
    free = p["over"] & p["off"]
    return stacked(s, free & p["under"], free), p["over"] & p["near"]


def conditions(s: TaskState, info: dict) -> dict:
    """Each condition of success, ``(n, m)`` bool per mover (true: met; where it does not apply,
    true), keyed by the words that say it is not met (``info``: :func:`evaluate`'s)."""
    p, pose = _parts(s), info["pose"]
    table, is_in = s.rec_is_table[:, None], s.is_in[:, None]
    placed = pose | ~p["over"] | ~p["off"]  # the support's rule, where it is the one unmet
    return {
        **released_and_still(info),
        "not over the receptacle": p["over"],
        "touching the table": p["off"],
        "not resting on its floor": placed | table | ~is_in,
        "not resting on its top": placed | table | is_in,
        "not on the table": placed | ~table,
    }


def evaluate(s: TaskState) -> dict:
    return staged_evaluate(s, *in_pose(s))


def reward(s: TaskState, info: dict):
    return staged_dense(s, info, MAX_REWARD)
