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

Reach: the horizontal distance from the base of TCPs 0.02-0.20 m above its table, over 3000
random joint configurations (99th percentile / max): Panda 0.91 / 0.93, SO-100 0.46 / 0.48, Koch
0.37 / 0.38, Fetch 1.08 / 1.09; the reach bands stay below, where top-down grasps work.

This module imports nothing heavy (the layout commands use it without the simulator); what
needs ManiSkill (model files, grasp checks, the pads' material) is in ``envs/agents.py``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DOWNLOAD_COMMAND = "python -m mani_skill.utils.download_asset {uid}"
GRAVITY = 9.81  # m/s^2
MANISKILL_FORCE_LIMIT = 100.0  # N m: ManiSkill 3.0.1's arm drives (panda, so_100, koch .py)
# m: the SO-100's and the Koch's movers stand this far from other objects, room for a jaw
# (1.5 cm thick, tools/make/measure_jaws.py) and the grasps' 3 mm obstacle margin beside them:
# at 1 cm a 2 cm ball beside an 8 cm tin had no grasp for either hand (accept6 seed 1)
SMALL_ROOM = 0.02
# the arms at rest, a box per link but the base's: (x_lo, x_hi, y_lo, y_hi, z_lo) m in the robot
# spot's frame, z_lo above the table top (tools/make/measure_rest.py; PlacementLimits.rest_arm):
# objects as tall as a link's lowest point stand clear of its box (accept8 seed 5: a 15 cm globe
# over the SO-100's jaws at rest, the start colliding and no path leaving it)
PANDA_REST_ARM = (
    (-0.055, 0.056, -0.130, 0.056, 0.142), (-0.056, 0.125, -0.056, 0.130, 0.280),
    (0.024, 0.253, -0.055, 0.112, 0.494), (0.141, 0.322, -0.112, 0.056, 0.540),
    (0.316, 0.634, -0.056, 0.130, 0.622), (0.533, 0.711, -0.057, 0.044, 0.629),
    (0.649, 0.743, -0.088, 0.054, 0.640), (0.694, 0.777, -0.101, 0.104, 0.607),
    (0.752, 0.806, -0.067, -0.039, 0.578), (0.752, 0.806, 0.039, 0.066, 0.578),
)  # link1 .. link7, hand, left and right fingers
SO100_REST_ARM = (
    (0.033, 0.097, -0.027, 0.027, 0.018), (0.063, 0.115, -0.036, 0.035, 0.109),
    (0.091, 0.249, -0.036, 0.027, 0.218), (0.222, 0.255, -0.036, 0.028, 0.176),
    (0.214, 0.263, -0.038, 0.031, 0.072), (0.214, 0.263, 0.006, 0.080, 0.094),
)  # Rotation_Pitch, Upper_Arm, Lower_Arm, Wrist_Pitch_Roll, Fixed_Jaw, Moving_Jaw
KOCH_REST_ARM = (
    (0.032, 0.080, -0.014, 0.015, 0.005), (0.029, 0.083, -0.020, 0.021, 0.041),
    (-0.013, 0.081, -0.022, 0.023, 0.040), (0.007, 0.112, -0.017, 0.018, 0.147),
    (0.088, 0.115, -0.024, 0.019, 0.168), (0.084, 0.108, -0.013, 0.018, 0.099),
    (0.104, 0.172, -0.016, 0.021, 0.148),
)  # link_1 .. link_6, gripper


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

# the control modes the scripted expert records in (``collect --control-mode``): it commands
# joint targets (pd_joint_pos), turned into the others' actions step by step (solvers/modes.py)
EXPERT_MODES = (
    "pd_joint_pos", "pd_joint_delta_pos", "pd_joint_target_delta_pos", "pd_joint_vel",
    "pd_ee_delta_pos", "pd_ee_delta_pose", "pd_ee_pose",
)  # fmt: skip
FETCH_GRASP = FingerGrasp(opening=(-1.0, 1.0))  # Fetch.is_grasping: its left finger's -y opens


@dataclass(frozen=True)
class Hand:
    """What the scripted expert (``solvers/``) needs of a robot's hand. The expert describes a
    grasp in one frame for every robot, ManiSkill's Panda ``panda_hand_tcp``'s: origin between
    the open jaws' tips, z the approach, y the closing direction.

    ``link``: the link the expert plans for (mplib's move group); ``grasp_in_link``: the grasp
    frame's pose in that link's frame (xyz, quaternion wxyz). ``boxes``: the open hand as
    boxes in the grasp frame (``solvers.gripper.GripperModel``'s fields: the jaws' opening,
    width, thickness, how far their tips reach past the origin, their length, the palm's x-y
    size and z extent). ``grasp_depth``: the grasp centre this far below an object's top
    (the jaws' usable length); ``approach_offset``: the pre-grasp this far back from the grasp
    along the approach. ``joint_vel``, ``joint_acc``: per arm joint, the fastest the
    expert plans (rad/s, rad/s^2). ``action_open``, ``action_closed``: the gripper's
    ``pd_joint_pos`` action open and shut; ``action_openings``: jaw gaps (m) and the actions
    that hold them, between which an opening is interpolated. ``tilt_tolerance``: see the
    field."""

    link: str
    grasp_in_link: tuple[float, ...]
    boxes: tuple[tuple[str, object], ...]
    grasp_depth: float
    approach_offset: float
    joint_vel: tuple[float, ...]
    joint_acc: tuple[float, ...]
    action_open: float
    action_closed: float
    action_openings: tuple[tuple[float, float], ...]  # (jaw gap m, action), gaps ascending
    max_path_steps: int = 180  # control steps: a longer plan is refused (a wrist flip, a
    # detour; the SO-100's joints follow at 0.4 rad/s, the Panda's at 0.8)
    tilt_tolerance: float = 0.0  # rad, how far a pose's orientation may stay off in the IK
    # (an arm of fewer than six joints, solvers/motion.py)
    planar: bool = False  # the hand approaches only within the arm's vertical plane (five
    # joints: base turn, three pitches, wrist roll): its grasps are aimed so
    fixed_jaw: float = 0.0  # m: a hand with one jaw that stands still (the SO-100's): its inner
    # face's y in the grasp frame (signed), from the robot's collision hulls
    # (tools/make/measure_jaws.py); the expert takes an object against it, the other jaw open
    # (solvers/grasp_choice.py); 0: the jaws close together about the origin
    tilt_reach: tuple[tuple[float, float, float], ...] = ()  # a planar hand's reachable
    # orientations: (m from the base, lowest, highest deg) the approach tilts from straight
    # down toward the far side at which its IK reaches a grasp 1.5 cm above the table, straight
    # ahead, by distance (tools/make/measure_tilts.py); empty: every tilt is tried
    # a jaw that the arm's PD gains drive closes gently (solvers/, PickPlaceSolver._close_gently):
    close_gap: float = 0.0  # m: first at once to the object's width plus this (0: shut at once)
    close_step: float = 0.0  # then its target leads the jaw by this (action) until it grasps
    squeeze: float = 0.0  # and stays this far (action) past where the jaw stands
    wedge_squeeze: float = 0.0  # instead where they press at an angle the grasp rule does not count
    # (0: squeeze; seen mostly on a retry): the SO-100's 8 mrad took a 1.7 cm prism, balls unchanged
    grip_lead: float = 0.0  # then, while it holds, its target is kept this far (action) past the
    # jaw at every control step (PickPlaceSolver._keep_grip): a PD jaw presses only by its lead,
    # and the SO-100's jaw crept to 0.3 mrad of the target its squeeze set (3 N on a hex pencil,
    # then none as the carry's turn began: the pencil fell out, accept10 4/12 -> 12/12 at 2
    # mrad); 0: the target set at the grasp stays (the Panda; the Koch, whose arm gives way)
    lift_heights: tuple[float, ...] = (0.05, 0.10)  # m, lifts after grasping, tried in order
    # (5 cm first saves the Panda 3-7 steps); the SO-100's first 2 cm, its carry rising the rest
    # (in pd_joint_delta_pos the lift cost 40-90 of 500 steps); not the Koch's (its arm gives
    # way: at 2 cm it lost the zoo's battery 3 times in 6)
    drifts: bool = False  # its arm gives way while its jaw squeezes an object (the Koch: mostly its
    # wrist, 0.05-0.3 rad off its targets, once 2.5): it plans from its joint targets and the hand
    # where they put it, and corrects at the goal while the object is off it (solvers/)
    convertible: bool = True  # its joint targets kept within what its other joint controllers
    # follow (solvers/follow.py); False: one controller drives every joint, which ManiSkill
    # 3.0.1's converter cannot convert anyway (the SO-100: 8 of 20 ran out of steps)

    def tilts_at(self, distance):
        """The approach tilts (deg, lowest and highest) this hand reaches an object at
        ``distance`` m from its base with (``tilt_reach``'s rows interpolated, its ends beyond
        them; (0, 90) without); ``distance`` a float or an array (then arrays)."""
        if not self.tilt_reach:
            return np.zeros_like(distance) + 0.0, np.zeros_like(distance) + 90.0
        at, lo, hi = np.asarray(self.tilt_reach, dtype=float).T
        return np.interp(distance, at, lo), np.interp(distance, at, hi)

    def action(self, opening: float) -> float:
        """The ``pd_joint_pos`` gripper action that opens the jaws ``opening`` m apart
        (``action_openings`` interpolated, clipped to its ends)."""
        table = self.action_openings
        if opening <= table[0][0]:
            return table[0][1]
        for (g0, a0), (g1, a1) in zip(table, table[1:], strict=False):
            if opening <= g1:
                return a0 + (opening - g0) / (g1 - g0) * (a1 - a0)
        return table[-1][1]


@dataclass(frozen=True)
class Robot:
    """One supported robot; see the module's docstring for the base placement."""

    uid: str  # ManiSkill's agent uid
    names: tuple[str, ...]  # other names a layout's relation.robot may use (lower case)
    rest_qpos: tuple[float, ...] | None  # every active joint, gripper open (None: the
    # agent's first keyframe)
    noise_joints: tuple[int, ...]  # joints that get the start noise (at most NOISE_DIMS)
    reach: tuple[float, float]  # m from its reach centre (reach_origin): placement limits' band
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
    hand: Hand | None = None  # what the scripted expert (solvers/) needs; None: it does not
    # drive this robot
    # m: the least gap placement keeps between the task's movers and every other object
    # (PlacementLimits.mover_clearance); None: the placement clearance, 1 cm (the Panda's)
    mover_clearance: float | None = None
    # m ahead of the spot: the centre of its reach band and heading cone
    # (PlacementLimits.reach_origin). The Koch's is its pan axis (ArmDriver._pan_axis, 6.8 cm
    # ahead; tested equal): it turns about it, so an object off to the side is as far for it as
    # one that far from the axis ahead. 0, the spot: the Panda (its axis stands there) and the
    # SO-100 (axis 4.5 cm ahead, but its band about the spot was measured and kept)
    reach_origin: float = 0.0
    rest_arm: tuple | None = None  # its links at rest (PlacementLimits.rest_arm); None: unmeasured
    arm_force_limit: float | None = None  # N m, the most its arm joints' drives exert
    # (ManiSkill 3.0.1's controller configs: force_limit=100 for the Panda, SO-100 and Koch; their
    # URDFs give none: so100.urdf's effort="0", the Koch's no effort); None: not read, unchecked
    pad_friction: float | None = None  # its jaw pads' friction (static and dynamic) instead of
    # its ManiSkill class's ``gripper`` material (envs/agents.set_pads); None: ManiSkill's

    @property
    def placement(self) -> dict:
        """The placement limits that follow the robot (``PlacementLimits``' fields): its reach
        band, its movers' clearance and its arm at rest."""
        return dict(reach_min=self.reach[0], reach_max=self.reach[1],
                    reach_origin=self.reach_origin, mover_clearance=self.mover_clearance,
                    rest_arm=self.rest_arm)  # fmt: skip

    @property
    def payload(self) -> float | None:
        """The heaviest object (kg) its arm holds up at the far end of its reach: the drives'
        force limit over the weight's lever there (its own links' weight is balanced by the
        simulator's passive forces); None where ``arm_force_limit`` is not known."""
        if self.arm_force_limit is None:
            return None
        return self.arm_force_limit / (GRAVITY * (self.reach[1] + self.reach_origin))

    def pads(self, maniskill_config: dict | None) -> float | None:
        """Its jaw pads' friction: ``pad_friction``, else its ManiSkill class's (None: none)."""
        pads = (maniskill_config or {}).get("_materials", {}).get("gripper") or {}
        return pads.get("dynamic_friction") if self.pad_friction is None else self.pad_friction

    @property
    def expert(self) -> bool:
        """Whether the scripted expert drives this robot."""
        return self.hand is not None

    def base_poses(self, spots, floor_z: float):
        """Base raw poses ``(n, 7)`` (xyz, quaternion wxyz, as ManiSkill's) from the layout
        spots' ``spots (n, 7)``; the spots themselves (same array) for a robot standing there."""
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
# the Panda's hand as the expert knows it: the grasp frame is panda_hand_tcp; its boxes are the
# bounding boxes of ManiSkill's finger and hand collision meshes (solvers/gripper.py's defaults);
# speeds within Franka's datasheet (velocity 2.175 rad/s for joints 1-4, 2.61 for 5-7;
# acceleration 15, 7.5, 10, 12.5, 15, 20, 20); pd_joint_pos maps the gripper's action [-1, 1] to
# each finger at [-0.01, 0.04] m
PANDA_HAND = Hand(
    link="panda_hand_tcp", grasp_in_link=(0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0), boxes=(),
    grasp_depth=0.035, approach_offset=0.08, joint_vel=(2.0, 2.0, 2.0, 2.0, 2.5, 2.5, 2.5),
    joint_acc=(15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0), action_open=1.0, action_closed=-1.0,
    action_openings=((-0.02, -1.0), (0.08, 1.0)),
)  # fmt: skip
# the SO-100's hand (its jaw's sections measured in ManiSkill 3.0.1's collision meshes, jaw at
# 0 rad): the grasp frame's origin midway between the jaws' tip links, z along -y of Fixed_Jaw,
# y along its x. The still jaw's inner face stands 0.0385 m from the origin (fixed_jaw), its tip
# 0.019 m past it; the moving jaw's face swings in from -0.025 m, its tip from 0.003 m behind the
# origin to 0.019 m past it at -0.7 rad (tools/make/measure_jaws.py). Modelled: the jaws 0.06 m
# apart, their tips 0.019 m past the origin (at 0.012 the real tips met the table under a short
# object), the palm behind them (0.02 m across: the jaws' roots; the jaw's motor, 0.048 m
# across, is 0.045 m back): objects are taken 0.02 m below their top, from 0.04 m back, against
# the still jaw (grasp_choice.py). Its pd_joint_pos drives the jaw's angle: 0 open, -1.1 shut,
# with the arm's gains (stiffness 1e3, 100 N m), so it closes gently, and holds with its target
# 2 mrad past the jaw (2 N m; with none, the jaw's target where it stood when it met the block,
# a block held by the drive's residual slipped at the lift: so100_block seed 2 in
# pd_joint_delta_pos); holding an object against the still jaw its wrist gives way 0.1-0.26 rad
# (drifts: docs/robots.md, "Small objects")
SO100_HAND = Hand(
    link="Fixed_Jaw", grasp_in_link=(-0.0306, -0.0873, 0.0, 0.5, 0.5, 0.5, -0.5),
    boxes=(("opening", 0.06), ("finger_width", 0.02), ("finger_thickness", 0.015),
           ("finger_tip", 0.019), ("finger_length", 0.044), ("palm_size", (0.02, 0.132)),
           ("palm_z", (-0.12, -0.025))),
    grasp_depth=0.02, approach_offset=0.04, joint_vel=(1.5,) * 5, joint_acc=(8.0,) * 5,
    action_open=0.0, action_closed=-1.1, tilt_tolerance=0.1, planar=True,
    action_openings=((0.005, -1.1), (0.0121, -1.0), (0.0187, -0.9), (0.0251, -0.8),
                     (0.0314, -0.7), (0.0362, -0.6), (0.0408, -0.5), (0.0456, -0.4),
                     (0.0509, -0.3), (0.0569, -0.2), (0.0636, -0.1), (0.0706, 0.0)),
    close_gap=0.004, close_step=0.02, squeeze=0.002, wedge_squeeze=0.008, grip_lead=0.002,
    max_path_steps=300, convertible=False, fixed_jaw=0.0385, drifts=True,
    lift_heights=(0.02, 0.05, 0.10),
    tilt_reach=((0.14, 0.0, 0.0), (0.18, 0.0, 15.0), (0.22, 0.0, 15.0), (0.26, 0.0, 30.0),
                (0.30, 0.0, 30.0), (0.34, 15.0, 45.0)),
)  # fmt: skip
# the Koch's hand (its jaws' collision hulls in ManiSkill 3.0.1's model): the fixed jaw is
# link_6 (inner face at x -0.009 over z -0.069..0), the moving jaw (link "gripper") turns about
# link_6's -y at x 0.007, z -0.013, 0 rad shut (tips 3 mm apart), 1.6 open. The grasp frame: z
# along link_6's -z, y along its x, origin mid-opening 0.058 down (the tips 0.011 past it).
# The moving jaw is slanted when open (its face furthest out at its tip), so the gap per angle
# is measured 0.015 above the origin (lower on the slanted jaw it is wider): 0.0445 m at 1.0 rad;
# above 1.25 rad its tip no longer reaches down there. Palm: link_5 and the jaws' roots above.
# The moving jaw's inner face ends at a knuckle 8-11 mm above the origin at the angles that
# close on 2-3 cm (0.33-0.6 rad): an object's top above it meets the knuckle's edge, and a 3 cm
# cube slipped out at every lift (grasp_depth 0.015); taken 0.005 below its top, the top stays
# below the knuckle by the descent's error (SCREW_END_TOLERANCE, 3 mm) and the face holds it.
# Its pd_joint_pos drives the jaw with stiffness 100, damping 1 (1 mrad: about 3 N on an object);
# on pads of friction 2 a squeeze of 3 mrad holds (0.01 rad, for ManiSkill's pads of 0.3: accept2-13
# 481 of 504, at 3 mrad 492), and the arm gives way under it (drifts). Its still jaw's face stands
# 0.0225 m from the origin on -y (fixed_jaw, tools/make/measure_jaws.py): objects are taken
# against it, as the SO-100's (centred, the moving jaw pushed a flat L-shaped block 1.4 cm
# across the table by its top edge and turned it)
KOCH_HAND = Hand(
    link="link_6", grasp_in_link=(0.0136, 0.0, -0.058, 0.0, 0.7071068, 0.7071068, 0.0),
    boxes=(("opening", 0.045), ("finger_width", 0.03), ("finger_thickness", 0.015),
           ("finger_tip", 0.011), ("finger_length", 0.033), ("palm_size", (0.052, 0.07)),
           ("palm_z", (-0.115, -0.022))),
    grasp_depth=0.005, approach_offset=0.04, joint_vel=(1.5,) * 5, joint_acc=(8.0,) * 5,
    action_open=1.6, action_closed=0.0, tilt_tolerance=0.1, planar=True,
    action_openings=((0.0027, 0.0), (0.0078, 0.1), (0.0129, 0.2), (0.0178, 0.3),
                     (0.0211, 0.4), (0.0243, 0.5), (0.0277, 0.6), (0.0315, 0.7),
                     (0.0357, 0.8), (0.0401, 0.9), (0.0445, 1.0), (0.0497, 1.1),
                     (0.0563, 1.2)),
    close_gap=0.004, close_step=0.02, squeeze=0.003, max_path_steps=300, convertible=False,
    drifts=True, fixed_jaw=-0.0225,
    tilt_reach=((0.12, 0.0, 0.0), (0.15, 0.0, 15.0), (0.19, 0.0, 30.0), (0.23, 0.0, 45.0),
                (0.26, 0.0, 60.0), (0.29, 15.0, 75.0), (0.32, 30.0, 75.0)),
)  # fmt: skip
# reach from 0.30 m: the expert's top-down grasps nearer the base need the shoulder bent back
# (place_two, 50 seeds: 4 failures, movers 0.23-0.25 m away, when the band began at 0.20; 1 at 0.30)
PANDA = Robot(
    uid="panda", names=("franka", "franka_panda"), rest_qpos=PANDA_REST,
    noise_joints=tuple(range(7)), reach=(0.30, 0.78), goal_inset=0.10, goal_height=(0.05, 0.25),
    gripper=PANDA_GRIPPER, tcp_link="panda_hand_tcp", grasp_check=PANDA_GRASP,
    camera_mount="panda_link0", camera_eye=(0.95, 0.0, 0.55), camera_target=(0.30, 0.0, 0.0),
    hand=PANDA_HAND, arm_force_limit=MANISKILL_FORCE_LIMIT, rest_arm=PANDA_REST_ARM,
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
            camera_target=PANDA.camera_target, hand=PANDA_HAND,
            arm_force_limit=MANISKILL_FORCE_LIMIT, rest_arm=PANDA_REST_ARM,
        ),
        # ManiSkill's table scene: base at the table's edge turned +90 deg, these joints;
        # its so100 motion planner opens the jaw at 0 rad (0.084 m between the tips) and
        # closes it at -0.8; the default controller steps the jaw by up to 0.2 rad; reach from
        # 0.14 m: nearer, its IK reaches no grasp 1.5 cm above the table (tilt_reach)
        Robot(
            uid="so100", names=("so_100", "so-100"),
            rest_qpos=(0.0, 0.0, 0.0, math.pi / 2, math.pi / 2, 0.0),
            noise_joints=tuple(range(5)), reach=(0.14, 0.30), goal_inset=0.05,
            goal_height=(0.04, 0.10),  # the expert reaches these holding a block
            gripper=Gripper(joints=1, open_qpos=0.0, closed_qpos=-1.1, max_opening=0.084,
                            action_index=5, action_kind="delta"),
            tcp_link=None, grasp_check=JAW_GRASP, camera_mount="Base",
            camera_eye=(0.55, 0.0, 0.40), camera_target=(0.18, 0.0, 0.0), base_yaw=math.pi / 2,
            tcp_tips=("Fixed_Jaw_tip", "Moving_Jaw_tip"),
            hand=SO100_HAND, arm_force_limit=MANISKILL_FORCE_LIMIT, mover_clearance=SMALL_ROOM,
            rest_arm=SO100_REST_ARM,
        ),
        # Koch v1.1: turned +90 deg as ManiSkill's keyframes; its hand pointing down, the jaws'
        # tips 0.10 m above the table 0.12 m out (ManiSkill's rest keyframe, folded, holds
        # them 0.02 m above it, where the expert's planner finds the start colliding), jaw
        # opened to its limit (1.6 rad: 0.078 m between gripper_tcp and gripper_tcp2; 0: shut);
        # reach to 0.24 m (blocks 0.25-0.26 m out off to the side had no grasp with IK);
        # pads of friction 2 as ManiSkill 3.0.1's Panda, SO-100, Fetch, WidowX AI (its Koch's: 0.3)
        Robot(
            uid="koch-v1.1", names=("koch", "koch_v1.1", "koch-v1.1"),
            rest_qpos=(0.0, 2.2, 1.6, 2.0, 0.0, 1.6),
            noise_joints=tuple(range(5)), reach=(0.052, 0.19), reach_origin=0.068,
            goal_inset=0.03,
            goal_height=(0.04, 0.10),  # the expert reaches these holding a block
            gripper=Gripper(joints=1, open_qpos=1.6, closed_qpos=0.0, max_opening=0.078,
                            action_index=5, action_kind="delta"),
            tcp_link="gripper_tcp", grasp_check=JAW_GRASP, camera_mount="base_link",
            camera_eye=(0.50, 0.0, 0.38), camera_target=(0.16, 0.0, 0.0), base_yaw=math.pi / 2,
            hand=KOCH_HAND, arm_force_limit=MANISKILL_FORCE_LIMIT, mover_clearance=SMALL_ROOM,
            rest_arm=KOCH_REST_ARM, pad_friction=2.0,
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
