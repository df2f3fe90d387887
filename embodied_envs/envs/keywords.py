"""Checks of ``PickEmbodiedGen-v1``'s own constructor keywords, before any simulation object.

Types come from the constructor's annotations (``CheckedEnv.check_keyword``); this module adds
the ranges and the structured values (:func:`check_value`, which config files' values pass
through too), what a layout set could meet mid-simulation, refused at construction
(:func:`one_robot`, :func:`check_layout_set`), and the values the keywords resolve to: the
arms (:func:`robot_arms`), their rest joints (:func:`rest_joints`, :func:`check_rest_limits`),
the placement limits and goal region (:func:`limits_and_goals`).
"""

from __future__ import annotations

import math
import numbers
import warnings

import numpy as np

from embodied_envs import robots
from embodied_envs.config import CameraSpec, resolve_robot
from embodied_envs.envs import agents
from embodied_envs.envs.arguments import check_quaternion, dataclass_arg
from embodied_envs.layout import GoalRegion, LayoutError, PlacementLimits
from embodied_envs.layout.errors import check_number
from embodied_envs.layout.placement import place
from embodied_envs.layout.rooms import resolve_rooms
from embodied_envs.layout.sets import LayoutSet
from embodied_envs.scene.layout_scene import scene_slots

NUMBER_RANGES = {  # numeric keywords: (low, high)
    "robot_init_qpos_noise": (0.0, 0.5),  # rad, std of the arm joints' start noise
    "objs_z_offset": (0.0, 0.1),  # m, objects start this far above their rest
    "robot_z_offset": (0.0, 0.1),  # m, the robot base stands this far above its spot
}


VISUAL_FACES_RANGE = (50, 10_000_000)  # robot_visual_faces: triangles per visual mesh part


def check_value(name: str, value) -> None:
    """A keyword's range or fields (its type is checked already).

    Raises:
        ValueError: naming the keyword, the value and what is accepted.
    """
    if name in NUMBER_RANGES:
        check_number(name, value, *NUMBER_RANGES[name])
    elif name == "placement_limits":
        dataclass_arg(PlacementLimits, value, name)
    elif name == "goal_region":
        dataclass_arg(GoalRegion, value, name)
    elif name == "camera_cfg":
        CameraSpec.from_cfg(value)
    elif name == "init_3dgs_quat":
        check_quaternion(name, value)
    elif name == "robot_init_qpos" and value is not None:
        joint_values(value)
    elif name == "robot_visual_faces" and value is not None:
        check_number(name, value, *VISUAL_FACES_RANGE, integer=True)
    elif name == "rooms":
        resolve_rooms(value)


REST_HELP = (
    "robot_init_qpos is the robot's rest joint positions (arm + gripper, one per active "
    "joint, rad or m), e.g. the Panda's hand-down rest [0, 0.3927, 0, -1.9635, 0, 2.3562, "
    "0.7854, 0.04, 0.04]; None: the robot entry's rest (robots.py)"
)


def joint_values(value, robot: str = "", dof: int = 0) -> tuple[float, ...]:
    """``robot_init_qpos``: a non-empty list of finite numbers (not booleans), as floats;
    ``robot`` and its ``dof`` (when known) are named in the error.

    Raises:
        ValueError: naming the keyword, the value, the robot (when given) and what it takes.
    """
    if isinstance(value, np.ndarray):
        value = value.tolist() if value.ndim == 1 else None
    ok = isinstance(value, list | tuple) and len(value) > 0
    ok = ok and all(isinstance(v, numbers.Real) and not isinstance(v, bool) for v in value)
    if not ok or not all(math.isfinite(v) for v in value):
        who = f" for robot {robot!r} ({dof} active joints)" if robot else ""
        count = f"{dof} " if dof else ""
        raise ValueError(
            f"robot_init_qpos={value!r}{who} must be a list of {count}finite numbers; {REST_HELP}"
        )
    return tuple(float(v) for v in value)


def rest_joints(robot_init_qpos, entries) -> tuple[np.ndarray, ...]:
    """Each arm's rest joints: ``robot_init_qpos`` for the first arm (a second keeps its
    entry's rest), else the entries' (:func:`agents.default_rest`). Its length is checked
    against the first arm's joints; the joint limits later (:func:`check_rest_limits`).

    Raises:
        ValueError: naming the keyword, the robot, the expected length and the fix.
    """
    rests = [agents.default_rest(e) for e in entries]
    if robot_init_qpos is None:
        return tuple(rests)
    uid, dof = entries[0].uid, len(rests[0])
    value = joint_values(robot_init_qpos, uid, dof)
    if len(value) != dof:
        raise ValueError(
            f"robot_init_qpos has {len(value)} values; robot {uid!r} has {dof} active joints "
            f"(arm + gripper). Fix: give {dof} joint positions, e.g. its rest "
            f"{[round(v, 4) for v in rests[0]]}"
            + (" (the first arm's; the second keeps its rest)" if len(entries) > 1 else "")
        )
    return (np.array(value), *rests[1:])


def check_rest_limits(rest: np.ndarray, agent, uid: str) -> None:
    """``robot_init_qpos`` within the joint limits of the loaded agent's articulation.

    Raises:
        ValueError: naming each joint outside its limits, the limits and the fix.
    """
    limits = agent.robot.get_qlimits()[0].cpu().numpy().astype(np.float64)  # (dof, 2)
    names = [j.name for j in agent.robot.get_active_joints()]
    tol = 1e-6
    bad = [
        f"joint {i} ({names[i]}) = {v:.4f} is outside [{lo:.4f}, {hi:.4f}]"
        for i, (v, (lo, hi)) in enumerate(zip(rest, limits, strict=True))
        if not lo - tol <= v <= hi + tol
    ]
    if bad:
        raise ValueError(
            f"robot_init_qpos={[round(float(v), 4) for v in rest]}: robot {uid!r}: "
            f"{'; '.join(bad)} (its articulation's joint limits). Fix: give every joint a value "
            "within its limits"
        )


def robot_defaults(entry: robots.Robot) -> tuple[dict, dict]:
    """The placement-limit and goal-region fields that follow the robot (its entry's reach,
    movers' clearance, goal inset and heights), as ``placement_limits`` and ``goal_region``
    dicts."""
    limits = entry.placement
    return limits, dict(inset=entry.goal_inset, height=tuple(entry.goal_height))


def with_defaults(value, defaults: dict):
    """A dataclass keyword's value with ``defaults`` under the fields the user did not set:
    None -> the defaults, a dict -> the defaults updated by it, a dataclass -> as given (every
    field set)."""
    if value is None:
        return dict(defaults)
    if isinstance(value, dict):
        return {**defaults, **value}
    return value


def one_robot(layout_set: LayoutSet, robot_uids: str | None) -> str:
    """The robot every layout of the set names (one agent serves every env)."""
    named = {
        x.source: resolve_robot(x.robot, robot_uids, str(x.source)) for x in layout_set.layouts
    }
    if len(set(named.values())) > 1:
        raise LayoutError(
            f"layout_file: the layouts of a set must name one robot, and these differ: "
            f"{ {str(k): v for k, v in named.items()} }. Fix: split the set by robot."
        )
    return next(iter(named.values()))


def robot_arms(layout_set: LayoutSet, robot_uids) -> tuple[str | tuple, tuple[robots.Robot, ...]]:
    """The ``robot_uids`` ManiSkill gets (one uid, or a tuple of two: its multi-agent env) and
    each arm's entry (``embodied_envs/robots.py``; the first stands at the layout's spot):
    ``robot_uids``, else the robot every layout of the set names.

    Raises:
        ValueError: a robot the env cannot load (``agents.check_robot``), in one line.
        LayoutError: layouts of a set that name different robots.
    """
    if robot_uids is not None:  # a gripperless or absent robot named in its own words
        agents.check_robot(robot_uids)
    two = isinstance(robot_uids, list | tuple)  # two arms: the first at the layout's spot
    robot = one_robot(layout_set, robot_uids[0] if two else robot_uids)
    agents.check_robot(robot)  # its model is on this machine
    uids = tuple(robot_uids) if two else (robot,)
    return uids if two else robot, tuple(robots.robot(u) for u in uids)


def limits_and_goals(
    entry: robots.Robot, placement_limits, goal_region, rest=None
) -> tuple[PlacementLimits, GoalRegion]:
    """The ``placement_limits`` and ``goal_region`` keywords as dataclasses, the robot's reach
    and goal band (:func:`robot_defaults`) under each field the user did not set; the goal band
    checked to lie within the reach. ``rest``: the arm's rest joints where the user gave them
    (``robot_init_qpos``): the robot's ``rest_arm`` boxes were measured at its own rest, which
    is warned about where they differ and the user did not set ``rest_arm``."""
    limits, goals = robot_defaults(entry)
    own = isinstance(placement_limits, PlacementLimits) or "rest_arm" in (placement_limits or {})
    if (rest is not None and entry.rest_arm is not None and not own
            and not np.allclose(rest, agents.default_rest(entry), atol=1e-6)):  # fmt: skip
        warnings.warn(
            f"robot_init_qpos: placement keeps objects clear of the {entry.uid}'s links at its "
            "own rest (robots.py rest_arm), not at robot_init_qpos. Fix: measure yours (python "
            "tools/make/measure_rest.py LAYOUT --qpos ...) and pass placement_limits="
            "dict(rest_arm=...)",
            stacklevel=3,
        )
    placement = dataclass_arg(
        PlacementLimits, with_defaults(placement_limits, limits), "placement_limits"
    )
    region = dataclass_arg(GoalRegion, with_defaults(goal_region, goals), "goal_region")
    region.check_reach(placement)
    return placement, region


def check_layout_set(
    layout_set: LayoutSet, replace_objs: bool, limits: PlacementLimits, num_envs: int
) -> None:
    """What a configuration could meet, refused now: a layout or asset pool member that cannot
    be placed, parallel envs that cannot merge their objects, file poses that do not fit a
    pool's members."""
    if replace_objs:  # an impossible layout fails here, not mid-simulation
        for member in layout_set.members():
            place(member, 0, limits)
    elif any(layout_set.pools):
        pooled = next(x for x, p in zip(layout_set.layouts, layout_set.pools, strict=True) if p)
        raise LayoutError(
            f"{pooled.source}: asset pools need replace_objs=True (the file's poses were "
            "made for one asset, and a drawn one may not rest there). Fix: pass "
            "replace_objs=True, or name one asset folder."
        )
    if num_envs > 1 and layout_set.varies:
        scene_slots(list(layout_set.layouts))
