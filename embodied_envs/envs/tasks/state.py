"""What the task rules read at one instant, per env, and the rules every kind shares."""

from __future__ import annotations

import functools
from dataclasses import dataclass
from types import SimpleNamespace
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
        arm_speed: ``(n, J)`` arm joint speeds over the last control step (``TaskReader``:
            displacement over time); ``opening``: ``(n,)`` fingers' opening, as a
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
        rim: ``(n,)`` height of the receptacle's top in its frame; ``floor``: ``(n,)`` of its
            floor (the lowest surface under its opening; the top where it has no inside);
            ``rec_top``: ``(n,)`` the height of its top in the world; ``rec_pos``: ``(n, 3)``
            its origin; ``is_in``: ``(n,)`` bool, the relation is "in" (else "on").
        rec_is_table: ``(n,)`` bool: the receptacle is the context (the table).
        table_z: ``(n,)`` height of the table's top.
        direction: ``(n, 2)`` unit vector of a move's direction in the world's XY.
        bounds: ``place.Bounds`` of the receptacle fields, made once per configuration
            (``TaskReader``); ``None``: ``place`` makes them on every call.
        top: ``(n, m)`` height of each mover's highest collision point; ``reach``: ``(n, m)``
            the farthest of its collision points from its centre. ``None`` (both) with one
            mover: ``place.stacked``, which reads them, has no other mover to rest on.

    ``bottom``, ``in_receptacle``, ``rec_top`` and ``opening`` are None in the state of the
    env's rules where ``pick``, which reads none of them, is the only kind present
    (``TaskReader.rules``).
    """

    tcp: Any
    goal: Any
    arm_speed: Any
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
    floor: Any
    rec_top: Any
    rec_pos: Any
    is_in: Any
    rec_is_table: Any
    table_z: Any
    direction: Any
    bounds: Any = None
    top: Any = None
    reach: Any = None

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


def every(x, axis=-1):
    """``x.all(axis)``; numpy's method adds a Python wrapper to ``np.logical_and.reduce``."""
    return np.logical_and.reduce(x, axis) if isinstance(x, np.ndarray) else x.all(axis)


def some(x, axis=-1):
    """``x.any(axis)``, likewise (``np.logical_or.reduce``)."""
    return np.logical_or.reduce(x, axis) if isinstance(x, np.ndarray) else x.any(axis)


def total(x, axis=-1):
    """``x.sum(axis)``, likewise (``np.add.reduce``)."""
    return np.add.reduce(x, axis) if isinstance(x, np.ndarray) else x.sum(axis)


def concat(arrays, axis):
    return np.concatenate(arrays, axis) if isinstance(arrays[0], np.ndarray) else \
        array_module(arrays[0]).cat(arrays, axis)  # fmt: skip


def number_set(**values):
    """A function ``x -> namespace`` of ``values`` (floats, or tuples of them) as ``x``'s rules
    compute with them: for numpy arrays, arrays of ``x``'s dtype (0-d for a float; made once
    per dtype); for tensors, the floats and tensors on ``x``'s device (once per device).
    numpy's arithmetic with a Python float converts it every time, twice the cost of the
    operation itself on one env's arrays; a 0-d array of the same dtype gives the same values
    (the float is cast to that dtype either way) without it."""

    @functools.cache
    def arrays(dtype) -> SimpleNamespace:
        return SimpleNamespace(**{k: np.array(v, dtype) for k, v in values.items()})

    @functools.cache
    def tensors(xp, dtype, device) -> SimpleNamespace:
        return SimpleNamespace(**{
            k: xp.tensor(v, dtype=dtype, device=device) if isinstance(v, tuple) else float(v)
            for k, v in values.items()
        })  # fmt: skip

    def numbers(x) -> SimpleNamespace:
        if isinstance(x, np.ndarray):
            return arrays(x.dtype)
        return tensors(array_module(x), x.dtype, x.device)

    return numbers


# the numbers the shared rules compute with
numbers = number_set(
    ZERO=0.0, ONE=1.0, FOUR=4.0, FIVE=5.0, STATIC_ARM=STATIC_ARM, REST_LIN=REST_LIN,
    REST_ANG=REST_ANG, OPEN_FRACTION=OPEN_FRACTION, HAND_AWAY=HAND_AWAY, XY=(1.0, 1.0, 0.0),
    REST_LIN_SOFT=REST_LIN_SOFT, REST_ANG_SOFT=REST_ANG_SOFT, SETTLE=SETTLE,
    RELEASE=2 - SETTLE, REST=(REST_LIN, REST_ANG), REST_SOFT=(REST_LIN_SOFT, REST_ANG_SOFT),
)  # fmt: skip


def as_number(value: float, x):
    """``value`` as ``x``'s rules compute with it (:func:`number_set`, for one value known only
    at the call): a 0-d array of ``x``'s dtype for a numpy array (made once), else itself."""
    return _number(float(value), x.dtype) if isinstance(x, np.ndarray) else value


@functools.cache
def _number(value: float, dtype) -> np.ndarray:
    return np.array(value, dtype)


def robot_static(s: TaskState, c: SimpleNamespace | None = None):
    """``(n,)``: every arm joint slower than ``STATIC_ARM`` over the last control step
    (ManiSkill's ``Panda.is_static`` threshold, on displacement rather than reported velocity)."""
    c = numbers(s.arm_speed) if c is None else c
    return every(s.arm_speed <= c.STATIC_ARM)


def as_float(x):
    """A bool array as float32, numpy or torch."""
    return x.astype(np.float32) if isinstance(x, np.ndarray) else x.float()


def current(done) -> tuple:
    """Each env's first mover not ``done (n, m)``, the last where all before it are, as an index:
    ``x[current(done)]`` is each env's row of that mover of ``x (n, m, ...)``. ``done <= last``
    (``last``: only the last mover) is "not done, or the last": its first true's column."""
    n, m = done.shape
    if m == 1:  # always the one mover
        return _ONE_MOVER
    if isinstance(done, np.ndarray):
        rows, last = _rows(n, m)
        return rows, (done <= last).argmax(1)
    xp = array_module(done)
    last = xp.arange(m, device=done.device) == m - 1
    return xp.arange(n, device=done.device), (done <= last).int().argmax(1)


_ONE_MOVER = (slice(None), 0)


@functools.cache
def _rows(n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
    """``current``'s constants for numpy: the row indices, and the last mover's mask."""
    return np.arange(n), np.arange(m) == m - 1


# the columns of staged_evaluate's ``norms (n, m, 5)``, one set of operations for all: each
# mover's speed, turning speed, distance from the TCP, distance from its destination, and that
# in the XY plane (the norm of ``(x, y, 0)``: the same float sum as of ``(x, y)``, plus 0)
LIN, ANG, HAND, DEST, DEST_XY = range(5)


def staged_evaluate(s: TaskState, pose, near) -> dict:
    """``place`` and ``move``: success when every mover is in its pose (``pose (n, m)``, the
    kind's own rule), released and at rest; the flags of the current mover. ``near (n, m)``:
    the kind's looser pose a mover let go there falls into (for the reward).

    Released: not grasped, and the fingers open (``OPEN_FRACTION``) or the hand away
    (``HAND_AWAY``) from the mover's centre; at rest: slower than ``REST_LIN`` and turning
    slower than ``REST_ANG``."""
    c = numbers(s.movers)
    to_dest = s.dest - s.movers
    vectors = (s.lin_vel, s.ang_vel, s.movers - s.tcp[:, None, :], to_dest, to_dest * c.XY)
    norms = norm(concat([v[..., None, :] for v in vectors], -2))
    away = norms[..., HAND] >= c.HAND_AWAY
    free = ~s.grasped & ((s.opening >= c.OPEN_FRACTION)[:, None] | away)
    rest = every(norms[..., LIN : ANG + 1] <= c.REST)
    done = pose & free & rest
    success, placed = every(done, 1), every(pose, 1)
    k = current(done)
    return {
        "success": success,
        "is_grasped": s.grasped[k],
        "is_obj_placed": placed,
        "is_robot_static": robot_static(s, c),
        "obj_to_goal_pos": to_dest[k],
        # for the reward, not in info: (n, m) each; the first mover not in its pose
        "pose": pose, "near": near, "released": free, "rest": rest, "norms": norms,
        "first_off_pose": current(pose),
    }  # fmt: skip


def released_and_still(info: dict) -> dict:
    """The conditions every staged kind shares (``info``: :func:`staged_evaluate`'s), ``(n, m)``
    each (true: met), keyed by the words that say a mover fails it (``place.conditions``)."""
    return {"not released": info["released"], "not at rest": info["rest"]}


def settled(speeds, c: SimpleNamespace):
    """``(n, m)`` in [0, 1] from ``speeds (n, m, 2)`` (each mover's speed, turning speed): 1 at
    rest (``REST_LIN``, ``REST_ANG``), falling off smoothly with the speeds above them
    (``REST_LIN_SOFT``, ``REST_ANG_SOFT``): a mover that twitches just over the thresholds
    keeps most of its credit, one falling or sliding keeps none."""
    over = at_least(speeds - c.REST, c.ZERO) / c.REST_SOFT
    return c.ONE - _module(speeds).tanh(total(over))


def let_go(s: TaskState, result: dict, c: SimpleNamespace):
    """``(n, m)`` in [0, 1]: 1 released (``result["released"]``), 0 grasped; between, the
    fingers' opening towards ``OPEN_FRACTION`` or the hand's distance towards ``HAND_AWAY``,
    whichever is nearer (fingers opening after a release, a hand near a mover placed before).
    A mover not grasped while the hand holds another one counts as released: the hand
    placing the next mover beside it does not pinch it."""
    xp, grasped = s.xp, s.grasped
    hand = result["norms"][..., HAND]
    part = xp.maximum(s.opening[:, None] / c.OPEN_FRACTION, hand / c.HAND_AWAY)
    free = result["released"] | some(grasped, 1)[:, None]
    # not grasped and not released: the opening under OPEN_FRACTION and the hand nearer than
    # HAND_AWAY, so ``part`` is at most 1 (a rounded quotient keeps the order): no clip needed
    return xp.where(grasped, c.ZERO, xp.where(free, c.ONE, part))


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
    xp, c = s.xp, numbers(s.movers)
    pose, norms = result["pose"], result["norms"]
    if isinstance(pose, np.ndarray) and not some(pose, None):
        placed = c.ZERO  # no mover in its pose: its credit unused (numpy; on tensors a branch
        # on values would wait for the GPU), 16 operations saved until the first is placed
    else:
        speed = settled(norms[..., LIN : ANG + 1], c)
        placed = c.FOUR + let_go(s, result, c) * (c.RELEASE + c.SETTLE * speed)
    active = s.grasped | result["near"]
    far = xp.tanh(c.FIVE * norms[..., HAND:])  # from the TCP, the destination, its XY
    carried = c.FOUR - far[..., DEST_XY - HAND] - far[..., DEST - HAND]
    credit = total(xp.where(pose, placed, xp.where(active, carried, c.ZERO)), 1)
    reach = xp.where(pose | active, c.ZERO, c.ONE - far[..., 0])
    credit = credit + reach[result["first_off_pose"]]
    top, movers = as_number(max_reward, credit), as_number(pose.shape[1], credit)
    return xp.where(result["success"], top, credit / movers)


STAGES = 6.0  # a mover's credit in staged_dense: reach, grasp, carry, lower, release, settle
