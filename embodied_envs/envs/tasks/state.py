"""What the task rules read at one instant, per env, and the rules every kind shares."""

from __future__ import annotations

import functools
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
DROP_GAP = 0.03  # m: a mover let go with its lowest point this close over its pose falls into it
REST_LIN_SOFT = 0.15  # m/s over REST_LIN: the settle credit falls to 0.24 (1 - tanh 1)
REST_ANG_SOFT = 5.0  # rad/s over REST_ANG: likewise
SETTLE = 0.5  # the settle stage's weight (StackCube's static term is half a stage too)


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
        return _module(self.tcp)


def _module(x):
    """``array_module``, numpy's arrays first (the CPU simulation's every step)."""
    return np if isinstance(x, np.ndarray) else array_module(x)


def at_least(x, low):
    """``x.clip(min=low)``; numpy's clip calls ``np.maximum``, here without its Python wrapper."""
    return np.maximum(x, low) if isinstance(x, np.ndarray) else x.clip(min=low)


def at_most(x, high):
    """``x.clip(max=high)``, likewise (``np.minimum``)."""
    return np.minimum(x, high) if isinstance(x, np.ndarray) else x.clip(max=high)


def norm(x, axis=-1):
    if isinstance(x, np.ndarray) and x.dtype.kind == "f":  # np.linalg.norm.s sum, no checks
        return np.sqrt(np.add.reduce(x * x, axis=axis))
    return array_module(x).linalg.norm(x, axis=axis)


def robot_static(s: TaskState):
    """``(n,)``: every arm joint slower than ``STATIC_ARM`` (ManiSkill's ``Panda.is_static``)."""
    return (s.xp.abs(s.arm_qvel) <= STATIC_ARM).all(-1)


def released(s: TaskState, hand=None):
    """``(n, m)``: not grasped, and the fingers open or the hand away from the mover (``hand``:
    the TCP's distance to each mover's centre where the caller has it)."""
    hand = norm(s.movers - s.tcp[:, None, :]) if hand is None else hand
    return ~s.grasped & ((s.opening >= OPEN_FRACTION)[:, None] | (hand >= HAND_AWAY))


def as_float(x):
    """A bool array as float32, numpy or torch."""
    return x.astype(np.float32) if isinstance(x, np.ndarray) else x.float()


def current(done):
    """``(n,)`` index of each env's first mover not ``done (n, m)`` (the last when all are)."""
    xp = _module(done)
    first = (~done).argmax(1) if xp is np else (~done).int().argmax(1)
    return xp.where(done.all(1), done.shape[1] - 1, first)


def take(x, k):
    """Row-wise ``x[i, k[i]]`` for ``x (n, m, ...)`` and ``k (n,)``."""
    if isinstance(x, np.ndarray):
        return x[_rows(len(k)), k]
    return x[array_module(x).arange(len(k), device=x.device), k]


@functools.cache
def _rows(n: int) -> np.ndarray:
    return np.arange(n)


def staged_evaluate(s: TaskState, pose, near) -> dict:
    """``place`` and ``move``: success when every mover is in its pose (``pose (n, m)``, the
    kind's own rule), released and at rest; the flags of the current mover. ``near (n, m)``:
    the kind's looser pose a mover let go there falls into (for the reward)."""
    hand = norm(s.movers - s.tcp[:, None, :])
    free = released(s, hand)
    lin, ang = norm(s.lin_vel), norm(s.ang_vel)
    done = pose & free & (lin <= REST_LIN) & (ang <= REST_ANG)  # at_rest, speeds kept
    k = current(done)
    return {
        "success": done.all(1),
        "is_grasped": take(s.grasped, k),
        "is_obj_placed": pose.all(1),
        "is_robot_static": robot_static(s),
        "obj_to_goal_pos": take(s.dest, k) - take(s.movers, k),
        # (n, m) each, for the reward, not in info
        "done": done, "pose": pose, "near": near, "released": free, "hand": hand,
        "speeds": (lin, ang),
    }  # fmt: skip


def settled(lin, ang):
    """``(n, m)`` in [0, 1]: 1 at rest (``REST_LIN``, ``REST_ANG``), falling off smoothly with
    the speeds above them (``REST_LIN_SOFT``, ``REST_ANG_SOFT``): a mover that twitches just
    over the thresholds keeps most of its credit, one falling or sliding keeps none."""
    over = at_least(lin - REST_LIN, 0) / REST_LIN_SOFT
    return 1 - _module(lin).tanh(over + at_least(ang - REST_ANG, 0) / REST_ANG_SOFT)


def let_go(s: TaskState, result: dict):
    """``(n, m)`` in [0, 1]: 1 released (``result["released"]``), 0 grasped; between, the
    fingers' opening towards ``OPEN_FRACTION`` or the hand's distance towards ``HAND_AWAY``,
    whichever is nearer (fingers opening after a release, a hand near a mover placed before).
    A mover not grasped while the hand holds another one counts as released: the hand
    placing the next mover beside it does not pinch it."""
    xp, grasped = s.xp, s.grasped
    part = xp.maximum(s.opening[:, None] / OPEN_FRACTION, result["hand"] / HAND_AWAY)
    free = result["released"] | grasped.any(1)[:, None]
    return xp.where(grasped, 0.0, xp.where(free, 1.0, at_most(part, 1)))


def staged_dense(s: TaskState, result: dict, max_reward: float):
    """The staged reward of ``place`` and ``move`` (``result``: ``staged_evaluate``'s), per
    env, in [0, ``STAGES``]: the mean over movers of each one's credit, in [0, ``STAGES``]:

    - in its pose: 4, + let go (:func:`let_go`) times (``2 - SETTLE`` + ``SETTLE`` settled
      (:func:`settled`)): release and settle share two stages, the settle credit's jolts when
      the fingers clear the mover weighing little;
    - grasped, or let go where it falls into its pose (``near``): 2 + carried over its
      destination ``1 - tanh(5 |xy - dest xy|)`` + brought to it ``1 - tanh(5 |p - dest|)``;
    - otherwise 0, but the current mover (the first not in its pose) adds reaching
      ``1 - tanh(5 |tcp - p|)``.

    A finished mover keeps its whole credit while the hand works on the next one, so the
    reward does not fall between movers; it is ``STAGES`` exactly when every mover is in its
    pose, released and at rest, which is success (``max_reward``, equal to it)."""
    xp, f = s.xp, as_float
    pose, grasped = result["pose"], s.grasped
    placed = 4 + let_go(s, result) * (2 - SETTLE + SETTLE * settled(*result["speeds"]))
    active = grasped | result["near"]
    off = s.movers - s.dest
    carried = 4 - xp.tanh(5 * norm(off[..., :2])) - xp.tanh(5 * norm(off))
    credit = xp.where(pose, placed, carried * f(active)).sum(1)
    k = current(pose)
    reach = 1 - xp.tanh(5 * norm(s.tcp - take(s.movers, k)))
    credit = credit + reach * f(~take(pose | active, k))
    return xp.where(result["success"], max_reward, credit / pose.shape[1])


STAGES = 6.0  # a mover's credit in staged_dense: reach, grasp, carry, lower, release, settle
