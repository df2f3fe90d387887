"""The expert's place and move flows: carry each mover to its destination, lower it to a
release height computed from both meshes, let go and back off (``envs/tasks/``' task kinds).

``PlaceFlow`` is a mixin of :class:`~embodied_envs.solvers.pick_place.PickPlaceSolver`.
"""

from __future__ import annotations

import numpy as np
import sapien
import torch


class PlaceFlow:
    """Carry, lower and release for place and move tasks (a mixin of the solver)."""

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
        tcp = self._hand_pose()

        def shifted(dz):
            return [sapien.Pose(tcp[i, :3] + [0, 0, dz[i]], tcp[i, 3:]) if envs[i] else None
                    for i in range(self.num_envs)]  # fmt: skip

        self._per_env("lower", shifted(-np.maximum(drop, 0.0)), obstacles=False,
                      settle=self.cfg.settle_steps, open_before=self.cfg.open_before)  # fmt: skip
        self._set_gripper(envs, self.robot_hand.action_open, release=True)
        tcp = self._hand_pose()
        self._per_env("withdraw", shifted(np.full(self.num_envs, self.cfg.approach_offset)),
                      obstacles=False)  # fmt: skip

    def _carry(self, envs: np.ndarray) -> None:
        """Carry the held target of ``envs`` to the goal (keeping its offset from the TCP as
        it is in the hand now), then correct the last millimetres. The goal is a position, so
        the hand may arrive turned about the vertical (``carry_yaws``, tried in order): a wrist
        near its joint limit would otherwise flip over on the way. A path that takes the
        object out over the table's edge is refused (the episode would end in ``fail``);
        where no carry plans, a planar hand's is tried pitched in its arm's plane about the
        object (``planar_lift_turns``), then the hand rises ``rise_clearance`` above the
        highest obstacle point and carries from there. A hand that drifts settles at the goal
        in short moves, again while the object is off it (``settle_rounds``)."""
        goal = self._carry_goal()
        hand = self._in_planned_hand()
        # the held object kept off the obstacles where it is to be put down (a pick goal may
        # lie next to an obstacle: the object is held there, and the check would refuse it)
        held = [h if r else None for h, r in zip(self._held_points(), self.releases, strict=True)]
        over = lambda i, path: self._over_table(i, path, hand[i], held[i])  # noqa: E731

        base = self._pan_axis()  # the base joint turns the hand about it

        def targets(yaws, todo, pitches=(), turn=False):
            tcp = self._hand_pose()
            st = self._task_state()  # the point the goal is for: centre, or origin (pick)
            obj = np.where(self.releases[:, None], st["movers"], st["origins"])[:, self.slot]
            out = []
            for i in range(self.num_envs):
                turns = list(yaws)
                # first the turn of the base joint (a planar hand's only way to another side)
                if (self.releases[i] or self.robot_hand.planar) and (len(yaws) > 1 or turn):
                    a, b = goal[i, :2] - base[i], obj[i, :2] - base[i]
                    turns.insert(0, np.arctan2(a[1], a[0]) - np.arctan2(b[1], b[0]))
                poses = [self._turned(goal[i], tcp[i], obj[i], yaw) for yaw in turns]
                out_ = np.append(goal[i, :2] - base[i], 0.0)
                across = np.cross([0.0, 0.0, 1.0], out_) / max(np.linalg.norm(out_), 1e-9)
                poses = [_pitched(p, goal[i], across, a) for a in pitches for p in poses] or poses
                out.append(poses if todo[i] else None)
            return out

        how = {}
        if self.releases.any():
            how = dict(methods=self.cfg.release_carry_methods,
                       option_steps=self.cfg.release_carry_option_steps)  # fmt: skip
        chosen = self._per_env("carry", targets(self.cfg.carry_yaws, envs), path_ok=over, **how)
        high = envs & np.array([c is None for c in chosen])
        if high.any() and self.robot_hand.planar:  # a five-joint arm: the hand pitched in its
            # plane at the goal, about the object (straight down it reaches a goal's height
            # only at some distances: Koch seeds 11, 20)
            for i in np.flatnonzero(high):
                self.reports[i].plan_failures.clear()
            pitches = np.deg2rad(self.cfg.planar_lift_turns)
            chosen = self._per_env("carry", targets(self.cfg.carry_yaws, high, pitches),
                                   path_ok=over, **how)  # fmt: skip
            high &= np.array([c is None for c in chosen])
        if high.any():  # over the obstacles: straight up, then the carry from there
            for i in np.flatnonzero(high):  # the carry from above may still plan
                self.reports[i].plan_failures.clear()
            tcp = self._hand_pose()
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
        if not self.plans_from_targets:
            self._per_env("settle", targets((0.0,), envs), obstacles=False)
            return
        # planned from targets (a hand that drifts; a hand that cannot turn, held off where the
        # plans put it): the settle repeated while the object is off the goal (the jaw's
        # push on the arm changes as it moves), each a short move (the hand turned with the
        # base first), or none: the object then stays where it is
        def short(i, path) -> str:
            return "" if len(path) <= self.cfg.settle_max_steps else f"{len(path)} steps, too long"

        off = envs.copy()
        for _ in range(1 + self.cfg.settle_rounds):
            off &= np.array([not r.plan_failures for r in self.reports])
            if not off.any() or self.ended:
                break
            self._per_env("settle", targets((0.0,), off, turn=True), obstacles=False,
                          path_ok=short)  # fmt: skip
            for i in np.flatnonzero(off):  # unplanned: it holds still, the episode goes on
                failures = self.reports[i].plan_failures
                if failures and failures[-1].startswith("settle:"):
                    failures.pop()
                    off[i] = False
            st = self._task_state()
            obj = np.where(self.releases[:, None], st["movers"], st["origins"])[:, self.slot]
            off &= np.linalg.norm(obj - goal, axis=1) > self.cfg.goal_tolerance

    def _in_planned_hand(self) -> np.ndarray:
        """Per env, the target's position in the grasp frame where moves are planned from
        (``_hand_pose``: the measured frame, ``_in_hand``, but where moves are planned from
        targets)."""
        if not self.plans_from_targets:
            return self._in_hand()
        tcp = _matrices(self._hand_pose())
        obj = self.target.pose.p.cpu().numpy()
        return np.einsum("nij,ni->nj", tcp[:, :3, :3], obj - tcp[:, :3, 3])

    def _held_points(self) -> np.ndarray:
        """Per env, the current mover's collision points ``(V, 3)`` in the TCP's frame now."""
        tcp = self._tcp().to_transformation_matrix().cpu().numpy()
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
        fingers = self._fingers()[i]
        base = self.base.agent.robot.pose.raw_pose[i].cpu().numpy().astype(np.float64)
        links = np.empty((len(path), 7))
        for k, q in enumerate(path):  # the planned link's pose (base frame) at each waypoint
            model.compute_forward_kinematics(np.concatenate([q[: self.arm_dof], fingers]))
            links[k] = model.get_link_pose(self.motion[i].link)
        grasp = self.grasp_in_link.to_transformation_matrix()
        tcp = _matrices(base[None]) @ _matrices(links) @ grasp  # (T, 4, 4) the grasp frame
        points = tcp[:, :3] @ np.append(in_hand, 1.0)  # (T, 3) the held object's centre
        if held is not None and self.clouds:
            at = np.einsum("tij,vj->tvi", tcp[:, :3, :3], held) + tcp[:, None, :3, 3]
            bound = self.cfg.carry_clearance  # nearer points only: the tree prunes the rest
            near, _ = self.cloud_tree(i).query(at.reshape(-1, 3), distance_upper_bound=bound)
            hit = (near.reshape(len(path), -1) < self.cfg.carry_clearance).any(1)
            if hit.any():
                return f"the held object meets an obstacle at waypoint {int(np.argmax(hit))}"
        top = self.base.layout_scene.episodes.top.rows(torch.tensor([i], device=self.base.device))
        xy = torch.as_tensor(points[None, :, :2], dtype=torch.float32)
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


def _pitched(pose: sapien.Pose, centre: np.ndarray, axis: np.ndarray, angle: float):
    """``pose`` turned by ``angle`` about the line through ``centre`` along ``axis`` (unit)."""
    turn = sapien.Pose(q=[np.cos(angle / 2), *(np.sin(angle / 2) * axis)])
    rot = turn.to_transformation_matrix()[:3, :3]
    return sapien.Pose(centre + rot @ (pose.p - centre), (turn * sapien.Pose(q=pose.q)).q)


def _matrices(poses: np.ndarray) -> np.ndarray:
    """``(n, 4, 4)`` transforms of ``poses (n, 7)`` ([x, y, z, qw, qx, qy, qz] each)."""
    w, x, y, z = poses[:, 3:].T
    out = np.zeros((len(poses), 4, 4))
    out[:, 0, :3] = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], 1)
    out[:, 1, :3] = np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], 1)
    out[:, 2, :3] = np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1)
    out[:, :3, 3], out[:, 3, 3] = poses[:, :3], 1.0
    return out
