"""Checks of ``PickEmbodiedGen-v1``'s own constructor keywords, before any simulation object.

Types come from the constructor's annotations (``CheckedEnv.check_keyword``); this module adds
the ranges and the structured values (:func:`check_value`, which config files' values pass
through too) and what a layout set could meet mid-simulation, refused at construction
(:func:`one_robot`, :func:`check_layout_set`).
"""

from __future__ import annotations

from embodied_envs.config import CameraSpec, resolve_robot
from embodied_envs.envs.arguments import check_quaternion, dataclass_arg
from embodied_envs.layout import GoalRegion, LayoutError, PlacementLimits
from embodied_envs.layout.errors import check_number
from embodied_envs.layout.placement import place
from embodied_envs.layout.sets import LayoutSet
from embodied_envs.robots import Robot
from embodied_envs.scene.layout_scene import scene_slots

NUMBER_RANGES = {  # numeric keywords: (low, high)
    "robot_init_qpos_noise": (0.0, 0.5),  # rad, std of the arm joints' start noise
    "objs_z_offset": (0.0, 0.1),  # m, objects start this far above their rest
    "robot_z_offset": (0.0, 0.1),  # m, the robot base stands this far above its spot
}


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


def robot_defaults(entry: Robot) -> tuple[dict, dict]:
    """The placement-limit and goal-region fields that follow the robot (its entry's reach,
    goal inset and heights), as ``placement_limits`` and ``goal_region`` dicts."""
    limits = dict(reach_min=entry.reach[0], reach_max=entry.reach[1])
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
    robots = {
        x.source: resolve_robot(x.robot, robot_uids, str(x.source)) for x in layout_set.layouts
    }
    if len(set(robots.values())) > 1:
        raise LayoutError(
            f"layout_file: the layouts of a set must name one robot, and these differ: "
            f"{ {str(k): v for k, v in robots.items()} }. Fix: split the set by robot."
        )
    return next(iter(robots.values()))


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
