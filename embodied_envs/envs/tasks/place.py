"""``place``: every mover ends in or on the receptacle (another object, or the table).

**Success**, for every mover: at rest (``state.REST_LIN``, ``REST_ANG``), released (not
grasped; fingers open or the hand away, ``state.released``) and in its pose:

- its centre over the receptacle's footprint (in the receptacle's frame);
- a receptacle object: its lowest point off the table (``OFF_TABLE``: it rests on the
  receptacle, not leaning on its outer wall from the table) and at most ``TOUCH`` above the
  receptacle's top (not hovering); for "in", its centre below the receptacle's rim;
- the table: its lowest point within ``TOUCH`` of the top.

Held above the receptacle, dropped and still bouncing, next to it on the table, leaning on
its side: not success. **Reward**: ``state.staged_dense``, ``MAX_REWARD`` at success only; a
mover let go over the footprint with its lowest point within ``state.DROP_GAP`` of the
receptacle's top (or the table's) keeps its carry credit while it falls into its pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from embodied_envs.envs.tasks.state import (
    DROP_GAP,
    OFF_TABLE,
    STAGES,
    TaskState,
    every,
    number_set,
    staged_dense,
    staged_evaluate,
    total,
)
from embodied_envs.layout.placement.rules import array_module

TOUCH = 0.01  # m: a lowest point this close above a support surface touches it
MAX_REWARD = STAGES  # the dense reward on success (its staged reward's maximum)
EDGE_TOLERANCE = 1e-9  # m: a centre this close outside the footprint's edge is over it
numbers = number_set(GAPS=(TOUCH, DROP_GAP))


@dataclass(frozen=True)
class Bounds:
    """What :func:`in_pose` compares with that stays the same over a configuration, per env
    (``TaskReader`` makes it once; ``TaskState.bounds``), from the state's receptacle fields.

    Attributes:
        normals: ``(n, 1, E, 2)``, ``offsets``: ``(n, 1, E)``: the footprint's half planes,
            the offsets less ``EDGE_TOLERANCE``.
        floor: ``(n, 1)`` the lowest a mover's lowest point rests on a receptacle object
            (``OFF_TABLE`` over the table's top); ``-inf`` where the receptacle is the table.
        rim: ``(n, 1)`` the highest a mover's centre rests in the receptacle's frame: its rim
            for "in" on an object, ``inf`` otherwise.
    """

    normals: Any
    offsets: Any
    floor: Any
    rim: Any

    @classmethod
    def of(cls, footprint: tuple, rim, is_in, rec_is_table, table_z) -> Bounds:
        """From those fields of a :class:`TaskState` (numpy arrays or tensors)."""
        (normals, offsets), xp = footprint, array_module(rim)
        floor = xp.where(rec_is_table, -math.inf, table_z + OFF_TABLE)
        rim = xp.where(is_in & ~rec_is_table, rim, math.inf)
        return cls(normals[:, None], offsets[:, None] - EDGE_TOLERANCE, floor[:, None],
                   rim[:, None])  # fmt: skip


def in_pose(s: TaskState):
    """``(n, m)`` each: each mover rests where the task wants it (released or not); near it
    (over the footprint, lowest point within ``DROP_GAP`` of the surface there)."""
    xp, c = s.xp, numbers(s.bottom)
    b = s.bounds
    if b is None:
        b = Bounds.of(s.footprint, s.rim, s.is_in, s.rec_is_table, s.table_z)
    xy = s.in_receptacle[..., :2]
    over = every(total(xy[:, :, None, :] * b.normals) >= b.offsets)
    top = xp.where(s.rec_is_table, s.table_z, s.rec_top)[:, None, None]  # the surface's height
    low = s.bottom[..., None] <= top + c.GAPS  # (n, m, 2): within TOUCH, within DROP_GAP of it
    pose = over & (s.bottom >= b.floor) & (s.in_receptacle[..., 2] < b.rim)
    return pose & low[..., 0], over & low[..., 1]


def evaluate(s: TaskState) -> dict:
    return staged_evaluate(s, *in_pose(s))


def reward(s: TaskState, info: dict):
    return staged_dense(s, info, MAX_REWARD)
