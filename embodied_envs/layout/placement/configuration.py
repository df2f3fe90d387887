"""Seeded, strict BFS placement of a layout's nodes (per configuration).

``place(layout, seed)`` re-draws the poses of the background, the context (table), the robot and
every object, in the order of the support tree (``tree.support_tree``, breadth first from the
table, larger footprints first; the per-episode sampler follows the same walk), then the
objects standing on the floor. Every draw comes from one ``numpy.random.Generator`` made from
the seed. Candidates are sampled in vectorised batches;
when an object cannot be placed a :class:`PlacementError` names it and the constraint that
rejected the most candidates.
"""

from __future__ import annotations

import math

import numpy as np

from embodied_envs.layout.errors import PlacementError
from embodied_envs.layout.placement.geometry import (
    Surface,
    key_bottom,
    key_footprint,
    key_geometry,
    polygon_centroid,
    posed_top,
    square,
)
from embodied_envs.layout.placement.limits import PlacementLimits
from embodied_envs.layout.placement.rules import (
    candidates_fit,
    half_planes,
    inward_normals,
    move_offset,
    pad_polygons,
    rotate,
)
from embodied_envs.layout.placement.tree import Standing, support_tree
from embodied_envs.layout.pools import with_first_members
from embodied_envs.layout.pose import LayoutPose
from embodied_envs.layout.schema import LayoutInfo


def robot_base_pose(top: Surface, u: float) -> LayoutPose:
    """Robot base on the shrunk top's boundary at perimeter fraction ``u``, facing the centre
    (``support_tree`` refuses a context whose top vanishes when shrunk)."""
    edge_hull = top.shrunk
    seg = np.roll(edge_hull, -1, axis=0) - edge_hull
    lengths = np.linalg.norm(seg, axis=1)
    s = u * lengths.sum()
    i = int(np.searchsorted(np.cumsum(lengths), s, side="right"))
    i = min(i, len(lengths) - 1)
    t = (s - (np.cumsum(lengths)[i] - lengths[i])) / max(lengths[i], 1e-12)
    xy = edge_hull[i] + t * seg[i]
    centre = polygon_centroid(top.hull)
    yaw = math.atan2(centre[1] - xy[1], centre[0] - xy[0])
    return LayoutPose.from_xyz_yaw([xy[0], xy[1], top.z], yaw)


class _Placer:
    def __init__(self, layout: LayoutInfo, rng: np.random.Generator, limits: PlacementLimits):
        self.layout = layout
        self.rng = rng
        self.limits = limits
        self.tree = support_tree(layout, limits)
        self.poses: dict[str, LayoutPose] = {}
        self.obstacles: list[np.ndarray] = []  # world footprints: robot base, then the items
        self.destinations: dict[int, np.ndarray] = {}  # a move's movers' there, by obstacle
        self.rest: list[np.ndarray] = []  # the arm at rest: a world box per link
        # each node's asset resolved once per call (file lookups are the slow part)
        self.foot = {n: key_footprint(k) for n, k in self.tree.keys.items()}
        self.foot_normals = {n: inward_normals(f) for n, f in self.foot.items()}
        self.min_z = {n: key_geometry(k).min_z for n, k in self.tree.keys.items()}

    def placed(self, polygons: list[np.ndarray]) -> tuple:
        """World footprints as ``candidates_fit``'s ``placed``: one env, padded to a common
        vertex count, with bounding circles."""
        padded = pad_polygons(polygons)[None]
        centres = padded.mean(2)
        radii = np.linalg.norm(padded - centres[:, :, None], axis=-1).max(-1)[0]
        return padded, inward_normals(padded), centres, radii

    def draws(self, node: str, region, placed, reach, shift, fails, xy_draw, gaps=None):
        """Candidates of ``node`` in batches until one meets every rule (``candidates_fit``);
        its ``(x, y, yaw)`` and world footprint, or None after ``max_attempts``. Rejections
        are added to ``fails`` (per rule; the clearance among the candidates meeting the
        others). ``gaps``: the least gap to each of ``placed`` (None: the clearance)."""
        lim = self.limits
        foot = self.foot[node]
        radius = float(np.linalg.norm(foot, axis=1).max())
        tried = 0
        while tried < lim.max_attempts:
            b = min(lim.batch, lim.max_attempts - tried)
            tried += b
            yaw = self.rng.uniform(-np.pi, np.pi, b)
            xy = xy_draw(b)
            masks = candidates_fit(
                xy[None], yaw[None], foot, self.foot_normals[node], radius, region, placed,
                lim.clearance if gaps is None else gaps, reach, shift,
            )  # fmt: skip
            ok = np.ones(b, bool)
            for rule in ("inside", "in_band", "facing", "destination"):
                if rule in masks:
                    fails[rule] += int((~masks[rule][0]).sum())
                    ok &= masks[rule][0]
            clear = masks["clear"][0]
            fails["clear"] += int((ok & ~clear).sum())
            hits = np.flatnonzero(ok & clear)
            if len(hits):
                k = hits[0]
                found = float(xy[k, 0]), float(xy[k, 1]), float(yaw[k])
                return found, rotate(foot, yaw[k]) + xy[k]
        return None

    def sample_object(self, it: Standing, surface: Surface) -> LayoutPose:
        lim = self.limits
        region = surface.shrunk  # support_tree refused a support whose shrunk top vanishes
        lo, hi = region.min(0), region.max(0)
        normals, offsets = half_planes(region)
        reach = None
        if it.manipulated:
            robot = self.poses[self.layout.robot]
            yaw = np.array([robot.yaw])
            reach = (
                lim.reach_centre(np.array([robot.p[:2]]), yaw), yaw,
                (lim.reach_min, lim.reach_max), lim.max_heading_deg,
            )  # fmt: skip
        placed = self.placed([self.obstacles[i] for i in it.avoid]
                             + [self.destinations[i] for i in it.avoid_destinations]
                             + [self.rest[k] for k in it.avoid_rest])  # fmt: skip
        rules = ["inside", "in_band", "facing"] if reach else ["inside"]
        shift = it.shift if reach else None
        fails = dict.fromkeys(rules + (["destination"] if shift else []) + ["clear"], 0)
        found = self.draws(
            it.node, (normals[None], offsets[None]), placed, reach, shift, fails,
            lambda b: self.rng.uniform(lo, hi, (b, 2)), np.array(it.gaps),
        )  # fmt: skip
        if found is None:
            names = {
                "inside": "footprint inside parent top",
                "clear": "no overlap with placed footprints",
                "in_band": f"within ({lim.reach_min}, {lim.reach_max}) m of the robot base"
                + (f"'s pan axis, {lim.reach_origin} m ahead" if lim.reach_origin else ""),
                "facing": f"within {lim.max_heading_deg:g} deg of the robot heading",
                "destination": "its move's destination on the top, within reach and clear",
            }
            named = {names[k]: v for k, v in fails.items()}
            worst = max(named, key=named.get)
            raise PlacementError(it.node, worst, lim.max_attempts,
                                 f"rejections per constraint: {named}")  # fmt: skip
        (x, y, yaw), foot = found
        if shift is not None:  # the footprint where the move takes it, kept clear by the rest
            self.destinations[len(self.obstacles)] = foot + move_offset(shift, reach[1])[0]
        self.obstacles.append(foot)
        return LayoutPose.from_xyz_yaw([x, y, surface.z - it.min_z], yaw)

    def sample_floor_object(self, node: str, ctx_poly: np.ndarray) -> LayoutPose:
        """An object standing on the floor (z = 0) around the table (world footprint
        ``ctx_poly``), clear of everything."""
        lim = self.limits

        def disc(b: int) -> np.ndarray:
            r = lim.floor_radius * np.sqrt(self.rng.uniform(0, 1, b))
            t = self.rng.uniform(-np.pi, np.pi, b)
            return np.stack([r * np.cos(t), r * np.sin(t)], 1)

        fails = {"clear": 0}
        placed = self.placed([*self.obstacles, ctx_poly])
        found = self.draws(node, None, placed, None, None, fails, disc)
        if found is None:
            rule = "no overlap with placed footprints"
            raise PlacementError(node, rule, lim.max_attempts, str({rule: fails["clear"]}))
        (x, y, yaw), foot = found
        self.obstacles.append(foot)
        return LayoutPose.from_xyz_yaw([x, y, -self.min_z[node]], yaw)

    def run(self) -> dict[str, LayoutPose]:
        layout, lim, rng, tree = self.layout, self.limits, self.rng, self.tree
        # 1. background: random yaw about its up axis, at the origin
        self.poses[layout.background] = LayoutPose.from_xyz_yaw(
            [0, 0, 0], rng.uniform(-np.pi, np.pi)
        )
        # 2. context: random yaw, centred, lowest point at z = 0
        ctx = tree.context
        z0 = -key_bottom(tree.keys[ctx], lim.bottom_percentile)
        ctx_pose = LayoutPose.from_xyz_yaw([0, 0, z0], rng.uniform(-np.pi, np.pi))
        self.poses[ctx] = ctx_pose
        surfaces = {ctx: posed_top(tree.context_top, ctx_pose)}
        # 3. robot on the table's edge, facing its centre
        robot = robot_base_pose(surfaces[ctx], rng.uniform(0, 1))
        self.poses[layout.robot] = robot
        self.obstacles.append(square(np.array(robot.p), lim.robot_footprint, robot.yaw))
        # the arm at rest, a box per link (PlacementLimits.rest_arm), in the world
        self.rest = [rotate(box, np.float64(robot.yaw)) + np.array(robot.p[:2])
                     for box in lim.rest_polygons()]  # fmt: skip
        # 4. objects, breadth first from the table, larger footprints first
        for it in tree.items:
            self.poses[it.node] = pose = self.sample_object(it, surfaces[it.parent])
            surfaces[it.node] = posed_top(it.top, pose)
        floor_kids = [
            c
            for c, r in layout.children(layout.background)
            if r == "FLOOR" and c not in self.poses and c != layout.robot
        ]
        ctx_poly = rotate(self.foot[ctx], np.float64(ctx_pose.yaw))
        for kid in floor_kids:
            self.poses[kid] = self.sample_floor_object(kid, ctx_poly)
        missing = [n for n in layout.object_nodes() if n not in self.poses]
        if missing:
            raise PlacementError(
                missing[0],
                "reachable from the context or the floor in the tree",
                0,
                "the node has no ON/IN/INSIDE parent chain to the context",
            )
        return self.poses


def place(
    layout: LayoutInfo, seed: int | np.random.Generator, limits: PlacementLimits | None = None
) -> LayoutInfo:
    """Re-draw every pose of a layout: background yaw, table yaw, robot spot, objects.

    Args:
        layout: a validated layout (its asset folders must exist).
        seed: an int, or a ``numpy.random.Generator`` that every draw then comes from.
        limits: the placement limits (default: :class:`PlacementLimits`'s defaults).

    Returns:
        A new layout with the background, context, robot and object poses re-drawn.

    Raises:
        PlacementError: naming the object and the constraint that failed most often.
    """
    rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
    try:  # a pooled node is placed as its first member (a configuration draws one first)
        poses = _Placer(with_first_members(layout), rng, limits or PlacementLimits()).run()
    except PlacementError as e:
        if layout.source is None or e.source:
            raise
        raise e.with_source(str(layout.source)) from None
    return layout.with_poses(poses)


def derive_seed(base_seed: int, env_index: int) -> int:
    """Seed of env ``env_index``'s placement from a base seed (stable across machines)."""
    return int(
        np.random.SeedSequence([int(base_seed) % 2**63, int(env_index)]).generate_state(1)[0]
    )
