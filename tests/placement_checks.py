"""Placement constraints checked independently of the placement code (shapely, trimesh).

The numbers are :class:`PlacementLimits`' (one definition of each rule's limit); the geometry
is computed here, without the placement helpers."""

import functools
import math

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation
from shapely.geometry import MultiPoint, Point

from embodied_envs.layout import LayoutPose, PlacementLimits, parse_urdf


@functools.lru_cache(maxsize=64)
def _collision_vertices(urdf) -> np.ndarray:
    spec = parse_urdf(urdf)
    mesh = trimesh.load(spec.collision.path, force="mesh", process=False)
    v = np.asarray(mesh.vertices) @ Rotation.from_euler("xyz", spec.collision.rpy).as_matrix().T
    return v + np.asarray(spec.collision.xyz)


def world_points(layout, node):
    """Collision vertices of a node in the world, computed without the placement helpers."""
    v = _collision_vertices(layout.urdf_path(node))
    x, y, z, qx, qy, qz, qw = layout.position[node]
    return v @ Rotation.from_quat([qx, qy, qz, qw]).as_matrix().T + [x, y, z]


def check_constraints(layout, limits: PlacementLimits | None = None):
    """Every placement constraint, checked with shapely; returns a list of violations."""
    lim = limits or PlacementLimits()
    bad = []
    table = world_points(layout, layout.context)
    top_z = table[:, 2].max()
    top = MultiPoint(table[table[:, 2] >= top_z - lim.top_band][:, :2].tolist()).convex_hull
    inner = top.buffer(-lim.hull_margin + 1e-6)
    if abs(np.percentile(table[:, 2], lim.bottom_percentile)) > 1e-6:
        bad.append("table bottom not at z=0")
    rx, ry, rz = layout.position[layout.robot][:3]
    rq = layout.position[layout.robot][3:]
    heading = Rotation.from_quat(rq).apply([1, 0, 0])
    if not math.isclose(top.exterior.distance(Point(rx, ry)), lim.hull_margin, abs_tol=1e-4):
        bad.append("robot not on the shrunk hull boundary")
    if abs(rz - top_z) > 1e-6:
        bad.append("robot not at table-top height")
    to_centre = np.array(top.centroid.coords[0]) - [rx, ry]
    cos = np.dot(heading[:2], to_centre) / np.linalg.norm(heading[:2]) / np.linalg.norm(to_centre)
    if cos < math.cos(math.radians(5)):
        bad.append("robot does not face the table centre")
    half = lim.robot_footprint / 2
    c, s = heading[0] / np.hypot(*heading[:2]), heading[1] / np.hypot(*heading[:2])
    robot_sq = MultiPoint(
        [(rx + c * a - s * b, ry + s * a + c * b) for a in (-half, half) for b in (-half, half)]
    ).convex_hull
    feet = {"robot": robot_sq}
    cx, cy = rx + c * lim.reach_origin, ry + s * lim.reach_origin  # the reach band's centre
    # the arm at rest, a box per link (PlacementLimits.rest_arm), in the world
    def world(xs, ys):  # a box in the robot's frame, in the world
        return MultiPoint([(rx + c * a - s * b, ry + s * a + c * b) for a in xs for b in ys])

    rest = [(world(box[:2], box[2:4]).convex_hull, box[4]) for box in lim.rest_arm or ()]
    destinations = {}
    shift = layout.task.shift()  # a move's destination from each mover's start, robot frame
    if shift is not None:
        dx, dy = c * shift[0] - s * shift[1], s * shift[0] + c * shift[1]
    for node in layout.object_nodes():
        if node == layout.context:
            continue
        pts = world_points(layout, node)
        foot = MultiPoint(pts[:, :2].tolist()).convex_hull
        if not inner.buffer(1e-6).contains(foot):
            bad.append(f"{node} footprint leaves the shrunk table top")
        if abs(pts[:, 2].min() - top_z) > 1e-6:
            bad.append(f"{node} does not rest on the table top ({pts[:, 2].min() - top_z:+.4f})")
        for other, f in feet.items():  # wider beside a mover (PlacementLimits.gap)
            gap = lim.gap(node, None if other == "robot" else other, layout.task.objects)
            if foot.distance(f) < gap - 1e-6:
                bad.append(f"{node} overlaps {other}")
        for k, (box, z0) in enumerate(rest):  # as tall as a link at rest: clear of its box
            if pts[:, 2].max() - top_z + lim.rest_clearance > z0 and (
                foot.distance(box) < lim.rest_clearance - 1e-6
            ):
                tall = pts[:, 2].max() - top_z
                bad.append(f"{node} ({tall:.3f} m tall) under the arm's link {k}")
        feet[node] = foot
        if shift is not None and node in layout.task.objects:  # where the move takes it
            there = MultiPoint((pts[:, :2] + [dx, dy]).tolist()).convex_hull
            if not inner.buffer(1e-6).contains(there):
                bad.append(f"{node}'s destination leaves the shrunk table top")
            ox, oy = np.asarray(layout.position[node][:2]) + [dx, dy]
            d = math.hypot(ox - cx, oy - cy)
            if not lim.reach_min < d < lim.reach_max:
                bad.append(f"{node}'s destination at {d:.3f} m from the robot")
            destinations[node] = there
        if node in layout.manipulated_objs:
            ox, oy = layout.position[node][:2]
            d = math.hypot(ox - cx, oy - cy)
            if not lim.reach_min < d < lim.reach_max:
                bad.append(f"{node} at {d:.3f} m from the robot")
            ang = math.degrees(
                abs(math.atan2(oy - cy, ox - cx) - math.atan2(heading[1], heading[0]))
            )
            ang = min(ang, 360 - ang)
            if ang > lim.max_heading_deg + 1e-6:
                bad.append(f"{node} at {ang:.1f} deg off the robot heading")
    for node, there in destinations.items():  # a move's destination is free
        for other, f in feet.items():
            gap = lim.gap(node, None if other == "robot" else other, layout.task.objects)
            if other != node and there.distance(f) < gap - 1e-6:
                bad.append(f"{node}'s destination overlaps {other}")
        for other, f in destinations.items():
            gap = lim.gap(node, other, layout.task.objects)
            if other < node and there.distance(f) < gap - 1e-6:
                bad.append(f"{node}'s destination overlaps {other}'s")
    return bad


def object_poses(u, env=0) -> dict[str, np.ndarray]:
    """Raw poses of env ``env``'s objects (everything but the table) now."""
    layout = u.layouts[env]
    return {
        node: u.env_actors[f"env{env}"][node].pose.raw_pose[0].cpu().numpy()
        for node in layout.object_nodes()
        if node != layout.context
    }


def episode_layout(u, env=0):
    """Env ``env``'s configuration with its objects where they stand now."""
    poses = {}
    for node, (x, y, z, qw, qx, qy, qz) in object_poses(u, env).items():
        poses[node] = LayoutPose.from_layout([x, y, z - u.objs_z_offset, qx, qy, qz, qw])
    return u.layouts[env].with_poses(poses)
