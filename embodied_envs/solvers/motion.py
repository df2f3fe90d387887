"""Seeded motion planning on mplib's kinematics and collision world.

mplib 0.1.1 (the version ManiSkill 3.0.1 pins) draws its IK restarts from pinocchio's global
random state and its RRTConnect from OMPL's time-seeded generator, and neither can be seeded
from Python: the same episode can succeed in one run and fail in the next, and two datasets
of the same seeds differ. ``SeededPlanner`` keeps mplib for what is deterministic (the robot
model, forward kinematics, CLIK, FCL collision checks, TOPP-RA time parameterisation; its
screw walk is ``screw.py``'s, timed in closed form) and draws everything random from a numpy
``Generator`` the caller seeds:

- IK: joint-limited CLIK from the current configuration first, then from configurations drawn
  uniformly within the joint limits; collision-free, distinct solutions, nearest first.
- A path: the straight joint-space line to the nearest solution when every configuration on it
  (checked so that no collision point moves more than ``check_distance`` between checks, by
  each joint's lever, :func:`joint_levers`) is free (the start itself is not checked: a move
  may leave a contact); otherwise RRT-Connect between the start and all solutions, then
  shortcuts, when the start is free (a search from a colliding start cannot grow). With a
  bound on the steps (``within``), a line whose exact length cannot beat it is not checked.
- Time: a straight line moves time-optimally from rest to rest within the joint limits
  (:func:`straight_line_trajectory`, exact and in closed form); a detour is densified to
  ``waypoint_step`` waypoints (so the spline TOPP-RA fits stays on the checked segments) and
  parameterised by mplib's ``TOPP``. What will run is checked
  again where the path has corners: where the spline rounds one into an obstacle, each
  straight segment runs alone, timed in closed form.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import mplib
import numpy as np
import sapien
from mani_skill.utils.geometry.trimesh_utils import get_component_mesh
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from embodied_envs.internals import link_components, px_joints
from embodied_envs.solvers.screw import rest_to_rest

STRAIGHT_BLOCKED = "the straight joint line is blocked"  # plan_to_pose(detour=False)
START_COLLIDES = "the start collides and the straight line is blocked: no detour is searched"
BOUND_SLACK = 0.9  # min_steps' bound is this part of the time-optimal rest-to-rest time


@dataclass(frozen=True)
class MotionConfig:
    """Tunable numbers of the seeded planner."""

    ik_restarts: int = 20  # random CLIK starts after the current configuration
    ik_solutions: int = 2  # distinct solutions collected before IK stops
    ik_tolerance: float = 1e-3  # 6-D pose distance a solution must reach (as mplib's IK)
    ik_iterations: int = 300  # CLIK iterations per start (mplib's default 1000: a start that
    # does not converge by 300 rarely does, measured 50 vs 54 of 100 random starts, at 0.4
    # instead of 1.0 ms per start)
    distinct: float = 0.1  # rad, solutions closer than this (joint norm) are one
    tilt_tolerance: float = 0.0  # rad: an arm of fewer than 6 joints reaches most poses only
    # nearly (the SO-100 turned 0.3 rad about the vertical from its rest grasp: 0.015 rad off);
    # its solutions are refined to the position exactly (``ik_tolerance`` m) with the hand's
    # orientation this close (the robot's hand entry sets it, robots.py)
    check_distance: float = 0.01  # m, the farthest a joint's move carries the robot's
    # collision geometry between two collision checks (obstacle points are 1 cm spheres): the
    # joint's move times its lever (``joint_levers``)
    waypoint_step: float = 0.05  # rad, largest joint move between the waypoints TOPP-RA fits
    rrt_step: float = 0.2  # rad, RRT-Connect extension
    rrt_samples: int = 1500  # RRT-Connect iterations before giving up
    shortcut_rounds: int = 30  # random shortcut tries on an RRT path


@functools.lru_cache(maxsize=1024)
def coarse_to_fine(n: int) -> tuple[int, ...]:
    """``1..n``, each once: ``n`` first, then the multiples of halving strides."""
    if n < 1:
        return ()
    order, seen = [n], {n}
    stride = 1 << n.bit_length()
    while stride:
        for k in range(stride, n, stride):
            if k not in seen:
                seen.add(k)
                order.append(k)
        stride //= 2
    return tuple(order)


def straight_line_trajectory(
    start: np.ndarray, goal: np.ndarray, vel: np.ndarray, acc: np.ndarray, time_step: float
) -> np.ndarray:
    """The time-optimal motion from rest at ``start`` to rest at ``goal`` along the straight
    joint line, each joint within its velocity and acceleration limits, sampled every
    ``time_step`` from its start, then its end: ``(T, dof)``, a waypoint per control step.
    (mplib's ``TOPP`` spreads ``int(duration / time_step)`` samples over the duration instead:
    a robot stepping through them moves up to ``T / (T - 1)`` faster than its limits.)

    On the line ``start + s * (goal - start)`` the limits bound ``ds/dt`` and ``d2s/dt2`` by
    their tightest joint, so ``s`` accelerates at that bound, cruises at that speed and brakes
    (a trapezoid; a triangle when the line is too short to reach the speed). This is the
    exact optimum of the problem TOPP-RA solves numerically on the same line.
    """
    start, goal = np.asarray(start, np.float64), np.asarray(goal, np.float64)
    span = np.abs(goal - start)
    moving = span > 0
    if not moving.any():
        return start[None].copy()
    speed = np.min(np.asarray(vel, np.float64)[moving] / span[moving])  # ds/dt at most
    rate = np.min(np.asarray(acc, np.float64)[moving] / span[moving])  # d2s/dt2 at most
    s = rest_to_rest(speed, rate, time_step)
    return start + s[:, None] * (goal - start)


def link_points(robot) -> tuple[list[str], list[np.ndarray]]:
    """Per link of the ManiSkill articulation ``robot`` with collision geometry, its name and
    its collision shapes' vertices in its frame (what :func:`joint_levers` measures)."""
    names, points = [], []
    for link in robot.get_links():
        mesh = get_component_mesh(link_components(link)[0], to_world_frame=False)
        if mesh is not None:
            names.append(link.get_name())
            points.append(np.asarray(mesh.vertices, dtype=np.float64))
    return names, points


def joint_levers(robot, planner: mplib.Planner, samples: int = 200, seed: int = 0) -> np.ndarray:
    """Per move-group joint of ``planner``, the farthest (m) the collision geometry it moves
    (its child link and every link beyond) reaches from its axis: the most over ``samples``
    seeded configurations within the joint limits, plus 5 %. A joint turning by ``d`` rad
    carries no collision point farther than ``d`` times its lever. The Panda's: 0.99, 1.02,
    0.76, 0.69, 0.27, 0.28, 0.11 m (the last joint turns only the hand; 3,000 samples give
    at most 2 % more).

    Args:
        robot: the ManiSkill articulation ``planner`` models (its links' collision shapes and
            joint axes; the planner's links in the articulation's order).
        planner: the ``mplib.Planner`` (its kinematics).
        samples, seed: the configurations drawn.
    """
    model = planner.pinocchio_model
    # the planner's link names of the SAPIEN link components
    named = {link_components(link)[0].get_name(): link.get_name() for link in robot.get_links()}
    names, points = link_points(robot)
    owner = np.concatenate([np.full(len(p), k) for k, p in enumerate(points)])
    local = np.concatenate(points)
    rows = [owner == k for k in range(len(points))]  # each link's rows of `local`

    def beyond(child) -> set[str]:  # the link and every link after it
        out, todo = set(), [child]
        while todo:
            link = todo.pop()
            out.add(named[link.get_name()])
            todo.extend(link.children)
        return out

    joints = [
        px_joints(robot.active_joints_map[planner.user_joint_names[i]])[0]
        for i in planner.move_group_joint_indices
    ]
    moved = [np.isin(owner, [k for k, n in enumerate(names) if n in beyond(j.child_link)])
             for j in joints]  # fmt: skip
    child = [planner.link_name_2_idx[named[j.child_link.get_name()]] for j in joints]
    in_child = [j.pose_in_child.to_transformation_matrix() for j in joints]
    frames = [planner.link_name_2_idx[n] for n in names]
    limits = np.asarray(planner.joint_limits, dtype=np.float64)
    rng = np.random.default_rng(seed)
    levers = np.zeros(len(joints))

    def matrix(i):
        p = model.get_link_pose(i)
        return sapien.Pose(p[:3], p[3:]).to_transformation_matrix()

    for _ in range(samples):
        model.compute_forward_kinematics(rng.uniform(limits[:, 0], limits[:, 1]))
        world = np.empty_like(local)
        for k, i in enumerate(frames):
            m = matrix(i)
            world[rows[k]] = local[rows[k]] @ m[:3, :3].T + m[:3, 3]
        for j in range(len(joints)):
            axis = matrix(child[j]) @ in_child[j]  # its x axis is the joint's
            rel = world[moved[j]] - axis[:3, 3]
            off = rel - np.outer(rel @ axis[:3, 0], axis[:3, 0])
            levers[j] = max(levers[j], float(np.sqrt((off * off).sum(1)).max()))
    return 1.05 * levers


class SeededPlanner:
    """Plans joint paths for one robot with randomness drawn from the caller's generator.

    Args:
        planner: an ``mplib.Planner`` (its model, collision world and obstacle point cloud).
        config: tunable numbers.
        levers: per move-group joint, how far (m) its links reach from its axis
            (:func:`joint_levers`); 1 m each when not given.
    """

    def __init__(self, planner: mplib.Planner, config: MotionConfig | None = None, levers=None):
        self.mp = planner
        self.cfg = config or MotionConfig()
        self.idx = np.asarray(planner.move_group_joint_indices)
        self.limits = np.asarray(planner.joint_limits, dtype=np.float64)  # (dof, 2)
        self.lo, self.hi = self.limits[self.idx, 0], self.limits[self.idx, 1]
        self.link = planner.link_name_2_idx[planner.move_group]
        self.levers = np.ones(len(self.idx)) if levers is None else np.asarray(levers, float)

    # --- collision ---------------------------------------------------------------------
    def free(self, q: np.ndarray) -> bool:
        """The move group at ``q`` (its joints only) collides with nothing."""
        self.mp.planning_world.set_qpos_all(q)
        return not self.mp.planning_world.collide()

    def edge_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Every configuration on the joint-space segment a-b is free (checked so that no
        joint's move between two checks carries its links more than ``check_distance``, ``b``
        included; ``b`` first, then coarse to fine, so that a blocked segment is found blocked
        after a few checks)."""
        n = int(np.ceil((np.abs(b - a) * self.levers).max() / self.cfg.check_distance))
        return all(self.free(a + (b - a) * (k / n)) for k in coarse_to_fine(n))

    # --- IK ------------------------------------------------------------------------------
    def ik(self, goal_base: np.ndarray, qpos: np.ndarray, rng: np.random.Generator):
        """Collision-free joint solutions (move group) reaching ``goal_base`` ([x, y, z, qw, qx,
        qy, qz] in the robot base frame), nearest to ``qpos`` first ([] when none), and the
        closest 6-D distance any restart reached (for the failure message)."""
        cfg, mp = self.cfg, self.mp
        start, solutions, best = qpos.copy(), [], np.inf
        # joint-limited CLIK; the other joints (the fingers) stay where they are
        q_min, q_max = qpos.copy(), qpos.copy()
        q_min[self.idx], q_max[self.idx] = self.lo, self.hi
        for k in range(cfg.ik_restarts + 2):
            if k == 1:  # the base joint turned toward the goal, the arm as it is
                start = self._turned_start(goal_base, qpos)
            elif k:
                start = qpos.copy()
                start[self.idx] = rng.uniform(self.lo, self.hi)
            q = mp.pinocchio_model.compute_IK_CLIK_JL(
                self.link, goal_base, start, q_min, q_max, max_iter=cfg.ik_iterations
            )
            q = np.array(q[0])
            if not mp.wrap_joint_limit(q):
                continue
            mp.pinocchio_model.compute_forward_kinematics(q)
            pose = mp.pinocchio_model.get_link_pose(self.link)
            dist = mp.distance_6D(goal_base[:3], goal_base[3:], pose[:3], pose[3:])
            if dist >= cfg.ik_tolerance and cfg.tilt_tolerance:
                q, dist = self._nearly(goal_base, q)
            best = min(best, dist)
            q = q[self.idx]
            if dist >= cfg.ik_tolerance or not self.free(q):
                continue
            if all(np.linalg.norm(s - q) >= cfg.distinct for s in solutions):
                solutions.append(q)
                if len(solutions) >= cfg.ik_solutions:
                    break
        here = qpos[self.idx]
        solutions.sort(key=lambda s: float(np.linalg.norm(s - here)))
        return solutions, best

    def _nearly(self, goal_base: np.ndarray, qpos: np.ndarray) -> tuple[np.ndarray, float]:
        """``qpos`` refined (bounded least squares over the move group's joints) to reach
        ``goal_base``'s position exactly and its orientation as near as the arm can, and the
        distance left: the position error, or ``inf`` when the orientation stays more than
        ``tilt_tolerance`` off (an arm of fewer than six joints)."""
        model, goal = self.mp.pinocchio_model, Rotation.from_quat(np.roll(goal_base[3:], -1))
        q = qpos.copy()

        def error(x: np.ndarray) -> np.ndarray:
            q[self.idx] = x
            model.compute_forward_kinematics(q)
            pose = model.get_link_pose(self.link)
            turn = Rotation.from_quat(np.roll(pose[3:], -1)) * goal.inv()
            # position first: a radian of turn weighs as 1 cm
            return np.concatenate([pose[:3] - goal_base[:3], 0.01 * turn.as_rotvec()])

        fit = least_squares(error, np.clip(qpos[self.idx], self.lo, self.hi),
                            bounds=(self.lo, self.hi), xtol=1e-10)  # fmt: skip
        res = error(fit.x)
        off, tilt = float(np.linalg.norm(res[:3])), float(np.linalg.norm(res[3:]) / 0.01)
        return q.copy(), off if tilt <= self.cfg.tilt_tolerance else np.inf

    def _turned_start(self, goal_base: np.ndarray, qpos: np.ndarray) -> np.ndarray:
        """``qpos`` with the first arm joint (the base's vertical axis) turned by the angle
        between the hand and ``goal_base`` about the base, within its limits: a start near the
        solution the arm reaches by turning, where the CLIK from ``qpos`` itself converged to
        none or to a far configuration (an elbow flipped: 2 rad and 140 steps of joint travel
        on place_two)."""
        model = self.mp.pinocchio_model
        model.compute_forward_kinematics(qpos)
        hand = model.get_link_pose(self.link)[:2]
        turn = np.arctan2(goal_base[1], goal_base[0]) - np.arctan2(hand[1], hand[0])
        turn = (turn + np.pi) % (2 * np.pi) - np.pi
        start = qpos.copy()
        j = self.idx[0]
        start[j] = np.clip(qpos[j] + turn, self.lo[0], self.hi[0])
        return start

    # --- paths ---------------------------------------------------------------------------
    def _steer(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        d = b - a
        n = np.linalg.norm(d)
        return b if n <= self.cfg.rrt_step else a + d * (self.cfg.rrt_step / n)

    def rrt_connect(self, start: np.ndarray, goals: list[np.ndarray], rng: np.random.Generator):
        """A collision-free joint path from ``start`` to one of ``goals``, or None."""
        start_tree = {"q": [start], "parent": [-1]}
        goal_tree = {"q": list(goals), "parent": [-1] * len(goals)}
        grow, other = start_tree, goal_tree
        for _ in range(self.cfg.rrt_samples):
            new = self._extend(grow, rng.uniform(self.lo, self.hi))
            if new is not None:
                reached = self._connect(other, grow["q"][new])
                if reached is not None:  # the two trees meet at one configuration
                    i, j = (new, reached) if grow is start_tree else (reached, new)
                    return self._branch(start_tree, i)[::-1] + self._branch(goal_tree, j)[1:]
            grow, other = other, grow
        return None

    def _nearest(self, tree, q) -> int:
        return int(np.argmin(np.linalg.norm(np.asarray(tree["q"]) - q, axis=1)))

    def _extend(self, tree, target) -> int | None:
        near = self._nearest(tree, target)
        q = self._steer(tree["q"][near], target)
        if not self.edge_free(tree["q"][near], q):
            return None
        tree["q"].append(q)
        tree["parent"].append(near)
        return len(tree["q"]) - 1

    def _connect(self, tree, target) -> int | None:
        """Extend ``tree`` towards ``target`` until it reaches it (its node) or is blocked."""
        i = self._nearest(tree, target)
        while True:
            q = self._steer(tree["q"][i], target)
            if not self.edge_free(tree["q"][i], q):
                return None
            tree["q"].append(q)
            tree["parent"].append(i)
            i = len(tree["q"]) - 1
            if np.array_equal(q, target):
                return i

    @staticmethod
    def _branch(tree, i) -> list[np.ndarray]:
        out = []
        while i != -1:
            out.append(tree["q"][i])
            i = tree["parent"][i]
        return out

    def shortcut(self, path: list[np.ndarray], rng: np.random.Generator) -> list[np.ndarray]:
        """Drops waypoints between random pairs whose straight segment is free."""
        path = list(path)
        for _ in range(self.cfg.shortcut_rounds):
            if len(path) < 3:
                break
            i, j = sorted(rng.choice(len(path), size=2, replace=False))
            if j - i > 1 and self.edge_free(path[i], path[j]):
                path = path[: i + 1] + path[j:]
        return path

    def densify(self, path: list[np.ndarray]) -> np.ndarray:
        """The path with waypoints every ``waypoint_step`` rad (at most) along its segments."""
        out = [path[0]]
        for a, b in zip(path[:-1], path[1:], strict=True):
            n = int(np.ceil(np.abs(b - a).max() / self.cfg.waypoint_step))
            out.extend(a + (b - a) * (k / n) for k in range(1, n + 1))
        return np.vstack(out)

    def min_steps(self, start: np.ndarray, goals: list[np.ndarray], time_step: float) -> int:
        """A lower bound on the waypoints of any time-parameterised path from ``start`` to one
        of ``goals`` (move group): every joint at most at its velocity and acceleration limits,
        from rest to rest (``BOUND_SLACK`` below that time, for the spline's rounding)."""
        v = np.asarray(self.mp.joint_vel_limits, dtype=np.float64)
        a = np.asarray(self.mp.joint_acc_limits, dtype=np.float64)
        d = np.abs(np.asarray(goals, dtype=np.float64) - start)
        # a joint moving d: accelerate to v, cruise, brake; or accelerate and brake (triangle)
        t = np.where(d <= v * v / a, 2 * np.sqrt(d / a), d / v + v / a)
        return int(BOUND_SLACK * t.max(axis=1).min() / time_step)

    def plan_to_pose(
        self,
        goal_world: np.ndarray,
        qpos: np.ndarray,
        rng: np.random.Generator,
        time_step: float,
        use_point_cloud: bool,
        within: int | None = None,
        detour: bool = True,
    ) -> dict:
        """mplib's ``plan_qpos_to_pose``, seeded: {"status", "position" (T, move group)}.

        ``within``: a path of this many waypoints or more is not wanted (a better one is known);
        when the IK solutions show that no path can be shorter (:meth:`min_steps`), nothing is
        planned and the status says so. ``detour=False``: the straight line or nothing (status
        ``STRAIGHT_BLOCKED`` where it is blocked; the same call with ``detour=True`` and the
        same generator state then plans the detour).
        """
        mp = self.mp
        qpos = np.clip(qpos.astype(np.float64), self.limits[:, 0] + 1e-3, self.limits[:, 1] - 1e-3)
        mp.planning_world.set_use_point_cloud(use_point_cloud)
        mp.planning_world.set_use_attach(False)
        mp.robot.set_qpos(qpos, True)  # the fingers stay where they are
        goals, closest = self.ik(mp.transform_goal_to_wrt_base(goal_world), qpos, rng)
        if not goals:
            return {"status": f"IK failed (closest {closest:.4f})"}
        start = qpos[self.idx]
        if within is not None and self.min_steps(start, goals, time_step) >= within:
            return {"status": f"no path shorter than {within} steps"}
        limits = mp.joint_vel_limits, mp.joint_acc_limits
        lines = [straight_line_trajectory(start, g, *limits, time_step) for g in goals]
        # a line that cannot beat `within` is not checked: it would be refused anyway
        wanted = [k for k, line in enumerate(lines) if within is None or len(line) < within]
        free = next((k for k in wanted if self.edge_free(start, goals[k])), None)
        if free is not None:
            return {"status": "Success", "position": lines[free]}
        if len(wanted) < len(goals):  # a detour is longer than the line it goes around
            return {"status": f"no straight line shorter than {within} steps"}
        if not detour:
            return {"status": STRAIGHT_BLOCKED}
        if not self.free(start):
            # no detour leaves a start that collides (round_table: 8 of 8 such searches
            # failed, each after all its samples, about 0.7 s; 24 of 24 from free starts
            # found a path)
            return {"status": START_COLLIDES}
        path = self.rrt_connect(start, goals, rng)
        if path is None:
            return {"status": "RRT-Connect failed"}
        path = self.shortcut(path, rng)
        if len(path) == 2:  # a free segment RRT-Connect found
            position = straight_line_trajectory(start, path[1], *limits, time_step)
            return {"status": "Success", "position": position}
        _, position, *_ = mp.TOPP(self.densify(path), time_step)
        # the spline TOPP-RA fits rounds the corners between segments: when that grazes an
        # obstacle, each straight segment runs alone (stopping at the corners)
        if not self.all_free(position):
            pieces = [
                straight_line_trajectory(a, b, *limits, time_step)
                for a, b in zip(path[:-1], path[1:], strict=True)
                if not np.array_equal(a, b)
            ]
            position = np.concatenate([pieces[0]] + [p[1:] for p in pieces[1:]])
            if not self.all_free(position):
                return {"status": "the time-parameterised path grazes an obstacle"}
        return {"status": "Success", "position": position}

    def all_free(self, position: np.ndarray) -> bool:
        """Every segment between the waypoints that will run is free (the first is the start)."""
        return all(self.edge_free(a, b) for a, b in zip(position[:-1], position[1:], strict=True))
