"""Test assets made here, in EmbodiedGen's asset format (``<stem>.urdf``, ``mesh/<stem>.obj``,
``mesh/<stem>_collision.obj``, meshes Y-up turned Z-up by the URDF), from trimesh shapes
designed Z-up with their lowest point at z = 0: tables and receptacles of several shapes, their
collision written as one object (of pieces, or one concave piece) or one object per part; hollow
things written to hide their hollows (an open surface, two objects, a shallow recess)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

URDF = """<?xml version="1.0"?>
<robot name="{stem}">
  <link name="{stem}">
    <visual>
      <geometry><mesh filename="mesh/{stem}.obj" scale="1 1 1"/></geometry>
      <origin xyz="0 0 0" rpy="1.5708 0 0"/>
    </visual>
    <collision>
      <geometry><mesh filename="mesh/{stem}_collision.obj" scale="1 1 1"/></geometry>
      <origin xyz="0 0 0" rpy="1.5708 0 0"/>
      <gazebo><mu1>0.7</mu1><mu2>0.6</mu2></gazebo>
    </collision>{inertial}
  </link>
</robot>
"""


def obj_text(meshes: list[trimesh.Trimesh], one_object: bool) -> str:
    """An OBJ of ``meshes`` (Z-up, stored Y-up), each its own object or all one object."""
    lines, base = [], 1
    for i, mesh in enumerate(meshes):
        v = np.asarray(mesh.vertices)
        if not one_object or i == 0:
            lines.append(f"o part{i}")
        lines += [f"v {x:.6f} {z:.6f} {-y:.6f}" for x, y, z in v]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in mesh.faces]
        base += len(v)
    return "\n".join(lines) + "\n"


def write_asset(
    folder: Path,
    stem: str,
    visual: list[trimesh.Trimesh],
    collision: list[trimesh.Trimesh] | None = None,
    one_object: bool = True,
    mass: float | None = None,
) -> Path:
    """An asset folder ``folder/stem`` centred on its bounding box (as EmbodiedGen's are); the
    collision mesh is the visual one unless given; its URDF."""
    collision = visual if collision is None else collision
    allv = np.concatenate([m.vertices for m in visual])
    centre = (allv.min(0) + allv.max(0)) / 2
    moved = [[m.copy().apply_translation(-centre) for m in ms] for ms in (visual, collision)]
    out = folder / stem
    (out / "mesh").mkdir(parents=True, exist_ok=True)
    (out / "mesh" / f"{stem}.obj").write_text(obj_text(moved[0], one_object=False))
    (out / "mesh" / f"{stem}_collision.obj").write_text(obj_text(moved[1], one_object))
    inertial = "" if mass is None else f'\n    <inertial><mass value="{mass}"/></inertial>'
    (out / f"{stem}.urdf").write_text(URDF.format(stem=stem, inertial=inertial))
    return out / f"{stem}.urdf"


def box(extents, centre) -> trimesh.Trimesh:
    return trimesh.creation.box(extents=extents).apply_translation(centre)


def table_pieces(top=0.76, thick=0.04, lx=1.1, ly=0.7, leg=0.05) -> list[trimesh.Trimesh]:
    """A table of five boxes: the top and four legs under it (the legs touch the top)."""
    parts = [box([lx, ly, thick], [0, 0, top - thick / 2])]
    for sx in (-1, 1):
        for sy in (-1, 1):
            c = [sx * (lx / 2 - 0.06), sy * (ly / 2 - 0.06), (top - thick) / 2]
            parts.append(box([leg, leg, top - thick], c))
    return parts


def round_table_pieces(top=0.74, thick=0.035, r=0.55) -> list[trimesh.Trimesh]:
    """A round table of three cylinders: the top, a stem and a foot."""
    cyl = trimesh.creation.cylinder
    return [
        cyl(r, thick, sections=48).apply_translation([0, 0, top - thick / 2]),
        cyl(0.05, top - thick, sections=32).apply_translation([0, 0, (top - thick) / 2]),
        cyl(0.3, 0.03, sections=32).apply_translation([0, 0, 0.015]),
    ]


BOWL_FLOOR = 0.006  # m: the bowls' floor thickness (the inside floor's height)


def bowl_shell(r0=0.045, r=0.08, h=0.055, t=BOWL_FLOOR) -> trimesh.Trimesh:
    """A bowl as one closed concave surface (a floor and a sloped wall, ``t`` thick)."""
    profile = [[0, 0], [r0, 0], [r, h], [r - t, h], [r0 - t, t], [0, t]]
    return trimesh.creation.revolve(np.asarray(profile, float), sections=40)


def bowl_wedges(r0=0.045, r=0.08, h=0.055, t=BOWL_FLOOR, n=16) -> list[trimesh.Trimesh]:
    """A bowl of ``n + 1`` convex parts that touch: a floor disc and ``n`` wall wedges."""
    parts = [trimesh.creation.cylinder(r0, t, sections=n).apply_translation([0, 0, t / 2])]
    for k in range(n):
        a = 2 * np.pi * np.array([k, k + 1]) / n
        pts = [[rr * np.cos(b), rr * np.sin(b), zz] for b in a
               for rr, zz in ((r0, 0), (r, h), (r - t, h), (r0 - t, t))]  # fmt: skip
        parts.append(trimesh.Trimesh(np.array(pts)).convex_hull)
    return parts


def open_box(w=0.12, d=0.1, h=0.08) -> trimesh.Trimesh:
    """A box open on top as a bare surface: a closed box less its lid (no thickness)."""
    b = trimesh.creation.box(extents=(w, d, h)).apply_translation([0, 0, h / 2])
    return trimesh.Trimesh(b.vertices, b.faces[b.face_normals[:, 2] < 0.9])


def mug_objects(r=0.04, h=0.09, t=0.004) -> list[trimesh.Trimesh]:
    """A mug as two objects: a closed concave body (4 mm floor and walls) and a handle."""
    profile = np.array([[0, 0], [r, 0], [r, h], [r - t, h], [r - t, t], [0, t]])
    body = trimesh.creation.revolve(profile, sections=24)
    handle = box([0.03, 0.012, 0.05], [r + 0.015, 0, h / 2])
    return [body, handle]


def tray(r=0.1, base=0.03, recess=0.01, rim=0.01) -> trimesh.Trimesh:
    """A closed tray: a 3 cm base with a 1 cm recess inside a 1 cm rim (hull 1.25x its volume,
    under the 1.3 that a volume ratio would need)."""
    top = base + recess
    profile = np.array([[0, 0], [r, 0], [r, top], [r - rim, top], [r - rim, base], [0, base]])
    return trimesh.creation.revolve(profile, sections=48)
