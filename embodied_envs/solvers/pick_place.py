"""Scripted, motion-planned pick-and-place for the Panda (mplib).

For every env the solver plans from that env's own robot and object state: grasps synthesised
from the target's collision geometry (``solvers/grasps.py``: antipodal, collision-free against
the object, the table and the distractors, ranked), posed where the object lies now; approach,
grasp, lift, carry the object to the goal and hold still. Table and distractors are obstacles
(surface point clouds). The loop is closed: after closing the fingers and after the lift the
solver checks the grasp (the object rose with the hand), and on a miss opens, backs off and
tries the next grasp; after the carry, an object that left its place in the hand (and is not
held) is grasped again from where it lies, while the episode has steps left. A failed plan is
recorded per env and stage; that env then holds still while the others go on.
"""

from __future__ import annotations

import dataclasses
import weakref
from dataclasses import dataclass, field

import mplib
import numpy as np
import sapien
import torch
from scipy.spatial import cKDTree

from embodied_envs.layout.assets import asset_geometry, convex_hull_2d
from embodied_envs.layout.pose import LayoutPose
from embodied_envs.robots import ROBOTS
from embodied_envs.solvers.follow import follow_limits, rate_limited, shortened
from embodied_envs.solvers.grasps import (
    GraspConfig,
    GripperModel,
    asset_grasps,
    grasp_is_valid,
    hull_points,
    posed_clearance,
    posed_grasps,
    widest_height,
)
from embodied_envs.solvers.motion import (
    STRAIGHT_BLOCKED,
    MotionConfig,
    SeededPlanner,
    joint_levers,
)

GRIPPER_OPEN = 1.0  # pd_joint_pos gripper action for open fingers
GRIPPER_CLOSED = -1.0  # and for closed fingers
# the Panda's pd_joint_pos gripper maps actions [-1, 1] to finger positions [-0.01, 0.04] m
FINGER_RANGE = (-0.01, 0.04)


def gripper_action(opening: float) -> float:
    """The gripper action that opens the fingers ``opening`` m apart."""
    lo, hi = FINGER_RANGE
    return float(np.clip(2 * (opening / 2 - lo) / (hi - lo) - 1, -1.0, 1.0))


@dataclass(frozen=True)
class SolverConfig:
    """Tunable numbers of the scripted policy."""

    approach_offset: float = 0.08  # m, pre-grasp distance above the grasp along the approach
    grasp_depth: float = 0.035  # m, grasp centre below the object's top
    min_tcp_height: float = 0.015  # m, lowest grasp centre above the support surface
    lift_heights: tuple[float, ...] = (0.05, 0.10)  # m, lifts after grasping, tried in order
    # (the carry plans from there: 5 cm before 10 saves 3-7 steps an episode on the shipped
    # layouts and the zoo, with the same successes)
    gripper_steps: int = 8  # control steps to open the gripper, and at most to close it
    finger_rest: float = 1e-4  # m per step: fingers moving less are at rest (closed on the
    # object: 3 steps on the shipped layouts)
    rest_steps: int = 40  # control steps at most, after the last release, for the movers to
    # come to rest (a banana rocks in a bowl; success ends the episode earlier)
    hold_steps: int = 10  # control steps holding still at the goal; a demo goes on for this
    # many steps after its task succeeds (the env terminates there), so that an arm replayed in
    # another controller, which lags the recorded one, comes to rest in success too
    # rad/s and rad/s^2 per arm joint, within the Panda's (Franka's datasheet: velocity 2.175
    # for joints 1-4 and 2.61 for 5-7; acceleration 15, 7.5, 10, 12.5, 15, 20, 20)
    joint_vel_limits: tuple[float, ...] = (2.0, 2.0, 2.0, 2.0, 2.5, 2.5, 2.5)
    joint_acc_limits: tuple[float, ...] = (15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0)
    convertible: bool = True  # joint targets every arm controller can replay (``follow.py``:
    # speeds and per-step changes within pd_joint_delta_pos's and pd_joint_vel's limits);
    # False: the speeds above, which only pd_joint_pos replays
    motion: MotionConfig = MotionConfig()  # the seeded IK and RRT-Connect (solvers/motion.py)
    max_path_steps: int = 180  # a longer plan (a wrist flip, a detour) is refused as "long"
    # (at the convertible speeds: default seeds 17 and 37 plan approaches and carries of
    # 121-150 steps, which a cap of 120 refused)
    obstacle_points: int = 3000  # surface samples per obstacle actor
    obstacle_radius: float = 0.01  # m, radius of each obstacle point
    base_clearance: float = 0.15  # m, obstacle points this close to the base (in XY) and
    # below base_clearance_height are dropped: the base stands on the table's edge
    base_clearance_height: float = 0.10  # m above the base
    grasp_candidates: int = 6  # posed grasps tried per attempt, best first
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
    carry_yaws: tuple[float, ...] = (0.0, np.pi / 2, -np.pi / 2, np.pi)  # rad, hand turns at
    # the goal about the vertical, tried in order
    release_carry_methods: tuple[str, ...] = ("rrt", "screw")  # a carry to a release: the
    # shortest straight joint line over every hand turn first (a screw path, straight in
    # space, turned the can's carry into 150-180 steps of joint travel on place_two)
    release_carry_option_steps: int | None = 10  # and the shortest of the turns wins
    release_surround: float = 0.08  # m, obstacles this far around the mover over its
    # destination are cleared too when it is carried there (``_carry_goal``)
    carry_clearance: float = 0.01  # m, the held object's collision points at least this far
    # from every obstacle point along a carry to a release (place, move; the planner sees the
    # arm, not what it holds)


@dataclass
class EnvReport:
    """What happened in one env."""

    env_index: int
    plan_failures: list[str] = field(default_factory=list)  # "stage: [option k: ]planner statuses"
    misses: list[str] = field(default_factory=list)  # "stage (attempt k)": grasps that slipped

    @property
    def planned(self) -> bool:
        return not self.plan_failures


@dataclass
class SolveResult:
    reports: list[EnvReport]
    steps: int
    info: dict  # the env's last info (success etc.), tensors

    @property
    def success(self) -> np.ndarray:
        return np.asarray(torch.as_tensor(self.info["success"]).cpu().numpy()).reshape(-1)


def grasp_frame(
    vertices_world: np.ndarray, support_z: float, cfg: SolverConfig, current_y: np.ndarray
):
    """Grasp centre and closing direction for a top-down grasp.

    The closing direction is the narrow side of the minimum-area rectangle around the object's
    XY footprint; its sign is the one closest to the gripper's current closing axis. Its height
    is ``grasp_depth`` below the top, or a round body's widest section above that
    (``grasps.widest_height``).
    """
    hull = convex_hull_2d(vertices_world[:, :2])
    best = None
    for i in range(len(hull)):
        e = hull[(i + 1) % len(hull)] - hull[i]
        u = e / (np.linalg.norm(e) + 1e-12)
        v = np.array([-u[1], u[0]])
        pu, pv = hull @ u, hull @ v
        area = (pu.max() - pu.min()) * (pv.max() - pv.min())
        if best is None or area < best[0]:
            best = (area, u, v, pu, pv)
    _, u, v, pu, pv = best
    wu, wv = pu.max() - pu.min(), pv.max() - pv.min()
    closing2 = u if wu < wv else v
    centre2 = u * (pu.max() + pu.min()) / 2 + v * (pv.max() + pv.min()) / 2
    closing = np.array([closing2[0], closing2[1], 0.0])
    if np.dot(closing, current_y) < 0:
        closing = -closing
    top = vertices_world[:, 2].max()
    z = max(top - cfg.grasp_depth, support_z + cfg.min_tcp_height)
    z = min(z, top - 0.005)
    z = widest_height(vertices_world, closing, z, top - 0.005)  # a round body: its equator
    return np.array([centre2[0], centre2[1], z]), closing


# per env (the unwrapped env object), its mplib planners, one per parallel env: building one
# parses the URDF and its collision meshes (5 ms, an episode's 2%). Solvers of one env run one
# after another; each sets everything a plan reads (base pose, joint limits, obstacle cloud,
# the robot's configuration) before planning.
_PLANNERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


# per robot URDF, its joints' levers (motion.joint_levers: 75 ms)
_LEVERS: dict[str, np.ndarray] = {}


def _levers(base) -> np.ndarray:
    """The levers of ``base``'s (an unwrapped env's) robot's arm joints."""
    if base.agent.urdf_path not in _LEVERS:
        _LEVERS[base.agent.urdf_path] = joint_levers(base.agent.robot, _planners(base)[0])
    return _LEVERS[base.agent.urdf_path]


def _planners(base) -> list[mplib.Planner]:
    """``base``'s (an unwrapped env's) mplib planners, built at its first solver."""
    if base not in _PLANNERS:
        robot = base.agent.robot
        _PLANNERS[base] = [
            mplib.Planner(
                urdf=base.agent.urdf_path,
                srdf=base.agent.urdf_path.replace(".urdf", ".srdf"),
                user_link_names=[link.get_name() for link in robot.get_links()],
                user_joint_names=[joint.get_name() for joint in robot.get_active_joints()],
                move_group="panda_hand_tcp",
            )
            for _ in range(base.num_envs)
        ]
    return _PLANNERS[base]


class PickPlaceSolver:
    """Plans and executes pick-and-place in every env of a ``PickEmbodiedGen-v1`` env.

    Args:
        env: the env (optionally wrapped); actions go through ``env.step`` so wrappers such as
            video recorders see every step.
        config: tunable numbers.
        seed: seeds everything random the solver does (IK restarts, RRT-Connect; each plan
            from this seed and its place in the episode): the same env state and seed give
            the same actions. The obstacle clouds are sampled once per asset
            (``grasps.hull_points``, seeded by the asset's content).
    """

    def __init__(self, env, config: SolverConfig | None = None, seed: int = 0):
        self.env = env
        self.base = env.unwrapped
        self.cfg = config or SolverConfig()
        self.seed = seed
        self.stages = 0  # _per_env calls so far: part of each plan's random key
        self.num_envs = self.base.num_envs
        uid = getattr(self.base.agent, "uid", None)
        if uid is None:  # ManiSkill's MultiAgent
            raise ValueError(
                f"robot_uids={self.base.robot_uids!r}: the scripted expert drives one arm; make "
                "the env with one robot (docs/robots.md)"
            )
        if not ROBOTS[uid].expert:  # grasps, gripper and plans are the Panda's for now
            drivable = [u for u, r in ROBOTS.items() if r.expert]
            raise ValueError(
                f"robot_uids={uid!r}: the scripted expert drives only {drivable} for now "
                "(docs/robots.md). Fix: make the env with robot_uids='panda', or drive this "
                "robot with your own policy"
            )
        if self.base.control_mode != "pd_joint_pos":
            raise ValueError(
                f"the solver drives control_mode='pd_joint_pos', got {self.base.control_mode!r}"
            )
        base_poses = self.base.agent.robot.pose.raw_pose.cpu().numpy()
        self.planners = _planners(self.base)
        # the joint targets' bounds, so that other controllers replay them (solvers/follow.py)
        self.follow = follow_limits(self.base.agent, 1 / self.base.control_timestep)
        vel = np.asarray(self.cfg.joint_vel_limits, dtype=np.float64)
        if self.cfg.convertible:
            vel = np.minimum(vel, self.follow.speed)
        for i, planner in enumerate(self.planners):
            planner.set_base_pose(base_poses[i])
            planner.joint_vel_limits = vel
            planner.joint_acc_limits = np.asarray(self.cfg.joint_acc_limits, dtype=np.float64)
        self.motion = [SeededPlanner(p, self.cfg.motion, _levers(self.base)) for p in self.planners]
        self.reports = [EnvReport(i) for i in range(self.num_envs)]
        self.steps = 0
        self.ended = False  # every env was truncated, failed, or succeeded hold_steps ago
        self.succeeded = np.zeros(self.num_envs, dtype=int)  # per env, steps in success so far
        self.last_info: dict = {}
        self._batched_actions = len(self.env.action_space.shape) == 2
        self.gripper = np.full(self.num_envs, GRIPPER_OPEN)
        self.clouds: list[np.ndarray] = []  # per env, the obstacle surface points (world)
        self.cloud_trees: list[cKDTree] = []  # and their KD-trees
        self.slot = 0  # the mover slot being taken (``env.task_scene.movers``)
        self.command = self._qpos()[:, :7]  # per env, the arm's last joint targets
        self._set_obstacles()

    # --- state ---------------------------------------------------------------------------
    def _qpos(self) -> np.ndarray:
        return self.base.agent.robot.get_qpos().cpu().numpy().astype(np.float64)

    @property
    def target(self):
        """The mover being taken, merged over envs."""
        return self.base.task_scene.movers[self.slot]

    def _node(self, i: int) -> str:
        return self.base.task_scene.mover_nodes[i][self.slot]

    def _set_obstacles(self) -> None:
        """Every object but the mover being taken, where it stands now, is an obstacle."""
        self.clouds, self.cloud_trees = [], []
        for i, layout in enumerate(self.base.layouts):
            actors = self.base.env_actors[f"env{i}"]
            clouds = []
            for node, actor in actors.items():
                if node == self._node(i):
                    continue
                points = hull_points(layout.asset_spec(node), self.cfg.obstacle_points)
                pose = LayoutPose.from_raw(actor.pose.raw_pose[0].cpu().numpy())
                clouds.append(pose.transform_points(points))
            cloud = np.concatenate(clouds)
            self.clouds.append(cloud)
            self.cloud_trees.append(cKDTree(cloud))
            base = self.base.layout_scene.robot_poses[i, :3].cpu().numpy()
            near_base = (
                np.linalg.norm(cloud[:, :2] - base[:2], axis=1) < self.cfg.base_clearance
            ) & (cloud[:, 2] < base[2] + self.cfg.base_clearance_height)
            self.planners[i].update_point_cloud(cloud[~near_base], radius=self.cfg.obstacle_radius)

    # --- planning ------------------------------------------------------------------------
    def _plan(
        self, i, pose: sapien.Pose, qpos: np.ndarray, how: str, obstacles: bool,
        key: tuple = (), within: int | None = None, detour: bool = True,
    ):  # fmt: skip
        """A joint path to ``pose`` for env i by ``how`` ("screw": mplib's straight screw
        motion; "rrt": the seeded planner), and a status ("" on success).

        ``obstacles=False`` is for the short straight moves next to the support surface (the
        final descent from the pre-grasp and the lift), which the surface's cloud would block.
        ``key`` names the plan within the episode: its random draws come from the solver's
        seed and this key alone, so skipping one plan changes no other. ``within``: a path of
        this many steps or more is not wanted (a better option is known; "rrt" only).
        ``detour=False`` ("rrt" only): the straight joint line or nothing (status
        ``STRAIGHT_BLOCKED``).
        """
        target = np.concatenate([pose.p, pose.q])
        dt = self.base.control_timestep
        if how == "screw":
            res = self.planners[i].plan_screw(
                target, qpos.copy(), time_step=dt, use_point_cloud=obstacles
            )
        else:
            rng = np.random.default_rng([self.seed, i, *key])
            res = self.motion[i].plan_to_pose(target, qpos, rng, dt, obstacles, within, detour)
        if res["status"] != "Success" or not len(res["position"]):
            return None, res["status"]
        if len(res["position"]) > self.cfg.max_path_steps:
            return None, f"{len(res['position'])} steps, over max_path_steps"
        return res["position"], ""

    def _execute(self, paths: list[np.ndarray | None], extra_steps: int = 0, until=None) -> None:
        """Step all envs along their paths in lockstep; envs without a path hold still.
        ``until()``: checked after every step; True ends the steps early."""
        paths = [None if p is None or not len(p) else self._commands(p, i)
                 for i, p in enumerate(paths)]  # fmt: skip
        lengths = [len(p) if p is not None else 0 for p in paths]
        n = max(lengths, default=0) + extra_steps
        for t in range(n):
            if self.ended:  # no step past the end of the episode
                return
            action = np.zeros((self.num_envs, 8), np.float32)
            for i, path in enumerate(paths):
                if path is not None:
                    action[i, :7] = path[min(t, len(path) - 1)]
                else:  # holds its last targets
                    action[i, :7] = self.command[i]
                action[i, 7] = self.gripper[i]
            if self.cfg.convertible:
                action[:, :7] = self._bounded(action[:, :7])
            self.command = action[:, :7].astype(np.float64)
            self._step(action)
            if until is not None and until():
                return

    def _commands(self, path: np.ndarray, i: int) -> np.ndarray:
        """Env i's arm joint targets that follow ``path`` (a waypoint per control step).

        ``pd_joint_pos`` drives each joint with ``stiffness * (target - q) - damping * qvel``,
        so a joint lags a moving target by ``damping / stiffness`` (0.1 s for the Panda, 5
        control steps) times its velocity: each target leads its waypoint by that much of the
        path's velocity, within the joint limits; the last target is the path's end. On a
        0.5 rad line at the solver's limits the arm stays within 0.022 rad of the path at
        every step instead of 0.16 (``test_joint_targets_lead_the_path...``).
        With ``convertible``, the targets move from the last ones at most ``follow.step`` a
        step (``follow.rate_limited``; the path's speed is within ``follow.speed``).
        """
        q = np.asarray(path, dtype=np.float64)[:, :7]
        lead = q.copy()
        if len(q) >= 3:
            arm = self.base.agent.controller.controllers["arm"].config
            dt = self.base.control_timestep
            lead = q + arm.damping / arm.stiffness * np.gradient(q, dt, axis=0)
            lead[-1] = q[-1]  # the path ends at rest there
            space = self.base.single_action_space
            lead = np.clip(lead, space.low[:7], space.high[:7])
        if not self.cfg.convertible:
            return lead
        return rate_limited(lead, self.command[i], self.follow.step)

    def _bounded(self, arm: np.ndarray) -> np.ndarray:
        """The arm targets ``arm`` (per env) moved at most ``follow.step`` from the last ones
        and leading the measured joints by at most ``follow.lead`` (a joint lagging its target
        more than planned, e.g. the lag building up as it starts, slows the targets down)."""
        arm = self.command + shortened(arm - self.command, self.follow.step)
        q = self._qpos()[:, :7]
        return q + shortened(arm - q, self.follow.lead)

    def _step(self, action: np.ndarray) -> None:
        a = action if self._batched_actions else action[0]
        _, _, terminated, truncated, info = self.env.step(a)
        self.last_info = info
        self.steps += 1
        flag = lambda x: np.asarray(torch.as_tensor(x).cpu()).reshape(-1)  # noqa: E731
        success = flag(info["success"])
        self.succeeded = np.where(success, self.succeeded + 1, 0)
        over = flag(truncated) | (flag(terminated) & ~success)
        self.ended = bool(np.all(over | (self.succeeded >= self.cfg.hold_steps)))

    def _per_env(
        self,
        stage: str,
        targets: list,
        methods: tuple[str, ...] = ("screw", "rrt"),
        obstacles: bool = True,
        settle: int = 0,
        option_steps: int | None = None,
        then=None,
        path_ok=None,
        on_choice=None,
        planned=None,
    ) -> list[sapien.Pose | None]:
        """Plan and execute one stage in every env that has not failed yet.

        Args:
            stage: named in failure reports.
            targets: per env a pose, a list of poses (options, best first), or None (hold
                still).
            methods: tried in order, each on every option before the next (a straight screw
                move to a later option before a planned detour to the first).
            option_steps: None: the first option a method plans to. Else every option is
                planned and the one with the fewest steps, plus this many per rank below the
                first, wins (a grasp ranked a little lower that the arm reaches directly
                before one behind a wrist turn).
            then: with ``option_steps``, ``then(i, k, qpos)``: the steps of the move that
                follows from where option k's path ends (None: it cannot be planned), added
                to the option's cost.
            path_ok: ``path_ok(i, path)``: why env i's planned path is refused ("" when not).
            on_choice: ``on_choice(i, k)``: env i will run option k (before any env moves).
            planned: ``planned(i)``: env i's path, planned already (from where the last stage
                ended), or None to plan it here.

        Returns:
            Per env the pose that was planned to (None where none could be).
        """
        qpos = self._qpos()
        paths, chosen = [], []
        self.stages += 1
        for i, target in enumerate(targets):
            options = target if isinstance(target, list) else [target]
            best = None
            ready = None if planned is None or target is None else planned(i)
            if ready is not None and not self.reports[i].plan_failures:
                best = (len(ready), ready, target, 0)
            elif target is not None and not self.reports[i].plan_failures:
                best, failures = self._choose(
                    i, options, qpos[i], methods, obstacles, option_steps, then, path_ok
                )
                if best is None:
                    self.reports[i].plan_failures.append(f"{stage}: " + "; ".join(failures))
                elif on_choice is not None:
                    on_choice(i, best[3])
            paths.append(None if best is None else best[1])
            chosen.append(None if best is None else best[2])
        # settle: steps holding the last waypoints, until the arms are there
        ends = qpos[:, :7].copy()
        for i, path in enumerate(paths):
            if path is not None:
                ends[i] = path[-1][:7]
        start, moving = self.steps, max((len(p) for p in paths if p is not None), default=0)

        def arrived() -> bool:
            if self.steps < start + moving:
                return False
            return np.abs(self._qpos()[:, :7] - ends).max() < self.cfg.settle_tolerance

        self._execute(paths, extra_steps=settle, until=arrived if settle else None)
        return chosen

    def _choose(self, i, options, qpos, methods, obstacles, option_steps, then, path_ok):
        """``_per_env``'s choice for env i: ``(cost, path, pose, k)`` of the option that wins
        (None when none plans) and the failures.

        With ``option_steps``, the winner is the least (cost, rank) over every option, found by
        branch and bound: an option whose rank alone, or whose shortest possible path
        (``SeededPlanner.min_steps``), cannot beat the best so far is not planned. The seeded
        planner's straight joint lines come first for every option, then the detours
        (RRT-Connect) where a line is blocked: a direct option found first bounds the detours.
        """
        best, failures = None, []
        for m, how in enumerate(methods):
            passes = (False, True) if how == "rrt" and option_steps is not None else (True,)
            todo = list(range(len(options)))
            for detour in passes:
                blocked = []  # options whose straight line is blocked: for the detour pass
                for k in todo:
                    within = None
                    if best is not None and option_steps is not None:
                        # a path of `within` steps or more cannot beat the best (ties: rank)
                        within = best[0] - option_steps * k + (k < best[3])
                        if within <= 0:
                            break  # later options rank lower still
                    key = (self.stages, m, k)
                    path, status = self._plan(
                        i, options[k], qpos, how, obstacles, key, within, detour
                    )
                    if status == STRAIGHT_BLOCKED:
                        blocked.append(k)
                        continue
                    if path is not None and path_ok is not None:
                        status = path_ok(i, path)
                        path = None if status else path
                    label = "" if len(options) == 1 else f"option {k}: "
                    if path is None:
                        failures.append(f"{label}{how}: {status}")
                        continue
                    cost = len(path) + (option_steps or 0) * k
                    if best is not None and (cost, k) > (best[0], best[3]):
                        continue  # what follows only adds steps
                    if then is not None:
                        end = np.concatenate([path[-1][:7], qpos[7:]])
                        more = then(i, k, end)
                        cost += self.cfg.max_path_steps if more is None else more
                    if best is None or (cost, k) < (best[0], best[3]):
                        best = (cost, path, options[k], k)
                    if option_steps is None:
                        return best, failures
                todo = blocked
            if best is not None:
                break
        return best, failures

    # --- the policy ----------------------------------------------------------------------
    def grasp_poses(self) -> list[list[tuple[sapien.Pose, float]]]:
        """Per env, the grasps to try where its target lies now, best first, each with the
        finger opening to approach with. First the top-down grasp across the footprint's
        narrow side and its 180-degree turn (a parallel gripper's same grasp at another wrist
        angle), fully open, when it passes the synthesised grasps' checks and clears the
        other objects by the wide margin (the grasp that cans and boxes take); then the
        synthesised grasps the gripper can take here (``grasps.posed_grasps``, pre-shaped);
        the footprint grasp last when it failed those checks, or when the asset's annotated
        grasps (``affordance_annot.json``) lead the synthesised ones."""
        agent = self.base.agent
        tcp = agent.tcp.pose.to_transformation_matrix().cpu().numpy()
        poses = []
        for i, layout in enumerate(self.base.layouts):
            actor = self.base.env_actors[f"env{i}"][self._node(i)]
            spec = layout.asset_spec(self._node(i))
            geom = asset_geometry(spec)
            pose = LayoutPose.from_raw(actor.pose.raw_pose[0].cpu().numpy())
            support = float(self.base.layout_scene.top_z[i])
            grasps = asset_grasps(spec, self.grasp_config)
            taken = posed_grasps(
                grasps, pose.matrix(), support, self.clouds[i], self.grasp_config,
                limit=self.cfg.grasp_candidates, with_index=True,
            )  # fmt: skip
            synthesised = [
                (agent.build_grasp_pose(approach, closing, centre), opening)
                for centre, closing, approach, opening, _ in taken
            ]
            # the asset's own annotated grasps (affordance_annot.json) lead when one is takeable
            annotated = bool(taken) and grasps.annotated is not None
            annotated = annotated and bool(grasps.annotated[taken[0][4]])
            verts = pose.transform_points(geom.vertices)
            centre, closing = grasp_frame(verts, support, self.cfg, tcp[i, :3, 1])
            down = np.array([0, 0, -1.0])
            footprint = [
                (agent.build_grasp_pose(down, c, centre), self.gripper_model.opening)
                for c in (closing, -closing)
            ]
            checked = (i, grasps, pose, centre)
            turned = self._turned_closing(i, tcp[i], centre)
            if turned is not None and self._footprint_fits(*checked, turned, support):
                # the wrist needs no turn: first
                footprint.insert(0, (agent.build_grasp_pose(down, turned, centre),
                                     self.gripper_model.opening))  # fmt: skip
            first = self._footprint_fits(*checked, closing, support) and not annotated
            poses.append(footprint + synthesised if first else synthesised + footprint)
        return poses

    def _footprint_fits(self, i, grasps, pose, centre, closing, support) -> bool:
        """Whether env i's top-down grasp at ``centre`` closing along ``closing`` passes the
        synthesised grasps' checks on the object (``pose``) and clears the other objects by the
        wide margin."""
        down = np.array([0, 0, -1.0])
        world_to_object = np.linalg.inv(pose.matrix())
        rot, t = world_to_object[:3, :3], world_to_object[:3, 3]
        # the footprint grasp's palm stops just above a can's lid: checked without margin
        exact = dataclasses.replace(self.grasp_config, margin=0.0)
        valid = grasp_is_valid(grasps, rot @ centre + t, rot @ closing, rot @ down, exact)
        _, roomy = posed_clearance(
            centre[None], closing[None], down[None],
            self.gripper_model.boxes(self.grasp_config.sweep)[None], support,
            self.clouds[i], self.grasp_config,
        )  # fmt: skip
        return valid and bool(roomy[0])

    def _turned_closing(self, i: int, tcp: np.ndarray, centre: np.ndarray) -> np.ndarray | None:
        """The hand's closing direction now (``tcp (4, 4)``) turned about the vertical as the
        arm's base joint turns from the hand to ``centre``: the top-down grasp there the wrist
        reaches without turning (a can's footprint has no narrow side, and a turn of the last
        joint by up to 90 degrees took 2 s at the convertible speeds); None where the hand's
        closing direction is vertical."""
        base = self.base.agent.robot.pose.raw_pose[i, :2].cpu().numpy()
        y = tcp[:2, 1]
        if np.linalg.norm(y) < 0.5:
            return None
        a, b = centre[:2] - base, tcp[:2, 3] - base
        turn = np.arctan2(a[1], a[0]) - np.arctan2(b[1], b[0])
        c, s = np.cos(turn), np.sin(turn)
        xy = np.array([c * y[0] - s * y[1], s * y[0] + c * y[1]])
        return np.array([*(xy / np.linalg.norm(xy)), 0.0])

    @property
    def grasp_config(self) -> GraspConfig:
        return GraspConfig(sweep=self.cfg.approach_offset)

    @property
    def gripper_model(self) -> GripperModel:
        return GripperModel()

    def _in_hand(self) -> np.ndarray:
        """Per env, the target's position in the TCP's frame now."""
        tcp = self.base.agent.tcp.pose.to_transformation_matrix().cpu().numpy()
        obj = self.target.pose.p.cpu().numpy()
        return np.einsum("nij,ni->nj", tcp[:, :3, :3], obj - tcp[:, :3, 3])

    def _moved(self, since: np.ndarray) -> np.ndarray:
        """Per env: the target lies more than ``moved_tolerance`` from ``since`` (positions)."""
        now = self.target.pose.p.cpu().numpy()
        return np.linalg.norm(now - since, axis=1) > self.cfg.moved_tolerance

    def _grasping(self) -> np.ndarray:
        """Per env: both fingers press on the target now (the env's ``is_grasped`` after the
        last step)."""
        return np.asarray(torch.as_tensor(self.last_info["is_grasped"]).cpu()).reshape(-1)

    def _steps_left(self) -> int:
        limit = getattr(getattr(self.env, "spec", None), "max_episode_steps", None) or 10**9
        return limit - self.steps

    def _set_gripper(self, envs: np.ndarray, value: float, release: bool = False) -> None:
        """Open or close the gripper of ``envs`` (the others keep theirs), the arms held
        still: ``gripper_steps`` steps; closing ends as soon as every env of ``envs`` grasps
        the target (the env's ``is_grasped``) with its fingers at rest; opening to ``release``
        a placed mover as soon as the fingers of ``envs`` are open as the release rule counts it
        (``task_scene.open_fraction``)."""
        self.gripper[envs] = value
        fingers = [self._qpos()[:, 7:]]

        def gripped() -> bool:
            now = self._qpos()[:, 7:]
            still = np.abs(now - fingers[0]).max(1) < self.cfg.finger_rest
            fingers[0] = now
            return bool(np.all((self._grasping() & still)[envs]))

        def opened() -> bool:  # open as the env's release rule counts it: nothing more to wait
            ts = self.base.task_scene
            lo, hi = ts.finger_span
            open_ = (self._qpos()[:, 7:].sum(1) - lo) / (hi - lo) >= ts.open_fraction
            return bool(np.all((open_ & ~self._grasping())[envs]))

        closing = value == GRIPPER_CLOSED
        self._execute(
            [None] * self.num_envs,
            self.cfg.gripper_steps,
            until=gripped if closing else (opened if release else None),
        )

    def _grasp(self, todo: np.ndarray, attempt: int) -> np.ndarray:
        """One grasp attempt in the envs ``todo``: approach the best reachable grasp, close,
        lift, and check; returns which envs hold the target after the lift. Envs that miss
        open and back off to where they came from."""
        cfg = self.cfg
        up = sapien.Pose([0, 0, -cfg.approach_offset])
        candidates = self.grasp_poses()
        planned_at = self.target.pose.p.cpu().numpy().copy()  # where the grasps were planned
        targets = [
            [g * up for g, _ in candidates[i]] if todo[i] else None for i in range(self.num_envs)
        ]

        descents, taken = {}, {}  # per (env, option) the descent planned; per env the one run

        def descent(i, k, qpos):  # the straight move from option k's pre-grasp to its grasp
            descents[i, k] = self._plan(i, targets[i][k] * up.inv(), qpos, "screw", False)[0]
            return descents[i, k]

        def take(i, k):  # env i runs option k: fingers pre-shaped on the way, its descent next
            self.gripper[i] = gripper_action(candidates[i][k][1])
            taken[i] = descents.get((i, k))

        pre = self._per_env(
            "approach", targets, ("rrt", "screw"), settle=cfg.settle_steps,
            option_steps=cfg.option_steps,
            then=lambda i, k, q: None if (p := descent(i, k, q)) is None else len(p),
            on_choice=take,
        )  # fmt: skip
        moved = self._moved(planned_at) & todo  # re-observed: no descent onto where it was
        grasps = [None if p is None or moved[i] else p * up.inv() for i, p in enumerate(pre)]
        # the descent ranked with the approach, from its end (the arm settled there); the arm
        # reaches the grasp before the fingers close
        self._per_env("grasp", grasps, obstacles=False, settle=cfg.settle_steps, planned=taken.get)
        # not again before closing: the descending fingers nudge a rolling body, and closing
        # on it still holds it (a smooth ball: 6/6 closing anyway, 3/6 backing off instead)
        self._set_gripper(todo & ~moved, GRIPPER_CLOSED)
        z0 = self.target.pose.p[:, 2].cpu().numpy()
        lifts = [
            None
            if g is None
            else [sapien.Pose(g.p + np.array([0, 0, h]), g.q) for h in cfg.lift_heights]
            for g in grasps
        ]
        self._per_env("lift", lifts, obstacles=False)
        # held: the object came up with the hand (a physical check, not a contact threshold)
        rose = self.target.pose.p[:, 2].cpu().numpy() - z0
        held = (rose > cfg.lift_check * min(cfg.lift_heights)) & todo
        held &= np.array([p is not None for p in pre]) & ~moved
        self.hand = self._in_hand()  # where the object sits in the hand after the lift
        missed = todo & ~held & np.array([not r.plan_failures for r in self.reports])
        for i in np.flatnonzero(missed):
            self.reports[i].misses.append(f"{'moved' if moved[i] else 'grasp'} (attempt {attempt})")
        if missed.any():  # open and back off upwards, for the next attempt
            self._set_gripper(missed, GRIPPER_OPEN)
            tcp = self.base.agent.tcp.pose.raw_pose.cpu().numpy()
            back = [
                sapien.Pose(tcp[i, :3] + np.array([0, 0, cfg.approach_offset]), tcp[i, 3:])
                if missed[i]
                else None
                for i in range(self.num_envs)
            ]
            self._per_env("retreat", back, obstacles=False)
        return held

    def solve(self) -> SolveResult:
        """Run the whole task in every env: each mover in turn (``pick``: the one, held at the
        goal; ``place`` and ``move``: carried over its destination, lowered, released, the
        hand withdrawn); returns per-env reports and the last info."""
        kinds = [t.kind for t in self.base.tasks]
        self.releases = np.array([k != "pick" for k in kinds])
        nodes = self.base.task_scene.mover_nodes
        for slot in range(len(self.base.task_scene.movers)):
            self.slot = slot
            todo = np.array([slot == 0 or n[slot] != n[slot - 1] for n in nodes])
            if slot:
                self._set_obstacles()
            self._take(todo)
        wait = self.cfg.rest_steps if self.releases.any() else self.cfg.hold_steps
        self._execute([None] * self.num_envs, extra_steps=wait)
        return SolveResult(self.reports, self.steps, self.last_info)

    def _take(self, envs: np.ndarray) -> None:
        """Grasp the current mover in ``envs``, carry it, and release it where its task says."""
        cfg = self.cfg
        self.hand = np.zeros((self.num_envs, 3))
        holding = np.zeros(self.num_envs, bool)
        placed = ~envs.copy()
        for attempt in range(cfg.grasp_attempts):
            todo = ~placed & np.array([not r.plan_failures for r in self.reports])
            todo &= ~holding
            if todo.any() and self._steps_left() >= cfg.attempt_steps and not self.ended:
                holding |= self._grasp(todo, attempt)
            carry = holding & ~placed
            if not carry.any():
                continue
            self._carry(carry)
            # dropped: the object left its place in the hand and the fingers hold nothing
            moved = np.linalg.norm(self._in_hand() - self.hand, axis=1)
            still = (moved < cfg.slip_tolerance) | self._grasping()
            for i in np.flatnonzero(carry & ~still):
                self.reports[i].misses.append(f"carry (attempt {attempt})")
            done = carry & still
            if (done & self.releases).any():
                self._release(done & self.releases)
            placed |= done
            dropped = carry & ~still
            holding &= ~dropped
            if dropped.any():  # grasp again from where the object lies
                self._set_gripper(dropped, GRIPPER_OPEN)
            if placed.all():
                break

    def _task_state(self):
        """The env's task state now, as numpy arrays (``envs/tasks/state.py``)."""
        goal = self.base.goal_site.pose.p
        state = self.base.task_reader.state(goal if self.base.gpu_sim_enabled else goal.numpy())
        keys = ("movers", "origins", "bottom", "dest", "rec_top", "rec_is_table", "table_z")
        return {k: np.asarray(torch.as_tensor(getattr(state, k)).cpu()) for k in keys}

    def _carry_goal(self) -> np.ndarray:
        """Per env, where the current mover's centre is carried: the pick goal; or over its
        destination, high enough that its lowest point clears by ``release_clearance`` the
        receptacle's top and every obstacle point around it there (within its widest reach
        from its centre plus ``release_surround``: a mover placed before, standing taller than
        the tray the next one is carried to, is passed over, not swept against)."""
        st, k = self._task_state(), self.slot
        goal = self.base.goal_site.pose.p.cpu().numpy().astype(np.float64)
        above = self._release_height(st)
        top = np.where(st["rec_is_table"], st["table_z"], st["rec_top"]).astype(np.float64)
        ts = self.base.task_scene
        reach = np.linalg.norm(ts.hulls[:, k, :, :2] - ts.centres[:, k, None, :2], axis=-1).max(1)
        for i, cloud in enumerate(self.clouds):
            near = np.linalg.norm(cloud[:, :2] - st["dest"][i, k, :2], axis=1)
            under = cloud[near <= reach[i] + self.cfg.release_surround, 2]
            if self.releases[i] and len(under):
                top[i] = max(top[i], under.max())
        low = st["movers"][:, k, 2] - st["bottom"][:, k]  # centre above the lowest point now
        lift = np.maximum(top + low - above, 0.0) + self.cfg.release_clearance
        over = np.concatenate([st["dest"][:, k, :2], (above + lift)[:, None]], 1)
        return np.where(self.releases[:, None], over, goal)

    def _release_height(self, st) -> np.ndarray:
        """Per env, the height of the current mover's centre at release: held as it is now,
        its lowest point ``release_gap`` above the surface under its destination."""
        k = self.slot
        half = self.base.task_scene.centres[:, k, 2] - self.base.task_scene.hulls[:, k, :, 2].min(1)
        surface = st["dest"][:, k, 2] - half  # the destination's support surface
        low = st["movers"][:, k, 2] - st["bottom"][:, k]
        return surface + low + self.cfg.release_gap

    def _release(self, envs: np.ndarray) -> None:
        """Lower the held mover of ``envs`` straight down to its release height, open, and
        withdraw the hand straight up."""
        st = self._task_state()
        drop = st["movers"][:, self.slot, 2] - self._release_height(st)
        tcp = self.base.agent.tcp.pose.raw_pose.cpu().numpy()

        def shifted(dz):
            return [sapien.Pose(tcp[i, :3] + [0, 0, dz[i]], tcp[i, 3:]) if envs[i] else None
                    for i in range(self.num_envs)]  # fmt: skip

        self._per_env("lower", shifted(-np.maximum(drop, 0.0)), obstacles=False,
                      settle=self.cfg.settle_steps)  # fmt: skip
        self._set_gripper(envs, GRIPPER_OPEN, release=True)
        tcp = self.base.agent.tcp.pose.raw_pose.cpu().numpy()
        self._per_env("withdraw", shifted(np.full(self.num_envs, self.cfg.approach_offset)),
                      obstacles=False)  # fmt: skip

    def _carry(self, envs: np.ndarray) -> None:
        """Carry the held target of ``envs`` to the goal (keeping its offset from the TCP as
        it is in the hand now), then correct the last millimetres. The goal is a position, so
        the hand may arrive turned about the vertical (``carry_yaws``, tried in order): a wrist
        near its joint limit would otherwise flip over on the way. A path that takes the
        object out over the table's edge is refused (the episode would end in ``fail``);
        where no carry plans, the hand first rises ``rise_clearance`` above the highest
        obstacle point and carries from there."""
        goal = self._carry_goal()
        hand = self._in_hand()
        # the held object kept off the obstacles where it is to be put down (a pick goal may
        # lie next to an obstacle: the object is held there, and the check would refuse it)
        held = [h if r else None for h, r in zip(self._held_points(), self.releases, strict=True)]
        over = lambda i, path: self._over_table(i, path, hand[i], held[i])  # noqa: E731

        base = self.base.agent.robot.pose.raw_pose[:, :2].cpu().numpy()

        def targets(yaws, todo):
            tcp = self.base.agent.tcp.pose.raw_pose.cpu().numpy()
            st = self._task_state()  # the point the goal is for: centre, or origin (pick)
            obj = np.where(self.releases[:, None], st["movers"], st["origins"])[:, self.slot]
            out = []
            for i in range(self.num_envs):
                turns = list(yaws)
                if self.releases[i] and len(yaws) > 1:  # first the turn of the base joint
                    a, b = goal[i, :2] - base[i], obj[i, :2] - base[i]
                    turns.insert(0, np.arctan2(a[1], a[0]) - np.arctan2(b[1], b[0]))
                poses = [self._turned(goal[i], tcp[i], obj[i], yaw) for yaw in turns]
                out.append(poses if todo[i] else None)
            return out

        how = {}
        if self.releases.any():
            how = dict(methods=self.cfg.release_carry_methods,
                       option_steps=self.cfg.release_carry_option_steps)  # fmt: skip
        chosen = self._per_env("carry", targets(self.cfg.carry_yaws, envs), path_ok=over, **how)
        high = envs & np.array([c is None for c in chosen])
        if high.any():  # over the obstacles: straight up, then the carry from there
            for i in np.flatnonzero(high):  # the carry from above may still plan
                self.reports[i].plan_failures.clear()
            tcp = self.base.agent.tcp.pose.raw_pose.cpu().numpy()
            up = [
                sapien.Pose(
                    [
                        *tcp[i, :2],
                        max(tcp[i, 2], self.clouds[i][:, 2].max() + self.cfg.rise_clearance),
                    ],
                    tcp[i, 3:],
                )
                if high[i]
                else None
                for i in range(self.num_envs)
            ]
            self._per_env("rise", up, obstacles=False)
            self._per_env("carry", targets(self.cfg.carry_yaws, high), path_ok=over, **how)
        self._per_env("settle", targets((0.0,), envs), obstacles=False)

    def _held_points(self) -> np.ndarray:
        """Per env, the current mover's collision points ``(V, 3)`` in the TCP's frame now."""
        tcp = self.base.agent.tcp.pose.to_transformation_matrix().cpu().numpy()
        obj = self.target.pose.to_transformation_matrix().cpu().numpy()
        rel = np.linalg.inv(tcp) @ obj  # (n, 4, 4) the object in the TCP frame
        hull = self.base.task_scene.hulls[:, self.slot].astype(np.float64)  # (n, V, 3)
        return np.einsum("nij,nvj->nvi", rel[:, :3, :3], hull) + rel[:, None, :3, 3]

    def _over_table(
        self, i: int, path: np.ndarray, in_hand: np.ndarray, held: np.ndarray | None = None
    ) -> str:
        """Why env i's path is refused: the held object (``in_hand``: its position in the TCP
        frame) leaves the table top's footprint at a waypoint, or its collision points
        (``held (V, 3)``, TCP frame) come within ``carry_clearance`` of an obstacle point;
        "" when neither."""
        model = self.planners[i].pinocchio_model
        fingers = self._qpos()[i, 7:]
        base = sapien.Pose(*np.split(self.base.agent.robot.pose.raw_pose[i].cpu().numpy(), [3]))
        points = []
        for k, q in enumerate(path):
            model.compute_forward_kinematics(np.concatenate([q[:7], fingers]))
            p = model.get_link_pose(self.motion[i].link)
            tcp = (base * sapien.Pose(p[:3], p[3:])).to_transformation_matrix()
            points.append(tcp[:3] @ np.append(in_hand, 1.0))
            if held is not None and self.cloud_trees:
                near, _ = self.cloud_trees[i].query(held @ tcp[:3, :3].T + tcp[:3, 3])
                if near.min() < self.cfg.carry_clearance:
                    return f"the held object meets an obstacle at waypoint {k}"
        top = self.base.layout_scene.episodes.top.rows(torch.tensor([i], device=self.base.device))
        xy = torch.as_tensor(np.array(points)[None, :, :2], dtype=torch.float32)
        inside = top.contains(xy.to(self.base.device))[0].cpu().numpy()
        return (
            ""
            if inside.all()
            else f"the object leaves the table at waypoint {int(np.argmin(inside))}"
        )

    @staticmethod
    def _turned(goal: np.ndarray, tcp: np.ndarray, obj: np.ndarray, yaw: float) -> sapien.Pose:
        """The TCP pose that puts the object at ``goal`` with the hand turned ``yaw`` about the
        world's vertical from its pose ``tcp`` now (the object turning with it)."""
        turn = sapien.Pose(q=[np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)])
        hand = turn * sapien.Pose(tcp[:3] - obj, tcp[3:])
        return sapien.Pose(goal + hand.p, hand.q)
