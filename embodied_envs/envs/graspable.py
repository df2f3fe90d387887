"""Objects an arm cannot take at all, refused at ``gym.make`` in one line.

A parallel gripper takes an object only across some width that fits between its open jaws: a
convex body's narrowest width is the least, over its hull's face normals, of its extent along
the normal. A manipulated object whose convex hull is wider than the robot's gripper opens
(``robots.Gripper.max_opening``) everywhere cannot be grasped by that robot; the env says so
before anything is simulated, naming the layout, the object and both widths.
"""

from __future__ import annotations

import numpy as np

from embodied_envs.layout import LayoutError
from embodied_envs.layout.assets import asset_geometry
from embodied_envs.layout.sets import LayoutSet
from embodied_envs.robots import Robot


def narrowest_width(vertices: np.ndarray) -> float:
    """The least width (m) of the convex hull of ``vertices (n, 3)`` over its face normals."""
    from scipy.spatial import ConvexHull, QhullError  # only where a layout is checked

    try:
        hull = ConvexHull(vertices)
    except QhullError:  # flat: no width at all
        return 0.0
    normals = hull.equations[:, :3]
    along = vertices @ normals.T  # (n, f)
    return float((along.max(0) - along.min(0)).min())


def check_graspable(layout_set: LayoutSet, robot: Robot) -> None:
    """Every manipulated object of every layout (and pool member) fits ``robot``'s open jaws
    somewhere.

    Raises:
        LayoutError: naming the layout file, the object, its narrowest width and the opening.
    """
    opening = robot.gripper.max_opening
    for layout in layout_set.members():
        for node in layout.manipulated_objs:
            width = narrowest_width(asset_geometry(layout.asset_spec(node)).vertices)
            if width > opening:
                raise LayoutError(
                    f"{layout.source}: the manipulated object {node!r} is {width * 100:.1f} cm "
                    f"across at its narrowest; {robot.uid}'s jaws open {opening * 100:.1f} cm "
                    "(embodied_envs/robots.py), so it cannot grasp it. Fix: a smaller object, "
                    "or a robot with a wider gripper (relation.robot or robot_uids=)"
                )
