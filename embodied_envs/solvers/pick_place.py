"""Scripted, motion-planned pick-and-place for the Panda (mplib).

For every env the solver plans from that env's own robot and object state: a top-down grasp
across the narrow side of the target's footprint (from its collision geometry in its current
pose), approach, grasp, lift, carry the object to the goal and hold still. Table and distractors
are obstacles (surface point clouds). A failed plan is recorded per env and stage; that env
then holds still while the others go on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mplib
import numpy as np
import sapien
import torch
import trimesh

from embodied_envs.layout.assets import asset_geometry, convex_hull_2d
from embodied_envs.layout.pose import LayoutPose

GRIPPER_OPEN = 1.0  # pd_joint_pos gripper action for open fingers
GRIPPER_CLOSED = -1.0  # and for closed fingers


@dataclass(frozen=True)
class SolverConfig:
    """Tunable numbers of the scripted policy."""

    approach_offset: float = 0.08  # m, pre-grasp distance above the grasp along the approach
    grasp_depth: float = 0.035  # m, grasp centre below the object's top
    min_tcp_height: float = 0.015  # m, lowest grasp centre above the support surface
    lift_heights: tuple[float, ...] = (0.10, 0.05)  # m, lifts after grasping, tried in order
    gripper_steps: int = 8  # control steps to close the gripper
    hold_steps: int = 10  # control steps holding still at the goal
    joint_vel_scale: float = 2.0  # times mplib's default joint velocity limit (1 rad/s)
    joint_acc_scale: float = 5.0  # times mplib's default joint acceleration limit (1 rad/s^2)
    rrt_planning_time: float = 1.5  # s, per RRTConnect call
    rrt_attempts: int = 3  # RRTConnect calls per stage before giving up (it is randomised)
    max_path_steps: int = 120  # a longer plan (a wrist flip, a detour) is refused as "long"
    obstacle_points: int = 3000  # surface samples per obstacle actor
    obstacle_radius: float = 0.01  # m, radius of each obstacle point
    base_clearance: float = 0.15  # m, obstacle points this close to the base (in XY) and
    # below base_clearance_height are dropped: the base stands on the table's edge
    base_clearance_height: float = 0.10  # m above the base


@dataclass
class EnvReport:
    """What happened in one env."""

    env_index: int
    plan_failures: list[str] = field(default_factory=list)  # "stage: mplib status"

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


def _sample_surface(vertices_parts: tuple[np.ndarray, ...], n: int, rng: np.random.Generator):
    points = []
    per = max(n // max(len(vertices_parts), 1), 50)
    for verts in vertices_parts:
        with np.errstate(all="ignore"):  # thin parts have near-zero volume; sampling is fine
            hull = trimesh.Trimesh(vertices=verts).convex_hull
            pts, _ = trimesh.sample.sample_surface(hull, per, seed=int(rng.integers(2**31)))
        points.append(pts)
    return np.concatenate(points)


def grasp_frame(
    vertices_world: np.ndarray, support_z: float, cfg: SolverConfig, current_y: np.ndarray
):
    """Grasp centre and closing direction for a top-down grasp.

    The closing direction is the narrow side of the minimum-area rectangle around the object's
    XY footprint; its sign is the one closest to the gripper's current closing axis.
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
    return np.array([centre2[0], centre2[1], z]), closing


class PickPlaceSolver:
    """Plans and executes pick-and-place in every env of a ``PickEmbodiedGen-v1`` env.

    Args:
        env: the env (optionally wrapped); actions go through ``env.step`` so wrappers such as
            video recorders see every step.
        config: tunable numbers.
        seed: seeds the obstacle point sampling.
    """

    def __init__(self, env, config: SolverConfig | None = None, seed: int = 0):
        self.env = env
        self.base = env.unwrapped
        self.cfg = config or SolverConfig()
        self.rng = np.random.default_rng(seed)
        self.num_envs = self.base.num_envs
        if self.base.control_mode != "pd_joint_pos":
            raise ValueError(
                f"the solver drives control_mode='pd_joint_pos', got {self.base.control_mode!r}"
            )
        agent = self.base.agent
        robot = agent.robot
        link_names = [link.get_name() for link in robot.get_links()]
        joint_names = [joint.get_name() for joint in robot.get_active_joints()]
        base_poses = robot.pose.raw_pose.cpu().numpy()
        self.planners = []
        for i in range(self.num_envs):
            planner = mplib.Planner(
                urdf=agent.urdf_path,
                srdf=agent.urdf_path.replace(".urdf", ".srdf"),
                user_link_names=link_names,
                user_joint_names=joint_names,
                move_group="panda_hand_tcp",
            )
            planner.set_base_pose(base_poses[i])
            planner.joint_vel_limits = (
                np.asarray(planner.joint_vel_limits) * self.cfg.joint_vel_scale
            )
            planner.joint_acc_limits = (
                np.asarray(planner.joint_acc_limits) * self.cfg.joint_acc_scale
            )
            self.planners.append(planner)
        self.reports = [EnvReport(i) for i in range(self.num_envs)]
        self.steps = 0
        self.ended = False  # the episode was truncated (or terminated) in every env
        self.last_info: dict = {}
        self._batched_actions = len(self.env.action_space.shape) == 2
        self.gripper = np.full(self.num_envs, GRIPPER_OPEN)
        self._set_obstacles()

    # --- state ---------------------------------------------------------------------------
    def _qpos(self) -> np.ndarray:
        return self.base.agent.robot.get_qpos().cpu().numpy().astype(np.float64)

    def _set_obstacles(self) -> None:
        for i, layout in enumerate(self.base.layouts):
            actors = self.base.env_actors[f"env{i}"]
            clouds = []
            for node, actor in actors.items():
                if node == layout.target_node:
                    continue
                geom = asset_geometry(layout.asset_spec(node))
                pose = LayoutPose.from_raw(actor.pose.raw_pose[0].cpu().numpy())
                parts = tuple(pose.transform_points(p) for p in geom.parts)
                clouds.append(_sample_surface(parts, self.cfg.obstacle_points, self.rng))
            cloud = np.concatenate(clouds)
            base = self.base.layout_scene.robot_poses[i, :3].cpu().numpy()
            near_base = (
                np.linalg.norm(cloud[:, :2] - base[:2], axis=1) < self.cfg.base_clearance
            ) & (cloud[:, 2] < base[2] + self.cfg.base_clearance_height)
            self.planners[i].update_point_cloud(cloud[~near_base], radius=self.cfg.obstacle_radius)

    # --- planning ------------------------------------------------------------------------
    def _plan(
        self, i, pose: sapien.Pose, qpos: np.ndarray, stage: str, screw_first=True, obstacles=True
    ):
        """A joint path to ``pose`` for env i, or None (the failure is recorded).

        ``obstacles=False`` is for the short straight moves next to the support surface (the
        final descent from the pre-grasp and the lift), which the surface's cloud would block.
        """
        planner = self.planners[i]
        target = np.concatenate([pose.p, pose.q])
        dt = self.base.control_timestep
        statuses = []
        rrt = ("rrt",) * self.cfg.rrt_attempts
        attempts = ("screw", *rrt) if screw_first else (*rrt, "screw")
        for how in attempts:
            if how == "screw":
                res = planner.plan_screw(
                    target, qpos.copy(), time_step=dt, use_point_cloud=obstacles
                )
            else:
                res = planner.plan_qpos_to_pose(
                    target,
                    qpos.copy(),
                    time_step=dt,
                    use_point_cloud=obstacles,
                    planning_time=self.cfg.rrt_planning_time,
                    wrt_world=True,
                )
            if res["status"] == "Success" and len(res["position"]) > self.cfg.max_path_steps:
                statuses.append(f"{how}: {len(res['position'])} steps, over max_path_steps")
                continue
            if res["status"] == "Success" and len(res["position"]):
                return res["position"]
            statuses.append(f"{how}: {res['status']}")
        self.reports[i].plan_failures.append(f"{stage}: " + "; ".join(statuses))
        return None

    def _execute(self, paths: list[np.ndarray | None], extra_steps: int = 0) -> None:
        """Step all envs along their paths in lockstep; envs without a path hold still."""
        qpos = self._qpos()
        lengths = [len(p) if p is not None else 0 for p in paths]
        n = max(lengths, default=0) + extra_steps
        for t in range(n):
            if self.ended:  # no step past the end of the episode
                return
            action = np.zeros((self.num_envs, 8), np.float32)
            for i, path in enumerate(paths):
                if path is not None and len(path):
                    action[i, :7] = path[min(t, len(path) - 1)][:7]
                else:
                    action[i, :7] = qpos[i, :7]
                action[i, 7] = self.gripper[i]
            self._step(action)

    def _step(self, action: np.ndarray) -> None:
        a = action if self._batched_actions else action[0]
        _, _, terminated, truncated, info = self.env.step(a)
        self.last_info = info
        self.steps += 1
        self.ended = bool(np.all(np.asarray(torch.as_tensor(terminated | truncated).cpu())))

    def _gripper(self, value: float) -> None:
        self.gripper[:] = value
        self._execute([None] * self.num_envs, extra_steps=self.cfg.gripper_steps)

    def _per_env(
        self, stage: str, targets: list, screw_first: bool = True, obstacles: bool = True
    ) -> list[sapien.Pose | None]:
        """Plan and execute one stage in every env that has not failed yet.

        Args:
            stage: named in failure reports.
            targets: per env a pose, a list of poses to try in order, or None (hold still).

        Returns:
            Per env the pose that was planned to (None where none could be).
        """
        qpos = self._qpos()
        paths, chosen = [], []
        for i, target in enumerate(targets):
            options = target if isinstance(target, list) else [target]
            path, pose = None, None
            if target is not None and not self.reports[i].plan_failures:
                for k, pose in enumerate(options):
                    name = stage if len(options) == 1 else f"{stage} (option {k})"
                    path = self._plan(i, pose, qpos[i], name, screw_first, obstacles)
                    if path is not None:  # the options tried before are not failures
                        self.reports[i].plan_failures.clear()
                        break
            paths.append(path)
            chosen.append(pose if path is not None else None)
        self._execute(paths)
        return chosen

    # --- the policy ----------------------------------------------------------------------
    def grasp_poses(self) -> list[list[sapien.Pose]]:
        """Per env, the top-down grasps to try: the narrow-side grasp with the closing axis
        nearer the gripper's current one first, then the same grasp turned by 180 degrees
        (the same for a parallel gripper, but another wrist angle for IK and joint limits)."""
        agent = self.base.agent
        tcp = agent.tcp.pose.to_transformation_matrix().cpu().numpy()
        poses = []
        for i, layout in enumerate(self.base.layouts):
            actor = self.base.env_actors[f"env{i}"][layout.target_node]
            geom = asset_geometry(layout.asset_spec(layout.target_node))
            pose = LayoutPose.from_raw(actor.pose.raw_pose[0].cpu().numpy())
            verts = pose.transform_points(geom.vertices)
            support = float(self.base.layout_scene.top_z[i])
            centre, closing = grasp_frame(verts, support, self.cfg, tcp[i, :3, 1])
            down = np.array([0, 0, -1.0])
            poses.append([agent.build_grasp_pose(down, c, centre) for c in (closing, -closing)])
        return poses

    def solve(self) -> SolveResult:
        """Run the whole pick-and-place in every env; returns per-env reports and the last info."""
        cfg = self.cfg
        up = sapien.Pose([0, 0, -cfg.approach_offset])
        candidates = self.grasp_poses()
        pre = self._per_env(
            "approach", [[g * up for g in c] for c in candidates], screw_first=False
        )
        grasps = [
            None if p is None else p * up.inv() for p in pre
        ]  # the grasp whose pre-grasp was reached
        self._per_env("grasp", grasps, obstacles=False)
        self._gripper(GRIPPER_CLOSED)
        lifts = [
            None
            if g is None
            else [sapien.Pose(g.p + np.array([0, 0, h]), g.q) for h in cfg.lift_heights]
            for g in grasps
        ]
        lifts = self._per_env("lift", lifts, obstacles=False)
        # carry: keep the object's offset from the TCP as it is in the hand now
        tcp = self.base.agent.tcp.pose.p.cpu().numpy()
        obj = self.base.obj.pose.p.cpu().numpy()
        goal = self.base.goal_site.pose.p.cpu().numpy()
        carries = [
            None if lifts[i] is None else sapien.Pose(goal[i] + (tcp[i] - obj[i]), lifts[i].q)
            for i in range(self.num_envs)
        ]
        self._per_env("carry", carries, screw_first=False)
        # fine correction: re-measure the in-hand offset and move the last few millimetres
        tcp = self.base.agent.tcp.pose.p.cpu().numpy()
        obj = self.base.obj.pose.p.cpu().numpy()
        fine = [
            None if lifts[i] is None else sapien.Pose(goal[i] + (tcp[i] - obj[i]), lifts[i].q)
            for i in range(self.num_envs)
        ]
        self._per_env("settle", fine, obstacles=False)
        self._execute([None] * self.num_envs, extra_steps=cfg.hold_steps)
        return SolveResult(self.reports, self.steps, self.last_info)
