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

from embodied_envs.envs.tasks.state import (
    DROP_GAP,
    OFF_TABLE,
    STAGES,
    TaskState,
    staged_dense,
    staged_evaluate,
)

TOUCH = 0.01  # m: a lowest point this close above a support surface touches it
MAX_REWARD = STAGES  # the dense reward on success (its staged reward's maximum)


def in_pose(s: TaskState):
    """``(n, m)`` each: each mover rests where the task wants it (released or not); near it
    (over the footprint, lowest point within ``DROP_GAP`` of the surface there)."""
    normals, offsets = s.footprint
    xy = s.in_receptacle[..., :2]
    over = ((xy[:, :, None, :] * normals[:, None]).sum(-1) >= offsets[:, None] - 1e-9).all(-1)
    table_z, rec_top = s.table_z[:, None], s.rec_top[:, None]
    on_object = (s.bottom >= table_z + OFF_TABLE) & (s.bottom <= rec_top + TOUCH)
    on_object &= ~s.is_in[:, None] | (s.in_receptacle[..., 2] < s.rim[:, None])
    on_table = s.bottom <= table_z + TOUCH
    pose = over & s.xp.where(s.rec_is_table[:, None], on_table, on_object)
    top = s.xp.where(s.rec_is_table[:, None], table_z, rec_top)
    return pose, over & (s.bottom <= top + DROP_GAP)


def evaluate(s: TaskState) -> dict:
    return staged_evaluate(s, *in_pose(s))


def reward(s: TaskState, info: dict):
    return staged_dense(s, info, MAX_REWARD)
