"""Turn a coloured or textured mesh into a splat of flat, surface-aligned Gaussians."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
import trimesh
from scipy.spatial.transform import Rotation

from embodied_envs.splat.model import GaussianSplat
from embodied_envs.splat.ply import SplatFileError, write_ply
from embodied_envs.splat.sh import SH_C0

FLAT_SCALE = 1e-3  # m, standard deviation of each Gaussian along the surface normal
SPREAD = 1.0  # in-plane standard deviation, in units of the mean sample spacing
OPACITY = 0.95  # opacity of every Gaussian


def _sample_colors(mesh: trimesh.Trimesh, points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """RGB in [0, 1] at surface points: texture, else vertex colours, else face colours."""
    visual = mesh.visual
    bary = trimesh.triangles.points_to_barycentric(mesh.triangles[faces], points)
    if visual.kind == "texture" and getattr(visual, "uv", None) is not None:
        image = getattr(visual.material, "image", None)
        if image is None and hasattr(visual.material, "baseColorTexture"):
            image = visual.material.baseColorTexture
        if image is not None:
            uv = np.einsum("nk,nkj->nj", bary, visual.uv[mesh.faces[faces]])
            tex = np.asarray(image.convert("RGB"), dtype=np.float64) / 255.0
            h, w = tex.shape[:2]
            col = np.clip(np.round((uv[:, 0] % 1.0) * (w - 1)).astype(int), 0, w - 1)
            row = np.clip(np.round((1.0 - uv[:, 1] % 1.0) * (h - 1)).astype(int), 0, h - 1)
            return tex[row, col]
        visual = visual.to_color()
    if visual.kind == "vertex":
        vc = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0
        return np.einsum("nk,nkj->nj", bary, vc[mesh.faces[faces]])
    if visual.kind == "face":
        return np.asarray(visual.face_colors, dtype=np.float64)[faces, :3] / 255.0
    return np.full((len(points), 3), 0.7)


def _frames_to_quats_wxyz(normals: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Rotations whose third axis is the normal; the in-plane angle is random."""
    helper = np.where(np.abs(normals[:, [0]]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(normals, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    phi = rng.uniform(0.0, 2.0 * math.pi, len(normals))[:, None]
    a, b = np.cos(phi) * t1 + np.sin(phi) * t2, -np.sin(phi) * t1 + np.cos(phi) * t2
    mats = np.stack([a, b, normals], axis=2)
    xyzw = Rotation.from_matrix(mats).as_quat()
    return xyzw[:, [3, 0, 1, 2]]


def mesh_to_splat(
    mesh: trimesh.Trimesh,
    count: int,
    seed: int = 0,
    visible_from: Sequence[float] | None = None,
) -> GaussianSplat:
    """Sample ``count`` flat Gaussians on a mesh's surface (SH degree 0).

    Sampling is area-weighted; each Gaussian lies in its face's plane with in-plane standard
    deviation ``SPREAD`` times the mean spacing and ``FLAT_SCALE`` along the normal, and takes
    the colour of the surface under it. Coordinates are kept as they are in the mesh.

    Args:
        mesh: a triangle mesh with a texture, vertex colours or face colours.
        count: number of Gaussians.
        seed: seeds the sampling.
        visible_from: if given, only faces whose front side faces this point are sampled
            (e.g. the inside of a room); the others would never be seen.

    Raises:
        ValueError: the mesh has no faces (left) or ``count`` is not positive.
    """
    if count < 1:
        raise ValueError(f"count must be positive, got {count}")
    faces = np.arange(len(mesh.faces))
    if visible_from is not None:
        to_eye = np.asarray(visible_from, dtype=np.float64) - mesh.triangles_center
        faces = faces[np.einsum("ij,ij->i", mesh.face_normals, to_eye) > 0]
    areas = mesh.area_faces[faces]
    if len(faces) == 0 or areas.sum() <= 0:
        raise ValueError("the mesh has no (visible) faces with area to sample")
    rng = np.random.default_rng(seed)
    picked = faces[rng.choice(len(faces), size=count, p=areas / areas.sum())]
    r1, r2 = rng.random((2, count))
    flip = r1 + r2 > 1.0
    r1, r2 = np.where(flip, 1.0 - r1, r1), np.where(flip, 1.0 - r2, r2)
    tri = mesh.triangles[picked]
    points = (
        tri[:, 0] + r1[:, None] * (tri[:, 1] - tri[:, 0]) + r2[:, None] * (tri[:, 2] - tri[:, 0])
    )
    normals = mesh.face_normals[picked]
    colors = _sample_colors(mesh, points, picked)
    spacing = math.sqrt(areas.sum() / count)
    log_scales = np.log([[SPREAD * spacing, SPREAD * spacing, FLAT_SCALE]]).repeat(count, 0)

    def t(a):
        return torch.as_tensor(np.asarray(a), dtype=torch.float32)

    return GaussianSplat(
        means=t(points),
        quats_wxyz=t(_frames_to_quats_wxyz(normals, rng)),
        log_scales=t(log_scales),
        opacity_logits=t(np.full(count, math.log(OPACITY / (1.0 - OPACITY)))),
        sh=t((colors - 0.5) / SH_C0)[:, None, :],
        normals=t(normals),
    )


def mesh_file_to_splat(
    mesh_path: str | os.PathLike,
    out: str | os.PathLike,
    count: int,
    seed: int = 0,
    visible_from: Sequence[float] | None = None,
    normals: bool = False,
) -> GaussianSplat:
    """Convert the mesh file ``mesh_path`` (any format trimesh reads) into a splat PLY at
    ``out`` (written to a temporary name, then renamed), with :func:`mesh_to_splat`'s sampling;
    ``normals`` also writes nx ny nz (unused by renderers). ``embodied-envs splat from-mesh``.

    Raises:
        SplatFileError: the mesh file is missing, unreadable, or has no faces to sample.
    """
    mesh_path = Path(mesh_path)
    if not mesh_path.is_file():
        raise SplatFileError(mesh_path, "this mesh file does not exist", "give a mesh file path")
    try:
        mesh = trimesh.load(mesh_path, force="mesh")
    except Exception as e:  # trimesh raises many types for a bad file: say which file
        raise SplatFileError(
            mesh_path, f"trimesh cannot read it as a mesh ({type(e).__name__}: {e})",
            "give a mesh file trimesh reads (PLY, OBJ, GLB, STL, ...)",
        ) from e  # fmt: skip
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise SplatFileError(
            mesh_path, "the file holds no triangle faces", "give a mesh with faces, not points"
        )
    try:
        splat = mesh_to_splat(mesh, count, seed=seed, visible_from=visible_from)
    except ValueError as e:
        raise SplatFileError(
            mesh_path, str(e), "give a positive count, or another --visible-from point"
        ) from e
    if not normals:
        splat = replace(splat, normals=None)
    write_ply(splat, out)
    return splat
