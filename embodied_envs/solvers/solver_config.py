"""The scripted policy's tunable numbers (:class:`SolverConfig`), read by the solver
(``pick_place.py``) and each of its rooms (``grasp_choice.py``, ``driver.py``, ...)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from embodied_envs.solvers.motion import MotionConfig


@dataclass(frozen=True)
class SolverConfig:
    """Tunable numbers of the scripted policy."""

    approach_offset: float | None = None  # m, pre-grasp distance above the grasp along the
    # approach (None: the robot's hand entry's, robots.py)
    grasp_depth: float | None = None  # m, grasp centre below the object's top (None: the
    # robot's hand entry's, robots.py)
    min_tcp_height: float = 0.015  # m, lowest grasp centre above the support surface
    lift_heights: tuple[float, ...] | None = None  # m, lifts after grasping, tried in order
    # (None: the robot's hand entry's, robots.py)
    gripper_steps: int = 8  # control steps to open the gripper, and at most to close it
    close_steps: int = 80  # control steps at most to close a jaw gently (``_close_gently``):
    # the SO-100's jaw at -0.3 to -0.5 rad closes 5 mm per 0.1 rad at its gentle 0.2 rad/s, and
    # pushing a 4.5 cm block across the margin to its still jaw took more than 40
    finger_rest: float = 1e-4  # m per step: fingers moving less are at rest (closed on the
    # object: 3 steps on the shipped layouts)
    rest_steps: int = 40  # control steps at most, after the last release, for the movers to
    # come to rest (a banana rocks in a bowl; success ends the episode earlier)
    hold_steps: int = 10  # control steps holding still at the goal; a demo goes on for this
    # many steps after its task succeeds (the env terminates there), so that an arm replayed in
    # another controller, which lags the recorded one, comes to rest in success too
    # rad/s and rad/s^2 per arm joint (None: the robot's hand entry's, robots.py)
    joint_vel_limits: tuple[float, ...] | None = None
    joint_acc_limits: tuple[float, ...] | None = None
    convertible: bool = True  # joint targets every arm controller can replay (``follow.py``:
    # speeds and per-step changes within pd_joint_delta_pos's and pd_joint_vel's limits);
    # False: the speeds above, which only pd_joint_pos replays
    consistent: bool = True  # demos made to be learned: nearby starts take the same grasp (the
    # first in rank order that plans, straight joint lines before detours; the synthesised
    # grasps ranked without the roomy-first preference a centimetre's move flips, each one's
    # closing folded toward the hand's), so they give nearby paths; False: the former,
    # diverse expert (the grasp whose approach costs fewest steps; ``collect --diverse``)
    fixed_hand: bool = False  # every grasp top-down with the hand's closing direction as it
    # starts, and no turn of the hand on the carry: demos that pd_ee_delta_pos, which keeps the
    # hand's orientation, replays (``grasp_choice.py``); an object the hand cannot take so fails
    motion: MotionConfig = MotionConfig()  # the seeded IK and RRT-Connect (solvers/motion.py)
    max_path_steps: int | None = None  # a longer plan (a wrist flip, a detour) is refused as
    # "long" (None: the robot's hand entry's: the Panda's 180)
    # (at the convertible speeds: default seeds 17 and 37 plan approaches and carries of
    # 121-150 steps, which a cap of 120 refused)
    obstacle_points: int = 3000  # surface samples per obstacle actor
    obstacle_radius: float = 0.01  # m, radius of each obstacle point
    base_clearance: float = 0.15  # m, obstacle points this close to the base (in XY) and
    # below base_clearance_height are dropped: the base stands on the table's edge
    base_clearance_height: float = 0.10  # m above the base
    grasp_candidates: int = 6  # posed grasps tried per attempt, best first
    planar_tilts: tuple[float, ...] = (30.0, 15.0, 45.0, 0.0, 60.0)  # deg, a planar hand's
    # (robots.py) approaches from straight down toward the far side of its arm's plane, in
    # order (the SO-100 reaches a box's top 0.27 m away tilted 15-60 degrees, not straight down)
    planar_lift_turns: tuple[float, ...] = (15.0, -15.0, 30.0, -30.0)  # deg, a planar hand's
    # lifts turned in its arm's plane, tried after the grasp's own orientation; and its carry's
    # pitches at the goal where no carry keeping the hand's orientation plans
    option_steps: int = 10  # a grasp one rank lower is taken when its approach is this many
    # steps shorter
    grasp_attempts: int = 3  # grasp, check, lift rounds per episode (a miss opens and retries)
    attempt_steps: int = 110  # steps an attempt needs at least: none starts with fewer left
    settle_steps: int = 6  # control steps at most at the pre-grasp and the grasp (the arm
    # lags), ending once every joint is within settle_tolerance of its target
    settle_tolerance: float = 0.01  # rad
    lift_check: float = 0.5  # the object held rises at least this part of the lift
    slip_tolerance: float = 0.03  # m, the object moving this far in the hand may be dropped
    moved_tolerance: float = 0.02  # m, a target moved this far since its grasps were planned
    # (knocked, rolling) is not grasped there: the next attempt plans from where it lies (at 1 cm
    # a smooth ball still rolling from its placement was given up 3 times in 6 seeds, at 2 cm 0)
    rise_clearance: float = 0.12  # m, above the highest obstacle point before a carry from above
    release_clearance: float = 0.04  # m, a carried mover's lowest point above the
    # receptacle's top (or the table) over its destination, before it is lowered
    release_gap: float = 0.01  # m, its lowest point above the surface when the hand opens
    open_before: int = 0  # control steps before the lowering ends that the hand starts opening:
    # none, it opens once the arm has settled at the bottom (at 3 it opened while the arm still
    # moved down, a state a policy cloned from it never reached: docs/evaluation.md)
    carry_yaws: tuple[float, ...] = (0.0, np.pi / 2, -np.pi / 2, np.pi)  # rad, hand turns at
    # the goal about the vertical, tried in order
    release_carry_methods: tuple[str, ...] = ("rrt", "screw")  # a carry to a release: the
    # shortest straight joint line over every hand turn first (a screw path, straight in
    # space, turned the can's carry into 150-180 steps of joint travel on place_two)
    release_carry_option_steps: int | None = 10  # and the shortest of the turns wins
    settle_rounds: int = 3  # a hand that drifts (robots.Hand.drifts): corrections at the goal
    goal_tolerance: float = 0.01  # m, while the object is this far off it, each a move of
    settle_max_steps: int = 40  # control steps at most
    release_surround: float = 0.08  # m, obstacles this far around the mover over its
    # destination are cleared too when it is carried there (``_carry_goal``)
    carry_clearance: float = 0.01  # m, the held object's collision points at least this far
    # from every obstacle point along a carry to a release (place, move; the planner sees the
    # arm, not what it holds)
