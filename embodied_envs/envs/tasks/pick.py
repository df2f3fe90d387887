"""``pick``: hold the mover still at the goal point (the shipped layouts' task); the
mover's place is its actor's origin, as ManiSkill's PickCube reads it.

**Success:** the mover within ``GOAL_THRESH`` of the goal, and the robot static (every arm
joint slower than ``STATIC_ARM``).

**Reward** (:func:`reward`), in [0, ``MAX_REWARD``]: reaching ``1 - tanh(5 |tcp - obj|)``;
grasped (1); placing ``1 - tanh(5 |obj - goal|)`` while grasped; static
``1 - tanh(5 |arm qvel|)`` while placed; ``MAX_REWARD`` on success.
"""

from __future__ import annotations

from embodied_envs.envs.tasks.state import TaskState, as_float, norm, robot_static

GOAL_THRESH = 0.025  # m, object-to-goal distance that counts as placed
MAX_REWARD = 5.0  # the dense reward on success; the normalised reward divides by it


def evaluate(s: TaskState) -> dict:
    obj_to_goal = s.goal - s.origins[:, 0]
    placed = norm(obj_to_goal) <= GOAL_THRESH
    static = robot_static(s)
    return {
        "success": placed & static,
        "is_grasped": s.grasped[:, 0],
        "is_obj_placed": placed,
        "is_robot_static": static,
        "obj_to_goal_pos": obj_to_goal,
    }


def reward(s: TaskState, info: dict):
    xp = s.xp
    grasped = as_float(info["is_grasped"])
    reward = 1 - xp.tanh(5 * norm(s.origins[:, 0] - s.tcp)) + grasped
    reward = reward + (1 - xp.tanh(5 * norm(info["obj_to_goal_pos"]))) * grasped
    static = 1 - xp.tanh(5 * norm(s.arm_qvel))
    reward = reward + static * as_float(info["is_obj_placed"])
    return xp.where(info["success"], MAX_REWARD, reward)
