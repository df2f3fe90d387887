"""``move``: the mover ends ``MIN_SHIFT`` or more from where it started, along a direction
(left, right, forward: away from the robot, backward) of the robot's frame, on the table.

**Success**, for every mover: its displacement in the table's plane at least ``MIN_SHIFT``
along the direction and within ``MAX_ANGLE_DEG`` of it; on the table (its lowest point within
``place.TOUCH`` of the top); released and at rest (``state``). **Reward**:
``state.staged_dense`` towards ``layout.task.MOVE_SHIFT`` along the direction; ``MAX_REWARD``
at success only (a mover let go shifted far enough, lowest point within ``state.DROP_GAP`` of
the table, keeps its carry credit while it falls).
"""

from __future__ import annotations

import math

from embodied_envs.envs.tasks.place import TOUCH
from embodied_envs.envs.tasks.state import (
    DROP_GAP,
    STAGES,
    TaskState,
    norm,
    number_set,
    released_and_still,
    staged_dense,
    staged_evaluate,
    total,
)

MIN_SHIFT = 0.10  # m along the direction
MAX_ANGLE_DEG = 45.0  # the displacement within this of the direction
MAX_REWARD = STAGES  # the dense reward on success (its staged reward's maximum)
numbers = number_set(MIN_SHIFT=MIN_SHIFT, COS_ANGLE=math.cos(math.radians(MAX_ANGLE_DEG)),
                     TOUCH=TOUCH, DROP_GAP=DROP_GAP)  # fmt: skip


def _parts(s: TaskState):
    """``(n, m)`` each: shifted far enough along the direction; on the table; near it."""
    c = numbers(s.movers)
    d = s.movers[..., :2] - s.start[..., :2]
    along = total(d * s.direction[:, None, :])
    shifted = (along >= c.MIN_SHIFT) & (along >= c.COS_ANGLE * norm(d))
    height = s.bottom - s.table_z[:, None]
    return shifted, height <= c.TOUCH, height <= c.DROP_GAP


def in_pose(s: TaskState):
    """``(n, m)`` each: each mover shifted far enough along the direction, on the table; near
    it (shifted, lowest point within ``DROP_GAP`` of the table)."""
    shifted, on_table, near = _parts(s)
    return shifted & on_table, shifted & near


def conditions(s: TaskState, info: dict) -> dict:
    """Each condition of success, ``(n, m)`` bool per mover (true: met), keyed by the words that
    say it is not met (``info``: :func:`evaluate`'s)."""
    shifted, on_table, _ = _parts(s)
    return {
        **released_and_still(info),
        "not moved far enough along the direction": shifted,
        "not on the table": on_table,
    }


def evaluate(s: TaskState) -> dict:
    return staged_evaluate(s, *in_pose(s))


def reward(s: TaskState, info: dict):
    return staged_dense(s, info, MAX_REWARD)
