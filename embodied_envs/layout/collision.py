"""Collision meshes the simulator would fill in, decomposed into convex parts when loaded.

SAPIEN's ``add_multiple_convex_collisions_from_file`` makes one convex hull of each object
(``o`` / ``g``) of an OBJ file, and one of the whole mesh for other formats. EmbodiedGen's CoACD
export writes one object per convex part, but a user's own export often writes a concave mesh
(a mug, a bowl, a table on legs) as one object: the simulator then fills it in (a mug becomes a
solid cylinder), and grasps, placement and "in the bowl" go wrong without a word.

A collision mesh that is one object and clearly not convex -- watertight with its convex hull
over ``CONCAVE_RATIO`` times its volume, or made of several disconnected pieces -- is decomposed
with CoACD (``COACD_PARAMS``, seeded) into an OBJ of one object per convex part, written once to
the cache folder (``$EMBODIED_ENVS_CACHE``, else ``~/.cache/embodied_envs``; named by the
mesh's content, so an edited mesh is decomposed again; never beside the user's files) with a
progress line on stderr. ``EMBODIED_ENVS_DECOMPOSE=0`` keeps such meshes as they are, with one
warning per file naming it and the fix. ``layout validate`` lists what was decomposed
(:data:`DECOMPOSED`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from embodied_envs.paths import atomic_output

CONCAVE_RATIO = 1.3  # convex hull volume / mesh volume above which one object is concave
# CoACD settings: concavity threshold 0.1 and at most 16 parts (a mug in ~10-30 s on one core)
COACD_PARAMS = dict(
    threshold=0.1,
    max_convex_hull=16,
    preprocess_resolution=30,
    resolution=1000,
    mcts_nodes=10,
    mcts_iterations=60,
    seed=0,
)
OPT_OUT_ENV = "EMBODIED_ENVS_DECOMPOSE"  # "0": keep one-object concave meshes (warned once)
CACHE_ENV = "EMBODIED_ENVS_CACHE"

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


def cache_folder() -> Path:
    root = os.environ.get(CACHE_ENV) or Path.home() / ".cache" / "embodied_envs"
    return Path(root) / "collision"


def concavity(path: Path) -> str | None:
    """Why the collision mesh at ``path`` would be filled in by the simulator, in words, or
    ``None`` (several objects, convex, or not measurable: not watertight)."""
    import trimesh  # only where a mesh is read

    try:
        if path.suffix.lower() == ".obj" and len(obj_objects(path)) > 1:
            return None  # one convex hull per object: EmbodiedGen's own export
        mesh = trimesh.load(path, force="mesh", process=True, skip_materials=True)
    except Exception:  # unreadable: refused with its reason where the mesh is checked
        return None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        return None
    pieces = mesh.split(only_watertight=False)
    if len(pieces) > 1:
        return f"one object of {len(pieces)} disconnected pieces"
    if not mesh.is_watertight or mesh.volume <= 0:
        return None
    ratio = mesh.convex_hull.volume / mesh.volume
    if ratio > CONCAVE_RATIO:
        return f"one concave object (its convex hull is {ratio:.1f}x its volume)"
    return None


def convex_collision(path: Path) -> Path:
    """The collision mesh to build from: ``path`` itself, or its decomposition into convex
    parts when the simulator would fill it in (see the module's docstring)."""
    stat = path.stat()
    return _convex_collision(path, stat.st_size, stat.st_mtime_ns, os.environ.get(OPT_OUT_ENV))


@functools.lru_cache(maxsize=1024)
def _convex_collision(path: Path, size: int, mtime_ns: int, opt_out: str | None) -> Path:
    reason = concavity(path)
    if reason is None:
        return path
    if opt_out == "0":
        if path not in _WARNED:
            _WARNED.add(path)
            warnings.warn(
                f"{path}: {reason}; the simulator makes one convex hull of it, a solid blob "
                f"(kept: {OPT_OUT_ENV}=0). Fix: export one object per convex part (EmbodiedGen's "
                f"CoACD export does), or unset {OPT_OUT_ENV} to decompose it on load.",
                stacklevel=2,
            )
        return path
    digest = hashlib.sha256(path.read_bytes())
    digest.update(json.dumps(COACD_PARAMS, sort_keys=True).encode())
    out = cache_folder() / f"{digest.hexdigest()[:32]}.obj"
    if not out.is_file():
        _decompose(path, out, reason)
    DECOMPOSED[path] = (reason, out)
    return out


def _decompose(path: Path, out: Path, reason: str) -> None:
    import coacd  # only where a mesh is decomposed (rare): importing it costs start-up
    import trimesh  # only where a mesh is read

    print(
        f"{path}: {reason}; decomposing it into convex parts with CoACD (seed "
        f"{COACD_PARAMS['seed']}), once, cached in {out.parent} ...",
        file=sys.stderr,
        flush=True,
    )
    start = time.perf_counter()
    mesh = trimesh.load(path, force="mesh", process=True, skip_materials=True)
    coacd.set_log_level("error")
    parts = coacd.run_coacd(coacd.Mesh(mesh.vertices, mesh.faces), **COACD_PARAMS)
    lines, base = [f"# {len(parts)} convex parts of {path.name} (CoACD {COACD_PARAMS})"], 1
    for i, (verts, faces) in enumerate(parts):
        lines.append(f"o part{i}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in np.asarray(verts)]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in np.asarray(faces)]
        base += len(verts)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(out) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
    seconds = time.perf_counter() - start
    print(f"{path}: {len(parts)} convex parts in {seconds:.1f} s", file=sys.stderr, flush=True)
