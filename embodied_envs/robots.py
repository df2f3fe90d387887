"""The robots the env can load, as data: one :class:`Robot` entry per ManiSkill uid.

Each entry holds what the env, the placement and the expert need to know about an arm, so no
other module carries a robot's numbers: its rest joint positions, where its base stands
relative to the layout's robot node, its reach (the default placement limits and goal region),
its gripper (opening, how its default controller opens and closes it), where its TCP and grasp
check come from, and where the ``base_camera`` sensor is mounted.

**Where the base stands.** A layout's robot node (``relation.robot``, its pose in
``position``) is a spot on the table's edge at the table top's height, facing the table (as
EmbodiedGen and ``embodied-envs layout generate`` put it). An arm's base link stands at that
spot moved ``edge_offset`` metres back (away from the table, along the spot's heading), turned
``base_yaw`` about z (ManiSkill's SO-100 and Koch models face their base frame's +y), on the
table top (``base_height="table"``) or on the floor under the spot (``"floor"``: the mobile
Fetch, which ManiSkill's own table scene puts 0.33 m behind the table's edge on the floor).
Reach and goal distances are measured from the spot, so a layout's check of its objects' reach
holds for every arm. The Panda stands exactly at the spot, as before.

Reach numbers: the horizontal distance from the base, over 3000 uniformly drawn joint
configurations, of TCPs 0.02-0.20 m above the base's table (ManiSkill 3.0.1 models; 99th
percentile / max): Panda 0.91 / 0.93, SO-100 0.46 / 0.48, Koch 0.37 / 0.38, Fetch (from its
base, table top 0.76 m) 1.08 / 1.09. ``reach_max`` stays below these, where top-down grasps
still work (the Panda's 0.78 m was measured with the expert).

This module imports nothing heavy: the layout commands and config files use it without the
simulator. What needs ManiSkill (whether a model file is on the machine, whether an agent class
has a grasp check) is in ``envs/agents.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

DOWNLOAD_COMMAND = "python -m mani_skill.utils.download_asset {uid}"


@dataclass(frozen=True)
class Gripper:
    """A parallel gripper: ``joints`` trailing qpos entries (each at ``open_qpos`` when open,
    ``closed_qpos`` when shut), ``max_opening`` metres between the jaws when open. In the
    robot's default controller (``pd_joint_delta_pos``) action ``action_index`` drives it:
    ``action_open`` opens, ``action_closed`` closes; ``"absolute"``: the value is the target
    (held), ``"delta"``: a step per control step (repeat it)."""

    joints: int
    open_qpos: float
    closed_qpos: float
    max_opening: float
    action_index: int
    action_kind: str  # "absolute" or "delta"
    action_open: float = 1.0
    action_closed: float = -1.0

    @property
    def span(self) -> tuple[float, float]:
        """The gripper joints' summed positions shut and open (the opening fraction's scale)."""
        return self.joints * self.closed_qpos, self.joints * self.open_qpos


@dataclass(frozen=True)
class FingerGrasp:
    """A grasp check by two finger links' contacts, the rule of ManiSkill's Panda, SO-100, Koch
    and Fetch ``is_grasping`` with their defaults: both fingers (the agent's ``finger1_link``,
    ``finger2_link``) press on the object with at least ``min_force`` newtons, each force within
    ``max_angle`` degrees of its finger's opening direction, ``opening[i]`` times the finger
    link's y axis. ``envs/contacts.py`` checks it in one CPU pass (ManiSkill's walks the scene's
    contacts twice in Python and makes a dozen one-env tensors: 1-2 ms per control step)."""

    max_angle: float = 85.0  # degrees
    opening: tuple[float, float] = (1.0, -1.0)  # sign of each finger link's y axis that opens
    min_force: float = 0.5  # N


PANDA_GRASP = FingerGrasp()  # Panda.is_grasping
JAW_GRASP = FingerGrasp(max_angle=110.0)  # SO100.is_grasping, Koch.is_grasping
FETCH_GRASP = FingerGrasp(opening=(-1.0, 1.0))  # Fetch.is_grasping: its left finger's -y opens


@dataclass(frozen=True)
class Robot:
    """One supported robot; see the module's docstring for the base placement."""

    uid: str  # ManiSkill's agent uid
    names: tuple[str, ...]  # other names a layout's relation.robot may use (lower case)
    rest_qpos: tuple[float, ...] | None  # every active joint, gripper open (None: the
    # agent's first keyframe)
    noise_joints: tuple[int, ...]  # joints that get the start noise (at most NOISE_DIMS)
    reach: tuple[float, float]  # m from the layout's robot spot: placement limits' band
    goal_inset: float  # m, the goal band is the reach band shrunk by this at both ends
    goal_height: tuple[float, float]  # m above the table top, goals' heights
    gripper: Gripper
    tcp_link: str | None  # link whose pose is the TCP; None: the agent's tcp_pose property
    grasp_check: FingerGrasp | None  # the agent's is_grasping rule; None: call it (any rule)
    camera_mount: str  # link the base_camera is mounted on
    camera_eye: tuple[float, float, float]  # in the facing frame at the spot (x to the table)
    camera_target: tuple[float, float, float]
    edge_offset: float = 0.0  # m, the base stands this far behind the spot
    base_yaw: float = 0.0  # rad, the base turned about z from the spot's heading
    base_height: str = "table"  # "table": on the spot; "floor": on the floor under it
    mobile_base: bool = False  # its wheels must not touch the ground (ManiSkill's Fetch)
    # tcp_link None: two links whose midpoint is the agent's tcp_pos, read on the CPU
    # simulation every step without the agent's property (0.3 ms there; None: the property)
    tcp_tips: tuple[str, str] | None = None
    in_wheel: bool = True  # False: its model is a separate ManiSkill download
    expert: bool = False  # the scripted expert (solvers/) drives it

    def base_poses(self, spots, floor_z: float):
        """Base raw poses ``(n, 7)`` (xyz, quaternion wxyz, as ManiSkill's) from the layout
        spots' ``spots (n, 7)``; the spots themselves (same array) for a robot standing there."""
        import numpy as np  # numpy only: the layout commands import this module

        spots = np.asarray(spots)
        if not self.edge_offset and not self.base_yaw and self.base_height == "table":
            return spots
        out = spots.astype(np.float64).copy()
        w, x, y, z = out[:, 3], out[:, 4], out[:, 5], out[:, 6]
        yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        out[:, 0] -= self.edge_offset * np.cos(yaw)
        out[:, 1] -= self.edge_offset * np.sin(yaw)
        if self.base_height == "floor":
            out[:, 2] = floor_z
        c, s = math.cos(self.base_yaw / 2), math.sin(self.base_yaw / 2)
        # spot quaternion times a turn about z: (w, x, y, z) * (c, 0, 0, s)
        out[:, 3:] = np.stack([w * c - z * s, x * c + y * s, y * c - x * s, z * c + w * s], 1)
        return out.astype(spots.dtype)

    def in_base_frame(self, point, drop: float = 0.0) -> tuple[float, float, float]:
        """A point given in the facing frame at the spot (x toward the table, z up, origin on
        the table top) in the base link's frame; ``drop``: how far the base stands below the
        spot (the table top's height above the floor for a floor-standing robot)."""
        x, y, z = point[0] + self.edge_offset, point[1], point[2] + drop
        c, s = math.cos(-self.base_yaw), math.sin(-self.base_yaw)
        return c * x - s * y, s * x + c * y, z


PANDA_REST = (0.0, math.pi / 8, 0.0, -3 * math.pi / 8, 0.0, 3 * math.pi / 4, math.pi / 4,
              0.04, 0.04)  # fmt: skip
# the Panda's gripper: pd_joint_pos on both fingers (mimic), actions [-1, 1] -> [-0.01, 0.04] m
PANDA_GRIPPER = Gripper(joints=2, open_qpos=0.04, closed_qpos=0.0, max_opening=0.08,
                        action_index=7, action_kind="absolute")  # fmt: skip
# reach from 0.30 m: the expert's top-down grasps nearer the base need the shoulder bent back
# (place_two, 50 seeds: 4 failures, movers 0.23-0.25 m away, when the band began at 0.20; 1 at 0.30)
PANDA = Robot(
    uid="panda", names=("franka", "franka_panda"), rest_qpos=PANDA_REST,
    noise_joints=tuple(range(7)), reach=(0.30, 0.78), goal_inset=0.10, goal_height=(0.05, 0.25),
    gripper=PANDA_GRIPPER, tcp_link="panda_hand_tcp", grasp_check=PANDA_GRASP,
    camera_mount="panda_link0", camera_eye=(0.95, 0.0, 0.55), camera_target=(0.30, 0.0, 0.0),
    expert=True,
)  # fmt: skip
ROBOTS: dict[str, Robot] = {
    r.uid: r
    for r in (
        PANDA,
        Robot(
            uid="panda_wristcam", names=(), rest_qpos=PANDA_REST, noise_joints=tuple(range(7)),
            reach=PANDA.reach, goal_inset=PANDA.goal_inset, goal_height=PANDA.goal_height,
            gripper=PANDA_GRIPPER, tcp_link="panda_hand_tcp", grasp_check=PANDA_GRASP,
            camera_mount="panda_link0", camera_eye=PANDA.camera_eye,
            camera_target=PANDA.camera_target, expert=True,
        ),
        # ManiSkill's table scene: base at the table's edge turned +90 deg, these joints;
        # its so100 motion planner opens the jaw at 0 rad (0.084 m between the tips) and
        # closes it at -0.8; the default controller steps the jaw by up to 0.2 rad
        Robot(
            uid="so100", names=("so_100", "so-100"),
            rest_qpos=(0.0, 0.0, 0.0, math.pi / 2, math.pi / 2, 0.0),
            noise_joints=tuple(range(5)), reach=(0.10, 0.36), goal_inset=0.05,
            goal_height=(0.05, 0.15),
            gripper=Gripper(joints=1, open_qpos=0.0, closed_qpos=-1.1, max_opening=0.084,
                            action_index=5, action_kind="delta"),
            tcp_link=None, grasp_check=JAW_GRASP, camera_mount="Base",
            camera_eye=(0.55, 0.0, 0.40), camera_target=(0.18, 0.0, 0.0), base_yaw=math.pi / 2,
            tcp_tips=("Fixed_Jaw_tip", "Moving_Jaw_tip"),
        ),
        # Koch v1.1: ManiSkill's rest keyframe (turned +90 deg), jaw opened to its limit
        # (1.6 rad: 0.078 m between gripper_tcp and gripper_tcp2; 0 rad: shut)
        Robot(
            uid="koch-v1.1", names=("koch", "koch_v1.1", "koch-v1.1"),
            rest_qpos=(0.0, 2.2, 3.017, -0.25, 0.0, 1.6),
            noise_joints=tuple(range(5)), reach=(0.10, 0.30), goal_inset=0.05,
            goal_height=(0.05, 0.15),
            gripper=Gripper(joints=1, open_qpos=1.6, closed_qpos=0.0, max_opening=0.078,
                            action_index=5, action_kind="delta"),
            tcp_link="gripper_tcp", grasp_check=JAW_GRASP, camera_mount="base_link",
            camera_eye=(0.50, 0.0, 0.38), camera_target=(0.16, 0.0, 0.0), base_yaw=math.pi / 2,
        ),
        # Fetch: ManiSkill's table-scene joints (torso up), fingers open (0.05 m each); on the
        # floor 0.345 m behind the spot (ManiSkill: 0.325 m behind the table's edge; the spot
        # is 0.02 m inside it). Action 7 of its 13 is the gripper (pd_joint_pos, mimic)
        Robot(
            uid="fetch", names=(),
            rest_qpos=(0.0, 0.0, 0.0, 0.386, 0.0, 0.0, 0.0, -math.pi / 4, 0.0, math.pi / 4, 0.0,
                       math.pi / 3, 0.0, 0.05, 0.05),
            noise_joints=(5, 7, 8, 9, 10, 11, 12), reach=(0.10, 0.60), goal_inset=0.08,
            goal_height=(0.05, 0.25),
            gripper=Gripper(joints=2, open_qpos=0.05, closed_qpos=0.0, max_opening=0.10,
                            action_index=7, action_kind="absolute"),
            tcp_link="gripper_link", grasp_check=FETCH_GRASP, camera_mount="base_link",
            camera_eye=(0.95, 0.0, 0.55), camera_target=(0.30, 0.0, 0.0),
            edge_offset=0.345, base_height="floor", mobile_base=True,
        ),
        # models that ManiSkill downloads separately (not in its wheel): rest joints from their
        # agents' keyframes ("rest", "ready_to_grasp"); gripper spans and reach are read from
        # their agent classes and data sheets, not measured: the models are not on this machine
        Robot(
            uid="xarm6_robotiq", names=("xarm6", "xarm"),
            rest_qpos=(0.0, 0.22, -1.23, 0.0, 1.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            noise_joints=tuple(range(6)), reach=(0.20, 0.65), goal_inset=0.10,
            goal_height=(0.05, 0.25),
            gripper=Gripper(joints=6, open_qpos=0.0, closed_qpos=0.81, max_opening=0.085,
                            action_index=6, action_kind="absolute"),
            tcp_link="eef", grasp_check=None, camera_mount="link_base",
            camera_eye=(0.95, 0.0, 0.55), camera_target=(0.30, 0.0, 0.0), in_wheel=False,
        ),
        Robot(
            uid="widowxai", names=("widowx_ai",),
            rest_qpos=(0.0, 1.38, 1.04, -1.26, 0.0, 0.0, 0.026, 0.026),
            noise_joints=tuple(range(6)), reach=(0.12, 0.45), goal_inset=0.06,
            goal_height=(0.05, 0.20),
            gripper=Gripper(joints=2, open_qpos=0.04, closed_qpos=0.0, max_opening=0.08,
                            action_index=6, action_kind="absolute"),
            tcp_link=None, grasp_check=None, camera_mount="base_link",
            camera_eye=(0.60, 0.0, 0.40), camera_target=(0.20, 0.0, 0.0), in_wheel=False,
        ),
        Robot(
            uid="widowx250s", names=("widowx", "widowx250", "wx250s"),
            rest_qpos=None,
            noise_joints=tuple(range(6)), reach=(0.12, 0.50), goal_inset=0.06,
            goal_height=(0.05, 0.20),
            gripper=Gripper(joints=2, open_qpos=0.037, closed_qpos=0.015, max_opening=0.074,
                            action_index=6, action_kind="absolute"),
            tcp_link=None, grasp_check=None, camera_mount="base_link",
            camera_eye=(0.60, 0.0, 0.40), camera_target=(0.20, 0.0, 0.0), in_wheel=False,
        ),
    )
}
SUPPORTED_ROBOTS = tuple(ROBOTS)
# EmbodiedGen's layout generator writes these names with no ManiSkill model (refused by name)
NO_MODEL_NAMES = ("ur5", "piper")
# layout robot names -> uids: every uid by itself, and its other names
ROBOT_NAMES: dict[str, str] = {
    **{uid: uid for uid in ROBOTS},
    **{name: r.uid for r in ROBOTS.values() for name in r.names},
}


def name_key(name: str) -> str:
    """A layout's robot name as the registry keys it: lower case, spaces as underscores."""
    return name.strip().lower().replace(" ", "_")


def robot(uid: str) -> Robot:
    """The entry of a supported uid (``KeyError`` for others: check names first)."""
    return ROBOTS[uid]
