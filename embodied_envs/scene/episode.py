"""Per-episode randomisation on each env's fixed table: object starts, goals, joint noise.

A configuration (construction or ``reconfigure``) fixes each env's table, robot spot and
background (``layout.placement.place``). Every episode then re-draws, for the reset envs only:

- the pose of every object standing on the table (or on another object), with the constraints
  of ``place()``: the whole footprint inside its parent's shrunk top, no overlap with placed
  footprints (robot base square included), manipulated objects within reach and heading of the
  robot, lowest point resting on the parent's top;
- the goal, uniformly over the reachable region above the table top (:class:`GoalRegion`).

Everything is a tensor over envs on the env's device, so one code path serves one CPU env and
thousands of GPU envs: each object gets one batch of ``episode_candidates`` candidates per env
and takes the first that meets every constraint (no loop over envs or tries). An env where
some object found no candidate keeps its configuration's arrangement for that episode; this is
counted in ``EpisodeSampler.fallbacks`` and warned about once.

Random numbers are counter-based: each episode of an env has one key, drawn from that env's
ManiSkill episode RNG, and every uniform is a hash of (key, stream, index). The same seed gives
the same start, and a partial reset draws nothing for the other envs. Small batches cost as
much as large ones (per-operation overhead dominates), so with few envs :meth:`EpisodeSampler.
draw` prepares a block of each env's next episode starts at once (keys drawn in blocks from
its RNG); a block is dropped when ManiSkill reseeds that env's RNG (:meth:`invalidate`), and
the draw after a reseed makes only the start the seeded reset uses: seeded resets
(evaluation, ``collect``, replays) pay for one start, not a block.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.limits import GoalRegion, PlacementLimits
from embodied_envs.layout.placement import (
    local_top,
    node_footprint,
    node_geometry,
    square,
    support_order,
)
from embodied_envs.layout.pose import wrap_angle
from embodied_envs.layout.schema import LayoutInfo

# --- counter-based random numbers ----------------------------------------------------------
GOAL_STREAM = 1 << 20  # object j uses stream j; these are far from any object index
NOISE_STREAM = GOAL_STREAM + 1
_GOLDEN = 0x9E3779B97F4A7C15  # splitmix64 constants
_MIX1 = 0xBF58476D1CE4E5B9
_MIX2 = 0x94D049BB133111EB


def _int64(x: int) -> int:
    """A 64-bit constant as the signed value torch's int64 arithmetic wraps around."""
    return x - (1 << 64) if x >= 1 << 63 else x


def _shift_right(z: torch.Tensor, k: int) -> torch.Tensor:
    """Logical right shift of int64 (torch's ``>>`` is arithmetic)."""
    return (z >> k) & ((1 << (64 - k)) - 1)


def uniforms(keys: torch.Tensor, stream: int, n: int) -> torch.Tensor:
    """``(b, n)`` float32 uniforms in [0, 1), a splitmix64 hash of (key, stream, index).

    Args:
        keys: ``(b,)`` integer key per env.
        stream: which sequence of the key (objects, goal, noise use different streams).
        n: numbers per env.
    """
    index = torch.arange(n, device=keys.device, dtype=torch.int64) + (stream << 32)
    z = keys.to(torch.int64)[:, None] * _int64(_GOLDEN) + index
    z = (z ^ _shift_right(z, 30)) * _int64(_MIX1)
    z = (z ^ _shift_right(z, 27)) * _int64(_MIX2)
    z = z ^ _shift_right(z, 31)
    return _shift_right(z, 40).to(torch.float32) * 2.0**-24  # 24 bits: exact in float32


def normals(keys: torch.Tensor, stream: int, n: int) -> torch.Tensor:
    """``(b, n)`` standard normal numbers (Box-Muller over :func:`uniforms`)."""
    u = uniforms(keys, stream, 2 * n).view(-1, 2, n)
    return torch.sqrt(-2.0 * torch.log1p(-u[:, 0])) * torch.cos(2 * math.pi * u[:, 1])


# --- batched 2D geometry ---------------------------------------------------------------------
def rotate(points: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """``points (m, 2)`` rotated by each ``yaw (...)``: ``(..., m, 2)``."""
    c, s = torch.cos(yaw)[..., None], torch.sin(yaw)[..., None]
    x, y = points[:, 0], points[:, 1]
    return torch.stack([c * x - s * y, s * x + c * y], -1)


def inward_normals(poly: torch.Tensor) -> torch.Tensor:
    """Inward unit edge normals of counter-clockwise polygons ``(..., m, 2)``."""
    e = torch.roll(poly, -1, dims=-2) - poly
    n = torch.stack([-e[..., 1], e[..., 0]], -1)
    return n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)


@dataclass(frozen=True)
class Shapes:
    """Convex polygons in their own frames, ready for support queries.

    Padded to a common vertex count ``M`` by repeating the last vertex and angle.

    Attributes:
        vertices: ``(S, M, 2)`` counter-clockwise vertices.
        angles: ``(S, M)`` outward normal angle of edge i (vertex i to i + 1), increasing from
            ``angles[:, 0]`` over one turn.
        count: ``(S,)`` real vertex counts.
    """

    vertices: torch.Tensor
    angles: torch.Tensor
    count: torch.Tensor
    normals: torch.Tensor  # (S, M, 2) inward unit edge normals; 0 on padded (empty) edges

    @classmethod
    def of(cls, polygons: list[np.ndarray], device: torch.device) -> Shapes:
        size = max(len(p) for p in polygons)
        verts, angles = [], []
        for p in polygons:
            e = np.roll(p, -1, axis=0) - p
            raw = np.arctan2(-e[:, 0], e[:, 1])  # outward normal (e_y, -e_x) of a CCW polygon
            turn = np.remainder(np.diff(raw), 2 * np.pi)
            a = raw[0] + np.concatenate([[0.0], np.cumsum(turn)])
            verts.append(np.concatenate([p, np.repeat(p[-1:], size - len(p), 0)]))
            angles.append(np.concatenate([a, np.repeat(a[-1:], size - len(p))]))

        def t(x, dtype=torch.float32):  # copies: cached arrays are read-only
            return torch.tensor(
                np.array(x), dtype=dtype, device=device
            )  # a copy: cached arrays are read-only

        vertices = t(verts)
        return cls(
            vertices, t(angles), t([len(p) for p in polygons], torch.int64),
            inward_normals(vertices),
        )  # fmt: skip

    def support(self, shape: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
        """``max over the polygon of (cos phi, sin phi) . v``, in the polygon's own frame.

        Args:
            shape: ``(S,)`` shape indices.
            phi: ``(S, ...)`` directions, one row per shape.
        """
        verts, angles, count = self.vertices[shape], self.angles[shape], self.count[shape]
        flat = phi.reshape(len(shape), -1)
        a0 = angles[:, :1]
        flat = a0 + torch.remainder(flat - a0, 2 * math.pi)  # within one turn from angles[0]
        # the extreme vertex in direction phi: vertex i lies between edge normals i-1 and i
        idx = torch.searchsorted(angles, flat, right=True)
        idx = torch.remainder(torch.minimum(idx, count[:, None]), count[:, None])
        v = torch.gather(verts, 1, idx[..., None].expand(*idx.shape, 2))
        h = torch.cos(flat) * v[..., 0] + torch.sin(flat) * v[..., 1]
        return h.reshape(phi.shape)


def overlap(
    p: torch.Tensor,
    q: torch.Tensor,
    clearance: float,
    p_normals: torch.Tensor,
    q_normals: torch.Tensor,
) -> torch.Tensor:
    """Separating-axis test of convex polygon pairs ``p (P, m, 2)``, ``q (P, k, 2)`` with their
    inward edge normals.

    Returns ``(P,)`` bool: True where a pair overlaps or is closer than ``clearance`` along
    every edge normal of both (the rule of ``layout.placement.polygons_overlap``).
    """
    axes = torch.cat([p_normals, q_normals], -2)
    on_p = axes @ p.transpose(-1, -2)
    on_q = axes @ q.transpose(-1, -2)
    apart = (on_p.amax(-1) + clearance <= on_q.amin(-1)) | (
        on_q.amax(-1) + clearance <= on_p.amin(-1)
    )
    return ~apart.any(-1)


def yaw_raw_poses(xy: torch.Tensor, z: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """ManiSkill raw poses ``(b, 7)``, ``[x, y, z, qw, qx, qy, qz]``, of yaw-only rotations."""
    zeros = torch.zeros_like(yaw)
    return torch.stack(
        [xy[:, 0], xy[:, 1], z, torch.cos(yaw / 2), zeros, zeros, torch.sin(yaw / 2)], -1
    )


@dataclass(frozen=True)
class Region:
    """Convex regions per env: ``inside(x) iff normals @ x >= offsets``, with their boxes."""

    normals: torch.Tensor  # (b, e, 2)
    offsets: torch.Tensor  # (b, e)
    lo: torch.Tensor  # (b, 2)
    hi: torch.Tensor  # (b, 2)
    z: torch.Tensor  # (b,) height of the surface

    @classmethod
    def of(cls, poly: torch.Tensor, z: torch.Tensor) -> Region:
        n = inward_normals(poly)
        return cls(n, (n * poly).sum(-1), poly.amin(-2), poly.amax(-2), z)

    def rows(self, idx: torch.Tensor) -> Region:
        return Region(self.normals[idx], self.offsets[idx], self.lo[idx], self.hi[idx], self.z[idx])

    def holds(
        self, shapes: Shapes, shape: torch.Tensor, xy: torch.Tensor, yaw: torch.Tensor
    ) -> torch.Tensor:
        """Whether polygons lie wholly inside, each env's in its own region.

        Args:
            shapes: the polygons.
            shape: ``(s,)`` shape indices.
            xy: ``(b, s, k, 2)`` positions of ``k`` candidates of each shape.
            yaw: ``(b, s, k)`` their yaws.

        Returns:
            ``(b, s, k)`` bool.
        """
        beta = torch.atan2(self.normals[..., 1], self.normals[..., 0])  # (b, e)
        # min over the polygon of n . (R v + xy) = n . xy - support(angle(-n) - yaw)
        phi = beta[:, None, None, :] + math.pi - yaw[..., None]  # (b, s, k, e)
        h = shapes.support(shape, phi.transpose(0, 1)).transpose(0, 1)
        lowest = (xy[..., None, :] * self.normals[:, None, None]).sum(-1) - h
        return (lowest >= self.offsets[:, None, None] - 1e-9).all(-1)

    def candidates(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Candidate positions ``(b, s, k, 2)`` uniform over each env's box and yaws
        ``(b, s, k)``, from uniforms ``u (b, s, 3, k)``."""
        lo, hi = self.lo[:, None, None], self.hi[:, None, None]
        return lo + u[:, :, :2].transpose(-1, -2) * (hi - lo), (2 * u[:, :, 2] - 1) * math.pi

    def contains(self, points: torch.Tensor) -> torch.Tensor:
        """``points (b, ..., 2)`` -> ``(b, ...)`` bool."""
        b, e = self.offsets.shape
        flat = points.reshape(b, -1, 2)
        ok = (flat @ self.normals.transpose(1, 2) >= self.offsets[:, None] - 1e-9).all(-1)
        return ok.reshape(points.shape[:-1])


@dataclass(frozen=True)
class _Item:
    """One object to place each episode (its footprint is shape ``1 + its index``)."""

    node: str
    parent: str
    radius: float  # of the footprint around the actor origin
    min_z: float  # lowest collision point in its own frame
    manipulated: bool
    avoid: torch.Tensor  # (1 + number of items,) bool: the placed footprints (robot base
    # first, then the items in order) to keep clear of; not its ancestors, on which it stands
    top: torch.Tensor | None  # (e, 2) shrunk top hull in its own frame, if it supports objects
    top_z: float  # height of its top in its own frame


@dataclass(frozen=True)
class EpisodeStart:
    """What one episode starts from, for a batch of envs."""

    objects: dict[str, torch.Tensor]  # node -> (b, 7) ManiSkill raw pose
    goal: torch.Tensor  # (b, 3)
    joint_noise: torch.Tensor  # (b, NOISE_DIMS) standard normal, scaled by the env


NOISE_DIMS = 7  # arm joints that get start noise (the fingers start exactly open)
MANY_OBJECTS = 16  # placing more objects every episode is warned about (resets slow down)
STARTS_PER_DRAW = 32  # episode starts prepared per sampler call at least (then per env)
FIRST_CHUNK = 8  # candidates per object tested before the rest (most draws need only these)


class EpisodeSampler:
    """Per-episode object starts, goals and joint noise for every env of a configuration.

    Args:
        layouts: the per-env layouts of the configuration (same nodes and assets).
        limits: placement limits (the constraints of ``place()``).
        goal_region: where goals are drawn.
        objs_z_offset: m added to every object's height (as at configuration).
        device: the env's device.
        env_ids: the env (index into ManiSkill's episode RNGs) of each layout; default
            ``0 .. len(layouts) - 1``. A scene whose envs hold different layouts has one
            sampler per layout, each over its own envs (``scene.layout_scene.SceneEpisodes``);
            every other argument and method indexes the sampler's own rows.

    Raises:
        LayoutError: when no point of a table top is within the goal region of its robot.
    """

    def __init__(
        self,
        layouts: list[LayoutInfo],
        limits: PlacementLimits,
        goal_region: GoalRegion | None = None,
        objs_z_offset: float = 0.0,
        device: torch.device | str = "cpu",
        env_ids: torch.Tensor | None = None,
    ):
        base = layouts[0]
        self.limits, self.device = limits, torch.device(device)
        self.goal_region = GoalRegion() if goal_region is None else goal_region
        self.objs_z_offset = float(objs_z_offset)
        self.fallbacks = 0  # envs that kept their configuration's arrangement
        rows = torch.arange(len(layouts), device=self.device)
        self.env_ids = rows if env_ids is None else torch.as_tensor(env_ids, device=self.device)
        ctx = self.context = base.context

        def t(x) -> torch.Tensor:
            return torch.tensor(np.array(x), dtype=torch.float32, device=self.device)

        order = support_order(base)
        parents = {parent for _, parent in order}
        feet = [node_footprint(base, node) for node, _ in order]
        robot_square = square(np.zeros(2), limits.robot_footprint, 0.0)  # in its own frame
        self.shapes = Shapes.of([robot_square, *feet], self.device)  # robot base, then items
        obstacles = ["robot"] + [node for node, _ in order]
        ancestors = {ctx: {ctx}}
        self.items: list[_Item] = []
        for (node, parent), foot in zip(order, feet, strict=True):
            ancestors[node] = ancestors[parent] | {node}
            top = None
            hull, top_z, shrunk = local_top(base, node, limits.top_band, limits.hull_margin)
            if node in parents:
                if shrunk is None:
                    raise LayoutError(
                        f"{base.source or '<layout>'}: the top of {node!r} is smaller than twice"
                        f" the hull margin ({limits.hull_margin} m), so nothing can stand on it."
                        " Fix: move its children to the table."
                    )
                top = t(shrunk)
            self.items.append(
                _Item(
                    node=node,
                    parent=parent,
                    radius=float(np.linalg.norm(foot, axis=1).max()),
                    min_z=node_geometry(base, node).min_z,
                    manipulated=node in base.manipulated_objs,
                    avoid=torch.tensor(
                        [o not in ancestors[parent] for o in obstacles], device=self.device
                    ),
                    top=top,
                    top_z=top_z,
                )
            )
        n = len(self.items)
        if n > MANY_OBJECTS:
            warnings.warn(
                f"{base.source or '<layout>'}: {n} objects are placed on the table every "
                f"episode (over {MANY_OBJECTS}); each one costs every reset a pass of the "
                "placement, so resets slow down with them (34 objects measured seconds per "
                "reset). Fix: fewer objects, or PlacementLimits.episode_candidates lower",
                stacklevel=2,
            )
        self.shape_idx = torch.arange(1, n + 1, device=self.device)  # item j is shape j + 1
        # bounding radius of each shape (robot base, items), clearance included
        self.radii = (
            torch.tensor(
                [limits.robot_footprint / math.sqrt(2.0)] + [it.radius for it in self.items],
                device=self.device,
            )
            + limits.clearance
        )
        # per env: the configuration's object poses (kept by an env whose draw fails)
        self.fallback = {
            it.node: t([lay.pose(it.node).raised(self.objs_z_offset).to_raw() for lay in layouts])
            for it in self.items
        }
        # per env: the table top (shrunk by the placement margin) and the robot
        ctx_poses = [lay.pose(ctx) for lay in layouts]
        robots = [lay.pose(lay.robot) for lay in layouts]
        ctx_hull, ctx_top, ctx_shrunk = local_top(base, ctx, limits.top_band, limits.hull_margin)
        if ctx_shrunk is None:
            raise LayoutError(
                f"{base.source or '<layout>'}: the top of {ctx!r} is smaller than twice the hull"
                f" margin ({limits.hull_margin} m). Fix: use a larger table."
            )
        self.top_z = t([ctx_top + p.p[2] for p in ctx_poses])
        self.table = Region.of(self._posed(ctx_shrunk, ctx_poses), self.top_z)
        self.top = Region.of(self._posed(ctx_hull, ctx_poses), self.top_z)  # whole top
        self.robot_xy = t([r.p[:2] for r in robots])
        self.robot_yaw = t([r.yaw for r in robots])
        self._init_goals(base, ctx, ctx_poses, layouts)
        # prepared starts: per env a block of its next episodes, and which one comes next
        self.block = max(1, STARTS_PER_DRAW // len(layouts))
        self._queue: EpisodeStart | None = None
        n = len(layouts)
        self._next = torch.zeros(n, dtype=torch.long, device=self.device)  # next start to use
        self._end = torch.zeros(n, dtype=torch.long, device=self.device)  # prepared starts
        # reseeded: the next draw makes only the start its seeded reset uses
        self._fresh = torch.zeros(n, dtype=torch.bool, device=self.device)

    def _posed(self, local: np.ndarray, poses) -> torch.Tensor:
        """A polygon in an asset's frame, posed per env (yaw and XY): ``(num_envs, m, 2)``."""
        yaw = torch.tensor([p.yaw for p in poses], dtype=torch.float32, device=self.device)
        xy = torch.tensor([p.p[:2] for p in poses], dtype=torch.float32, device=self.device)
        poly = torch.tensor(np.array(local), dtype=torch.float32, device=self.device)
        return rotate(poly, yaw) + xy[:, None]

    def _init_goals(self, base: LayoutInfo, ctx: str, ctx_poses, layouts) -> None:
        """The goal region per env: top hull shrunk by the goal margin, reach band, heading."""
        g = self.goal_region
        hull, _, shrunk = local_top(base, ctx, self.limits.top_band, g.margin)
        self.goal_table = Region.of(
            self._posed(hull if shrunk is None else shrunk, ctx_poses), self.top_z
        )
        # bounding box of the reach sector (dense arc samples, padded) within the top's box
        half = math.radians(self.limits.max_heading_deg)
        a = self.robot_yaw[:, None] + torch.linspace(-half, half, 361, device=self.device)
        band = g.distance_band(self.limits)
        arcs = torch.cat([r * torch.stack([a.cos(), a.sin()], -1) for r in band], 1)
        arcs = arcs + self.robot_xy[:, None]
        self.goal_lo = torch.maximum(arcs.amin(1) - 1e-3, self.goal_table.lo)
        self.goal_hi = torch.minimum(arcs.amax(1) + 1e-3, self.goal_table.hi)
        # the region must not be empty: check on a fine grid, as a layout error
        s = torch.linspace(0, 1, 64, device=self.device)
        grid = torch.stack(torch.meshgrid(s, s, indexing="ij"), -1).reshape(-1, 2)
        pts = self.goal_lo[:, None] + grid * (self.goal_hi - self.goal_lo)[:, None]
        inside = self._in_goal_region(pts, torch.arange(len(layouts), device=self.device))
        empty = ~inside.any(1)
        # a known point of each region, for the (p < 1e-9) draw that finds none
        rows = torch.arange(len(layouts), device=self.device)
        self.goal_fallback = pts[rows, inside.to(torch.uint8).argmax(1)]
        if bool(empty.any()):
            lay = layouts[int(empty.nonzero()[0])]
            raise LayoutError(
                f'{lay.source or "<layout>"}: position["{lay.robot}"]: no point of the "{ctx}" '
                f"top lies within {band} m of the robot base and {self.limits.max_heading_deg} "
                "deg of its heading. Fix: put the robot at the table's edge, facing the table."
            )

    def _in_goal_region(self, xy: torch.Tensor, env_idx: torch.Tensor) -> torch.Tensor:
        """``xy (b, k, 2)`` -> ``(b, k)``: inside the goal region of each env."""
        near, far = self.goal_region.distance_band(self.limits)
        rel = xy - self.robot_xy[env_idx][:, None]
        d = rel.norm(dim=-1)
        return (
            self.goal_table.rows(env_idx).contains(xy)
            & (d >= near)
            & (d <= far)
            & (
                _heading_error(rel, self.robot_yaw[env_idx][:, None])
                <= math.radians(self.limits.max_heading_deg)
            )
        )

    # --- draws ---------------------------------------------------------------------------
    def invalidate(self, env_idx: torch.Tensor | None = None) -> None:
        """Drop the prepared starts of ``env_idx`` (all when None): their RNG was reseeded, and
        the next draw of each makes only the start its seeded reset uses."""
        rows = slice(None) if env_idx is None else env_idx
        self._next[rows] = self._end[rows] = 0
        self._fresh[rows] = True

    def reseeded(self, seed, env_idx, enhanced_determinism: bool) -> None:
        """After ManiSkill's ``_set_episode_rng(seed, env_idx)``: a seed re-creates every env's
        episode RNG; without one, only enhanced determinism re-creates those of ``env_idx``."""
        if seed is not None:
            self.invalidate()
        elif enhanced_determinism:
            self.invalidate(torch.as_tensor(env_idx, device=self.device))

    def draw(self, env_idx: torch.Tensor, rngs) -> EpisodeStart:
        """The next episode start of each env in ``env_idx``.

        Args:
            env_idx: ``(b,)`` envs being reset.
            rngs: ManiSkill's ``BatchedRNG`` of all envs (``_batched_episode_rng``); only the
                envs whose block of starts ran out are read.
        """
        if bool(self._fresh[env_idx].all()):  # a seeded reset: its starts alone, none queued
            self._fresh[env_idx] = False
            return self._starts(env_idx, self._keys(rngs, env_idx, 1))
        empty = self._next[env_idx] >= self._end[env_idx]
        if bool(empty.any()):
            self._refill(env_idx[empty], rngs)
        take = self._next[env_idx]
        self._next[env_idx] = take + 1
        q = self._queue
        return EpisodeStart(
            {k: v[env_idx, take] for k, v in q.objects.items()},
            q.goal[env_idx, take],
            q.joint_noise[env_idx, take],
        )

    def _refill(self, refill: torch.Tensor, rngs) -> None:
        """Prepare the next starts of the envs ``refill``: one for a just reseeded env (reset
        together with envs that were not), a block for the others. The keys are the RNG's
        next numbers either way (a size-k draw of NumPy's ``RandomState`` begins with its
        size-j draws, j < k), so how starts are prepared never changes which an env gets."""
        fresh = self._fresh[refill]
        groups = [(refill[fresh], 1), (refill[~fresh], self.block)]
        keys, flat = [], []
        for envs, size in groups:
            if len(envs):
                keys.append(self._keys(rngs, envs, size))
                flat.append(envs.repeat_interleave(size))
        start = self._starts(torch.cat(flat), torch.cat(keys))
        n = len(self._next)
        if self._queue is None:
            self._queue = EpisodeStart(
                {k: _blocks(v, n, self.block) for k, v in start.objects.items()},
                _blocks(start.goal, n, self.block),
                _blocks(start.joint_noise, n, self.block),
            )
        offset = 0
        for envs, size in groups:
            if not len(envs):
                continue
            rows = slice(offset, offset + len(envs) * size)
            for queue, new in zip(_fields(self._queue), _fields(start), strict=True):
                queue[envs, :size] = new[rows].view(len(envs), size, -1)
            self._end[envs] = size
            offset += len(envs) * size
        self._next[refill] = 0
        self._fresh[refill] = False

    def _keys(self, rngs, envs: torch.Tensor, size: int) -> torch.Tensor:
        """The next ``size`` episode keys of each env in ``envs`` from its RNG, env-major."""
        drawn = np.asarray(rngs[self.env_ids[envs].cpu().numpy()].randint(0, 2**31, size=size))
        return torch.as_tensor(drawn.reshape(-1), device=self.device)

    def _starts(self, env_idx: torch.Tensor, keys: torch.Tensor) -> EpisodeStart:
        """The episode starts of the keys ``(b,)`` of the envs ``env_idx (b,)``."""
        return EpisodeStart(
            self.objects(env_idx, keys),
            self.goals(env_idx, keys),
            normals(keys, NOISE_STREAM, NOISE_DIMS),
        )

    def objects(self, env_idx: torch.Tensor, keys: torch.Tensor) -> dict[str, torch.Tensor]:
        """Each object's start pose ``(b, 7)`` (ManiSkill raw) for the envs ``env_idx``."""
        k, n = self.limits.episode_candidates, len(self.items)
        b = len(env_idx)
        rows = torch.arange(b, device=self.device)
        regions = {self.context: self.table.rows(env_idx)}
        robot_xy, robot_yaw = self.robot_xy[env_idx], self.robot_yaw[env_idx]
        # placed footprints (shape i: robot base, then the items): world polygons, their
        # normals, origins
        shapes = self.shapes
        polys = robot_xy.new_zeros((b, n + 1, *shapes.vertices.shape[1:]))
        poly_normals, origins = torch.zeros_like(polys), robot_xy.new_zeros((b, n + 1, 2))
        polys[:, 0] = rotate(shapes.vertices[0], robot_yaw) + robot_xy[:, None]
        poly_normals[:, 0], origins[:, 0] = rotate(shapes.normals[0], robot_yaw), robot_xy
        drawn: dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}
        ok_env = torch.ones(b, dtype=torch.bool, device=self.device)
        u = uniforms(keys, 0, 3 * k * n).view(b, n, 3, k)
        placed = (polys, poly_normals, origins, robot_xy, robot_yaw)
        for j, it in enumerate(self.items):
            region, shape = regions[it.parent], j + 1
            first, found = self._first_fit(j, it, region, u[:, j], placed)
            ok_env &= found
            chosen = u[rows, j, :, first][:, None, :, None]  # (b, 1, 3, 1)
            xy, yaw = (x[:, 0, 0] for x in region.candidates(chosen))
            z = region.z - it.min_z
            drawn[it.node] = (xy, z, yaw)
            if j + 1 < n:  # a footprint that later objects keep clear of
                polys[:, shape] = rotate(shapes.vertices[shape], yaw) + xy[:, None]
                poly_normals[:, shape] = rotate(shapes.normals[shape], yaw)
                origins[:, shape] = xy
            if it.top is not None:
                regions[it.node] = Region.of(rotate(it.top, yaw) + xy[:, None], z + it.top_z)
        failed = int((~ok_env).sum())
        if failed:
            if self.fallbacks == 0:
                warnings.warn(
                    f"per-episode placement found no valid arrangement for {failed} env(s) "
                    f"within {k} candidates per object; they keep their configuration's "
                    "arrangement this episode (counted in EpisodeSampler.fallbacks). Fix: raise "
                    "PlacementLimits.episode_candidates or use fewer/smaller objects.",
                    stacklevel=2,
                )
            self.fallbacks += failed
        out = {}
        for node, (xy, z, yaw) in drawn.items():
            raw = yaw_raw_poses(xy, z + self.objs_z_offset, yaw)
            out[node] = torch.where(ok_env[:, None], raw, self.fallback[node][env_idx])
        return out

    def _first_fit(self, j: int, it, region: Region, u: torch.Tensor, placed):
        """The first of item j's candidates (uniforms ``u (b, 3, k)``) that meets every rule
        in each env, and whether one does: ``(first (b,), found (b,))``.

        Candidates are tested in chunks (``FIRST_CHUNK``, then the rest) and the test stops
        once every env has its first fit: a seeded reset of one env tests a few candidates,
        not ``episode_candidates``. The first fit does not depend on the chunks.
        """
        polys, poly_normals, origins, robot_xy, robot_yaw = placed
        shapes, radii, shape = self.shapes, self.radii, j + 1
        b, k = u.shape[0], u.shape[-1]
        first = torch.zeros(b, dtype=torch.int64, device=self.device)
        found = torch.zeros(b, dtype=torch.bool, device=self.device)
        for lo, hi in ((0, min(FIRST_CHUNK, k)), (min(FIRST_CHUNK, k), k)):
            if lo == hi:
                continue
            xy, yaw = (x[:, 0] for x in region.candidates(u[:, None, :, lo:hi]))
            ok = region.holds(shapes, self.shape_idx[j : j + 1], xy[:, None], yaw[:, None])[:, 0]
            if it.manipulated:
                ok &= self._within_reach(xy, robot_xy, robot_yaw)
            # separating-axis tests only where bounding circles meet, all obstacles at once
            rel = xy[:, :, None] - origins[:, None, :shape]
            near = torch.hypot(rel[..., 0], rel[..., 1]) < it.radius + radii[:shape]
            e, c, o = (near & ok[..., None] & it.avoid[:shape]).nonzero(as_tuple=True)
            pair_yaw = yaw[e, c]
            hit = overlap(
                rotate(shapes.vertices[shape], pair_yaw) + xy[e, c, None],
                polys[e, o],
                self.limits.clearance,
                rotate(shapes.normals[shape], pair_yaw),
                poly_normals[e, o],
            )
            ok[e[hit], c[hit]] = False
            new = ok.any(1) & ~found
            first = torch.where(new, lo + ok.to(torch.uint8).argmax(1), first)
            found |= new
            if bool(found.all()):
                break
        return first, found

    def _within_reach(
        self, xy: torch.Tensor, robot_xy: torch.Tensor, robot_yaw: torch.Tensor
    ) -> torch.Tensor:
        """Where a manipulated object may stand: within the reach band and heading cone of
        the robot (``xy (b, ..., 2)``, ``robot_xy (b, 2)``, ``robot_yaw (b,)``)."""
        lim = self.limits
        extra = (1,) * (xy.dim() - 2)
        rel = xy - robot_xy.view(-1, *extra, 2)
        d = torch.hypot(rel[..., 0], rel[..., 1])
        heading = _heading_error(rel, robot_yaw.view(-1, *extra))
        return (
            (d > lim.reach_min)
            & (d < lim.reach_max)
            & (heading <= math.radians(lim.max_heading_deg))
        )

    def goals(self, env_idx: torch.Tensor, keys: torch.Tensor) -> torch.Tensor:
        """Goal positions ``(b, 3)``, uniform over each env's goal region (rejection)."""
        g, k = self.goal_region, self.goal_region.candidates
        b = len(env_idx)
        u = uniforms(keys, GOAL_STREAM, 2 * k + 1).view(b, -1)
        lo, hi = self.goal_lo[env_idx], self.goal_hi[env_idx]
        xy = lo[:, None] + u[:, : 2 * k].view(b, k, 2) * (hi - lo)[:, None]
        ok = self._in_goal_region(xy, env_idx)
        first = ok.to(torch.uint8).argmax(1)
        xy = xy[torch.arange(b, device=self.device), first]
        found = ok.any(1)
        if not bool(found.all()):  # the region fills >= ~20% of its box: p < 1e-6 per draw
            warnings.warn(
                f"goal draw: none of {k} candidates fell in the goal region of "
                f"{int((~found).sum())} env(s); they take a fixed point of their region",
                stacklevel=2,
            )
            xy = torch.where(found[:, None], xy, self.goal_fallback[env_idx])
        h = g.height[0] + u[:, -1] * (g.height[1] - g.height[0])
        return torch.cat([xy, (self.top_z[env_idx] + h)[:, None]], 1)


def _blocks(x: torch.Tensor, n: int, block: int) -> torch.Tensor:
    """An empty ``(n, block, ...)`` queue for rows like those of ``x``."""
    return x.new_zeros((n, block, *x.shape[1:]))


def _fields(start: EpisodeStart) -> list[torch.Tensor]:
    """The tensors of a start, in a fixed order."""
    return [*start.objects.values(), start.goal, start.joint_noise]


def _heading_error(rel: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """``|angle(rel) - yaw|`` wrapped to [0, pi]; ``yaw`` broadcasts against ``rel[..., 0]``."""
    bearing = torch.atan2(rel[..., 1], rel[..., 0])
    return wrap_angle(bearing - yaw).abs()
