"""Scripted, motion-planned pick-and-place for the arms with a hand entry (mplib).

For every env the solver plans from that env's own robot and object state: grasps synthesised
from the target's collision geometry (``solvers/grasps.py``: antipodal, collision-free against
the object, the table and the distractors, ranked), posed where the object lies now; approach,
grasp, lift, carry the object to the goal and hold still. Table and distractors are obstacles
(surface point clouds). The loop is closed: after closing the fingers and after the lift the
solver checks the grasp (the object rose with the hand), and on a miss opens, backs off and
tries the next grasp; after the carry, an object that left its place in the hand (and is not
held) is grasped again from where it lies, while the episode has steps left. A failed plan is
recorded per env and stage; that env then holds still while the others go on.

The solver is cut in rooms: the grasp choice (``grasp_choice.py``), planning and execution
(``driver.py``), opening and closing the hand (``jaws.py``), the place and move flows
(``place_flow.py``); this file holds the state, the grasp attempt and the episode.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import sapien
import torch
from mani_skill.utils.structs.pose import Pose
from scipy.spatial import cKDTree

from embodied_envs.internals import px_articulations
from embodied_envs.layout.pose import LayoutPose
from embodied_envs.robots import ROBOTS
from embodied_envs.solvers.driver import ArmDriver
from embodied_envs.solvers.grasp_choice import GraspChoice, asset_spec
from embodied_envs.solvers.grasps import GraspConfig, hull_points
from embodied_envs.solvers.gripper import GripperModel
from embodied_envs.solvers.jaws import Jaws
from embodied_envs.solvers.models import follow_limits, levers, mode_actions, planners
from embodied_envs.solvers.motion import SeededPlanner
from embodied_envs.solvers.place_flow import PlaceFlow
from embodied_envs.solvers.solver_config import SolverConfig


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


class PickPlaceSolver(GraspChoice, PlaceFlow, Jaws, ArmDriver):
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
        self.seed = seed
        self.stages = 0  # _per_env calls so far: part of each plan's random key
        self.num_envs = self.base.num_envs
        uid = getattr(self.base.agent, "uid", None)
        if uid is None:  # ManiSkill's MultiAgent
            raise ValueError(
                f"robot_uids={self.base.robot_uids!r}: the scripted expert drives one arm; make "
                "the env with one robot (docs/robots.md)"
            )
        if not ROBOTS[uid].expert:
            drivable = [u for u, r in ROBOTS.items() if r.expert]
            raise ValueError(
                f"robot_uids={uid!r}: the scripted expert drives only {drivable} for now "
                "(docs/robots.md). Fix: make the env with one of them, or drive this robot "
                "with your own policy"
            )
        self.robot_hand = hand = ROBOTS[uid].hand
        rule = ROBOTS[uid].grasp_check
        # the close's own check: the rule at any angle (PickPlaceSolver._pressing)
        self.press_rule = None if rule is None else dataclasses.replace(rule, max_angle=180.0)
        self.gripper_entry = ROBOTS[uid].gripper
        cfg = config or SolverConfig()
        self.cfg = dataclasses.replace(
            cfg,
            grasp_depth=hand.grasp_depth if cfg.grasp_depth is None else cfg.grasp_depth,
            approach_offset=cfg.approach_offset or hand.approach_offset,
            lift_heights=cfg.lift_heights or hand.lift_heights,
            max_path_steps=cfg.max_path_steps or hand.max_path_steps,
            convertible=cfg.convertible and hand.convertible,
            joint_vel_limits=cfg.joint_vel_limits or hand.joint_vel,
            joint_acc_limits=cfg.joint_acc_limits or hand.joint_acc,
            carry_yaws=(0.0,) if cfg.fixed_hand else cfg.carry_yaws,
            motion=dataclasses.replace(
                cfg.motion, tilt_tolerance=max(cfg.motion.tilt_tolerance, hand.tilt_tolerance)
            ),
        )
        # the grasp frame (z approach, y closing) in the planned link's frame, and back
        self.grasp_in_link = sapien.Pose(hand.grasp_in_link[:3], hand.grasp_in_link[3:])
        self.link_in_grasp = self.grasp_in_link.inv()
        base_poses = self.base.agent.robot.pose.raw_pose.cpu().numpy()
        self.planners = planners(self.base)
        self.arm_dof = len(self.planners[0].move_group_joint_indices)  # the gripper's after them
        # joint targets as the env's control mode's actions; their bounds (pd_joint_pos's)
        self.mode_actions = mode_actions(self.base, self.arm_dof)
        self.target_bounds = self.mode_actions.bounds
        # the joint targets' bounds, so that other controllers replay them (solvers/follow.py)
        self.follow = follow_limits(self.base.agent, 1 / self.base.control_timestep, self.arm_dof)
        vel = np.asarray(self.cfg.joint_vel_limits, dtype=np.float64)
        if self.cfg.convertible:
            vel = np.minimum(vel, self.follow.speed)
        for i, planner in enumerate(self.planners):
            planner.set_base_pose(base_poses[i])
            planner.joint_vel_limits = vel
            planner.joint_acc_limits = np.asarray(self.cfg.joint_acc_limits, dtype=np.float64)
        self.motion = [SeededPlanner(p, self.cfg.motion, levers(self.base)) for p in self.planners]
        self.reports = [EnvReport(i) for i in range(self.num_envs)]
        self.firm = np.zeros(self.num_envs, bool)  # per env: it lost a grip; it presses (jaws.py)
        self.steps = 0
        self.ended = False  # every env was truncated, failed, or succeeded hold_steps ago
        self.succeeded = np.zeros(self.num_envs, dtype=int)  # per env, steps in success so far
        self.last_info: dict = {}
        self._batched_actions = len(self.env.action_space.shape) == 2
        self.gripper = np.full(self.num_envs, self.robot_hand.action_open)
        self.gripping = np.zeros(self.num_envs, bool)  # per env: its jaw holds on (jaws.py)
        self.clouds: list[np.ndarray] = []  # per env, the obstacle surface points (world)
        self._trees: dict[int, cKDTree] = {}  # their KD-trees, made where asked (cloud_tree)
        self.slot = 0  # the mover slot being taken (``env.task_scene.movers``)
        self.command = self._qpos()[:, : self.arm_dof]  # per env, the arm's last joint targets
        self._set_obstacles()

    # --- state ---------------------------------------------------------------------------
    def _qpos(self) -> np.ndarray:
        robot = self.base.agent.robot
        if not self.base.gpu_sim_enabled:  # the one env's joints, as get_qpos reads them
            return px_articulations(robot)[0].qpos[None].astype(np.float64)
        return robot.get_qpos().cpu().numpy().astype(np.float64)

    def _fingers(self) -> np.ndarray:
        """Per env, the gripper's joint positions (after the arm's)."""
        return self._qpos()[:, self.arm_dof :]

    def _tcp(self):
        """Per env, the grasp frame's pose now (a ManiSkill ``Pose``): the planned link's pose
        times the hand entry's ``grasp_in_link``."""
        link = self.base.agent.robot.links_map[self.robot_hand.link].pose
        return link * Pose.create(self.grasp_in_link)

    @property
    def target(self):
        """The mover being taken, merged over envs."""
        return self.base.task_scene.movers[self.slot]

    def _node(self, i: int) -> str:
        return self.base.task_scene.mover_nodes[i][self.slot]

    def _set_obstacles(self) -> None:
        """Every object but the mover being taken, where it stands now, is an obstacle."""
        self.clouds, self._trees = [], {}
        for i, layout in enumerate(self.base.layouts):
            actors = self.base.env_actors[f"env{i}"]
            clouds = []
            for node, actor in actors.items():
                if node == self._node(i):
                    continue
                points = hull_points(asset_spec(layout, node), self.cfg.obstacle_points)
                pose = LayoutPose.from_raw(actor.pose.raw_pose[0].cpu().numpy())
                clouds.append(pose.transform_points(points))
            cloud = np.concatenate(clouds)
            self.clouds.append(cloud)
            base = self.base.layout_scene.robot_poses[i, :3].cpu().numpy()
            near_base = (
                np.linalg.norm(cloud[:, :2] - base[:2], axis=1) < self.cfg.base_clearance
            ) & (cloud[:, 2] < base[2] + self.cfg.base_clearance_height)
            self.planners[i].update_point_cloud(cloud[~near_base], radius=self.cfg.obstacle_radius)

    def cloud_tree(self, i: int) -> cKDTree:
        """Env i's obstacle points in a KD-tree, made at the first query (only a carry to a
        release asks: a pick episode makes none)."""
        if i not in self._trees:
            self._trees[i] = cKDTree(self.clouds[i])
        return self._trees[i]

    # --- the policy ----------------------------------------------------------------------
    @property
    def grasp_config(self) -> GraspConfig:
        return GraspConfig(sweep=self.cfg.approach_offset)

    @property
    def gripper_model(self) -> GripperModel:
        """The robot's open hand as boxes (its hand entry; the Panda's: the defaults)."""
        return GripperModel(**dict(self.robot_hand.boxes))

    def _in_hand(self) -> np.ndarray:
        """Per env, the target's position in the TCP's frame now."""
        tcp = self._tcp().to_transformation_matrix().cpu().numpy()
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

    def _pressing(self) -> np.ndarray:
        """Per env: both jaws press on the target now, at any angle (the robot's grasp rule,
        ``Robot.grasp_check``, without its angle), where a gentle close stops. A wedge's
        faces push a jaw off its opening direction: a lying triangular prism's, 30 degrees off
        the closing line, pushed the SO-100's moving jaw 116-121 degrees off it, past
        ManiSkill's 110, and a close waiting for that rule squeezed on to 20 N, the prism
        wedged under the jaws (accept9's prism: 3 of 6 taken, now 6 of 6)."""
        if self.press_rule is None:
            return self._grasping()
        return self.base.task_reader.presses(self.target, self.press_rule)

    def _steps_left(self) -> int:
        limit = getattr(getattr(self.env, "spec", None), "max_episode_steps", None) or 10**9
        return limit - self.steps

    def _grasp(self, todo: np.ndarray, attempt: int) -> np.ndarray:
        """One grasp attempt in the envs ``todo``: approach the best reachable grasp, close,
        lift, and check; returns which envs hold the target after the lift. Envs that miss
        open and back off to where they came from."""
        cfg = self.cfg
        up = sapien.Pose([0, 0, -cfg.approach_offset])
        self._leave_start(todo)
        candidates = self.grasp_poses()
        for i in np.flatnonzero(todo):  # said here: the approach has no option to fail on
            if not candidates[i] and not self.reports[i].plan_failures:
                self.reports[i].plan_failures.append(
                    "grasp: none clears the table and the other objects (the hand's boxes, "
                    "GraspConfig's margins)"
                )
        planned_at = self.target.pose.p.cpu().numpy().copy()  # where the grasps were planned
        targets = [
            [g * up for g, _ in candidates[i]] if todo[i] else None for i in range(self.num_envs)
        ]

        descents, taken = {}, {}  # per (env, option) the descent planned; per env the one run

        def descent(i, k, qpos):  # the straight move from option k's pre-grasp to its grasp
            descents[i, k] = self._plan(i, targets[i][k] * up.inv(), qpos, "screw", False)[0]
            return descents[i, k]

        def take(i, k):  # env i runs option k: fingers pre-shaped on the way, its descent next
            self.gripper[i] = self.robot_hand.action(candidates[i][k][1])
            taken[i] = descents.get((i, k))

        pre = self._per_env(
            "approach", targets, ("rrt", "screw"), settle=cfg.settle_steps,
            option_steps=cfg.option_steps, rank_first=cfg.consistent,
            then=lambda i, k, q: None if (p := descent(i, k, q)) is None else len(p),
            on_choice=take, twins=self.grasp_twins,
        )  # fmt: skip
        moved = self._moved(planned_at) & todo  # re-observed: no descent onto where it was
        grasps = [None if p is None or moved[i] else p * up.inv() for i, p in enumerate(pre)]
        # the descent ranked with the approach, from its end (the arm settled there); the arm
        # reaches the grasp before the fingers close
        self._per_env("grasp", grasps, obstacles=False, settle=cfg.settle_steps, planned=taken.get)
        # not again before closing: the descending fingers nudge a rolling body, and closing
        # on it still holds it (a smooth ball: 6/6 closing anyway, 3/6 backing off instead)
        self._set_gripper(todo & ~moved, self.robot_hand.action_closed)
        z0 = self.target.pose.p[:, 2].cpu().numpy()
        lifts = [
            None
            if g is None
            else [sapien.Pose(g.p + np.array([0, 0, h]), q)
                  for q in self._lift_turns(i, g) for h in cfg.lift_heights]  # fmt: skip
            for i, g in enumerate(grasps)
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
        self.firm |= missed & ~moved
        if missed.any():  # open and back off upwards, for the next attempt
            self._set_gripper(missed, self.robot_hand.action_open)
            tcp = self._hand_pose()
            back = [  # or stay: the lift rose already (a five-joint arm may not rise further)
                [sapien.Pose(tcp[i, :3] + np.array([0, 0, cfg.approach_offset]), tcp[i, 3:]),
                 sapien.Pose(tcp[i, :3], tcp[i, 3:])]
                if missed[i]
                else None
                for i in range(self.num_envs)
            ]  # fmt: skip
            self._per_env("retreat", back, obstacles=False)
        return held

    def _lift_turns(self, i: int, grasp: sapien.Pose) -> list[np.ndarray]:
        """The hand's orientations to lift env i's grasp with: the grasp's; a planar hand's
        also turned in its arm's vertical plane by ``planar_lift_turns`` (a five-joint arm that
        took a block tilted cannot always rise keeping the tilt: SO-100 seeds 21 and 46)."""
        if not self.robot_hand.planar:
            return [grasp.q]
        out = grasp.p[:2] - self._pan_axis()[i]
        across = np.array([-out[1], out[0], 0.0]) / max(np.linalg.norm(out), 1e-9)
        half = np.deg2rad(np.asarray(self.cfg.planar_lift_turns)) / 2
        turns = [sapien.Pose(q=[np.cos(h), *(np.sin(h) * across)]) for h in half]
        return [grasp.q, *((t * sapien.Pose(q=grasp.q)).q for t in turns)]

    def _start_collides(self, i: int, qpos: np.ndarray) -> bool:
        """Whether env i's robot at ``qpos`` (every joint) meets its obstacle points (their
        spheres: ``obstacle_radius`` past the objects)."""
        motion = self.motion[i]
        motion.mp.planning_world.set_use_point_cloud(True)
        motion.mp.planning_world.set_use_attach(False)
        motion.mp.robot.set_qpos(qpos, True)
        return not motion.free(qpos[motion.idx])

    def _leave_start(self, envs: np.ndarray) -> None:
        """Where the robot of ``envs`` stands among the obstacle points before an approach
        (an object against its hand at rest: so100_block seed 10, a can under the SO-100's
        moving jaw, 9 mm from its tip), the hand first rises ``approach_offset`` straight up,
        without them: no path leaves a start that collides (``motion.START_COLLIDES``), and
        none is planned from one."""
        qpos, tcp = self._plan_start(), self._hand_pose()
        up = np.array([0.0, 0.0, self.cfg.approach_offset])
        targets = [
            sapien.Pose(tcp[i, :3] + up, tcp[i, 3:])
            if envs[i] and not self.reports[i].plan_failures
            and self._start_collides(i, qpos[i]) else None
            for i in range(self.num_envs)
        ]  # fmt: skip
        if any(t is not None for t in targets):
            self._per_env("leave the start", targets, obstacles=False)

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
        self.firm[:] = False  # a slip on another mover says nothing of this one
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
            self.firm |= dropped
            holding &= ~dropped
            if dropped.any():  # grasp again from where the object lies
                self._set_gripper(dropped, self.robot_hand.action_open)
            if placed.all():
                break
