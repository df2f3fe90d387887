"""Per-episode randomisation on each env's fixed table: object starts, goals, joint noise.

A configuration (construction or ``reconfigure``) fixes each env's table, robot spot and
background (``configuration.place``). Every episode then re-draws, for the reset envs only:

- the pose of every object standing on the table (or on another object), in the order of the
  support tree ``place()`` walks (``tree.support_tree``), by the placement rules of
  ``rules.py``, the same functions ``place()`` runs: the whole footprint inside its
  parent's shrunk top, clear of placed footprints (robot base square included), manipulated
  objects within reach and heading of the robot; its lowest point resting on the parent's top;
- the goal, uniformly over the reachable region above the table top (:class:`GoalRegion`).

Everything is an array over envs, so one code path serves one CPU env and thousands of GPU
envs: each object gets one batch of ``episode_candidates`` candidates per env and takes the
first that meets every rule (no loop over envs or tries). The arrays are numpy's on a CPU env
(a few envs; each torch operation's fixed cost would dominate) and torch's on a GPU; the rules
and this module's code run unchanged on either (``batch.Arrays``, ``rules.array_module``). An
env where some object found no candidate keeps its configuration's arrangement for that
episode; this is counted in ``EpisodeSampler.fallbacks`` and warned about once.

Random numbers are counter-based: each episode of an env has one key, drawn from that env's
ManiSkill episode RNG, and every uniform is a hash of (key, stream, index) (``batch.uniforms``).
The same seed gives the same start, and a partial reset draws nothing for the other envs. With
few envs :meth:`EpisodeSampler.draw` prepares a block of each env's next episode starts at once
(keys drawn in blocks from its RNG); a block is dropped when ManiSkill reseeds that env's RNG
(:meth:`invalidate`), and the draw after a reseed makes only the start the seeded reset uses:
seeded resets (evaluation, ``collect``, replays) pay for one start, not a block.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.placement.batch import (
    Arrays,
    Region,
    Shapes,
    normals,
    uniforms,
    yaw_raw_poses,
)
from embodied_envs.layout.placement.geometry import local_top, square
from embodied_envs.layout.placement.limits import GoalRegion, PlacementLimits
from embodied_envs.layout.placement.rules import (
    candidates_fit,
    first_true,
    move_offset,
    rotate,
    within_reach,
)
from embodied_envs.layout.placement.tree import support_tree
from embodied_envs.layout.schema import LayoutInfo

# --- random number streams of an episode key (``batch.uniforms``) --------------------------
GOAL_STREAM = 1 << 20  # object j uses stream j; these are far from any object index
NOISE_STREAM = GOAL_STREAM + 1


@dataclass(frozen=True)
class EpisodeStart:
    """What one episode starts from, for a batch of envs (tensors on the env's device, or a
    sampler's own arrays inside it)."""

    objects: dict[str, torch.Tensor]  # node -> (b, 7) ManiSkill raw pose
    goal: torch.Tensor  # (b, 3)
    joint_noise: torch.Tensor  # (b, NOISE_DIMS) standard normal, scaled by the env

    def map(self, fn) -> EpisodeStart:
        return EpisodeStart({k: fn(v) for k, v in self.objects.items()}, fn(self.goal),
                            fn(self.joint_noise))  # fmt: skip


NOISE_DIMS = 7  # at most this many arm joints get start noise (robots.py noise_joints)
MANY_OBJECTS = 16  # placing more objects every episode is warned about (resets slow down)
STARTS_PER_DRAW = 32  # episode starts prepared per sampler call at least (then per env)
FIRST_CHUNK = 8  # candidates per object tested before the rest (most draws need only these)
ROWS_KEPT = 64  # env row sets whose arrays a numpy sampler keeps indexed (a CPU env: one)


@dataclass(frozen=True)
class _Rows:
    """The configuration's per-env arrays at some envs' rows: what every draw of them reads."""

    table: Region  # the top, shrunk by the placement margin
    goal_table: Region
    robot_xy: object
    robot_yaw: object
    robot_foot: object  # (b, 1 + links, M, 2): the base's square, the arm's links at rest
    robot_foot_normals: object
    goal_lo: object
    goal_hi: object
    top_z: object
    reach_xy: object  # where the reach band is centred (PlacementLimits.reach_centre)


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
        backend: ``"numpy"`` or ``"torch"`` arrays for the draws (default: numpy on the CPU,
            torch on a GPU; :class:`Arrays`). Public methods take and return tensors either way.

    Raises:
        LayoutError: when no point of a table top is within the goal region of its robot.
        PlacementError: a top that something stands on is too small (``tree.support_tree``).
    """

    def __init__(
        self,
        layouts: list[LayoutInfo],
        limits: PlacementLimits,
        goal_region: GoalRegion | None = None,
        objs_z_offset: float = 0.0,
        device: torch.device | str = "cpu",
        env_ids: torch.Tensor | None = None,
        backend: str | None = None,
    ):
        base = layouts[0]
        self.arrays = a = Arrays(device, backend)
        self.limits, self.device = limits, a.device
        self.goal_region = GoalRegion() if goal_region is None else goal_region
        self.objs_z_offset = float(objs_z_offset)
        self.fallbacks = 0  # envs that kept their configuration's arrangement
        rows = torch.arange(len(layouts), device=self.device)
        self.env_ids = rows if env_ids is None else torch.as_tensor(env_ids, device=self.device)
        self._rng_rows = self.env_ids.cpu().numpy()  # into ManiSkill's (numpy) episode RNGs
        ctx = self.context = base.context

        tree = support_tree(base, limits)  # the objects in placement order (as ``place``)
        self.items = tree.items  # item j's footprint is shape 1 + j (0: the robot base)
        robot_square = square(np.zeros(2), limits.robot_footprint, 0.0)  # in its own frame
        rest = limits.rest_polygons()  # the arm at rest, a box per link, in the robot's frame
        self.shapes = Shapes.of([robot_square, *(it.footprint for it in self.items), *rest], a)
        n = len(self.items)
        # the footprints each keeps clear of: slot i (0: the robot base, 1 + j: item j), where
        # a move task's movers are n + i: where the move takes slot i (``rules``), then the
        # arm's links at rest from slot ``rest0`` (shapes n + 1 ...)
        moves = any(it.shift is not None for it in self.items)
        self.rest0 = n + 1 + (n if moves else 0)
        self.slots = self.rest0 + len(rest)
        self.avoid = [a.index(it.avoid + tuple(n + i for i in it.avoid_destinations)
                              + tuple(self.rest0 + k for k in it.avoid_rest))
                      for it in self.items]  # fmt: skip
        self.gaps = [a(it.gaps) for it in self.items]  # the least gap to each avoided
        radii = self.shapes.radii
        self.radii = a.xp.concatenate([radii[: n + 1], radii[1 : n + 1] if moves else radii[:0],
                                       radii[n + 1 :]])  # fmt: skip
        self.tops = [a(it.top.shrunk) if it.supports else None for it in self.items]
        if n > MANY_OBJECTS:
            warnings.warn(
                f"{base.source or '<layout>'}: {n} objects are placed on the table every "
                f"episode (over {MANY_OBJECTS}); each one costs every reset a pass of the "
                "placement, so resets slow down with them (34 objects measured seconds per "
                "reset). Fix: fewer objects, or PlacementLimits.episode_candidates lower",
                stacklevel=2,
            )
        # per env: the configuration's object poses (kept by an env whose draw fails)
        self.fallback = {
            it.node: a([lay.pose(it.node).raised(self.objs_z_offset).to_raw() for lay in layouts])
            for it in self.items
        }
        # per env: the table top (shrunk by the placement margin) and the robot
        ctx_poses = [lay.pose(ctx) for lay in layouts]
        robots = [lay.pose(lay.robot) for lay in layouts]
        ctx_hull, ctx_top, ctx_shrunk = tree.context_top
        self.top_z = a([ctx_top + p.p[2] for p in ctx_poses])
        self.table = Region.of(self._posed(ctx_shrunk, ctx_poses), self.top_z)
        self.top = Region.of(self._posed(ctx_hull, ctx_poses), self.top_z)  # whole top
        self.robot_xy = a([r.p[:2] for r in robots])
        self.robot_yaw = a([r.yaw for r in robots])
        self.reach_xy = limits.reach_centre(self.robot_xy, self.robot_yaw)  # the band's centre
        # the robot base's footprint per env (fixed for the configuration) and its normals,
        # with the arm's links at rest after it: (E, 1 + links, M, 2)
        robot = a.xp.concatenate([self.shapes.vertices[:1], self.shapes.vertices[n + 1 :]])
        robot_normals = a.xp.concatenate([self.shapes.normals[:1], self.shapes.normals[n + 1 :]])
        yaw = self.robot_yaw[:, None]
        self.robot_foot = rotate(robot, yaw) + self.robot_xy[:, None, None]
        self.robot_foot_normals = rotate(robot_normals, yaw)
        self._kept_rows: dict[bytes, _Rows] = {}  # numpy: row sets' arrays, by their bytes
        self._init_goals(base, ctx, ctx_poses, layouts)
        # prepared starts: per env a block of its next episodes, and which one comes next
        self.block = max(1, STARTS_PER_DRAW // len(layouts))
        self._queue: EpisodeStart | None = None
        n = len(layouts)
        self._next = a.zeros(n, "int64")  # next start to use
        self._end = a.zeros(n, "int64")  # prepared starts
        # reseeded: the next draw makes only the start its seeded reset uses
        self._fresh = a.zeros(n, "bool")

    def _posed(self, local: np.ndarray, poses):
        """A polygon in an asset's frame, posed per env (yaw and XY): ``(num_envs, m, 2)``."""
        a = self.arrays
        yaw, xy = a([p.yaw for p in poses]), a([p.p[:2] for p in poses])
        return rotate(a(local), yaw) + xy[:, None]

    def _init_goals(self, base: LayoutInfo, ctx: str, ctx_poses, layouts) -> None:
        """The goal region per env: top hull shrunk by the goal margin, reach band, heading."""
        g, a, xp = self.goal_region, self.arrays, self.arrays.xp
        hull, _, shrunk = local_top(base, ctx, self.limits.top_band, g.margin)
        self.goal_table = Region.of(
            self._posed(hull if shrunk is None else shrunk, ctx_poses), self.top_z
        )
        # bounding box of the reach sector (dense arc samples, padded) within the top's box
        half = math.radians(self.limits.max_heading_deg)
        angle = self.robot_yaw[:, None] + a(np.linspace(-half, half, 361))
        band = g.distance_band(self.limits)
        arcs = xp.concatenate([r * xp.stack([xp.cos(angle), xp.sin(angle)], -1) for r in band], 1)
        arcs = arcs + self.reach_xy[:, None]
        self.goal_lo = xp.maximum(xp.amin(arcs, 1) - 1e-3, self.goal_table.lo)
        self.goal_hi = xp.minimum(xp.amax(arcs, 1) + 1e-3, self.goal_table.hi)
        # the region must not be empty: check on a fine grid, as a layout error
        s = np.linspace(0, 1, 64)
        grid = a(np.stack(np.meshgrid(s, s, indexing="ij"), -1).reshape(-1, 2))
        pts = self.goal_lo[:, None] + grid * (self.goal_hi - self.goal_lo)[:, None]
        rows = a.index(np.arange(len(layouts)))
        first, inside = first_true(self._in_goal_region(pts, rows))
        # a known point of each region, for the (p < 1e-9) draw that finds none
        self.goal_fallback = pts[rows, first]
        if not bool(inside.all()):
            lay = layouts[int(np.flatnonzero(self.arrays.numpy(~inside))[0])]
            raise LayoutError(
                f'{lay.source or "<layout>"}: position["{lay.robot}"]: no point of the "{ctx}" '
                f"top lies within {band} m of the robot base and {self.limits.max_heading_deg} "
                "deg of its heading. Fix: put the robot at the table's edge, facing the table."
            )

    def _rows(self, env_idx) -> _Rows:
        """The per-env arrays at the rows ``env_idx``; a numpy sampler keeps them (indexing
        them anew costs a few-env draw more than its arithmetic)."""
        key = env_idx.tobytes() if self.arrays.xp is np else None
        rows = self._kept_rows.get(key) if key is not None else None
        if rows is None:
            rows = _Rows(
                self.table.rows(env_idx), self.goal_table.rows(env_idx), self.robot_xy[env_idx],
                self.robot_yaw[env_idx], self.robot_foot[env_idx],
                self.robot_foot_normals[env_idx], self.goal_lo[env_idx], self.goal_hi[env_idx],
                self.top_z[env_idx], self.reach_xy[env_idx],
            )  # fmt: skip
            if key is not None:
                if len(self._kept_rows) >= ROWS_KEPT:
                    self._kept_rows.clear()
                self._kept_rows[key] = rows
        return rows

    def _in_goal_region(self, xy, env_idx):
        """``xy (b, k, 2)`` -> ``(b, k)``: inside the goal region of each env (the top shrunk
        by the goal margin; the reach rule with the band shrunk by the goal inset)."""
        r = self._rows(env_idx)
        in_band, facing = within_reach(
            xy,
            r.reach_xy[:, None],
            r.robot_yaw[:, None],
            self.goal_region.distance_band(self.limits),
            self.limits.max_heading_deg,
        )
        return r.goal_table.contains(xy) & in_band & facing

    # --- draws ---------------------------------------------------------------------------
    def invalidate(self, env_idx=None) -> None:
        """Drop the prepared starts of ``env_idx`` (all when None): their RNG was reseeded, and
        the next draw of each makes only the start its seeded reset uses."""
        rows = slice(None) if env_idx is None else self.arrays.index(env_idx)
        self._next[rows] = 0
        self._end[rows] = 0
        self._fresh[rows] = True

    def reseeded(self, seed, env_idx, enhanced_determinism: bool) -> None:
        """After ManiSkill's ``_set_episode_rng(seed, env_idx)``: a seed re-creates every env's
        episode RNG; without one, only enhanced determinism re-creates those of ``env_idx``."""
        if seed is not None:
            self.invalidate()
        elif enhanced_determinism:
            self.invalidate(env_idx)

    def draw(self, env_idx: torch.Tensor, rngs) -> EpisodeStart:
        """The next episode start of each env in ``env_idx`` (tensors on the env's device).

        Args:
            env_idx: ``(b,)`` envs being reset.
            rngs: ManiSkill's ``BatchedRNG`` of all envs (``_batched_episode_rng``); only the
                envs whose block of starts ran out are read.
        """
        idx = self.arrays.index(env_idx)
        if bool(self._fresh[idx].all()):  # a seeded reset: its starts alone, none queued
            self._fresh[idx] = False
            return self._starts(idx, self._keys(rngs, idx, 1)).map(self.arrays.tensor)
        empty = self._next[idx] >= self._end[idx]
        if bool(empty.any()):
            self._refill(idx[empty], rngs)
        take = self._next[idx]
        self._next[idx] = take + 1
        return self._queue.map(lambda q: self.arrays.tensor(q[idx, take]))

    def _refill(self, refill, rngs) -> None:
        """Prepare the next starts of the envs ``refill``: one for a just reseeded env (reset
        together with envs that were not), a block for the others. The keys are the RNG's
        next numbers either way (a size-k draw of NumPy's ``RandomState`` begins with its
        size-j draws, j < k), so how starts are prepared never changes which an env gets."""
        xp = self.arrays.xp
        fresh = self._fresh[refill]
        groups = [(refill[fresh], 1), (refill[~fresh], self.block)]
        keys, flat = [], []
        for envs, size in groups:
            if len(envs):
                keys.append(self._keys(rngs, envs, size))
                flat.append(xp.repeat_interleave(envs, size) if xp is torch
                            else np.repeat(envs, size))  # fmt: skip
        start = self._starts(xp.concatenate(flat), xp.concatenate(keys))
        n = len(self._next)
        if self._queue is None:
            self._queue = start.map(lambda x: self.arrays.zeros((n, self.block, *x.shape[1:])))
        offset = 0
        for envs, size in groups:
            if not len(envs):
                continue
            rows = slice(offset, offset + len(envs) * size)
            for queue, new in zip(_fields(self._queue), _fields(start), strict=True):
                queue[envs, :size] = new[rows].reshape(len(envs), size, -1)
            self._end[envs] = size
            offset += len(envs) * size
        self._next[refill] = 0
        self._fresh[refill] = False

    def _keys(self, rngs, envs, size: int):
        """The next ``size`` episode keys of each env in ``envs`` from its RNG, env-major."""
        rows = self._rng_rows[self.arrays.numpy(envs)]
        drawn = np.asarray(rngs[rows].randint(0, 2**31, size=size))
        return self.arrays.index(drawn.reshape(-1))

    def _starts(self, env_idx, keys) -> EpisodeStart:
        """The episode starts of the keys ``(b,)`` of the envs ``env_idx (b,)``, in the
        sampler's arrays."""
        return EpisodeStart(
            self._objects(env_idx, keys),
            self._goals(env_idx, keys),
            normals(keys, NOISE_STREAM, NOISE_DIMS),
        )

    def objects(self, env_idx, keys) -> dict[str, torch.Tensor]:
        """Each object's start pose ``(b, 7)`` (ManiSkill raw) for the envs ``env_idx``, from
        the episode keys ``(b,)``."""
        a = self.arrays
        return {k: a.tensor(v) for k, v in self._objects(a.index(env_idx), a.index(keys)).items()}

    def goals(self, env_idx, keys) -> torch.Tensor:
        """Goal positions ``(b, 3)``, uniform over each env's goal region (rejection)."""
        a = self.arrays
        return a.tensor(self._goals(a.index(env_idx), a.index(keys)))

    def _objects(self, env_idx, keys) -> dict:
        k, n = self.limits.episode_candidates, len(self.items)
        a, xp = self.arrays, self.arrays.xp
        b = len(env_idx)
        rows = a.index(np.arange(b))
        r = self._rows(env_idx)
        regions = {self.context: r.table}
        robot_xy, robot_yaw = r.robot_xy, r.robot_yaw
        # placed footprints (shape i: robot base, then the items): world polygons, their
        # normals, origins
        shapes = self.shapes
        polys = a.zeros((b, self.slots, *shapes.vertices.shape[1:]))
        poly_normals, origins = a.zeros(polys.shape), a.zeros((b, self.slots, 2))
        polys[:, 0], poly_normals[:, 0] = r.robot_foot[:, 0], r.robot_foot_normals[:, 0]
        polys[:, self.rest0 :] = r.robot_foot[:, 1:]
        poly_normals[:, self.rest0 :] = r.robot_foot_normals[:, 1:]
        origins[:, 0] = robot_xy
        origins[:, self.rest0 :] = robot_xy[:, None]
        placed = (polys, poly_normals, origins)
        drawn = {}
        ok_env = a.zeros(b, "bool") | True
        u = uniforms(keys, 0, 3 * k * n).reshape(b, n, 3, k)
        for j, it in enumerate(self.items):
            region, shape = regions[it.parent], j + 1
            first, found = self._first_fit(j, it, region, u[:, j], placed, r.reach_xy, robot_yaw)
            ok_env = ok_env & found
            chosen = u[rows, j, :, first][..., None]  # (b, 3, 1)
            xy, yaw = (x[:, 0] for x in region.candidates(chosen))
            z = region.z - it.min_z
            drawn[it.node] = (xy, z, yaw)
            if j + 1 < n:  # a footprint that later objects keep clear of
                polys[:, shape] = rotate(shapes.vertices[shape], yaw) + xy[:, None]
                poly_normals[:, shape] = rotate(shapes.normals[shape], yaw)
                origins[:, shape] = xy
                if it.shift is not None:  # where the move takes it: kept clear too
                    offset = move_offset(it.shift, robot_yaw)  # (b, 1, 2)
                    polys[:, n + shape] = polys[:, shape] + offset
                    poly_normals[:, n + shape] = poly_normals[:, shape]
                    origins[:, n + shape] = xy + offset[:, 0]
            if self.tops[j] is not None:
                top = rotate(self.tops[j], yaw) + xy[:, None]
                regions[it.node] = Region.of(top, z + it.top.z)
        failed = int((~ok_env).sum())
        if failed:
            if self.fallbacks == 0:
                warnings.warn(
                    f"per-episode placement found no valid arrangement for {failed} env(s) "
                    f"within {k} candidates per object; they keep their configuration's "
                    "arrangement this episode (counted in EpisodeSampler.fallbacks). Fix: raise "
                    "PlacementLimits.episode_candidates or use fewer/smaller objects.",
                    stacklevel=3,
                )
            self.fallbacks += failed
        out = {}
        for node, (xy, z, yaw) in drawn.items():
            raw = yaw_raw_poses(xy, z + self.objs_z_offset, yaw)
            if failed:  # those envs keep their configuration's arrangement
                raw = xp.where(ok_env[:, None], raw, self.fallback[node][env_idx])
            out[node] = raw
        return out

    def _first_fit(self, j: int, it, region: Region, u, placed, reach_xy, robot_yaw):
        """The first of item j's candidates (uniforms ``u (b, 3, k)``) that meets every rule
        (``rules.candidates_fit``) in each env, and whether one does: ``(first (b,), found
        (b,))``.

        Candidates are tested in chunks (``FIRST_CHUNK``, then the rest) and the test stops
        once every env has its first fit: a seeded reset of one env tests a few candidates,
        not ``episode_candidates``. The first fit does not depend on the chunks.
        """
        lim, shapes, shape, xp = self.limits, self.shapes, j + 1, self.arrays.xp
        k = u.shape[-1]
        polys, poly_normals, origins = placed
        avoid = self.avoid[j]
        keep_clear = (polys[:, avoid], poly_normals[:, avoid], origins[:, avoid],
                      self.radii[avoid])  # fmt: skip
        reach = None
        if it.manipulated:
            band = (lim.reach_min, lim.reach_max)
            reach = (reach_xy, robot_yaw, band, lim.max_heading_deg)
        first = found = None
        for lo, hi in ((0, min(FIRST_CHUNK, k)), (min(FIRST_CHUNK, k), k)):
            if lo == hi:
                continue
            xy, yaw = region.candidates(u[..., lo:hi])
            masks = candidates_fit(
                xy, yaw, shapes.vertices[shape], shapes.normals[shape], shapes.radii[shape],
                (region.normals, region.offsets), keep_clear, self.gaps[j], reach,
                it.shift if reach is not None else None,
            )  # fmt: skip
            ok = masks.pop("clear")
            for mask in masks.values():
                ok = ok & mask
            index, any_ok = first_true(ok)
            if found is None:  # the first chunk (first_true gives 0 where none fits)
                first, found = index, any_ok
            else:
                new = any_ok & ~found
                first = xp.where(new, lo + index, first)
                found = found | new
            if bool(found.all()):
                break
        return first, found

    def _goals(self, env_idx, keys):
        g, k = self.goal_region, self.goal_region.candidates
        xp = self.arrays.xp
        b = len(env_idx)
        u = uniforms(keys, GOAL_STREAM, 2 * k + 1).reshape(b, -1)
        r = self._rows(env_idx)
        lo, hi = r.goal_lo, r.goal_hi
        xy = lo[:, None] + u[:, : 2 * k].reshape(b, k, 2) * (hi - lo)[:, None]
        first, found = first_true(self._in_goal_region(xy, env_idx))
        xy = xy[self.arrays.index(np.arange(b)), first]
        if not bool(found.all()):  # the region fills >= ~20% of its box: p < 1e-6 per draw
            warnings.warn(
                f"goal draw: none of {k} candidates fell in the goal region of "
                f"{int((~found).sum())} env(s); they take a fixed point of their region",
                stacklevel=3,
            )
            xy = xp.where(found[:, None], xy, self.goal_fallback[env_idx])
        h = g.height[0] + u[:, -1] * (g.height[1] - g.height[0])
        return xp.concatenate([xy, (r.top_z + h)[:, None]], 1)


def _fields(start: EpisodeStart) -> list:
    """The arrays of a start, in a fixed order."""
    return [*start.objects.values(), start.goal, start.joint_noise]
