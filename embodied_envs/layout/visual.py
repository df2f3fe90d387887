"""Checks of an asset's visual mesh: it loads, its materials and textures lie in the asset
folder and read as images, and it stands where its collision mesh does."""

from __future__ import annotations

import warnings
from pathlib import Path

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
from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.folders import resolve_path

MAX_TEXTURE_BYTES = 256 << 20  # a texture file larger than this is refused before reading


def check_visual_mesh(spec: AssetSpec) -> None:
    """The visual mesh loads and holds finite vertices (it is rendered as it is), and every
    material and texture it names (OBJ ``mtllib``, ``map_*``) lies in the asset folder and
    reads as an image of at most ``MAX_IMAGE_SIDE`` px a side: SAPIEN would otherwise fail
    minutes later, without naming the node. A collision mesh whose top or bottom stands
    over ``VISUAL_MISMATCH`` from the visual mesh's is warned about once (placement and the
    simulator stand objects on the collision mesh: they would float or sink on camera).

    Raises:
        LayoutError: naming the file and the first bad vertex, material or texture.
    """
    key = ("visual heights", FileVersion.of(spec.visual.path), spec.visual)
    low, high = ASSET_FILES.get(key, lambda: _heights(spec.visual))
    geom = asset_geometry(spec)
    below, above = geom.min_z - low, geom.max_z - high
    if max(abs(below), abs(above)) > VISUAL_MISMATCH and spec.urdf_path not in _WARNED_MISMATCH:
        _WARNED_MISMATCH.add(spec.urdf_path)
        warnings.warn(
            f"{spec.urdf_path}: its collision mesh's top is {above * 1000:+.1f} mm and its bottom"
            f" {below * 1000:+.1f} mm from its visual mesh's: objects rest on the collision mesh,"
            " so on camera they float over it or sink into it by as much (and it does on"
            " its own support). Fix: export the collision mesh from the visual mesh's shape.",
            stacklevel=2,
        )
    if spec.visual.path.suffix.lower() == ".obj":
        _check_materials(spec.visual.path, spec.urdf_path.parent)


VISUAL_MISMATCH = 2e-3  # m: a collision top or bottom this far from the visual one is warned
_WARNED_MISMATCH: set = set()


def _heights(visual: MeshRef) -> tuple[float, float]:
    """The lowest and highest point of a visual mesh in the actor frame (Z-up)."""
    z = visual.to_link_frame(_load_parts_checked(visual, collision=False).vertices)[:, 2]
    return float(z.min()), float(z.max())


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
