"""Each env's task in the scene: its movers and receptacle as actors merged over envs, their
geometry, destinations, the :class:`TaskState` read from the simulation every step, and each
env's own kind's rule results (:meth:`TaskReader.rules`, :meth:`TaskReader.by_kind`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from mani_skill.utils.structs import Actor
from scipy.spatial import ConvexHull

from embodied_envs.envs import fast_reads
from embodied_envs.envs.agents import is_grasping, tcp_pose, tcp_position_cpu
from embodied_envs.envs.contacts import grasped_cpu
from embodied_envs.envs.contacts import is_grasping as grasped_by
from embodied_envs.envs.fast_reads import raw_poses
from embodied_envs.envs.tasks import KIND_IDS, RULES, place
from embodied_envs.envs.tasks.state import OPEN_FRACTION, TaskState
from embodied_envs.envs.tasks.unmet import unmet_conditions
from embodied_envs.internals import bodies, entities, px_articulations
from embodied_envs.layout.assets import asset_geometry
from embodied_envs.layout.placement.rules import half_planes, pad_polygons
from embodied_envs.layout.task import DIRECTION_XY, MOVE_SHIFT, Task

SPREAD = 0.9  # several movers' destinations spread over this part of the receptacle's length


def quat_matrix(q):
    """Rotation matrices ``(..., 3, 3)`` of scalar-first quaternions ``q (..., 4)`` (numpy or
    torch, as ManiSkill's raw poses hold them)."""
    if isinstance(q, np.ndarray):
        return _quat_matrix_np(q)
    w, x, y, z = (q[..., i] for i in range(4))
    entries = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(entries, -1).reshape(*q.shape[:-1], 3, 3)


# quat_matrix's nine entries as ``diagonal + 2 * sign * (a + b)`` of products of two of the
# quaternion's components (w, x, y, z = 0..3): one numpy operation each for all entries, with
# the same float operations as the torch form, so the same values to the bit
_FIRST = [(2, 2), (1, 2), (1, 3), (1, 2), (1, 1), (2, 3), (1, 3), (2, 3), (1, 1)]  # fmt: skip
_SECOND = [(3, 3), (0, 3), (0, 2), (0, 3), (3, 3), (0, 1), (0, 2), (0, 1), (2, 2)]  # fmt: skip
_LEFT, _RIGHT = np.array(_FIRST + _SECOND).T
_SIGN = np.array([1, -1, 1, 1, 1, -1, -1, 1, 1], np.float32)  # of the second product
_TWICE = np.array([-2, 2, 2, 2, -2, 2, 2, 2, -2], np.float32)  # the diagonal: 1 - 2 (a + b)


def _quat_matrix_np(q: np.ndarray) -> np.ndarray:
    products = q[..., _LEFT] * q[..., _RIGHT]
    out = _TWICE * (products[..., :9] + _SIGN * products[..., 9:])
    out[..., ::4] += 1
    return out.reshape(*q.shape[:-1], 3, 3)


def as_tensor(value, device: torch.device) -> torch.Tensor:
    """``torch.as_tensor(value, device=device)``; a numpy array for the CPU shared as
    ``torch.from_numpy`` shares it (the same tensor, a third of the cost: the rules' results
    become the info's tensors at every step)."""
    if type(value) is np.ndarray and device.type == "cpu":
        try:
            return torch.from_numpy(value)
        except (TypeError, ValueError):  # a dtype or strides torch cannot share
            pass
    return torch.as_tensor(value, device=device)


def support_height(parts: tuple[np.ndarray, ...], xy: np.ndarray, default: float) -> float:
    """The highest point of any convex part straight above or below ``xy`` (its top surface
    there: a bowl's floor, a box's lid), in the actor's frame; ``default`` where none is."""
    height = support_heights(parts, np.asarray(xy, float)[None], np.nan)[0]
    return default if np.isnan(height) else float(height)


def support_heights(parts: tuple[np.ndarray, ...], xy: np.ndarray, default: float) -> np.ndarray:
    """:func:`support_height` at each of the points ``xy (P, 2)``, ``(P,)``."""
    best = np.full(len(xy), -np.inf)
    for verts in parts:
        try:
            eq = ConvexHull(verts).equations  # n . p + d <= 0 inside
        except Exception:  # a flat part: no volume, nothing to stand on
            continue
        n, d = eq[:, :3], eq[:, 3] + xy @ eq[:, :2].T  # d: (P, F)
        up, down, side = n[:, 2] > 1e-9, n[:, 2] < -1e-9, np.abs(n[:, 2]) <= 1e-9
        within = ~(d[:, side] > 1e-9).any(1)  # the vertical line through xy meets the part
        top = (-d[:, up] / n[up, 2]).min(1) if up.any() else np.full(len(xy), np.nan)
        low = (-d[:, down] / n[down, 2]).max(1) if down.any() else np.full(len(xy), -np.inf)
        ok = within & (top >= low)  # nan (no top face) compares false
        best = np.where(ok & (top > best), top, best)
    return np.where(np.isfinite(best), best, default)


FLOOR_GRID = 15  # points a side of the grid where a receptacle's floor is sought
FLOOR_SPAN = 0.5  # over its footprint shrunk to this part about its centre: under the opening
# (a mug's handle, lower than its rim, is not its floor)


def cavity_floor(rec, poly: np.ndarray) -> float:
    """The receptacle's floor in its frame: the lowest support height (:func:`support_heights`)
    over a grid of points inside its footprint ``poly (K, 2)`` shrunk to ``FLOOR_SPAN`` about
    its centre, where any part is; its top (``rec.max_z``: no inside) where none is lower. A
    bowl's or a tray's floor; a box's lid."""
    centre = poly.mean(0)
    poly = centre + FLOOR_SPAN * (poly - centre)
    lo, hi = poly.min(0), poly.max(0)
    ticks = [np.linspace(a, b, FLOOR_GRID + 2)[1:-1] for a, b in zip(lo, hi, strict=True)]
    xy = np.stack(np.meshgrid(*ticks), -1).reshape(-1, 2)
    normals, offsets = half_planes(poly)
    xy = xy[(xy @ normals.T >= offsets).all(1)]
    heights = support_heights(rec.parts, xy, np.inf)
    return float(min(heights.min(initial=np.inf), rec.max_z))


@dataclass
class TaskScene:
    """The tasks of all envs of one configuration.

    Attributes:
        tasks: per env, its :class:`Task`.
        kinds: ``(n,)`` each env's kind index (``tasks.KIND_IDS``).
        movers: per mover slot, the movers merged over envs (an env with fewer movers repeats
            its last one); ``mover_nodes[i][k]`` names env i's mover in slot k.
        receptacle: the receptacle merged over envs (the context where an env has none).
    """

    tasks: list[Task]
    kinds: torch.Tensor
    movers: list[Actor]
    mover_nodes: list[list[str]]
    receptacle: Actor
    hulls: np.ndarray  # (n, m, V, 3) each mover's collision points in its frame
    centres: np.ndarray  # (n, m, 3) each mover's centre (its collision box's) in its frame
    reach: np.ndarray  # (n, m) the farthest of each mover's collision points from its centre
    footprint: tuple  # (normals (n, E, 2), offsets (n, E)) receptacle footprint, its frame
    rim: np.ndarray  # (n,) receptacle top in its frame
    floor: np.ndarray  # (n,) its floor in its frame (``cavity_floor``; the top: no inside)
    dest_local: np.ndarray  # (n, m, 3) each mover's destination in the receptacle's frame
    # (n, 6) in the receptacle's frame: its footprint's box centre (x, y) and size (x, y), its
    # rim (``rim``) and floor (``floor``) heights (the state observation's ``receptacle_geometry``)
    rec_geometry: np.ndarray
    is_in: np.ndarray  # (n,) bool
    rec_is_table: np.ndarray  # (n,) bool
    direction: np.ndarray  # (n, 2) world XY unit vector of a move
    finger_span: tuple[float, float]  # the fingers' summed joint positions closed and open
    open_fraction: float = OPEN_FRACTION  # fingers opened this part of the span are open

    @classmethod
    def build(cls, layouts, env_actors, robot_poses: np.ndarray, finger_span) -> TaskScene:
        n = len(layouts)
        tasks = [x.task for x in layouts]
        m = max(len(t.objects) for t in tasks)
        nodes = [list(t.objects) + [t.objects[-1]] * (m - len(t.objects)) for t in tasks]
        movers = [
            Actor.merge([env_actors[f"env{i}"][nodes[i][k]] for i in range(n)], name=f"mover{k}")
            for k in range(m)
        ]
        rec_nodes = [t.receptacle or x.context for t, x in zip(tasks, layouts, strict=True)]
        receptacle = Actor.merge(
            [env_actors[f"env{i}"][rec_nodes[i]] for i in range(n)], name="receptacle"
        )
        hulls, centres, polys, rims, floors, dests, geometry = [], [], [], [], [], [], []
        for i, layout in enumerate(layouts):
            geoms = [asset_geometry(layout.asset_spec(node)) for node in nodes[i]]
            hulls.append([_hull_points(g.vertices) for g in geoms])
            centres.append([(g.vertices.min(0) + g.vertices.max(0)) / 2 for g in geoms])
            rec = asset_geometry(layout.asset_spec(rec_nodes[i]))
            poly = rec.top_hull(0.02) if rec_nodes[i] == layout.context else rec.footprint()
            polys.append(poly)
            rims.append(rec.max_z)
            floors.append(rec.max_z if rec_nodes[i] == layout.context else cavity_floor(rec, poly))
            low, high = poly.min(0), poly.max(0)
            geometry.append([*(low + high) / 2, *(high - low), rims[-1], floors[-1]])
            widths = [2 * np.linalg.norm(h[:, :2] - c[:2], axis=1).max()
                      for h, c in zip(hulls[-1], centres[-1], strict=True)]  # fmt: skip
            dests.append(_destinations(rec, poly, [g.min_z for g in geoms], centres[-1], widths))
        size = max(len(h) for hs in hulls for h in hs)
        hulls = np.array([[np.concatenate([h, np.repeat(h[:1], size - len(h), 0)]) for h in hs]
                          for hs in hulls], np.float32)  # fmt: skip
        centres = np.array(centres, np.float32)
        normals, offsets = half_planes(pad_polygons(polys))
        yaw = _yaws(robot_poses)
        way = np.array([DIRECTION_XY.get(t.direction, (1.0, 0.0)) for t in tasks])
        c, s = np.cos(yaw), np.sin(yaw)
        direction = np.stack([c * way[:, 0] - s * way[:, 1], s * way[:, 0] + c * way[:, 1]], -1)
        return cls(
            tasks=tasks,
            kinds=torch.tensor([KIND_IDS[t.kind] for t in tasks]),
            movers=movers,
            mover_nodes=nodes,
            receptacle=receptacle,
            hulls=hulls,
            centres=centres,
            reach=np.linalg.norm(hulls - centres[:, :, None], axis=-1).max(-1),
            footprint=(normals.astype(np.float32), offsets.astype(np.float32)),
            rim=np.array(rims, np.float32),
            floor=np.array(floors, np.float32),
            dest_local=np.array(dests, np.float32),
            rec_geometry=np.array(geometry, np.float32),
            is_in=np.array([t.relation == "in" for t in tasks]),
            rec_is_table=np.array([r == x.context for r, x in zip(rec_nodes, layouts, strict=1)]),
            direction=direction.astype(np.float32),
            finger_span=finger_span,
        )

    def destinations(self, rows, rec_pose, start, goal):
        """``(b, m, 3)`` each mover's destination for an episode of the envs ``rows (b,)``: on
        the receptacle (its raw pose ``rec_pose (b, 7)`` now), ``MOVE_SHIFT`` along the
        direction from ``start (b, m, 3)`` (``move``), or over the ``goal (b, 3)`` on the
        table (a place on the table). Torch tensors, or numpy arrays (the CPU simulation's
        one env: a tenth of torch's cost per call)."""
        if isinstance(start, np.ndarray):
            xp, cat = np, np.concatenate

            def t(x):
                return np.asarray(x)[rows]

            def like(x, shape):
                return np.broadcast_to(x, shape)
        else:
            xp, cat = torch, torch.cat

            def t(x):
                return torch.as_tensor(x, device=start.device)[rows.cpu()].to(start.device)

            def like(x, shape):
                return x.expand(shape)

        rot = quat_matrix(rec_pose[:, 3:])
        on_rec = rec_pose[:, None, :3] + (rot[:, None] @ t(self.dest_local)[..., None])[..., 0]
        on_table = cat([like(goal[:, None, :2], start[..., :2].shape), on_rec[..., 2:]], -1)
        place = xp.where(t(self.rec_is_table)[:, None, None], on_table, on_rec)
        shifted = start.copy() if xp is np else start.clone()
        shifted[..., :2] += t(self.direction)[:, None] * MOVE_SHIFT
        is_move = (t(self.kinds) == KIND_IDS["move"])[:, None, None]
        return xp.where(is_move, shifted, place)


def _hull_points(vertices: np.ndarray) -> np.ndarray:
    """The collision points that can be lowest: the hull's vertices."""
    try:
        return vertices[ConvexHull(vertices).vertices]
    except Exception:  # flat: every vertex
        return vertices


def _yaws(robot_poses: np.ndarray) -> np.ndarray:
    q = np.asarray(robot_poses)[:, 3:]
    w, x, y, z = q.T
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def _destinations(
    rec, poly: np.ndarray, mover_min_z: list[float], centres, widths: list[float]
) -> np.ndarray:
    """``(m, 3)`` in the receptacle's frame: each mover's centre resting upright on the
    receptacle's top surface, spread along its footprint's longer side. Along ``SPREAD`` of
    that side, the movers (``widths``: each one's largest width, whatever its turn) leave equal
    gaps between each other and the ends: room for the fingers around the mover put down next
    to one placed before (two cans on a tray: 3.4 cm gaps instead of 1.2 at equal spacing of
    their centres); where they do not fit, their centres are spaced equally."""
    centre = poly.mean(0)
    extent = poly.max(0) - poly.min(0)
    axis = np.eye(2)[int(np.argmax(extent))]
    m, length = len(mover_min_z), SPREAD * extent.max()
    gap = (length - sum(widths)) / (m + 1)
    out = []
    for k, min_z in enumerate(mover_min_z):
        if gap > 0:
            at = -length / 2 + (k + 1) * gap + sum(widths[:k]) + widths[k] / 2
        else:
            at = ((k + 1) / (m + 1) - 0.5) * length
        xy = centre + at * axis
        out.append([*xy, support_height(rec.parts, xy, rec.max_z) - min_z + centres[k][2]])
    return np.array(out)


class TaskReader:
    """Reads :class:`TaskState` from the simulation: from ManiSkill's structs as tensors on
    the GPU simulation, and on the CPU simulation's one env as numpy arrays straight from the
    SAPIEN objects, as ManiSkill's ``Actor.pose``, ``Link.pose`` and ``Articulation.qpos``
    read them (each torch operation's fixed cost would make up most of a step's rules). Applies
    the rules of the kinds present (:attr:`kinds`) and picks each env's own kind's results."""

    def __init__(self, env, scene: TaskScene, table_z: torch.Tensor, tensors: bool | None = None):
        self.env, self.ts = env, scene
        self.gpu = env.gpu_sim_enabled if tensors is None else tensors  # read as on the GPU
        arr = (lambda x: torch.as_tensor(x, device=env.device)) if self.gpu else np.asarray
        self.arr = arr
        self.hulls, self.centres = arr(scene.hulls), arr(scene.centres)
        self.hulls_t = self.hulls.swapaxes(-1, -2)  # (n, m, 3, V)
        self.footprint = tuple(arr(x) for x in scene.footprint)
        self.rim, self.floor, self.is_in = arr(scene.rim), arr(scene.floor), arr(scene.is_in)
        self.reach = arr(scene.reach) if scene.hulls.shape[1] > 1 else None  # place.stacked
        self.rec_is_table, self.direction = arr(scene.rec_is_table), arr(scene.direction)
        self.table_z = arr(table_z.cpu().numpy()) if not self.gpu else table_z
        n, m = scene.hulls.shape[:2]
        self.start = arr(np.zeros((n, m, 3), np.float32))
        self.dest = arr(np.zeros((n, m, 3), np.float32))
        self.kinds = sorted({t.kind for t in scene.tasks}, key=KIND_IDS.get)  # those present
        kinds = scene.kinds.to(env.device)
        self.masks = {k: kinds == KIND_IDS[k] for k in self.kinds}  # (n,) per kind
        maxima = torch.tensor([RULES[k].MAX_REWARD for k in RULES], dtype=torch.float32)
        self.max_reward = maxima.to(env.device)[kinds]  # (n,) each env's kind's MAX_REWARD
        # (n, m + 1): what can fall off the table, each mover and the receptacle not the table
        can_fall = np.concatenate([np.ones((n, m), bool), ~scene.rec_is_table[:, None]], 1)
        self.can_fall = arr(can_fall)
        # place's bounds, once: the receptacle fields they come from stay the same
        self.bounds = place.Bounds.of(
            self.footprint, self.rim, self.floor, self.is_in, self.rec_is_table, self.table_z
        )
        # the arm's joint positions when the control step began (``before_step``), and the envs
        # reset since (their arm counts as still: nothing has moved it yet)
        self.step_start = None
        self.fresh = arr(np.ones(n, bool))

    def before_step(self) -> None:
        """At the start of a control step (the env's ``_before_control_step``): keep the arm's
        joint positions, from which :meth:`state` measures its speeds."""
        robot = self.env.main_agent.robot
        if self.gpu:
            self.step_start = robot.get_qpos().clone()
        else:
            self.step_start = px_articulations(robot)[0].qpos[None]
        self.fresh[:] = False

    def state_set(self, env_idx, goal: torch.Tensor) -> None:
        """A state was set from outside (``set_state_dict``; ``env_idx`` None: every env): nothing
        moved it yet; in the envs not stepped since their reset it is where the episode starts,
        and the movers' starts and destinations are read from it (``goal (n, 3)``: the goal
        markers now, which the state set)."""
        self.step_start = None
        device = self.env.device
        rows = torch.as_tensor(self.fresh).nonzero()[:, 0].to(device)
        if env_idx is not None:
            rows = rows[torch.isin(rows, torch.as_tensor(env_idx, device=device))]
        if len(rows):
            self.begin_episode(rows, goal[rows])

    def begin_episode(self, env_idx: torch.Tensor, goal) -> torch.Tensor:
        """Record the envs' mover starts and destinations after their poses were set
        (``goal (b, 3)``: those envs' pick goals); returns the destinations ``(b, m, 3)``."""
        if self.gpu:
            goal = torch.as_tensor(goal, device=self.env.device)
            poses = torch.stack([a.pose.raw_pose[env_idx] for a in self.ts.movers], 1)
            centres = torch.as_tensor(self.ts.centres, device=poses.device)
            centres = centres[env_idx.to(poses.device)]
            start = poses[..., :3] + (quat_matrix(poses[..., 3:]) @ centres[..., None])[..., 0]
            rec = self.ts.receptacle.pose.raw_pose[env_idx]
            dest = self.ts.destinations(env_idx, rec, start, goal)
            self.start[env_idx], self.dest[env_idx] = start, dest
            self.fresh[env_idx] = True
            return dest
        # the one env's, in numpy: read from SAPIEN at once (ManiSkill's reads and torch's
        # per-call cost: 0.8 ms of a reset)
        idx = env_idx.cpu().numpy()
        raw = raw_poses([*self.ts.movers, self.ts.receptacle])
        poses, rec = raw[:, :-1], raw[:, -1]
        centres = self.ts.centres[idx]
        start = poses[..., :3] + (quat_matrix(poses[..., 3:]) @ centres[..., None])[..., 0]
        goal = goal.cpu().numpy() if isinstance(goal, torch.Tensor) else np.asarray(goal)
        dest = self.ts.destinations(idx, rec, start, goal.astype(np.float32))
        self.start[idx], self.dest[idx] = start, dest
        self.fresh[idx] = True
        return torch.from_numpy(dest)

    def _read(self):
        """The TCP, the robot's joint positions, the raw poses ``(n, m + 1, 7)`` of the movers
        and then the receptacle, the movers' velocities and grasp flags."""
        agent, movers, rec = self.env.main_agent, self.ts.movers, self.ts.receptacle
        entry = self.env.robot_entry
        if self.gpu:
            poses = torch.stack([a.pose.raw_pose for a in movers] + [rec.pose.raw_pose], 1)
            return (
                tcp_pose(agent, entry).p, agent.robot.get_qpos(), poses,
                torch.stack([a.linear_velocity for a in movers], 1),
                torch.stack([a.angular_velocity for a in movers], 1),
                torch.stack([is_grasping(agent, a, entry) for a in movers], 1),
            )  # fmt: skip
        robot = px_articulations(agent.robot)[0]
        if entry.grasp_check is not None:  # one walk over the contacts for every mover
            grasped = grasped_cpu(agent, movers, entry.grasp_check)[None]
        else:
            grasped = np.array([[bool(is_grasping(agent, a, entry)[0]) for a in movers]])
        # every pose and velocity in one array: numpy's cost is per call, not per value
        parts = []
        for actor in (*movers, rec):
            pose = entities(actor)[0].pose
            parts += (pose.p, pose.q)
        for actor in movers:
            body = bodies(actor)[0]
            parts += (body.linear_velocity, body.angular_velocity)
        flat, k = np.concatenate(parts), 7 * (len(movers) + 1)
        vel = flat[k:].reshape(1, len(movers), 2, 3)
        return (
            tcp_position_cpu(agent, entry), robot.qpos[None], flat[:k].reshape(1, -1, 7),
            vel[:, :, 0], vel[:, :, 1], grasped,
        )  # fmt: skip

    def _arm_speed(self, arm_qpos):
        """``(n, J)`` each arm joint's speed over the last control step: its displacement since
        the step began over the step's duration (0 in an env reset since). Not the simulator's
        joint velocities: an arm whose jaws squeeze an object can report 0.2-0.6 rad/s with its
        joints still to 1e-4 rad (ManiSkill's SO-100; docs/robots.md)."""
        if self.step_start is None:
            return abs(arm_qpos) * 0
        moved = abs(arm_qpos - self.step_start[:, : arm_qpos.shape[1]])
        speed = moved / self.env.control_timestep
        return speed * ~self.fresh[:, None]

    def state(self, goal, full: bool = True) -> TaskState:
        """The state now; ``goal (n, 3)`` the pick goal (same array type as the reads).
        ``full=False``: what ``pick``'s rules and the env's ``fail`` read, ``bottom``,
        ``in_receptacle``, ``rec_top`` and ``opening`` None (:meth:`rules` of pick alone)."""
        tcp, qpos, poses, lin, ang, grasped = self._read()
        m = poses.shape[1] - 1
        origin, rec = poses[:, :m, :3], poses[:, m]
        rots = quat_matrix(poses[..., 3:])  # the movers' and the receptacle's, in one call
        rot, rec_rot = rots[:, :m], rots[:, m]
        p = origin + (rot @ self.centres[..., None])[..., 0]  # the movers' centres
        j = self.env.robot_entry.gripper.joints  # the trailing gripper joints
        bottom = local = rec_top = opening = top = None
        if full:
            low = (rot[..., 2:3, :] @ self.hulls_t)[..., 0, :]  # (n, m, V)
            bottom = origin[..., 2] + (low.min(-1) if not self.gpu else low.amin(-1))
            if self.reach is not None:  # several movers: one may rest on another
                top = origin[..., 2] + (low.max(-1) if not self.gpu else low.amax(-1))
            local = ((p - rec[:, None, :3])[..., None, :] @ rec_rot[:, None])[..., 0, :]
            rec_top = rec[:, 2] + self.rim
            lo, hi = self.ts.finger_span
            opening = (qpos[:, -j:].sum(-1) - lo) / (hi - lo)
        return TaskState(
            tcp=tcp, goal=goal, arm_speed=self._arm_speed(qpos[:, :-j]), opening=opening,
            movers=p, origins=origin, lin_vel=lin, ang_vel=ang, bottom=bottom, grasped=grasped,
            start=self.start, dest=self.dest, in_receptacle=local, footprint=self.footprint,
            rim=self.rim, floor=self.floor, rec_top=rec_top, rec_pos=rec[:, :3], is_in=self.is_in,
            rec_is_table=self.rec_is_table, table_z=self.table_z, direction=self.direction,
            bounds=self.bounds, top=top, reach=self.reach,
        )  # fmt: skip

    def rules(self, goal) -> tuple[TaskState, dict]:
        """The state now (:meth:`state`; without the fields only ``place`` and ``move`` read
        where ``pick`` is the one kind present: 11 array operations less every step) and each
        present kind's rule results (``RULES[kind].evaluate``), kind -> dict."""
        state = self.state(goal, full=self.kinds != ["pick"])
        return state, {k: RULES[k].evaluate(state) for k in self.kinds}

    def presses(self, obj, rule) -> np.ndarray:
        """Per env (bool): the robot's fingers hold ``obj`` by ``rule`` (a ``robots.FingerGrasp``,
        not the robot's own: the expert's close checks the press at any angle) now."""
        return np.asarray(grasped_by(self.env.agent, obj, rule).cpu()).reshape(-1)

    def goal(self):
        """The goal marker's position now, as this reader's arrays hold it."""
        site = self.env.goal_site
        return site.pose.p if self.gpu else fast_reads.positions(site)

    def unmet(self) -> list[list[str]]:
        """Per env, the conditions of success its movers miss now, in words: ``"can: not at
        rest"`` per mover that misses any; ``[]`` where it succeeds
        (:func:`~embodied_envs.envs.tasks.unmet.unmet_conditions`)."""
        state, results = self.rules(self.goal())
        return unmet_conditions(state, results, self.ts.tasks)

    def by_kind(self, results: dict, key: str) -> torch.Tensor:
        """``key`` of each env's own kind (``results``: kind -> dict of per-env values), as a
        tensor on the env's device."""
        if len(results) == 1:  # one kind present (every shipped layout): its values
            return as_tensor(next(iter(results.values()))[key], self.env.device)
        out = None
        for kind, res in results.items():
            value = as_tensor(res[key], self.env.device)
            if out is None:
                out = value
            else:
                mask = self.masks[kind]
                out = torch.where(mask.reshape(-1, *[1] * (value.ndim - 1)), value, out)
        return out
