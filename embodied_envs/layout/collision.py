"""Collision meshes the simulator would fill in, made of convex parts when loaded, without
changing their shape.

SAPIEN's ``add_multiple_convex_collisions_from_file`` makes one convex hull of each object
(``o`` / ``g``) of an OBJ file, and one of the whole mesh for other formats. EmbodiedGen's CoACD
export writes one object per convex part, but a user's own export often writes a table on legs,
a bowl or a mug as one object: the simulator then fills it in (a mug becomes a solid cylinder,
the space between a table's legs solid), and grasps, placement and "in the bowl" go wrong.

A collision mesh written as one object is read as its pieces (:func:`pieces`: the closed
surfaces as the file connects them, else the surfaces its vertex positions join):

- a convex piece (its hull within ``CONCAVE_RATIO`` of its volume), or one whose volume cannot
  be measured (not closed), becomes its own convex hull: exact, no CoACD;
- a closed concave piece is decomposed by CoACD (``COACD_PARAMS``, seeded) without manifold
  pre-processing (the piece is closed already; the pre-processing remeshes it on a voxel grid
  and grows it by up to half a voxel: 1 cm on a 1.1 m table at resolution 30). Every part must
  lie within ``BOUNDS_TOLERANCE`` of the piece's bounding box (it is then clamped into it) and
  the parts must hold ``VOLUME_RATIO`` of the piece's volume.

A mesh of one convex (or open) piece is kept as it is. A decomposition that fails a check, or
a mesh with a flat piece, is kept as the user wrote it (the simulator makes one hull of it) with
one warning naming the file. A degenerate mesh (flat, a point, no volume: :func:`thickness`
under ``MIN_COLLISION_THICKNESS``) is never decomposed: ``assets.py`` refuses it, naming the
file. The result is written once to the cache folder (``$EMBODIED_ENVS_CACHE``, else
``~/.cache/embodied_envs``; named by the mesh's content and every setting here, so an edited
mesh or a changed method is decomposed again; never beside the user's files) with a progress
line on stderr. ``EMBODIED_ENVS_DECOMPOSE=0`` keeps such meshes as they are, with one warning
per file naming it and the fix. ``layout validate`` lists what was decomposed (:data:`DECOMPOSED`).
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import os
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from embodied_envs.paths import atomic_output

CONCAVE_RATIO = 1.3  # convex hull volume / volume above which a closed piece is concave
# an open piece (no volume) whose hull reaches farther than this share of its size from its
# surface is concave (a bowl surface, a box without a lid): warned, the simulator fills it in
OPEN_CONCAVITY = 0.1
FILL_SAMPLES = 4000  # surface points sampled (seeded) on an open piece and on its hull
OPEN_NOTE = "open and concave"  # in the reason of a mesh with such pieces
MIN_COLLISION_THICKNESS = 1e-3  # m: a collision mesh thinner than this (any direction) is flat
BOUNDS_TOLERANCE = 1e-3  # m: how far a CoACD part may reach past its piece's bounding box
# the CoACD parts' total volume / the piece's: they cover it (>= 1 but for rounding) and fill
# in at most what CONCAVE_RATIO lets a convex piece fill in
VOLUME_RATIO = (0.98, CONCAVE_RATIO)
# CoACD settings: concavity threshold 0.05 (of half the piece's size), parts merged down to 64
# at most (a cap of 16 merged a bowl's floor with its wall: 3 mm over the floor); no manifold
# pre-processing (pieces given to CoACD are closed; the pre-processing would grow them)
COACD_PARAMS = dict(
    threshold=0.05,
    max_convex_hull=64,
    preprocess_mode="off",
    resolution=1000,
    mcts_nodes=10,
    mcts_iterations=60,
    seed=0,
)
SLOW_FACES = 10_000  # a concave piece over this many faces: the progress line says to wait
METHOD = 3  # in the cache key: a decomposition made by an earlier method is not reused (3:
# faces written twice read once, inside-out closed pieces turned out)
OPT_OUT_ENV = "EMBODIED_ENVS_DECOMPOSE"  # "0": keep one-object concave meshes (warned once)
CACHE_ENV = "EMBODIED_ENVS_CACHE"
KEPT = "# kept as written: "  # second line of a cache file recording a refused decomposition

# original collision mesh -> what was found and the decomposed file (read by `layout validate`)
DECOMPOSED: dict[Path, tuple[str, Path]] = {}
_WARNED: set[Path] = set()


def obj_objects(path: Path) -> list[np.ndarray]:
    """The vertices each object (``o`` or ``g``) of an OBJ file uses in its faces."""
    vertices: list[list[bytes]] = []
    groups: list[list[int]] = [[]]
    with open(path, "rb") as fh:
        for line in fh:
            if line.startswith(b"v "):
                vertices.append(line.split()[1:4])
            elif line.startswith((b"o ", b"g ")):
                if groups[-1]:
                    groups.append([])
            elif line.startswith(b"f "):
                for token in line.split()[1:]:
                    i = int(token.split(b"/")[0])
                    groups[-1].append(i - 1 if i > 0 else len(vertices) + i)
    table = np.asarray(vertices, dtype=np.float64)
    return [table[np.unique(g)] for g in groups if g]


OBJ_COUNTED = (b"v", b"vt", b"vn")  # what an OBJ face's index, texture index, normal index count


def absolute_indices(data: bytes) -> bytes:
    """An OBJ file's text with every negative (relative) index of its faces, lines and points
    made absolute: ``-1`` is the last vertex (texture coordinate, normal) written *before* that
    line, as the OBJ format reads it (trimesh counts from the file's last one)."""
    counts = dict.fromkeys(OBJ_COUNTED, 0)
    out = []
    for line in data.splitlines():
        words = line.split()
        head = words[0] if words else b""
        if head in counts:
            counts[head] += 1
        elif head in (b"f", b"l", b"p") and b"-" in line:
            tokens = [head]
            for word in words[1:]:
                parts = word.split(b"/")
                for k, key in enumerate(OBJ_COUNTED[: len(parts)]):
                    if parts[k].startswith(b"-"):
                        parts[k] = str(counts[key] + int(parts[k]) + 1).encode()
                tokens.append(b"/".join(parts))
            line = b" ".join(tokens)
        out.append(line)
    return b"\n".join(out) + b"\n"


def load_mesh(path: Path):
    """trimesh's reading of the mesh file at ``path`` (one mesh, no vertex merged, no
    materials), an OBJ's negative face indices read as the OBJ format reads them
    (:func:`absolute_indices`)."""
    import trimesh  # only where a mesh is read

    options = dict(force="mesh", process=False, skip_materials=True)
    if path.suffix.lower() == ".obj":
        data = path.read_bytes()
        if any(w.startswith(b"-") for ln in data.splitlines() if ln.startswith((b"f ", b"l "))
               for w in ln.split()[1:]):  # fmt: skip
            return trimesh.load(io.BytesIO(absolute_indices(data)), file_type="obj", **options)
    return trimesh.load(path, **options)


def thickness(vertices: np.ndarray) -> float:
    """The least extent of points along the coordinate axes and their principal axes: 0 for a
    point, a line or a plane at any tilt."""
    v = np.asarray(vertices, dtype=np.float64)
    v = v - v.mean(0)
    axes = np.linalg.svd(v, full_matrices=False)[2]
    return float(min(np.ptp(v, 0).min(), np.ptp(v @ axes.T, 0).min()))


def cache_folder() -> Path:
    root = os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "embodied_envs"
    return Path(root) / "collision"


@dataclass(frozen=True)
class Piece:
    """A piece of a one-object collision mesh and what becomes of it."""

    mesh: object  # trimesh.Trimesh
    ratio: float | None  # convex hull volume / volume; None when not closed

    @property
    def concave(self) -> bool:
        return self.ratio is not None and self.ratio > CONCAVE_RATIO


def _read(path: Path):
    """The mesh at ``path`` as the file connects it (no vertex merged), or ``None`` when it is
    not one object of finite vertices (refused, or built as it is, by ``assets.py``)."""
    import trimesh  # only where a mesh is read

    try:
        if path.suffix.lower() == ".obj" and len(obj_objects(path)) > 1:
            return None  # one convex hull per object: EmbodiedGen's own export
        mesh = load_mesh(path)
    except Exception:  # unreadable: refused with its reason where the mesh is checked
        return None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        return None
    # the shape alone: normals and texture coordinates would keep equal positions apart
    mesh = once_each(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False))
    mesh.remove_unreferenced_vertices()
    if not np.isfinite(mesh.vertices).all():
        return None
    return mesh


def pieces(mesh) -> list[Piece]:
    """The pieces of a one-object mesh: its closed surfaces as the file connects them (parts
    written one after another, touching or not), else -- when one is open, as in a file of
    unshared triangles -- the surfaces its equal vertex positions join."""
    import trimesh  # only where a mesh is read

    found = mesh.split(only_watertight=False)
    if not all(p.is_watertight for p in found):
        merged = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)  # equal positions
        found = once_each(merged).split(only_watertight=False)
    out = []
    for p in found:
        if p.is_watertight and p.is_winding_consistent and p.volume < 0:
            p = p.copy()  # closed, written inside out (every face turned inward)
            p.invert()
        measurable = p.is_volume and p.volume > 0
        out.append(Piece(p, p.convex_hull.volume / p.volume if measurable else None))
    return out


def once_each(mesh):
    """``mesh`` with each face written more than once (the same three vertices, either way
    round) kept once: a face written twice joins no neighbour, and splits a closed surface
    into pieces of a face each."""
    import trimesh  # only where a mesh is read

    _, first = np.unique(np.sort(mesh.faces, axis=1), axis=0, return_index=True)
    if len(first) == len(mesh.faces):
        return mesh
    return trimesh.Trimesh(mesh.vertices, mesh.faces[np.sort(first)], process=False)


def open_concave(piece: Piece) -> bool:
    """Whether an open piece's convex hull reaches farther than ``OPEN_CONCAVITY`` of its
    size from its surface (sampled, seeded): the simulator would fill it in."""
    import trimesh  # only where a mesh is read

    mesh = piece.mesh
    if piece.ratio is not None or thickness(mesh.vertices) < MIN_COLLISION_THICKNESS:
        return False
    surface = trimesh.sample.sample_surface(mesh, FILL_SAMPLES, seed=0)[0]
    hull = trimesh.sample.sample_surface(mesh.convex_hull, FILL_SAMPLES, seed=0)[0]
    reach = float(cKDTree(surface).query(hull)[0].max())
    return reach > OPEN_CONCAVITY * float(np.ptp(mesh.vertices, 0).max())


def concavity(path: Path) -> str | None:
    """Why the collision mesh at ``path`` would be filled in by the simulator, in words, or
    ``None`` (several objects, one convex or open piece, degenerate, or unreadable)."""
    plan = _plan(path)
    return None if plan is None else plan[0]


def _plan(path: Path) -> tuple[str, list[Piece]] | None:
    mesh = _read(path)
    if mesh is None or thickness(mesh.vertices) < MIN_COLLISION_THICKNESS:
        return None  # degenerate: refused by assets.py before anything is decomposed
    found = pieces(mesh)
    concave = [p for p in found if p.concave]
    opened = sum(map(open_concave, found))
    if len(found) == 1:
        if opened:
            _warn_open(path, f"one {OPEN_NOTE} object (not closed: no volume)")
        if not concave:
            return None
        return f"one concave object (its convex hull is {concave[0].ratio:.1f}x its volume)", found
    reason = f"one object of {len(found)} disconnected pieces"
    if concave:
        reason += f", {len(concave)} of them concave"
    if opened:
        reason += f", {opened} {OPEN_NOTE} (not closed: no volume)"
    return reason, found


def _warn_open(path: Path, reason: str) -> None:
    _warn_once(
        path,
        f"{path}: {reason}; the simulator makes one convex hull of an open piece, filled in"
        " (it cannot be decomposed without growing it). Fix: close the mesh, or export one"
        " object per convex part (EmbodiedGen's CoACD export does).",
    )


def convex_collision(path: Path) -> Path:
    """The collision mesh to build from: ``path`` itself, or its convex parts when the simulator
    would fill it in (see the module's docstring)."""
    stat = path.stat()
    return _convex_collision(path, stat.st_size, stat.st_mtime_ns, os.environ.get(OPT_OUT_ENV))


def _settings() -> str:
    """Every setting the result depends on, for the cache key."""
    return json.dumps(
        dict(
            method=METHOD,
            coacd=COACD_PARAMS,
            concave=CONCAVE_RATIO,
            bounds=BOUNDS_TOLERANCE,
            volume=VOLUME_RATIO,
            thin=MIN_COLLISION_THICKNESS,
            open=(OPEN_CONCAVITY, FILL_SAMPLES),
        ),
        sort_keys=True,
    )


@functools.lru_cache(maxsize=1024)
def _convex_collision(path: Path, size: int, mtime_ns: int, opt_out: str | None) -> Path:
    digest = hashlib.sha256(path.read_bytes())
    digest.update(_settings().encode())
    out = cache_folder() / f"{digest.hexdigest()[:32]}.obj"
    if opt_out != "0" and out.is_file():  # made before from these bytes with these settings
        with open(out) as fh:
            reason, outcome = fh.readline()[2:].strip(), fh.readline()
    else:
        plan = _plan(path)
        if plan is None:
            return path
        reason, found = plan
        if opt_out == "0":
            _warn_once(
                path,
                f"{path}: {reason}; the simulator makes one convex hull of it, a solid blob "
                f"(kept: {OPT_OUT_ENV}=0). Fix: export one object per convex part (EmbodiedGen's "
                f"CoACD export does), or unset {OPT_OUT_ENV} to decompose it on load.",
            )
            return path
        outcome = _decompose(path, out, reason, found)
    if OPEN_NOTE in reason and not outcome.startswith(KEPT):
        _warn_open(path, reason)
    if outcome.startswith(KEPT):
        _warn_once(
            path,
            f"{path}: {reason}; {outcome[len(KEPT) :].strip()}, so it is kept as written: the "
            "simulator makes one convex hull of it, a solid blob. Fix: export one object per "
            "convex part (EmbodiedGen's CoACD export does).",
        )
        return path
    DECOMPOSED[path] = (reason, out)
    return out


def _warn_once(path: Path, text: str) -> None:
    if path not in _WARNED:
        _WARNED.add(path)
        warnings.warn(text, stacklevel=4)


class Refused(Exception):
    """Why a mesh is kept as written rather than decomposed."""


def _decompose(path: Path, out: Path, reason: str, found: list[Piece]) -> str:
    """Write the convex parts of ``found`` to ``out``, headed by the reason and the outcome
    (the parts, or why the mesh is kept as written: ``KEPT``); the outcome."""
    concave = sum(p.concave for p in found)
    how = f"CoACD (seed {COACD_PARAMS['seed']}) on {concave} concave, " if concave else ""
    faces = sum(len(p.mesh.faces) for p in found if p.concave)
    # CoACD takes seconds on a few thousand faces, most of a minute on 100,000 (on one core)
    wait = f"; it may take a minute ({faces:,} faces)" if faces > SLOW_FACES else ""
    print(
        f"{path}: {reason}; making convex parts ({how}one hull per convex piece), once, "
        f"cached in {out.parent}{wait} ...",
        file=sys.stderr,
        flush=True,
    )
    start = time.perf_counter()
    try:
        parts = [part for i, piece in enumerate(found) for part in _convex_parts(piece, i)]
        outcome = f"# {len(parts)} convex parts of {path.name} ({_settings()})"
    except Refused as e:
        parts, outcome = [], f"{KEPT}{e}"
    lines = [f"# {reason}", outcome]
    base = 1
    for i, verts in enumerate(parts):
        faces = _hull_faces(verts)
        lines.append(f"o part{i}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in verts]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in faces]
        base += len(verts)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(out) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    seconds = time.perf_counter() - start
    done = f"{len(parts)} convex parts" if parts else outcome[2:]
    print(f"{path}: {done} in {seconds:.1f} s", file=sys.stderr, flush=True)
    return outcome


def _hull_faces(verts: np.ndarray) -> np.ndarray:
    """Outward triangles of the convex hull of ``verts`` (every vertex is on it)."""
    hull = ConvexHull(verts)
    faces = hull.simplices.copy()
    centre = verts.mean(0)
    a, b, c = (verts[faces[:, i]] for i in range(3))
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), a - centre) < 0
    faces[inward] = faces[inward][:, ::-1]
    return faces


def _convex_parts(piece: Piece, index: int) -> list[np.ndarray]:
    """The vertices of each convex part of a piece: its hull's, or CoACD's parts checked
    against the piece (bounds within ``BOUNDS_TOLERANCE``, volume within ``VOLUME_RATIO``)."""
    mesh = piece.mesh
    if thickness(mesh.vertices) < MIN_COLLISION_THICKNESS:
        raise Refused(f"its piece {index} is flat")
    if not piece.concave:
        v = np.asarray(mesh.vertices)
        return [v[ConvexHull(v).vertices]]
    import coacd  # only where a mesh is decomposed (rare): importing it costs start-up

    coacd.set_log_level("error")
    result = coacd.run_coacd(coacd.Mesh(mesh.vertices, mesh.faces), **COACD_PARAMS)
    lo, hi = mesh.bounds
    parts, volume = [], 0.0
    for verts, _ in result:
        verts = np.asarray(verts, dtype=np.float64)
        reach = max(float((lo - verts).max()), float((verts - hi).max()))
        if reach > BOUNDS_TOLERANCE:
            raise Refused(
                f"a convex part of its piece {index} reaches {reach * 1000:.1f} mm past the "
                f"piece's bounds (over {BOUNDS_TOLERANCE * 1000:g} mm)"
            )
        verts = np.clip(verts, lo, hi)
        if thickness(verts) < MIN_COLLISION_THICKNESS / 10:
            continue  # a sliver CoACD cut off: no volume to collide with
        hull = ConvexHull(verts)
        parts.append(verts[hull.vertices])
        volume += float(hull.volume)
    ratio = volume / mesh.volume
    if not VOLUME_RATIO[0] <= ratio <= VOLUME_RATIO[1]:
        raise Refused(
            f"the convex parts of its piece {index} hold {ratio:.2f}x its volume (outside "
            f"{VOLUME_RATIO[0]:g} to {VOLUME_RATIO[1]:g})"
        )
    bounds = np.concatenate(parts)
    gap = max(float(np.abs(bounds.min(0) - lo).max()), float(np.abs(bounds.max(0) - hi).max()))
    if gap > BOUNDS_TOLERANCE:
        raise Refused(
            f"the convex parts of its piece {index} miss its bounds by {gap * 1000:.1f} mm"
        )
    return parts


def solid_top(parts: list[np.ndarray], xy) -> float:
    """The highest z at ``xy`` inside any of the convex ``parts`` (vertex arrays, Z-up):
    where an object dropped there would rest; -inf when no part is under it."""
    best = -np.inf
    for verts in parts:
        eq = ConvexHull(verts).equations  # a . p + d <= 0 inside
        rhs = -(eq[:, 3] + eq[:, :2] @ np.asarray(xy, float))
        az = eq[:, 2]
        up = az > 1e-12
        down = az < -1e-12
        flat = ~(up | down)
        if np.any(rhs[flat] < -1e-12):
            continue
        high = (rhs[up] / az[up]).min()
        low = (rhs[down] / az[down]).max()
        if low <= high + 1e-12:
            best = max(best, float(high))
    return best
