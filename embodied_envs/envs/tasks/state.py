"""What the task rules read at one instant, per env, and the rules every kind shares."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from embodied_envs.layout.placement.rules import array_module

# thresholds every kind shares (docs/tasks.md says why these)
STATIC_ARM = 0.2  # rad/s: every arm joint slower is a static robot (ManiSkill's Panda.is_static)
REST_LIN = 0.01  # m/s: a mover slower is at rest (ManiSkill's StackCube / PlaceSphere)
REST_ANG = 0.5  # rad/s: and turning slower (likewise)
OPEN_FRACTION = 0.9  # fingers opened this part of their span are open
HAND_AWAY = 0.10  # m: or the TCP this far from the mover's centre
OFF_TABLE = 0.003  # m: a mover's lowest point this far above the table's top does not touch it


@dataclass(frozen=True)
class TaskState:
    """Per env (first axis ``n``) and per mover (second axis ``m``; an env with fewer movers
    repeats its last one, which leaves "every mover" rules unchanged). Numpy arrays on the
    CPU simulation, tensors on the GPU.

    Attributes:
        tcp, goal: ``(n, 3)``: the TCP; the pick goal (``pick``) or the current mover's
            destination (``place``, ``move``).
        arm_qvel: ``(n, J)`` arm joint speeds; ``opening``: ``(n,)`` fingers' opening, as a
            part of their span (0 closed, 1 open).
        movers, lin_vel, ang_vel: ``(n, m, 3)``: each mover's centre (its collision box's)
            and velocities; ``origins``: ``(n, m, 3)`` their actors' origins.
        bottom: ``(n, m)`` height of each mover's lowest collision point.
        grasped: ``(n, m)`` bool, the gripper grasps that mover (ManiSkill's rule).
        start: ``(n, m, 3)`` each mover's centre when the episode began.
        dest: ``(n, m, 3)`` each mover's destination (its centre, resting there).
        in_receptacle: ``(n, m, 3)`` each mover's centre in the receptacle's frame.
        footprint: ``(normals (n, E, 2), offsets (n, E))``: the receptacle's footprint in its
            frame (inside: ``normals @ xy >= offsets`` on every edge, ``rules.half_planes``).
        rim: ``(n,)`` height of the receptacle's top in its frame; ``rec_top``: ``(n,)`` the
            height of its top in the world; ``rec_pos``: ``(n, 3)`` its origin;
            ``is_in``: ``(n,)`` bool,
            the relation is "in" (else "on").
        rec_is_table: ``(n,)`` bool: the receptacle is the context (the table).
        table_z: ``(n,)`` height of the table's top.
        direction: ``(n, 2)`` unit vector of a move's direction in the world's XY.
    """

    tcp: Any
    goal: Any
    arm_qvel: Any
    opening: Any
    movers: Any
    origins: Any
    lin_vel: Any
    ang_vel: Any
    bottom: Any
    grasped: Any
    start: Any
    dest: Any
    in_receptacle: Any
    footprint: tuple
    rim: Any
    rec_top: Any
    rec_pos: Any
    is_in: Any
    rec_is_table: Any
    table_z: Any
    direction: Any

    @property
    def xp(self):
        return array_module(self.tcp)


def norm(x, axis=-1):
    return array_module(x).linalg.norm(x, axis=axis)


def robot_static(s: TaskState):
    """``(n,)``: every arm joint slower than ``STATIC_ARM`` (ManiSkill's ``Panda.is_static``)."""
    return (s.xp.abs(s.arm_qvel) <= STATIC_ARM).all(-1)


def at_rest(s: TaskState):
    """``(n, m)``: each mover moves and turns slower than ``REST_LIN`` and ``REST_ANG``."""
    return (norm(s.lin_vel) <= REST_LIN) & (norm(s.ang_vel) <= REST_ANG)


def released(s: TaskState):
    """``(n, m)``: not grasped, and the fingers open or the hand away from the mover."""
    away = norm(s.movers - s.tcp[:, None, :]) >= HAND_AWAY
    return ~s.grasped & ((s.opening >= OPEN_FRACTION)[:, None] | away)


def as_float(x):
    """A bool array as float32, numpy or torch."""
    return x.astype(np.float32) if isinstance(x, np.ndarray) else x.float()


def current(done):
    """``(n,)`` index of each env's first mover not ``done (n, m)`` (the last when all are)."""
    xp = array_module(done)
    first = (~done).argmax(1) if xp is np else (~done).int().argmax(1)
    return xp.where(done.all(1), done.shape[1] - 1, first)


def take(x, k):
    """Row-wise ``x[i, k[i]]`` for ``x (n, m, ...)`` and ``k (n,)``."""
    xp = array_module(x)
    rows = np.arange(len(k)) if xp is np else xp.arange(len(k), device=x.device)
    return x[rows, k]


def staged_evaluate(s: TaskState, pose) -> dict:
    """``place`` and ``move``: success when every mover is in its pose (``pose (n, m)``, the
    kind's own rule), released and at rest; the flags of the current mover."""
    free = released(s)
    done = pose & free & at_rest(s)
    k = current(done)
    return {
        "success": done.all(1),
        "is_grasped": take(s.grasped, k),
        "is_obj_placed": pose.all(1),
        "is_robot_static": robot_static(s),
        "obj_to_goal_pos": take(s.dest, k) - take(s.movers, k),
        "done": done,  # (n, m), the poses and releases: for the reward, not in info
        "pose": pose,
        "released": free,
    }


def staged_dense(s: TaskState, result: dict, max_reward: float):
    """``place`` and ``move``: :func:`staged_reward` of ``staged_evaluate``'s ``result``;
    ``max_reward`` on success."""
    done = result["done"]
    k = current(done)
    staged = staged_reward(s, k, take(result["pose"], k), done.sum(1), done.shape[1],
                           take(result["released"], k))  # fmt: skip
    return s.xp.where(result["success"], max_reward, staged)


def staged_reward(s: TaskState, k, in_pose, done_before, count: int, free=None):
    """The staged reward of ``place`` and ``move``, per env, in [0, ``STAGES``]: for the
    current mover ``k`` (``(n,)``), reach (1) and grasp (1); while grasped, carry over the
    destination (1) and lower to it (1) (kept when let go within 2 cm of it); in its pose
    (``in_pose (n,)``), released (1) and the arm still (1); then (``done_before``: movers
    already done, ``(n,)``) each finished mover adds a whole share: ``(done_before + stage /
    STAGES) * STAGES / count``. ``free``: the current mover's :func:`released` when the caller
    has it."""
    xp, f = s.xp, as_float
    p, dest = take(s.movers, k), take(s.dest, k)
    grasped = f(take(s.grasped, k))
    free = f(take(released(s), k) if free is None else free)
    reach = 1 - xp.tanh(5 * norm(s.tcp - p))
    carry = 1 - xp.tanh(5 * norm(p[:, :2] - dest[:, :2]))
    lower = (1 - xp.tanh(5 * xp.abs(p[:, 2] - dest[:, 2]))) * (carry > 0.9)
    still = 1 - xp.tanh(5 * norm(s.arm_qvel))
    # held, or just let go over its destination (falling the release gap): carried and lowered
    stage = xp.where((grasped > 0) | (lower > 0.9), 2 + carry + lower, reach + grasped)
    stage = xp.where(in_pose, 4 + free + free * still, stage)
    return (done_before + stage / STAGES) * STAGES / count


STAGES = 6.0  # staged_reward's stages: reach, grasp, carry, lower, release, still
