"""Coarser visual meshes for cheaper camera frames.

SAPIEN's CPU renderer (Mesa's lavapipe) spends its time on triangles, not pixels: the Panda's
135k visual triangles cost ~25 ms a frame at 64x64 and at 128x128 alike, the rest of the
default scene ~2.5 ms. :func:`simplify_visuals` replaces every triangle-mesh part of the given
entities' render bodies by a quadric-decimated copy of at most ``max_faces`` triangles (trimesh's
``simplify_quadric_decimation``, the ``fast-simplification`` library), keeping its material,
its local pose and its scale; texture coordinates are taken from the nearest original vertex.
Collision shapes, segmentation ids and poses are untouched: only what cameras see changes.
"""

from __future__ import annotations

import hashlib

import numpy as np
import sapien
import trimesh
from scipy.spatial import cKDTree

MIN_FACES = 50  # the smallest face budget a part may be given (below: shapes fall apart)
DECIMATION_AGGRESSION = 5  # fast-simplification's default balance of speed and quality
# decimated parts of this process: (part's bytes digest, max_faces) -> the arrays SAPIEN takes
_CACHE: dict[tuple[str, int], tuple[np.ndarray, ...]] = {}


def _decimated(part, max_faces: int) -> tuple[np.ndarray, ...]:
    """``part``'s vertices, triangles, normals and uvs with at most ``max_faces`` triangles."""
    vertices = np.asarray(part.get_vertices(), np.float32)
    faces = np.asarray(part.get_triangles(), np.int64)
    uvs = part.get_vertex_uv()
    key = (hashlib.sha1(vertices.tobytes() + faces.tobytes()).hexdigest(), max_faces)
    if key not in _CACHE:
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        # a glTF part splits its vertices at every UV and normal seam: weld them first, or the
        # decimation tears the surface apart along the seams
        mesh.merge_vertices(merge_tex=True, merge_norm=True)
        if len(mesh.faces) > max_faces:
            mesh = mesh.simplify_quadric_decimation(
                face_count=max_faces, aggression=DECIMATION_AGGRESSION
            )
        new_vertices = np.asarray(mesh.vertices, np.float32)
        nearest = cKDTree(vertices).query(new_vertices)[1]
        has_uv = uvs is not None and len(uvs) == len(vertices)
        new_uvs = (np.asarray(uvs, np.float32)[nearest] if has_uv
                   else np.zeros((len(new_vertices), 2), np.float32))  # fmt: skip
        _CACHE[key] = (
            new_vertices,
            np.asarray(mesh.faces, np.uint32),
            np.asarray(mesh.vertex_normals, np.float32),
            new_uvs,
        )
    return _CACHE[key]


def simplify_visuals(entities, max_faces: int) -> tuple[int, int]:
    """Replace the triangle meshes of ``entities``' render bodies by decimated copies of at
    most ``max_faces`` triangles per mesh part (parts already within it are kept as they are).

    Args:
        entities: SAPIEN entities (e.g. a robot's links' ``_objs``' entities), in a scene.
        max_faces: the face budget of one part (at least ``MIN_FACES``).

    Returns:
        The triangles before and after.
    """
    if max_faces < MIN_FACES:
        raise ValueError(f"max_faces={max_faces} must be at least {MIN_FACES}")
    before = after = 0
    for entity in entities:
        body = entity.find_component_by_type(sapien.render.RenderBodyComponent)
        if body is None:
            continue
        meshes = [s for s in body.render_shapes
                  if isinstance(s, sapien.render.RenderShapeTriangleMesh)]  # fmt: skip
        counts = [len(p.get_triangles()) for s in meshes for p in s.parts]
        before += sum(counts)
        if all(c <= max_faces for c in counts):  # nothing to decimate: the body stays
            after += sum(counts)
            continue
        coarse = sapien.render.RenderBodyComponent()
        coarse.set_name(body.name)
        for shape in body.render_shapes:
            if not isinstance(shape, sapien.render.RenderShapeTriangleMesh):
                coarse.attach(shape.clone() if hasattr(shape, "clone") else shape)
                continue
            for part in shape.parts:
                vertices, faces, normals, uvs = _decimated(part, max_faces)
                after += len(faces)
                new = sapien.render.RenderShapeTriangleMesh(
                    vertices, faces, normals, uvs, part.material
                )
                new.local_pose = shape.local_pose
                new.set_scale(shape.scale)
                coarse.attach(new)
        visibility = body.visibility
        entity.remove_component(body)
        entity.add_component(coarse)
        coarse.visibility = visibility
    return before, after
