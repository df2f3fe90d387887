"""The expert's arm driver: plans per env, executed at rates every controller follows.

``ArmDriver`` is the machinery under :class:`~embodied_envs.solvers.pick_place.PickPlaceSolver`:
plan a move for each env that needs one (seeded planners, ``solvers/motion.py``), execute the
joint paths together with the per-step bounds of ``solvers/follow.py``, and choose among options
(grasps, turns) by the steps they cost. The gripper's action values are the robot's hand entry's
(``robots.py``).
"""

from __future__ import annotations

import numpy as np
import sapien
import torch

from embodied_envs.solvers.follow import rate_limited, shortened
from embodied_envs.solvers.modes import CATCH_UP
from embodied_envs.solvers.motion import STRAIGHT_BLOCKED
from embodied_envs.solvers.screw import polyline_trajectory, screw_waypoints

START_REFUSED = " at waypoint 0"  # how a path_ok reason that refuses a path's start ends


class ArmDriver:
    """Planning and execution for every env of the solver (a mixin: the solver holds the env,
    its planners, the config and the per-env reports)."""

    def _plan(
        self, i, pose: sapien.Pose, qpos: np.ndarray, how: str, obstacles: bool,
        key: tuple = (), within: int | None = None, detour: bool = True,
    ):  # fmt: skip
        """A joint path that brings the grasp frame to ``pose`` for env i by ``how``
        ("screw": mplib's straight screw motion; "rrt": the seeded planner), and a status (""
        on success).

        ``obstacles=False`` is for the short straight moves next to the support surface (the
        final descent from the pre-grasp and the lift), which the surface's cloud would block.
        ``key`` names the plan within the episode: its random draws come from the solver's
        seed and this key alone, so skipping one plan changes no other. ``within``: a path of
        this many steps or more is not wanted (a better option is known; "rrt" only).
        ``detour=False`` ("rrt" only): the straight joint line or nothing (status
        ``STRAIGHT_BLOCKED``).
        """
        link = pose * self.link_in_grasp  # the planned link's pose
        target = np.concatenate([link.p, link.q])
        dt = self.base.control_timestep
        if how == "screw":
            res = self._screw(i, target, qpos, obstacles)
        else:
            rng = np.random.default_rng([self.seed, i, *key])
            res = self.motion[i].plan_to_pose(target, qpos, rng, dt, obstacles, within, detour)
        if res["status"] != "Success" or not len(res["position"]):
            return None, res["status"]
        if len(res["position"]) > self.cfg.max_path_steps:
            return None, f"{len(res['position'])} steps, over max_path_steps"
        return res["position"], ""

    @property
    def plans_from_targets(self) -> bool:
        """Whether moves are planned from the arm's last joint targets, not from where it
        stands: for a hand that drifts (``robots.Hand.drifts``), and in a mode that keeps the
        hand's orientation (``pd_ee_delta_pos``: its IK takes the arm to the targets' hand
        position, turned as it is; planned from there, a carry would first turn it back)."""
        return self.robot_hand.drifts or self.mode_actions.keeps_orientation

    def _plan_start(self) -> np.ndarray:
        """Per env, the configuration plans start from: the measured joints; where moves are
        planned from targets (:attr:`plans_from_targets`) the arm's last joint targets, which
        its paths go on from (the Koch's arm stands off them while the jaw squeezes)."""
        qpos = self._qpos()
        if self.plans_from_targets:
            qpos[:, : self.arm_dof] = self.command
        return qpos

    def _pan_axis(self) -> np.ndarray:
        """Per env, ``(n, 2)``: where the arm's first joint (its base turn, a vertical axis)
        stands in the world's xy. A five-joint arm's hand moves in a vertical plane through
        it, and the base turn swings the hand about it: the SO-100's stands 4.5 cm ahead of its
        base link's origin, the Koch's 6.8 cm; a plane through the origin missed a mover 55
        degrees off the heading by 13 degrees (every grasp out of the Koch's reach)."""
        base = self.base.agent.robot.pose.raw_pose.cpu().numpy().astype(np.float64)
        name = self.base.agent.robot.get_active_joints()[0].child_link.name
        w, x, y, z = base[:, 3:].T  # the base stands upright: its yaw turns the offset
        yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        out, qpos = base[:, :2].copy(), self._plan_start()
        for i, planner in enumerate(self.planners):  # the joint's URDF origin, on its axis at
            model = planner.pinocchio_model  # any turn (the Panda's: exactly over its base)
            model.compute_forward_kinematics(qpos[i])
            ox, oy = model.get_link_pose(model.get_link_names().index(name))[:2]
            c, s = np.cos(yaw[i]), np.sin(yaw[i])
            out[i] += [c * ox - s * oy, s * ox + c * oy]
        return out.astype(np.float32)  # as the simulator's poses (the Panda's: its base's)

    def _hand_pose(self) -> np.ndarray:
        """Per env, the grasp frame's pose ``(n, 7)`` moves are planned from: where it is; where
        moves are planned from targets, where the arm's joint targets put it (forward
        kinematics)."""
        if not self.plans_from_targets:
            return self._tcp().raw_pose.cpu().numpy()
        base = self.base.agent.robot.pose.raw_pose.cpu().numpy().astype(np.float64)
        out = np.empty((self.num_envs, 7))
        for i, fingers in enumerate(self._fingers()):
            model = self.planners[i].pinocchio_model
            model.compute_forward_kinematics(np.concatenate([self.command[i], fingers]))
            link = model.get_link_pose(self.motion[i].link)
            pose = sapien.Pose(base[i, :3], base[i, 3:]) * sapien.Pose(link[:3], link[3:])
            pose = pose * self.grasp_in_link
            out[i] = [*pose.p, *pose.q]
        return out

    def _screw(self, i: int, target: np.ndarray, qpos: np.ndarray, obstacles: bool) -> dict:
        """mplib's screw motion of env i's planned link to ``target`` (world), timed in closed
        form at the planner's joint limits (``solvers/screw.py``): {"status", "position"}."""
        planner = self.planners[i]
        planner.planning_world.set_use_point_cloud(obstacles)
        planner.planning_world.set_use_attach(False)
        goal = planner.transform_goal_to_wrt_base(target)
        path, status = screw_waypoints(planner, goal, qpos)
        if path is None:
            return {"status": status}
        limits = planner.joint_vel_limits, planner.joint_acc_limits
        dt = self.base.control_timestep
        return {"status": "Success", "position": polyline_trajectory(path, *limits, dt)}

    def _execute(
        self, paths: list[np.ndarray | None], extra_steps: int = 0, until=None, open_before=0
    ) -> None:
        """Step all envs along their paths in lockstep; envs without a path hold still.
        ``until()``: checked after every step; True ends the steps early. ``open_before``:
        an env's hand is commanded open this many steps before the end of its path (a release
        while the lowering brakes)."""
        paths = [None if p is None or not len(p) else self._commands(p, i)
                 for i, p in enumerate(paths)]  # fmt: skip
        lengths = [len(p) if p is not None else 0 for p in paths]
        n = max(lengths, default=0) + extra_steps
        for t in range(n):
            if self.ended:  # no step past the end of the episode
                return
            n = self.arm_dof
            action = np.zeros((self.num_envs, n + 1), np.float32)
            self._keep_grip()
            for i, path in enumerate(paths):
                if path is not None and open_before and t >= len(path) - open_before:
                    self.gripper[i] = self.robot_hand.action_open
                    self.gripping[i] = False
                if path is not None:
                    action[i, :n] = path[min(t, len(path) - 1)]
                else:  # holds its last targets
                    action[i, :n] = self.command[i]
                action[i, n] = self.gripper[i]
            if self.cfg.convertible:
                action[:, :n] = self._bounded(action[:, :n])
            self.command = action[:, :n].astype(np.float64)
            self._step(action)
            if until is not None and until():
                return

    def _commands(self, path: np.ndarray, i: int) -> np.ndarray:
        """Env i's arm joint targets that follow ``path`` (a waypoint per control step).

        ``pd_joint_pos`` drives each joint with ``stiffness * (target - q) - damping * qvel``,
        so a joint lags a moving target by ``damping / stiffness`` (``follow.lag``: 0.1 s for the
        Panda and the SO-100, 5 control steps) times its velocity: each target leads its
        waypoint by that much of the path's velocity, within the joint limits; the last target
        is the path's end. On a 0.5 rad line at the solver's limits the arm stays within 0.022
        rad of the path at every step instead of 0.16 (``test_joint_targets_lead_the_path...``).
        With ``convertible``, the targets move from the last ones at most ``follow.step`` a
        step (``follow.rate_limited``; the path's speed is within ``follow.speed``).
        """
        n = self.arm_dof
        q = np.asarray(path, dtype=np.float64)[:, :n]
        lead = q.copy()
        if len(q) >= 3:
            dt = self.base.control_timestep
            lead = q + self.follow.lag * np.gradient(q, dt, axis=0)
            lead[-1] = q[-1]  # the path ends at rest there
            lead = np.clip(lead, *self.target_bounds)
        if not self.cfg.convertible:
            return lead
        return rate_limited(lead, self.command[i], self.follow.step)

    def _bounded(self, arm: np.ndarray) -> np.ndarray:
        """The arm targets ``arm`` (per env) moved at most ``follow.step`` from the last ones
        and leading the measured joints by at most ``follow.lead`` (a joint lagging its target
        more than planned, e.g. the lag building up as it starts, slows the targets down). An
        end-effector mode drives the hand to where the targets put it, by joints of its IK's
        choosing (``solvers/modes.py``): the lead is the hand's, not bounded here."""
        arm = self.command + shortened(arm - self.command, self.follow.step)
        if not self.mode_actions.joint_targets:  # the hand's pose follows them, not the joints
            return arm
        q = self._qpos()[:, : self.arm_dof]
        return q + shortened(arm - q, self.follow.lead)

    def _step(self, action: np.ndarray) -> None:
        """One control step of every env: ``action`` holds the arm's joint targets and the
        hand's action (``pd_joint_pos``), given to the env in its control mode
        (``solvers/modes.py``); while that mode's action had to be clipped, up to
        ``modes.CATCH_UP`` steps more toward the same targets, each while a clipped joint
        still gains on its target (``ModeActions.gaining``)."""
        out = self.mode_actions(action)
        for _ in range(1 + CATCH_UP):
            self._step_once(out)
            if self.ended or not self.mode_actions.clipped:
                return
            excess = self.mode_actions.excess
            out = self.mode_actions(action)
            if not self.mode_actions.gaining(excess):
                return

    def _step_once(self, action: np.ndarray) -> None:
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
        open_before: int = 0,
        rank_first: bool = False,
        twins: list | None = None,
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
            path_ok: ``path_ok(i, path)``: why env i's planned path is refused ("" when not);
                a reason ending in ``START_REFUSED`` refuses the start, which every path
                shares: no further option or method is planned.
            on_choice: ``on_choice(i, k)``: env i will run option k (before any env moves).
            planned: ``planned(i)``: env i's path, planned already (from where the last stage
                ended), or None to plan it here.
            open_before: each env's hand is commanded open this many steps before its path
                ends (``_execute``).
            rank_first: with ``option_steps``, the first option in rank order that plans (its
                ``then`` too) wins, a straight joint line to any option before a detour to
                any: a choice that follows the options' order, not the steps they cost
                (``SolverConfig.consistent``).
            twins: with ``rank_first``, per env a label per option (None: none): options of
                one label are one grasp at other wrist turns (a two-jaw grasp turned by pi);
                the first that plans is weighed against the later ones of its label, and the
                one whose path and ``then`` cost the fewest steps wins (the wrist roll the
                short way: so100_block seeds 5 and 7 turned it 4.4 rad, 10 s in
                ``pd_joint_delta_pos``, where the other way was 1.1-1.3 rad).

        Returns:
            Per env the pose that was planned to (None where none could be).
        """
        qpos = self._plan_start()
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
                    i, options, qpos[i], methods, obstacles, option_steps, then, path_ok,
                    rank_first, None if twins is None else twins[i],
                )
                if best is None:
                    self.reports[i].plan_failures.append(f"{stage}: " + "; ".join(failures))
                elif on_choice is not None:
                    on_choice(i, best[3])
            paths.append(None if best is None else best[1])
            chosen.append(None if best is None else best[2])
        # settle: steps holding the last waypoints, until the arms are there
        n = self.arm_dof
        ends = qpos[:, :n].copy()
        for i, path in enumerate(paths):
            if path is not None:
                ends[i] = path[-1][:n]
        start, moving = self.steps, max((len(p) for p in paths if p is not None), default=0)

        def arrived() -> bool:
            if self.steps < start + moving:
                return False
            return self.mode_actions.arrived(self._qpos(), ends, self.cfg.settle_tolerance)

        self._execute(paths, settle, arrived if settle else None, open_before)
        return chosen

    def _choose(
        self, i, options, qpos, methods, obstacles, option_steps, then, path_ok, rank_first=False,
        twins=None,
    ):  # fmt: skip
        """``_per_env``'s choice for env i: ``(cost, path, pose, k)`` of the option that wins
        (None when none plans) and the failures.

        With ``option_steps``, the winner is the least (cost, rank) over every option, found by
        branch and bound: an option whose rank alone, or whose shortest possible path
        (``SeededPlanner.min_steps``), cannot beat the best so far is not planned. The seeded
        planner's straight joint lines come first for every option, then the detours
        (RRT-Connect) where a line is blocked: a direct option found first bounds the detours.
        ``rank_first``: the first option in rank order whose path and ``then`` both plan; where
        no option's ``then`` plans, the first whose path does (as without ``rank_first``, an
        option whose ``then`` fails costs ``max_path_steps`` more: the stage after it plans
        again from where the arm then is; the SO-100's lying marker, held-out seeds 0, 1, 3, 4).
        ``twins`` (with ``rank_first``): a label per option; the first option that plans is
        weighed against the later options of its label, by their steps alone, a twin whose
        straight line is blocked by its detour (so100_block seed 10: the short way's line
        passed the can, its long way turned the wrist 3.1 rad).
        """
        best, failures, unplanned = None, [], None
        per_rank = 0 if rank_first else (option_steps or 0)  # steps a rank lower costs
        for m, how in enumerate(methods):
            passes = (False, True) if how == "rrt" and option_steps is not None else (True,)
            todo = list(range(len(options)))
            for detour in passes:
                blocked = []  # options whose straight line is blocked: for the detour pass
                queue = list(todo)
                while queue:
                    k = queue.pop(0)
                    within = None
                    if best is not None and option_steps is not None:
                        # a path of `within` steps or more cannot beat the best (ties: rank)
                        within = best[0] - per_rank * k + (k < best[3])
                        if within <= 0:
                            break  # later options rank lower still
                    key = (self.stages, m, k)
                    twin = best is not None and rank_first  # its detour weighed at once
                    path, status = self._plan(
                        i, options[k], qpos, how, obstacles, key, within, detour or twin
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
                        if status.endswith(START_REFUSED):  # every path starts there
                            return best, failures
                        continue
                    cost = len(path) + per_rank * k
                    if best is not None and (cost, k) > (best[0], best[3]):
                        continue  # what follows only adds steps
                    if then is not None:
                        end = np.concatenate([path[-1][: self.arm_dof], qpos[self.arm_dof :]])
                        more = then(i, k, end)
                        if more is None and rank_first:
                            failures.append(f"{label}{how}: what follows does not plan")
                            if unplanned is None:  # taken only where no option's does
                                unplanned = (cost + self.cfg.max_path_steps, path, options[k], k)
                            continue
                        cost += self.cfg.max_path_steps if more is None else more
                    first = best is None
                    if best is None or (cost, k) < (best[0], best[3]):
                        best = (cost, path, options[k], k)
                    if option_steps is None or (rank_first and twins is None):
                        return best, failures
                    if first and rank_first:  # then its twins: blocked before it, and after
                        queue = [j for j in blocked + queue if twins[j] == twins[k]]
                        blocked = []
                if best is not None and rank_first:  # its twins weighed: no detour to any
                    return best, failures
                todo = blocked
            if best is not None:
                break
        return (unplanned if best is None else best), failures
