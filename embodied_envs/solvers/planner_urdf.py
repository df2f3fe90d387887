"""A robot's URDF as mplib's planner takes it.

mplib's parser (urdfdom) refuses a joint ``<limit>`` without ``effort`` and ``velocity``, and
its planner loads each collision mesh's convex hull from ``<mesh>.convex.stl`` beside it.
ManiSkill 3.0.1's Koch has neither: :func:`planner_urdf` writes a copy that has both (the
limits' effort and velocity, which PhysX and the planner ignore; the hulls by trimesh) in the
temporary folder. Other robots' URDFs are used as they are.
"""

from __future__ import annotations

import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import trimesh


def planner_urdf(path: str) -> str:
    """``path``, a robot's URDF, or where it has a limit without effort or velocity, its copy
    for mplib (its SRDF copied beside it)."""
    src = Path(path)
    tree = ET.parse(src)
    bare = [lim for lim in tree.iter("limit") if "effort" not in lim.attrib]
    if not bare:
        return path
    out = Path(tempfile.gettempdir()) / "embodied_envs_urdf" / src.parent.name
    urdf = out / src.name
    if urdf.exists():
        return str(urdf)
    (out / "meshes").mkdir(parents=True, exist_ok=True)
    for lim in bare:
        lim.set("effort", "100")
        lim.set("velocity", "10")
    for kind in ("visual", "collision"):
        for k, mesh in enumerate(tree.findall(f"./link/{kind}/geometry/mesh")):
            name = mesh.get("filename")
            file = (
                src.parent.parent / name[len("package://") :]
                if name.startswith("package://")
                else src.parent / name
            )
            local = f"meshes/{kind}{k}_{file.name}"
            mesh.set("filename", local)
            hull = trimesh.load(file, force="mesh").convex_hull
            if not hull.is_watertight:  # a thin plate (the Koch's link_3 part 4): its box
                hull = hull.bounding_box_oriented
            hull.export(out / local)  # the file mplib's parser opens
            if kind == "collision":
                hull.export(out / f"{local}.convex.stl")  # the hull its planner loads
    tree.write(urdf)
    srdf = src.with_suffix(".srdf")
    if srdf.exists():
        urdf.with_suffix(".srdf").write_text(srdf.read_text())
    return str(urdf)
