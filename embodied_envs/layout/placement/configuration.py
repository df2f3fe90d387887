"""Seeded, strict BFS placement of a layout's nodes.

``place(layout, seed)`` re-draws the poses of the background, the context (table), the robot and
every object, breadth first from the table and larger footprints first. Every draw comes from
one ``numpy.random.Generator`` made from the seed. Candidates are sampled in vectorised batches;
when an object cannot be placed a :class:`PlacementError` names it and the constraint that
rejected the most candidates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from embodied_envs.layout.assets import (
    ASSET_FILES,
    AssetGeometry,
    FileVersion,
    asset_geometry,
    convex_hull_2d,
    parse_urdf,
    urdf_path_for,
)
from embodied_envs.layout.errors import PlacementError
from embodied_envs.layout.limits import PlacementLimits
from embodied_envs.layout.pools import asset_pools, with_first_members
from embodied_envs.layout.pose import LayoutPose
from embodied_envs.layout.rules import (
    candidates_fit,
    half_planes,
    inward_normals,
    overlap,
    pad_polygons,
    rotate,
)
from embodied_envs.layout.schema import MAX_INTERPENETRATION, REST_TOLERANCE, LayoutInfo

SUPPORT_RELATIONS = ("ON", "IN", "INSIDE")


AssetKey = tuple[FileVersion, FileVersion]  # (URDF, collision mesh) of a node's asset


def asset_key(layout: LayoutInfo, node: str) -> AssetKey:
    """The versions of a node's URDF and collision mesh: the key of every value derived from
    its geometry (``ASSET_FILES``), so an edited file is read again."""
    urdf = FileVersion.of(str(urdf_path_for(Path(layout.asset_base, layout.assets[node]), node)))
    return urdf, FileVersion.of(_spec(urdf).collision.path)


def _spec(urdf: FileVersion):
    return ASSET_FILES.get(("urdf", urdf), lambda: parse_urdf(Path(urdf.path)))


def _geometry(key: AssetKey) -> AssetGeometry:
    return asset_geometry(_spec(key[0]), key[1])


def node_geometry(layout: LayoutInfo, node: str) -> AssetGeometry:
    """Collision geometry of a node's asset (parsed once per file version)."""
    return _geometry(asset_key(layout, node))


def _footprint(key: AssetKey) -> np.ndarray:
    return ASSET_FILES.get(("footprint", key), lambda: _geometry(key).footprint())


def _bottom(key: AssetKey, percentile: float) -> float:
    return ASSET_FILES.get(
        ("bottom", key, percentile),
        lambda: float(np.percentile(_geometry(key).vertices[:, 2], percentile)),
    )


def _top(key: AssetKey, band: float, margin: float):
    def compute():
        geom = _geometry(key)
        hull = geom.top_hull(band)
        try:
            shrunk = shrink_polygon(hull, margin)
        except ValueError:
            shrunk = None
        return hull, geom.max_z, shrunk

    return ASSET_FILES.get(("top", key, band, margin), compute)


def local_top(layout: LayoutInfo, node: str, band: float, margin: float):
    """The top of a node's asset in its own actor frame: ``(hull, top_z, shrunk hull or None)``."""
    return _top(asset_key(layout, node), band, margin)


def support_order(layout: LayoutInfo) -> list[tuple[str, str]]:
    """``(node, parent)`` of every object standing on the context or on another object, in
    placement order: breadth first from the context, larger footprints first."""
    order: list[tuple[str, str]] = []
    queue = [layout.context]
    while queue:
        parent = queue.pop(0)
        kids = [
            c for c, r in layout.children(parent) if r in SUPPORT_RELATIONS and c != layout.robot
        ]
        kids.sort(key=lambda n: -polygon_area(node_footprint(layout, n)))
        order += [(kid, parent) for kid in kids]
        queue += kids
    return order


def _surface_at(key: AssetKey, pose: LayoutPose, band: float, margin: float) -> Surface:
    """The top surface of an asset (``asset_key``) standing upright at ``pose`` (yaw only).

    Shrinking commutes with rotation and translation, so the shrunk hull is computed once per
    asset in its own frame.
    """
    hull, top_z, shrunk = _top(key, band, margin)
    yaw, xy = np.float64(pose.yaw), np.asarray(pose.p[:2])
    return Surface(
        rotate(hull, yaw) + xy,
        top_z + pose.p[2],
        None if shrunk is None else rotate(shrunk, yaw) + xy,
    )


def node_footprint(layout: LayoutInfo, node: str) -> np.ndarray:
    """2D convex footprint ``(m, 2)`` of a node in its own actor frame (counter-clockwise)."""
    return _footprint(asset_key(layout, node))


def polygon_area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def polygon_centroid(poly: np.ndarray) -> np.ndarray:
    """Area centroid of a simple polygon."""
    x, y = poly[:, 0], poly[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = cross.sum() / 2.0
    if abs(area) < 1e-12:
        return poly.mean(axis=0)
    return np.array([((x + xn) * cross).sum(), ((y + yn) * cross).sum()]) / (6.0 * area)


def shrink_polygon(poly: np.ndarray, margin: float) -> np.ndarray:
    """The CCW convex polygon moved inward by ``margin`` on every edge."""
    n, c = half_planes(poly)
    c = c + margin
    n0, c0 = np.roll(n, 1, axis=0), np.roll(c, 1)  # edge i-1 meets edge i at vertex i
    det = n0[:, 0] * n[:, 1] - n0[:, 1] * n[:, 0]
    ok = np.abs(det) > 1e-12
    x = (c0 * n[:, 1] - n0[:, 1] * c)[ok] / det[ok]
    y = (n0[:, 0] * c - c0 * n[:, 0])[ok] / det[ok]
    pts = np.stack([x, y], 1)
    keep = np.all(pts @ n.T >= c - 1e-9, axis=1) if len(pts) else np.zeros(0, bool)
    if keep.sum() < 3:
        raise ValueError(f"polygon vanishes when shrunk by {margin} m")
    return convex_hull_2d(pts[keep])


def square(center: np.ndarray, side: float, yaw: float) -> np.ndarray:
    h = side / 2.0
    local = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    return rotate(local, np.float64(yaw)) + center[:2]


@dataclass(frozen=True)
class Surface:
    """The top of a placed support: its hull (world XY, CCW), height, and the hull shrunk by
    the placement margin (None when the top is too small to shrink)."""

    hull: np.ndarray
    z: float
    shrunk: np.ndarray | None = None


def world_vertices(geom: AssetGeometry, pose: LayoutPose) -> np.ndarray:
    return pose.transform_points(geom.vertices)


def top_surface(vertices: np.ndarray, band: float) -> Surface:
    top_z = float(vertices[:, 2].max())
    top = vertices[vertices[:, 2] >= top_z - band]
    return Surface(convex_hull_2d(top[:, :2]), top_z)


def robot_base_pose(top: Surface, u: float) -> LayoutPose:
    """Robot base on the shrunk top's boundary at perimeter fraction ``u``, facing the centre."""
    if top.shrunk is None:
        raise PlacementError(
            "robot",
            "on the table top's shrunk boundary",
            0,
            "the table top is smaller than twice the hull margin",
        )
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
        self.poses: dict[str, LayoutPose] = {}
        self.obstacles: dict[str, np.ndarray] = {}  # node -> world footprint polygon
        # resolve each node's asset once per call (file lookups are the slow part)
        self.keys = {n: asset_key(layout, n) for n in layout.object_nodes()}
        self.foot = {n: _footprint(k) for n, k in self.keys.items()}
        self.foot_normals = {n: inward_normals(f) for n, f in self.foot.items()}
        self.min_z = {n: _geometry(k).min_z for n, k in self.keys.items()}

    def placed(self, nodes: list[str], extra: list[np.ndarray] = ()) -> tuple:
        """The world footprints of ``nodes`` (and ``extra`` polygons) as ``candidates_fit``'s
        ``placed``: one env, padded to a common vertex count, with bounding circles."""
        padded = pad_polygons([self.obstacles[n] for n in nodes] + list(extra))[None]
        centres = padded.mean(2)
        radii = np.linalg.norm(padded - centres[:, :, None], axis=-1).max(-1)[0]
        return padded, inward_normals(padded), centres, radii

    def draws(self, node: str, region, placed, reach, fails, xy_draw):
        """Candidates of ``node`` in batches until one meets every rule (``candidates_fit``);
        its ``(x, y, yaw)``, or None after ``max_attempts``. Rejections are added to ``fails``
        (per rule; the clearance among the candidates meeting the others)."""
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
                lim.clearance, reach,
            )  # fmt: skip
            ok = np.ones(b, bool)
            for rule in ("inside", "in_band", "facing"):
                if rule in masks:
                    fails[rule] += int((~masks[rule][0]).sum())
                    ok &= masks[rule][0]
            clear = masks["clear"][0]
            fails["clear"] += int((ok & ~clear).sum())
            hits = np.flatnonzero(ok & clear)
            if len(hits):
                k = hits[0]
                self.obstacles[node] = rotate(foot, yaw[k]) + xy[k]
                return float(xy[k, 0]), float(xy[k, 1]), float(yaw[k])
        return None

    def sample_object(
        self, node: str, parent: str, surface: Surface, ancestors: set[str]
    ) -> LayoutPose:
        lim = self.limits
        layout = self.layout
        region = surface.shrunk
        if region is None:
            raise PlacementError(
                node,
                "footprint inside parent top",
                0,
                "the parent's top is smaller than twice the hull margin",
            )
        lo, hi = region.min(0), region.max(0)
        normals, offsets = half_planes(region)
        reach = None
        if node in layout.manipulated_objs:
            robot = self.poses[layout.robot]
            reach = (
                np.array([robot.p[:2]]), np.array([robot.yaw]),
                (lim.reach_min, lim.reach_max), lim.max_heading_deg,
            )  # fmt: skip
        placed = self.placed([n for n in self.obstacles if n not in ancestors])
        fails = dict.fromkeys(["inside", "in_band", "facing", "clear"] if reach else
                              ["inside", "clear"], 0)  # fmt: skip
        found = self.draws(
            node, (normals[None], offsets[None]), placed, reach, fails,
            lambda b: self.rng.uniform(lo, hi, (b, 2)),
        )  # fmt: skip
        if found is None:
            names = {
                "inside": "footprint inside parent top",
                "clear": "no overlap with placed footprints",
                "in_band": f"within ({lim.reach_min}, {lim.reach_max}) m of the robot base",
                "facing": f"within {lim.max_heading_deg:g} deg of the robot heading",
            }
            named = {names[k]: v for k, v in fails.items()}
            worst = max(named, key=named.get)
            raise PlacementError(node, worst, lim.max_attempts,
                                 f"rejections per constraint: {named}")  # fmt: skip
        x, y, yaw = found
        return LayoutPose.from_xyz_yaw([x, y, surface.z - self.min_z[node]], yaw)

    def sample_floor_object(self, node: str, ctx_poly: np.ndarray) -> LayoutPose:
        """An object standing on the floor (z = 0) around the table (world footprint
        ``ctx_poly``), clear of everything."""
        lim = self.limits

        def disc(b: int) -> np.ndarray:
            r = lim.floor_radius * np.sqrt(self.rng.uniform(0, 1, b))
            t = self.rng.uniform(-np.pi, np.pi, b)
            return np.stack([r * np.cos(t), r * np.sin(t)], 1)

        fails = {"clear": 0}
        placed = self.placed(list(self.obstacles), [ctx_poly])
        found = self.draws(node, None, placed, None, fails, disc)
        if found is None:
            rule = "no overlap with placed footprints"
            raise PlacementError(node, rule, lim.max_attempts, str({rule: fails["clear"]}))
        x, y, yaw = found
        return LayoutPose.from_xyz_yaw([x, y, -self.min_z[node]], yaw)

    def run(self) -> dict[str, LayoutPose]:
        layout, lim, rng = self.layout, self.limits, self.rng
        # 1. background: random yaw about its up axis, at the origin
        self.poses[layout.background] = LayoutPose.from_xyz_yaw(
            [0, 0, 0], rng.uniform(-np.pi, np.pi)
        )
        # 2. context: random yaw, centred, lowest point at z = 0
        ctx = layout.context
        z0 = -_bottom(self.keys[ctx], lim.bottom_percentile)
        ctx_pose = LayoutPose.from_xyz_yaw([0, 0, z0], rng.uniform(-np.pi, np.pi))
        self.poses[ctx] = ctx_pose
        surfaces = {ctx: _surface_at(self.keys[ctx], ctx_pose, lim.top_band, lim.hull_margin)}
        # 3. robot on the table's edge, facing its centre
        robot = robot_base_pose(surfaces[ctx], rng.uniform(0, 1))
        self.poses[layout.robot] = robot
        self.obstacles[layout.robot] = square(np.array(robot.p), lim.robot_footprint, robot.yaw)
        # 4. objects, breadth first from the table, larger footprints first
        ancestors = {ctx: {ctx}}
        for kid, parent in support_order(layout):
            self.poses[kid] = self.sample_object(kid, parent, surfaces[parent], ancestors[parent])
            surfaces[kid] = _surface_at(
                self.keys[kid], self.poses[kid], lim.top_band, lim.hull_margin
            )
            ancestors[kid] = ancestors[parent] | {kid}
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


def floor_height(layout: LayoutInfo) -> float:
    """The floor's height: the lowest point of the objects standing ``FLOOR`` (the file's poses
    keep it within ``REST_TOLERANCE`` of z = 0), or 0 when nothing does."""
    objects = set(layout.object_nodes())
    lows = [
        float(world_vertices(node_geometry(layout, child), layout.pose(child))[:, 2].min())
        for parent in layout.tree
        for child, relation in layout.children(parent)
        if relation == "FLOOR" and child in objects
    ]
    return min(lows, default=0.0)


def check_file_poses(layout: LayoutInfo) -> list[str]:
    """Problems of a layout's own poses that the simulator would act out badly (asset pools'
    nodes are left out: their poses are always drawn, for the member drawn).

    - an object ``ON`` a parent has its lowest point within ``REST_TOLERANCE`` of the parent's
      top, its origin over the parent's top hull (grown by the tolerance); ``IN`` / ``INSIDE``
      between the parent's bottom and top; a ``FLOOR`` object on z = 0;
    - footprints of objects on the same parent overlap at most ``MAX_INTERPENETRATION`` deep.
    """
    f = layout.source or "<layout>"
    tol = REST_TOLERANCE
    problems = []
    objects = set(layout.object_nodes()) - set(asset_pools(layout))
    world = {n: world_vertices(node_geometry(layout, n), layout.pose(n)) for n in objects}
    for parent in [*layout.tree]:
        kids = [(c, r) for c, r in layout.children(parent) if c in objects and c != parent]
        for child, relation in kids:
            low = float(world[child][:, 2].min())
            where = f'{f}: position["{child}"]'
            if relation == "FLOOR" or parent not in objects:
                if abs(low) > tol and relation == "FLOOR":
                    problems.append(
                        f"{where}: its lowest point is at z = {low:.3f} m, not on the floor "
                        f"(z = 0 within {tol} m). Fix: set z so that it stands on the floor."
                    )
                continue
            top = top_surface(world[parent], PlacementLimits().top_band)
            bottom = float(world[parent][:, 2].min())
            if relation == "ON":
                ok, want = abs(low - top.z) <= tol, f'the top of "{parent}" (z = {top.z:.3f})'
            else:
                ok = bottom - tol <= low <= top.z + tol
                want = f'inside "{parent}" (z {bottom:.3f} to {top.z:.3f})'
            if not ok:
                problems.append(
                    f"{where}: its lowest point is at z = {low:.3f} m, not on {want} within "
                    f"{tol} m. Fix: set its z so that it rests on its parent, or pass "
                    "replace_objs=True and let the placement re-draw it."
                )
            normals, offsets = half_planes(top.hull)
            xy = np.asarray(layout.pose(child).p[:2])
            if len(top.hull) >= 3 and not np.all(normals @ xy >= offsets - tol):
                problems.append(
                    f'{where}: it stands off the top of "{parent}" (x, y = {xy.round(3).tolist()}).'
                    " Fix: move it over its parent, or pass replace_objs=True."
                )
        feet = {c: convex_hull_2d(world[c][:, :2]) for c, r in kids if r == "ON"}
        names = sorted(feet)
        for i, a in enumerate(names):
            for b in names[i + 1 :]:
                if len(feet[a]) >= 3 and len(feet[b]) >= 3:
                    pa, pb = feet[a], feet[b]
                    normals_a, normals_b = inward_normals(pa), inward_normals(pb)
                    if overlap(pa, pb, -MAX_INTERPENETRATION, normals_a, normals_b):
                        problems.append(
                            f'{f}: position["{a}"] and position["{b}"]: their footprints '
                            f"overlap by more than {MAX_INTERPENETRATION} m. Fix: move them "
                            "apart, or pass replace_objs=True."
                        )
    problems += _check_robot_pose(layout, world)
    return problems


ROBOT_REST_TOLERANCE = 0.05  # m, the robot base's height off the top of its table
ROBOT_EDGE_DISTANCE = 0.25  # m, the robot base's distance from the table top's edge


def _check_robot_pose(layout: LayoutInfo, world: dict[str, np.ndarray]) -> list[str]:
    """The robot stands on its table's edge at the top's height (as EmbodiedGen and
    ``place`` put it): not floating, not sunk into the table or under the floor, not away from
    the table, where the task would be silently impossible."""
    ctx = layout.context
    if ctx not in world:
        return []
    top = top_surface(world[ctx], PlacementLimits().top_band)
    robot = layout.pose(layout.robot)
    where = f'{layout.source or "<layout>"}: position["{layout.robot}"]'
    z = float(robot.p[2])
    if abs(z - top.z) > ROBOT_REST_TOLERANCE:
        return [
            f"{where}: the robot base is at z = {z:.3f} m, {z - top.z:+.3f} m from the top of "
            f'"{ctx}" (z = {top.z:.3f}); it must stand at the top\'s height (within '
            f"{ROBOT_REST_TOLERANCE} m) on its edge. Fix: set its z to {top.z:.3f}, or let "
            "`embodied-envs layout generate` place it."
        ]
    if len(top.hull) < 3:
        return []
    normals, offsets = half_planes(top.hull)
    inward = float((normals @ np.asarray(robot.p[:2]) - offsets).min())  # < 0: outside
    if abs(inward) > ROBOT_EDGE_DISTANCE:
        side = "inside" if inward > 0 else "outside"
        return [
            f"{where}: the robot base is {abs(inward):.3f} m {side} the edge of the top of "
            f'"{ctx}"; it must stand on the edge (within {ROBOT_EDGE_DISTANCE} m). Fix: move '
            "it to the table's edge, or let `embodied-envs layout generate` place it."
        ]
    return []


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
