"""Objects an arm cannot take at all, refused at ``gym.make`` in one line.

A parallel gripper takes an object only across some width that fits between its open jaws: a
convex body's narrowest width is the least, over its hull's face normals, of its extent along
the normal. An object the task moves (every mover of ``layout.task``: a manipulated object, or
a distractor the sentence names) whose convex hull is wider than the robot's gripper opens
(``robots.Gripper.max_opening``) everywhere cannot be grasped by that robot; the env says so
before anything is simulated, naming the layout, the object and both widths. Likewise an object
heavier than the robot's arm holds up at the end of its reach (``robots.Robot.payload``: its
drives' force limit), naming the object's mass and the limit.
"""

from __future__ import annotations

import numpy as np

from embodied_envs.layout import LayoutError
from embodied_envs.layout.assets import DEFAULT_DENSITY, AssetSpec, asset_geometry
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


def asset_mass(spec: AssetSpec) -> float:
    """The object's mass (kg) as the scene builds it: the URDF's, else 1000 kg/m^3 over its
    collision volume (``scene/builder.py``)."""
    return spec.mass if spec.mass is not None else DEFAULT_DENSITY * asset_geometry(spec).volume


def check_graspable(layout_set: LayoutSet, robot: Robot) -> None:
    """Every object the task of every layout (and pool member) moves fits ``robot``'s open jaws
    somewhere and weighs at most what its arm holds up (``Robot.payload``).

    Raises:
        LayoutError: naming the layout file, the object, its narrowest width and the opening,
            or its mass and the payload.
    """
    opening, payload = robot.gripper.max_opening, robot.payload
    for layout in layout_set.members():
        for node in layout.task.objects:  # the movers, wherever the layout lists them
            spec = layout.asset_spec(node)
            what = "manipulated object" if node in layout.manipulated_objs else "task's mover"
            if payload is not None and (mass := asset_mass(spec)) > payload:
                raise LayoutError(
                    f"{layout.source}: the {what} {node!r} weighs {mass:.3g} kg; "
                    f"{robot.uid}'s arm holds up at most {payload:.3g} kg at its reach (its "
                    "drives' force limit, embodied_envs/robots.py), so it cannot lift it. Fix: "
                    "a lighter object (its URDF's inertial/mass), or a stronger robot "
                    "(relation.robot or robot_uids=)"
                )
            width = narrowest_width(asset_geometry(spec).vertices)
            if width > opening:
                raise LayoutError(
                    f"{layout.source}: the {what} {node!r} is {width * 100:.1f} cm "
                    f"across at its narrowest; {robot.uid}'s jaws open {opening * 100:.1f} cm "
                    "(embodied_envs/robots.py), so it cannot grasp it. Fix: a smaller object, "
                    "or a robot with a wider gripper (relation.robot or robot_uids=)"
                )
