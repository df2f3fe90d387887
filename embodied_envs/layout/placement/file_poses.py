"""Checks of a layout file's own poses (``load_layout``): what the simulator would act out
badly, each problem one line naming the file, the node and the fix; and the floor's height."""

from __future__ import annotations

import numpy as np

from embodied_envs.layout.assets import convex_hull_2d
from embodied_envs.layout.placement.geometry import node_geometry, top_surface, world_vertices
from embodied_envs.layout.placement.limits import PlacementLimits
from embodied_envs.layout.placement.rules import half_planes, inward_normals, overlap
from embodied_envs.layout.pools import asset_pools
from embodied_envs.layout.schema import MAX_INTERPENETRATION, REST_TOLERANCE, LayoutInfo


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
