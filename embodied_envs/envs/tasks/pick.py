"""``pick``: hold the mover still at the goal point (the shipped layouts' task); the
mover's place is its actor's origin, as ManiSkill's PickCube reads it.

**Success:** the mover within ``GOAL_THRESH`` of the goal, and the robot static (every arm
joint slower than ``STATIC_ARM``).

**Reward** (:func:`reward`), in [0, ``MAX_REWARD``], PickCube's stages: reaching
``1 - tanh(5 |tcp - obj|)`` (1) until grasped; grasped (2: the reach is done); while grasped,
placing ``1 - tanh(5 d)`` (1) with ``d`` the object's distance to the goal beyond
``GOAL_THRESH`` (1 once placed), and static ``1 - tanh(e / STATIC_SOFT)`` (1) scaled by the
placing term, with ``e`` the fastest arm joint's speed over ``STATIC_ARM`` (1 once static).
So it is ``MAX_REWARD`` exactly at success (held), and an arm that speeds up just past the
static threshold, or an object just outside the goal, loses only a little of it.
"""

from __future__ import annotations

from embodied_envs.envs.tasks.state import (
    STATIC_ARM,
    TaskState,
    at_least,
    norm,
    number_set,
    robot_static,
)

GOAL_THRESH = 0.025  # m, object-to-goal distance that counts as placed
STATIC_SOFT = 1.0  # rad/s over STATIC_ARM: the static credit falls to 0.24 (1 - tanh 1)
MAX_REWARD = 4.0  # the dense reward on success; the normalised reward divides by it
# the numbers the rules compute with, of the arrays' dtype (state.number_set: the same values)
numbers = number_set(
    ZERO=0.0, ONE=1.0, TWO=2.0, FIVE=5.0, GOAL_THRESH=GOAL_THRESH, STATIC_ARM=STATIC_ARM,
    STATIC_SOFT=STATIC_SOFT, MAX_REWARD=MAX_REWARD,
)


def evaluate(s: TaskState) -> dict:
    obj_to_goal = s.goal - s.origins[:, 0]
    placed = norm(obj_to_goal) <= numbers(obj_to_goal).GOAL_THRESH
    static = robot_static(s)
    return {
        "success": placed & static,
        "is_grasped": s.grasped[:, 0],
        "is_obj_placed": placed,
        "is_robot_static": static,
        "obj_to_goal_pos": obj_to_goal,
    }


def conditions(s: TaskState, info: dict) -> dict:
    """Each condition of success, ``(n, 1)`` bool (true: met), keyed by the words that say it
    is not met (``info``: :func:`evaluate`'s)."""
    return {
        "not at the goal": info["is_obj_placed"][:, None],
        "the arm not static": info["is_robot_static"][:, None],
    }


def reward(s: TaskState, info: dict):
    xp, c = s.xp, numbers(s.origins)
    reach = c.ONE - xp.tanh(c.FIVE * norm(s.origins[:, 0] - s.tcp))
    place = c.ONE - xp.tanh(c.FIVE * at_least(norm(info["obj_to_goal_pos"]) - c.GOAL_THRESH,
                                              c.ZERO))  # fmt: skip
    speed = s.arm_speed
    speed = xp.maximum.reduce(speed, -1) if xp.__name__ == "numpy" else speed.amax(-1)
    static = c.ONE - xp.tanh(at_least(speed - c.STATIC_ARM, c.ZERO) / c.STATIC_SOFT)
    reward = xp.where(info["is_grasped"], c.TWO + place * (c.ONE + static), reach)
    return xp.where(info["success"], c.MAX_REWARD, reward)
