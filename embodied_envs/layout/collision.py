"""Collision meshes the simulator would fill in, made of convex parts when loaded, without
changing their shape.

SAPIEN's ``add_multiple_convex_collisions_from_file`` makes one convex hull of each object
(``o`` / ``g``) of an OBJ file, and one of the whole mesh for other formats. EmbodiedGen's CoACD
export writes one object per convex part, but a user's own export often writes a table on legs,
a bowl or a mug as one object: the simulator then fills it in (a mug becomes a solid cylinder,
the space between a table's legs solid), and grasps, placement and "in the bowl" go wrong.

A collision mesh written as one object is read as its pieces (:func:`pieces`: the closed
surfaces as the file connects them, else the surfaces its vertex positions join). A piece is
concave when its hull fills a hollow of it (``layout/hollow.py``: probed from above in the
object's frame as it rests, whatever the file's objects, closure or recess depth) or, closed,
its hull exceeds ``CONCAVE_RATIO`` of its volume:

- a convex piece becomes its own convex hull: exact, no CoACD;
- a concave piece is decomposed by CoACD (``COACD_PARAMS``, seeded) without manifold
  pre-processing (the pre-processing remeshes it on a voxel grid and grows it by up to half a
  voxel: 1 cm on a 1.1 m table at resolution 30); an open one is first made a closed shell
  (``hollow.shell``). Every part must lie within ``BOUNDS_TOLERANCE`` of the piece's bounding
  box (it is then clamped into it), the parts of a closed piece must hold ``VOLUME_RATIO`` of
  its volume, and they must fill no hollow of the piece (probed again).

A mesh of several objects (EmbodiedGen's CoACD export: one convex part each) is kept as it is
unless an object's hull fills a hollow of it (a mug written as a body and a handle): then its
concave objects are decomposed as above, the others kept as their hulls. A mesh of one convex
piece is kept as it is. A decomposition that fails a check (a hollow still filled among
them), or a mesh with a flat piece, is kept as the user wrote it (the simulator makes one hull
of it) with one warning naming the file, why (the gap in mm) and the fix. A degenerate mesh
(flat, a point, no volume: :func:`thickness` under ``MIN_COLLISION_THICKNESS``) is never
decomposed: ``assets.py`` refuses it, naming the file. The result is written once to the cache
folder (``$EMBODIED_ENVS_CACHE``, else ``~/.cache/embodied_envs``; named by the mesh's content,
the object's frame and every setting here, so an edited mesh or a changed method is decomposed
again; never beside the user's files) with a progress line on stderr.
``EMBODIED_ENVS_DECOMPOSE=0`` keeps such meshes as they are, with one warning per file naming it
and the fix. ``layout validate`` lists what was decomposed (:data:`DECOMPOSED`).
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
from scipy.spatial import ConvexHull

from embodied_envs.layout import hollow
from embodied_envs.paths import atomic_output

CONCAVE_RATIO = 1.3  # convex hull volume / volume above which a closed piece is concave
# the mesh file's frame to the object's as it rests (Z up), row-major: EmbodiedGen's Y-up
# meshes turned by the URDF's rpy="1.5708 0 0"; parse_urdf passes each URDF's own
YUP_FRAME = (1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 1.0, 0.0)
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
COACD_RETRIES = 2  # parts that still fill a hollow: CoACD again at half the threshold, this often
SLOW_FACES = 10_000  # a concave piece over this many faces: the progress line says to wait
METHOD = 4  # in the cache key: a decomposition made by an earlier method is not reused (3:
# faces written twice read once, inside-out closed pieces turned out; 4: the hollow probe)
OPT_OUT_ENV = "EMBODIED_ENVS_DECOMPOSE"  # "0": keep one-object concave meshes (warned once)
CACHE_ENV = "EMBODIED_ENVS_CACHE"
KEPT = "# kept as written: "  # second line of a cache file recording a refused decomposition

# original collision mesh -> what was found and the decomposed file (read by `layout validate`)
DECOMPOSED: dict[Path, tuple[str, Path]] = {}
_WARNED: set[Path] = set()


def obj_objects(path: Path) -> list[np.ndarray]:
    """The vertices each object (``o`` or ``g``) of an OBJ file uses in its faces."""
    table, used, _ = obj_groups(path)
    return [table[np.unique(g)] for g in used]


def obj_groups(path: Path) -> tuple[np.ndarray, list[list[int]], list[np.ndarray]]:
    """An OBJ file's vertex table, the vertices each object (``o`` or ``g``) uses in its faces
    and its triangles (polygons as fans), as indices into the table; objects with faces only."""
    vertices: list[list[bytes]] = []
    used: list[list[int]] = [[]]
    tris: list[list[list[int]]] = [[]]
    with open(path, "rb") as fh:
        for line in fh:
            if line.startswith(b"v "):
                vertices.append(line.split()[1:4])
            elif line.startswith((b"o ", b"g ")):
                if used[-1]:
                    used.append([])
                    tris.append([])
            elif line.startswith(b"f "):
                ids = [int(t.split(b"/")[0]) for t in line.split()[1:]]
                ids = [i - 1 if i > 0 else len(vertices) + i for i in ids]
                used[-1] += ids
                tris[-1] += [[ids[0], ids[k], ids[k + 1]] for k in range(1, len(ids) - 1)]
    table = np.asarray(vertices, dtype=np.float64)
    keep = [k for k, g in enumerate(used) if g]
    return table, [used[k] for k in keep], [np.asarray(tris[k], int).reshape(-1, 3) for k in keep]


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
    """A piece of a collision mesh (or an object of a multi-object one) and what becomes of it."""

    mesh: object  # trimesh.Trimesh
    ratio: float | None  # convex hull volume / volume; None when not closed
    fills: hollow.Hollow | None = None  # what its hull fills, in the object's frame

    @property
    def filled(self) -> bool:
        return self.fills is not None and self.fills.filled

    @property
    def concave(self) -> bool:
        return self.filled or (self.ratio is not None and self.ratio > CONCAVE_RATIO)

    def words(self) -> str:
        if self.ratio is not None and self.ratio > CONCAVE_RATIO:
            return f"its convex hull is {self.ratio:.1f}x its volume"
        closed = "" if self.ratio is not None else "not closed; "
        return f"{closed}its convex hull makes {self.fills.words()}"


def _read(path: Path) -> list | None:
    """The objects of the mesh at ``path`` (one unless an OBJ names several), each as the file
    connects it (no vertex merged), or ``None`` when they are not of finite vertices
    (refused, or built as they are, by ``assets.py``)."""
    import trimesh  # only where a mesh is read

    try:
        if path.suffix.lower() == ".obj" and len(obj_objects(path)) > 1:
            table, _, tris = obj_groups(path)
            meshes = [trimesh.Trimesh(table, t, process=False) for t in tris]
        else:
            meshes = [load_mesh(path)]
    except Exception:  # unreadable: refused with its reason where the mesh is checked
        return None
    out = []
    for mesh in meshes:
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            return None
        # the shape alone: normals and texture coordinates would keep equal positions apart
        mesh = once_each(trimesh.Trimesh(mesh.vertices, mesh.faces, process=False))
        mesh.remove_unreferenced_vertices()
        if not np.isfinite(mesh.vertices).all():
            return None
        out.append(mesh)
    return out


def pieces(mesh, frame: tuple | None = None, patch: bool = False) -> list[Piece]:
    """The pieces of a one-object mesh: its closed surfaces as the file connects them (parts
    written one after another, touching or not), else -- when one is open, as in a file of
    unshared triangles -- the surfaces its equal vertex positions join; with ``frame`` (the
    file's to the object's, :data:`YUP_FRAME`), what each one's hull fills. ``patch``: holes of
    one triangle or quad closed (trimesh's repair; a box's missing lid is one quad)."""
    import trimesh  # only where a mesh is read

    found = mesh.split(only_watertight=False, repair=patch)
    if not all(p.is_watertight for p in found):
        merged = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True)  # equal positions
        found = once_each(merged).split(only_watertight=False, repair=patch)
    return [_piece(p, frame) for p in found]


def _piece(p, frame: tuple | None) -> Piece:
    if p.is_watertight and p.is_winding_consistent and p.volume < 0:
        p = p.copy()  # closed, written inside out (every face turned inward)
        p.invert()
    ratio = p.convex_hull.volume / p.volume if p.is_volume and p.volume > 0 else None
    return Piece(p, ratio, None if frame is None else fill(p, [p.vertices], frame))


def fill(mesh, parts: list[np.ndarray], frame: tuple) -> hollow.Hollow:
    """What convex ``parts`` (vertices in the file's frame) fill of ``mesh``'s hollows, probed
    in the object's frame (``frame``: the file's to it, row-major)."""
    turn = np.asarray(frame, dtype=np.float64).reshape(3, 3).T
    return hollow.filled_hollow(mesh.triangles @ turn, [np.asarray(v) @ turn for v in parts])


def once_each(mesh):
    """``mesh`` with each face written more than once (the same three vertices, either way
    round) kept once: a face written twice joins no neighbour, and splits a closed surface
    into pieces of a face each."""
    import trimesh  # only where a mesh is read

    _, first = np.unique(np.sort(mesh.faces, axis=1), axis=0, return_index=True)
    if len(first) == len(mesh.faces):
        return mesh
    return trimesh.Trimesh(mesh.vertices, mesh.faces[np.sort(first)], process=False)


def concavity(path: Path, frame: tuple = YUP_FRAME) -> str | None:
    """Why the collision mesh at ``path`` would be filled in by the simulator, in words, or
    ``None`` (convex objects or pieces, degenerate, or unreadable)."""
    plan = _plan(path, frame)
    return None if plan is None else plan[0]


def _plan(path: Path, frame: tuple) -> tuple[str, list[Piece]] | None:
    objects = _read(path)
    if objects is None or thickness(np.concatenate([m.vertices for m in objects])) < (
        MIN_COLLISION_THICKNESS
    ):
        return None  # degenerate: refused by assets.py before anything is decomposed
    if len(objects) > 1:  # one hull per object in the simulator: its hollows are filled
        whole = [_piece(m, frame) for m in objects]
        if not any(p.filled for p in whole):
            return None
        found = [q for p in whole for q in (pieces(p.mesh, frame) if p.filled else [p])]
        worst = max((p for p in whole if p.filled), key=lambda p: p.fills.gap)
        count = sum(p.filled for p in whole)
        return f"{len(objects)} objects, {count} of them concave ({worst.words()})", found
    found = pieces(objects[0], frame)
    concave = [p for p in found if p.concave]
    if len(found) == 1:
        return (f"one concave object ({concave[0].words()})", found) if concave else None
    reason = f"one object of {len(found)} disconnected pieces"
    if concave:
        worst = max(concave, key=lambda p: p.fills.gap if p.fills else 0.0)
        reason += f", {len(concave)} of them concave ({worst.words()})"
    return reason, found


def convex_collision(path: Path, frame: tuple = YUP_FRAME) -> Path:
    """The collision mesh to build from: ``path`` itself, or its convex parts when the simulator
    would fill it in (see the module's docstring); ``frame``: the file's frame to the object's
    as it rests (Z up), row-major, where hollows are probed."""
    stat = path.stat()
    frame = tuple(round(float(x), 6) + 0.0 for x in frame)
    env = os.environ.get(OPT_OUT_ENV)
    return _convex_collision(path, stat.st_size, stat.st_mtime_ns, env, frame)


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
            hollow=(hollow.HOLLOW_TOLERANCE, hollow.PROBES, hollow.PROBE_MARGIN),
            floor=float(hollow.FLOOR_TILT),
            shell=hollow.SHELL_THICKNESS,
            retries=COACD_RETRIES,
        ),
        sort_keys=True,
    )


@functools.lru_cache(maxsize=1024)
def _convex_collision(
    path: Path, size: int, mtime_ns: int, opt_out: str | None, frame: tuple
) -> Path:
    digest = hashlib.sha256(path.read_bytes())
    digest.update(_settings().encode())
    digest.update(repr(frame).encode())
    out = cache_folder() / f"{digest.hexdigest()[:32]}.obj"
    if opt_out != "0" and out.is_file():  # made before from these bytes with these settings
        with open(out) as fh:
            reason, outcome = fh.readline()[2:].strip(), fh.readline()
    else:
        plan = _plan(path, frame)
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
        outcome = _decompose(path, out, reason, found, frame)
    if outcome.startswith(KEPT):
        _warn_once(
            path,
            f"{path}: {reason}; {outcome[len(KEPT) :].strip()}, so it is kept as written: the "
            "simulator makes one convex hull of it, a solid blob. Fix: export one object per "
            "convex part (EmbodiedGen's CoACD export does), closed where it is hollow.",
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


def _decompose(path: Path, out: Path, reason: str, found: list[Piece], frame: tuple) -> str:
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
        parts = [p for i, piece in enumerate(found) for p in _convex_parts(piece, i, frame)]
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


def _convex_parts(piece: Piece, index: int, frame: tuple) -> list[np.ndarray]:
    """The vertices of each convex part of a piece: its hull's, or CoACD's parts of it (of its
    shell when open) checked against it: bounds within ``BOUNDS_TOLERANCE``, volume within
    ``VOLUME_RATIO`` (closed), no hollow filled (probed in ``frame``)."""
    mesh = piece.mesh
    if thickness(mesh.vertices) < MIN_COLLISION_THICKNESS:
        raise Refused(f"its piece {index} is flat")
    if not piece.concave:
        v = np.asarray(mesh.vertices)
        return [v[ConvexHull(v).vertices]]
    solid = mesh if piece.ratio is not None else hollow.shell(mesh)
    if solid is None:
        raise Refused(f"its piece {index} is open and cannot be made a closed shell")
    threshold = COACD_PARAMS["threshold"]
    for _ in range(COACD_RETRIES + 1):
        parts = _coacd_parts(mesh, solid, index, threshold)
        still = fill(mesh, parts, frame)
        if not still.filled:
            return parts
        threshold /= 2  # a share of the piece's half size: a 4 mm dip in a 16 cm bowl at 0.05
    raise Refused(f"the convex parts of its piece {index} still make {still.words()}")


def _coacd_parts(mesh, solid, index: int, threshold: float) -> list[np.ndarray]:
    """CoACD's convex parts of ``solid`` (``mesh``, or its shell) at ``threshold``, clamped
    into ``mesh``'s bounds and checked against it (bounds, and volume when closed)."""
    import coacd  # only where a mesh is decomposed (rare): importing it costs start-up

    coacd.set_log_level("error")
    params = COACD_PARAMS | dict(threshold=threshold)
    result = coacd.run_coacd(coacd.Mesh(solid.vertices, solid.faces), **params)
    lo, hi = mesh.bounds  # a shell's parts are clamped into its surface's bounds
    allowed = BOUNDS_TOLERANCE + (hollow.SHELL_THICKNESS / 2 if solid is not mesh else 0.0)
    parts, volume = [], 0.0
    for verts, _ in result:
        verts = np.asarray(verts, dtype=np.float64)
        reach = max(float((lo - verts).max()), float((verts - hi).max()))
        if reach > allowed:
            raise Refused(
                f"a convex part of its piece {index} reaches {reach * 1000:.1f} mm past the "
                f"piece's bounds (over {allowed * 1000:g} mm)"
            )
        verts = np.clip(verts, lo, hi)
        if thickness(verts) < MIN_COLLISION_THICKNESS / 10:
            continue  # a sliver CoACD cut off: no volume to collide with
        hull = ConvexHull(verts)
        parts.append(verts[hull.vertices])
        volume += float(hull.volume)
    ratio = volume / mesh.volume if solid is mesh else 1.0  # a shell's clamped parts: less
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
    return float(hollow.part_tops(parts, np.asarray(xy, dtype=np.float64))[0])
