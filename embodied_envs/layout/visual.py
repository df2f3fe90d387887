"""Checks of an asset's visual mesh: it loads, its materials and textures lie in the asset
folder and read as images, and it stands where its collision mesh does (every face of the two
boxes, the volume, and its hollows: ``layout/hollow.py``)."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

from embodied_envs.layout.assets import (
    ASSET_FILES,
    MAX_IMAGE_SIDE,
    AssetSpec,
    FileVersion,
    MeshRef,
    _load_parts_checked,
    asset_geometry,
)
from embodied_envs.layout.collision import load_mesh, once_each, pieces
from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.folders import resolve_path
from embodied_envs.layout.hollow import Hollow, filled_hollow

MAX_TEXTURE_BYTES = 256 << 20  # a texture file larger than this is refused before reading


def check_visual_mesh(spec: AssetSpec) -> None:
    """The visual mesh loads and holds finite vertices (it is rendered as it is), and every
    material and texture it names (OBJ ``mtllib``, ``map_*``) lies in the asset folder and
    reads as an image of at most ``MAX_IMAGE_SIDE`` px a side: SAPIEN would otherwise fail
    minutes later, without naming the node. Its collision mesh stands where it does
    (:func:`check_collision_matches`).

    Raises:
        LayoutError: naming the file and the first bad vertex, material or texture, or the
            URDF and both boxes when the collision mesh stands elsewhere.
    """
    key = ("visual shape", FileVersion.of(spec.visual.path), spec.visual)
    shape = ASSET_FILES.get(key, lambda: _visual_shape(spec.visual))
    check_collision_matches(spec, shape)
    if spec.visual.path.suffix.lower() == ".obj":
        _check_materials(spec.visual.path, spec.urdf_path.parent)


VISUAL_MISMATCH = 2e-3  # m: a face of the collision box this far from the visual box's, or a
# volume apart by this depth over the visual surface, is warned about (once per URDF)
VISUAL_REFUSED = 5e-3  # m: a face this far apart is refused ...
VISUAL_REFUSED_SHARE = 0.02  # ... or this share of the collision box's longest side, if more
# (a large object's export tolerance: 24 mm on a 1.2 m table)
FACES = ("-x", "-y", "-z", "+x", "+y", "+z")  # the box faces, in the object's frame (Z-up)
UNIT_SCALES = {1000.0: "millimetres", 100.0: "centimetres"}  # a visual box this many times
# the collision box (within 5 %) reads as a visual mesh written in that unit
_WARNED_MISMATCH: set = set()


@dataclass(frozen=True)
class VisualShape:
    """The box, volume and area of a visual mesh in the actor frame (Z-up)."""

    lo: np.ndarray  # (3,) lowest x, y, z, m
    hi: np.ndarray  # (3,) highest x, y, z, m
    volume: float | None  # m^3; None when the mesh does not close a volume
    area: float  # m^2


def _visual_shape(visual: MeshRef) -> VisualShape:
    import trimesh  # only where a mesh is read

    mesh = _load_parts_checked(visual, collision=False)
    v = visual.to_link_frame(mesh.vertices)
    mesh = once_each(trimesh.Trimesh(v, mesh.faces, process=False))
    found = pieces(mesh)  # closed surfaces, as written or joined by equal positions
    volume = None if any(p.ratio is None for p in found) else sum(p.mesh.volume for p in found)
    return VisualShape(v.min(0), v.max(0), volume, float(mesh.area))


def face_offsets(spec: AssetSpec, shape: VisualShape) -> np.ndarray:
    """How far each face of the collision box (``FACES``) reaches past the visual box's, m:
    positive out of it, negative short of it."""
    v = asset_geometry(spec).vertices
    return np.concatenate([shape.lo - v.min(0), v.max(0) - shape.hi])


def check_collision_matches(spec: AssetSpec, shape: VisualShape) -> None:
    """The collision mesh stands where the visual mesh does: objects rest, collide and are
    grasped on the collision mesh, so on camera they float, sink or pass into each other by
    as much as the two differ. Every face of the two boxes (in the object's frame) is
    compared: over ``VISUAL_REFUSED`` (or ``VISUAL_REFUSED_SHARE`` of the object) is refused,
    over ``VISUAL_MISMATCH`` warned about once per URDF, as is a volume apart by more than
    ``VISUAL_MISMATCH`` spread over the visual surface (a hollow filled in, a part missing;
    compared when the visual mesh closes a volume), as is a hollow of the visual mesh the
    collision parts fill (:func:`hollow.filled_hollow`: a thing set in it would float).

    Raises:
        LayoutError: naming the URDF, both boxes, the faces apart and the fix.
    """
    geom = asset_geometry(spec)
    offsets = face_offsets(spec, shape)
    apart = ", ".join(
        f"{face} {d * 1000:+.1f} mm"
        for face, d in zip(FACES, offsets, strict=True)
        if abs(d) > VISUAL_MISMATCH
    )
    boxes = (
        f"collision box {_box(geom.vertices.min(0), geom.vertices.max(0))}, visual box "
        f"{_box(shape.lo, shape.hi)} (x, y, z in the object's frame)"
    )
    worst = float(np.abs(offsets).max())
    size = float(np.ptp(geom.vertices, 0).max())
    limit = max(VISUAL_REFUSED, VISUAL_REFUSED_SHARE * size)
    if worst > limit:
        raise LayoutError(
            f"{spec.urdf_path}: its collision mesh stands apart from its visual mesh by up to "
            f"{worst * 1000:.1f} mm, over {limit * 1000:.1f} mm (its faces {apart}; +: out of the"
            f" visual box): {boxes}; "
            "objects rest and are grasped on the collision mesh, so on camera they would float,"
            f" sink or pass into each other. Fix: {_fix(spec, geom.vertices, shape)}"
        )
    notes = (
        [f"its collision box's faces stand {apart} off its visual box's (+: out of it; {boxes})"]
        if apart
        else []
    )
    if shape.volume is not None and shape.area > 0:
        depth = (geom.volume - shape.volume) / shape.area
        if abs(depth) > VISUAL_MISMATCH:
            notes.append(
                f"its collision volume is {geom.volume * 1e6:.1f} cm^3 against its visual "
                f"mesh's {shape.volume * 1e6:.1f} cm^3 ({depth * 1000:+.1f} mm over its surface:"
                f" {'a hollow filled in' if depth > 0 else 'a part missing'})"
            )
    filled = visual_hollow(spec)
    fix = "export the collision mesh from the visual mesh's shape"
    if filled.filled:
        notes.append(f"its collision mesh makes {filled.words()} of its visual mesh")
        fix += " as convex parts, one object each, that leave its hollows open"
    if notes and spec.urdf_path not in _WARNED_MISMATCH:
        _WARNED_MISMATCH.add(spec.urdf_path)
        warnings.warn(
            f"{spec.urdf_path}: {'; '.join(notes)}: objects rest and are grasped on the "
            "collision mesh, so on camera they float, sink or pass into each other by as much."
            f" Fix: {fix}.",
            stacklevel=3,
        )


def visual_hollow(spec: AssetSpec) -> Hollow:
    """What the asset's collision parts fill of its visual mesh's hollows, in its frame (Z up);
    read once per version of the two files."""
    versions = (FileVersion.of(spec.visual.path), FileVersion.of(spec.collision.path))
    key = ("visual hollow", *versions, spec.visual, spec.collision)

    def probe() -> Hollow:
        mesh = load_mesh(spec.visual.path)
        triangles = spec.visual.to_link_frame(mesh.vertices)[mesh.faces]
        return filled_hollow(triangles, list(asset_geometry(spec).parts))

    return ASSET_FILES.get(key, probe)


def _box(lo: np.ndarray, hi: np.ndarray) -> str:
    return "[" + ", ".join(f"{a:.4f}..{b:.4f}" for a, b in zip(lo, hi, strict=True)) + "] m"


def _fix(spec: AssetSpec, collision: np.ndarray, shape: VisualShape) -> str:
    """The fix of a refused mismatch: a visual mesh's scale when it reads as written in other
    units, else the URDF origins or the collision mesh's export."""
    ratio = (shape.hi - shape.lo) / np.maximum(np.ptp(collision, 0), 1e-9)
    for scale, unit in UNIT_SCALES.items():
        if np.allclose(ratio, scale, rtol=0.05):
            return (
                f"its visual mesh reads as written in {unit} ({scale:g}x the collision mesh): give"
                f' its <visual> <mesh> scale="{1 / scale:g} {1 / scale:g} {1 / scale:g}" in the'
                " URDF, or export it in metres."
            )
    export = "export the collision mesh from the visual mesh's shape, in the same frame."
    v, c = spec.visual, spec.collision
    if (v.xyz, v.rpy, v.scale) == (c.xyz, c.rpy, c.scale):
        return export[0].upper() + export[1:]
    return (
        "give <visual> and <collision> the same <origin> and scale in the URDF (now xyz"
        f" {list(v.xyz)} rpy {list(v.rpy)} scale {list(v.scale)} and xyz {list(c.xyz)} rpy"
        f" {list(c.rpy)} scale {list(c.scale)}), or {export}"
    )


def _inside(path: Path, folder: Path, what: str, source: Path, name: str) -> Path:
    """``path`` resolved, refused when outside ``folder`` or missing."""
    path = resolve_path(path, f"{source}: {what}")
    if not path.is_relative_to(folder):
        raise LayoutError(
            f"{source}: {what} {name} lies outside the asset folder {folder}. Fix: copy it into"
            " the asset folder and name it relative to the file that uses it."
        )
    if not path.is_file():
        raise LayoutError(f"{source}: {what} {name} does not exist (looked at {path}).")
    return path


def _check_materials(obj: Path, folder: Path) -> None:
    with open(obj, "rb") as fh:
        lines = [line for line in fh if line.startswith(b"mtllib") and len(line.split()) > 1]
    libraries = [line.split(None, 1)[1].decode(errors="replace").strip() for line in lines]
    for name in libraries:
        mtl = _inside(obj.parent / name, folder, "material file", obj, name)
        for line in mtl.read_text(errors="replace").splitlines():
            words = line.split()
            if words and (words[0].lower().startswith("map_") or words[0] in ("bump", "disp")):
                tex_name = words[-1]  # options such as -s 1 1 1 come before the file name
                tex = _inside(mtl.parent / tex_name, folder, "texture", mtl, tex_name)
                key = ("texture checked", FileVersion.of(tex))
                ASSET_FILES.get(key, lambda mtl=mtl, tex=tex: _check_texture(mtl, tex))


def _check_texture(mtl: Path, tex: Path) -> bool:
    size = tex.stat().st_size
    if size > MAX_TEXTURE_BYTES:
        raise LayoutError(
            f"{mtl}: texture {tex.name} is {size:,} bytes, over {MAX_TEXTURE_BYTES:,}."
            " Fix: downscale it."
        )
    try:
        with Image.open(tex) as im:
            w, h = im.size
            im.verify()  # the file's structure (chunks, checksums), without decoding pixels
    except Exception as e:  # PIL raises many types for unreadable images
        raise LayoutError(f"{mtl}: texture {tex.name} is not a readable image ({e}).") from None
    if max(w, h) > MAX_IMAGE_SIDE:
        raise LayoutError(
            f"{mtl}: texture {tex.name} is {w}x{h} px, over {MAX_IMAGE_SIDE} px a side (it would"
            f" cost {w * h * 4 / 1e9:.1f} GB to load). Fix: downscale it."
        )
    return True
