#!/usr/bin/env python
"""Make the grasp zoo: odd shapes as EmbodiedGen-format assets, and a layout around each.

Each shape is a union of convex parts (boxes, cylinders, spheres) written as EmbodiedGen writes
an asset: ``<name>/<name>.urdf`` with ``mesh/<name>.obj`` (visual) and
``mesh/<name>_collision.obj`` (one OBJ object per convex part, as SAPIEN splits it), meshes Y-up
turned Z-up by the URDF's ``<origin rpy="1.5708 0 0">``. Each layout is the shipped default
scene (table, room, distractors) with the shape as its target. Sizes fit the Panda's 8 cm
opening somewhere on every shape.

Usage: python tools/make/make_grasp_zoo.py [--out tests/data/zoo]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
from pathlib import Path

import trimesh
from make_assets import urdf_text, write_obj  # tools/make/: one object per part, Y-up

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "embodied_envs" / "data"
ZOO = ROOT / "tests" / "data" / "zoo"  # the shipped zoo: the tests' and benchmarks' data
SEGMENTS = 24  # sides of a cylinder part
TABLE_TOP = 0.760  # m, the default layout's table top (every shape's lowest point is z = 0)


def box(size, centre=(0, 0, 0), yaw=0.0, pitch=0.0) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=size)
    rot = trimesh.transformations.euler_matrix(0.0, pitch, yaw)
    m.apply_transform(rot)
    m.apply_translation(centre)
    return m


def cylinder(radius, height, centre=(0, 0, 0), axis="z", sections=SEGMENTS) -> trimesh.Trimesh:
    m = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    if axis == "x":
        m.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))
    elif axis == "y":
        m.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [1, 0, 0]))
    m.apply_translation(centre)
    return m


def arc_of_boxes(radius, thickness, height, start, stop, n, z=0.0) -> list[trimesh.Trimesh]:
    """Boxes along a circular arc (angles in radians), each tangent to it."""
    parts = []
    step = (stop - start) / n
    chord = 2 * radius * math.sin(step / 2) + 0.004  # overlap a little: one solid
    for k in range(n):
        a = start + (k + 0.5) * step
        centre = (radius * math.cos(a), radius * math.sin(a), z)
        parts.append(box((thickness, chord, height), centre, yaw=a))
    return parts


def shapes() -> dict[str, tuple[list[trimesh.Trimesh], float, str]]:
    """name -> (convex parts in the object's Z-up frame, mass kg, description)."""
    h = {}
    h["ring"] = (arc_of_boxes(0.04, 0.018, 0.018, 0, 2 * math.pi, 12, 0.009), 0.08,
                 "a flat ring")  # fmt: skip
    wall = arc_of_boxes(0.034, 0.007, 0.09, 0, 2 * math.pi, 14, 0.045)
    handle = [
        box((0.03, 0.012, 0.012), (0.049, 0.0, 0.075)),
        box((0.012, 0.012, 0.062), (0.062, 0.0, 0.045)),
        box((0.03, 0.012, 0.012), (0.049, 0.0, 0.015)),
    ]
    h["handled_cup"] = (wall + handle + [cylinder(0.034, 0.008, (0, 0, 0.004))], 0.25,
                "a mug with a handle")  # fmt: skip
    tilt = math.radians(35)
    rim = []
    for k in range(16):
        a = (k + 0.5) * 2 * math.pi / 16
        r = 0.055
        rim.append(
            box(
                (0.008, 0.024, 0.045), (r * math.cos(a), r * math.sin(a), 0.022), yaw=a, pitch=tilt
            )  # fmt: skip
        )
    h["shallow_bowl"] = (rim + [cylinder(0.045, 0.008, (0, 0, 0.004))], 0.2, "a shallow bowl")
    h["l_bracket"] = (
        [
            box((0.12, 0.03, 0.03), (0.0, 0.0, 0.015)),
            box((0.03, 0.09, 0.03), (-0.045, 0.06, 0.015)),
        ],
        0.15,
        "an L-shaped bracket",
    )
    h["t_shape"] = (
        [box((0.14, 0.03, 0.03), (0.0, 0.05, 0.015)), box((0.03, 0.1, 0.03), (0.0, -0.015, 0.015))],
        0.15,
        "a T-shaped block",
    )
    h["arc"] = (arc_of_boxes(0.1, 0.03, 0.03, math.radians(-50), math.radians(50), 8, 0.015),
                0.12, "a curved bar")  # fmt: skip
    h["rod"] = ([cylinder(0.011, 0.22, (0, 0, 0.011), axis="x")], 0.08, "a long thin rod")
    h["bottle"] = (
        [cylinder(0.03, 0.16, (0, 0, 0.08)), cylinder(0.014, 0.06, (0, 0, 0.19))],
        0.3,
        "a tall bottle",
    )
    h["ball"] = ([trimesh.creation.icosphere(subdivisions=2, radius=0.022)], 0.05, "a small ball")
    h["ball"][0][0].apply_translation((0, 0, 0.022))
    h["slab"] = ([box((0.13, 0.06, 0.018), (0, 0, 0.009))], 0.2, "a flat slab")
    h["side_can"] = ([cylinder(0.028, 0.11, (0, 0, 0.028), axis="y")], 0.15,
                     "a can lying on its side")  # fmt: skip
    h["small_cube"] = ([box((0.028, 0.028, 0.028), (0, 0, 0.014))], 0.04, "a small cube")
    h["big_ball"] = ([trimesh.creation.icosphere(subdivisions=2, radius=0.03)], 0.1, "a big ball")
    h["big_ball"][0][0].apply_translation((0, 0, 0.03))
    h["wheel"] = ([cylinder(0.04, 0.015, (0, 0, 0.04), axis="y")], 0.1,
                  "a wheel standing on its edge")  # fmt: skip
    return h


def write_asset(folder: Path, name: str, parts: list[trimesh.Trimesh], mass: float) -> None:
    """The asset's files; each convex part is one object (``o``) of the OBJ files, which is
    how SAPIEN splits a collision mesh into convex shapes."""
    (folder / "mesh").mkdir(parents=True)
    hulls = [p.convex_hull for p in parts]
    write_obj(folder / "mesh" / f"{name}_collision.obj", [(h, None) for h in hulls], None)
    write_obj(folder / "mesh" / f"{name}.obj", [(h, None) for h in hulls], None)
    (folder / f"{name}.urdf").write_text(urdf_text(name, (0.7, 0.6), mass))


def write_layout(
    path: Path, name: str, desc: str, assets: Path, shipped: Path | None = None
) -> None:
    """The shipped default scene graded on the shape (in place of the can); ``shipped`` is the
    shipped assets' folder as the layout names it (default: relative to the shipped zoo's
    layouts, the same text under any --out)."""
    data = json.loads((DATA / "layouts" / "default.json").read_text())
    rel = data["relation"]
    rel["manipulated_objs"] = [name]
    rel["task_desc"] = f"Pick up {desc} and hold it at the green goal."
    for key in ("objs_mapping", "position", "objs_desc"):
        data[key] = {(name if k == "can" else k): v for k, v in data[key].items()}
    data["objs_desc"][name] = desc
    data["tree"]["table"] = [[name if c == "can" else c, r] for c, r in data["tree"]["table"]]
    if shipped is None:
        shipped = Path(os.path.relpath(DATA / "assets", ZOO / "layouts"))
    data["assets"] = {
        (name if k == "can" else k): str(shipped / Path(v).name) for k, v in data["assets"].items()
    }
    data["assets"][name] = str(Path("..", assets.name, name))
    # the file's own pose of the shape: where the can stood, its lowest point on the top
    data["position"][name][2] = TABLE_TOP + 0.001
    path.write_text(json.dumps(data, indent=4) + "\n")


def write_shapes(
    out: Path, cases: dict[str, tuple[list[trimesh.Trimesh], float, str]], what: str,
    shipped: Path | None = None,
) -> None:
    """Each case (name -> convex parts, mass kg, description) as an asset under ``out/assets``
    and a layout around it under ``out/layouts``, both emptied first; ``shipped`` as in
    ``write_layout``. The zoo's and the round sweep's ``main``."""
    assets, layouts = out / "assets", out / "layouts"
    for folder in (assets, layouts):
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
    for name, (parts, mass, desc) in cases.items():
        write_asset(assets / name, name, parts, mass)
        write_layout(layouts / f"{name}.json", name, desc, assets, shipped)
    print(f"wrote {len(cases)} {what} to {assets} and their layouts to {layouts}")


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=ZOO)
    write_shapes(ap.parse_args(argv).out, shapes(), "shapes")


if __name__ == "__main__":
    main()
