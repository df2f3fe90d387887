"""``move``: the mover ends ``MIN_SHIFT`` or more from where it started, along a direction
(left, right, forward: away from the robot, backward) of the robot's frame, on the table.

**Success**, for every mover: its displacement in the table's plane at least ``MIN_SHIFT``
along the direction and within ``MAX_ANGLE_DEG`` of it; on the table (its lowest point within
``place.TOUCH`` of the top); released and at rest (``state``). **Reward**:
``state.staged_reward`` towards ``layout.task.MOVE_SHIFT`` along the direction; ``MAX_REWARD``
on success.
"""

from __future__ import annotations

import math

from embodied_envs.envs.tasks.place import TOUCH
from embodied_envs.envs.tasks.state import (
    STAGES,
    TaskState,
    norm,
    staged_dense,
    staged_evaluate,
)

MIN_SHIFT = 0.10  # m along the direction
MAX_ANGLE_DEG = 45.0  # the displacement within this of the direction
MAX_REWARD = STAGES + 1


def in_pose(s: TaskState):
    """``(n, m)``: each mover shifted far enough along the direction, on the table."""
    d = s.movers[..., :2] - s.start[..., :2]
    along = (d * s.direction[:, None, :]).sum(-1)
    aligned = along >= math.cos(math.radians(MAX_ANGLE_DEG)) * norm(d)
    return (along >= MIN_SHIFT) & aligned & (s.bottom <= s.table_z[:, None] + TOUCH)


def evaluate(s: TaskState) -> dict:
    return staged_evaluate(s, in_pose(s))


def reward(s: TaskState, info: dict):
    return staged_dense(s, info, MAX_REWARD)
