"""Generated data compared as data, so that a generator of ``tools/make/`` re-run on another
processor or with another numpy/scipy/trimesh release still matches what is shipped, and a real
change still fails (``tests/test_shipped_data.py``):

- OBJ meshes by geometry: per object (``o``), the same vertices within one step of the written
  precision, and the same surface: faces as sets, coplanar faces merged into one facet (qhull's
  convex hulls come in another face order, and may split a flat side along its other diagonal,
  on another machine), each facet by its oriented boundary edges; every other line as it is;
- binary PLY files by their values in file order, floats within a relative tolerance of float32;
- JSON files by value, floats within a relative tolerance;
- anything else byte for byte.

Each tolerance is stated once, below, with the quantity it follows from."""

from __future__ import annotations

import itertools
import json
import math
from collections import Counter
from pathlib import Path

import numpy as np
import trimesh

# the OBJ writers' precision (tools/make/make_assets.py, write_obj: "%.6f", metres): a last-bit
# difference of a coordinate computed on another processor rounds, at most, to the neighbouring
# step, so a vertex matches within one step on each axis; a real change moves one by far more
OBJ_STEP = 1e-6  # m
# float32 values of a PLY (the room's mesh, the splat): float64 arithmetic that differs in its
# last bits, rounded to float32 (2**-23 relative), then carried through the splat's log, exp and
# normalisations: 10 float32 steps, relative to the largest magnitude of the column
FLOAT32_RTOL = 10 * 2.0**-23
# JSON numbers are Python floats written in full (repr): float64 steps (2**-52), with margin
JSON_RTOL = 1e-12


def differ(got: Path, want: Path) -> str | None:
    """Why the file ``got`` does not hold the data of ``want`` (None when it does)."""
    a, b = got.read_bytes(), want.read_bytes()
    if a == b:
        return None
    compare = {".obj": _obj_differ, ".ply": _ply_differ, ".json": _json_differ}.get(got.suffix)
    if compare is None:
        return "bytes differ"
    return compare(a, b)


# --- OBJ -------------------------------------------------------------------------------------


def parse_obj(data: bytes) -> list[tuple[list[str], np.ndarray, np.ndarray]]:
    """The OBJ's objects in order: (its other lines, vertices as integer steps of OBJ_STEP,
    faces as 0-based indices into them). The lines before the first ``o`` are an object too."""
    objects, lines, verts, faces, first = [], [], [], [], 0
    for line in data.decode().splitlines():
        word = line.split(maxsplit=1)[0] if line.strip() else ""
        if word == "o":
            objects.append((lines, verts, faces, first))
            first += len(verts)
            lines, verts, faces = [], [], []
        if word == "v":
            verts.append([round(float(x) / OBJ_STEP) for x in line.split()[1:4]])
        elif word == "f":
            faces.append([int(x.split("/")[0]) - 1 for x in line.split()[1:]])
        else:
            lines.append(line)
    objects.append((lines, verts, faces, first))
    return [
        (lines, np.array(v, np.int64).reshape(-1, 3), np.array(f, np.int64).reshape(-1, 3) - start)
        for lines, v, f, start in objects
    ]


def _obj_differ(got: bytes, want: bytes) -> str | None:
    try:
        a, b = parse_obj(got), parse_obj(want)
    except (ValueError, UnicodeDecodeError) as err:
        return f"not an OBJ of triangles ({err})"
    if len(a) != len(b):
        return f"{len(a)} objects, not {len(b)}"
    for k, ((lines_a, va, fa), (lines_b, vb, fb)) in enumerate(zip(a, b, strict=True)):
        if lines_a != lines_b:
            return f"object {k}: lines other than v and f differ"
        why = mesh_differ(va, fa, vb, fb)
        if why:
            return f"object {k}: {why}"
    return None


def mesh_differ(va, fa, vb, fb) -> str | None:
    """Why mesh A (integer vertices ``va``, triangles ``fa``) is not mesh B: a vertex of either
    more than one step away from every vertex of the other, or another surface (by facets)."""
    if len(va) != len(vb) or len(fa) != len(fb):
        return f"{len(va)} vertices and {len(fa)} faces, not {len(vb)} and {len(fb)}"
    index = {tuple(v): i for i, v in enumerate(vb.tolist())}
    steps = list(itertools.product((0, -1, 1), repeat=3))
    mapping = []
    for v in va.tolist():
        near = {index[w] for d in steps if (w := (v[0] + d[0], v[1] + d[1], v[2] + d[2])) in index}
        if len(near) != 1:
            return f"vertex {np.array(v) * OBJ_STEP} matches {len(near)} vertices, not one"
        mapping.append(near.pop())
    if sorted(mapping) != list(range(len(vb))):
        return "vertices do not match one to one"
    mapped = np.array(mapping)[fa] if len(fa) else fa
    coords = vb * OBJ_STEP  # both surfaces on B's coordinates: the same coplanar decisions
    if facets(coords, mapped) != facets(coords, fb):
        return "faces differ (as sets of coplanar facets, by their oriented boundaries)"
    return None


def facets(vertices: np.ndarray, faces: np.ndarray) -> Counter:
    """The surface as a multiset of facets (coplanar neighbouring faces, trimesh's ``facets``;
    any other face alone), each by its boundary: the directed edges of its faces that no face
    of it runs back along. Independent of face order and of how a flat facet is triangulated;
    a flipped, moved, missing or added face changes it."""
    if len(faces) == 0:
        return Counter()
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    groups = [list(g) for g in mesh.facets]
    grouped = {i for g in groups for i in g}
    groups += [[i] for i in range(len(faces)) if i not in grouped]
    out = Counter()
    for g in groups:
        edges = Counter((int(f[i]), int(f[(i + 1) % 3])) for f in faces[g] for i in range(3))
        out[frozenset(e for e in edges if (e[1], e[0]) not in edges)] += 1
    return out


# --- PLY -------------------------------------------------------------------------------------

PLY_TYPES = {"float": "<f4", "double": "<f8", "uchar": "u1", "uint8": "u1", "int": "<i4",
             "uint": "<u4", "short": "<i2", "ushort": "<u2", "char": "i1"}  # fmt: skip


def parse_ply(data: bytes) -> tuple[list[str], dict[str, np.ndarray]]:
    """A binary little-endian PLY: its header lines and each element as a structured array
    (a list property as a fixed-length field: the triangles of a mesh)."""
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode().splitlines()
    if "format binary_little_endian 1.0" not in header:
        raise ValueError("not a binary little-endian PLY")
    elements, offset = {}, end
    for name, count, props in _ply_elements(header):
        fields = []
        for prop in props:
            if prop[0] == "list":  # count then items: a fixed count (3: triangles) assumed
                fields += [("n", PLY_TYPES[prop[1]]), (prop[3], PLY_TYPES[prop[2]], 3)]
            else:
                fields.append((prop[1], PLY_TYPES[prop[0]]))
        dtype = np.dtype(fields)
        elements[name] = np.frombuffer(data, dtype, count, offset)
        offset += dtype.itemsize * count
    if offset != len(data):
        raise ValueError(f"{len(data) - offset} bytes after the elements")
    return header, elements


def _ply_elements(header: list[str]):
    elements = []
    for line in header:
        words = line.split()
        if words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            elements[-1][2].append(words[1:])
    return elements


def _ply_differ(got: bytes, want: bytes) -> str | None:
    try:
        (head_a, a), (head_b, b) = parse_ply(got), parse_ply(want)
    except (ValueError, KeyError, IndexError, UnicodeDecodeError) as err:
        return f"bytes differ (not a PLY read here: {err})"
    if head_a != head_b:
        return "headers differ"
    for name in b:
        for field in b[name].dtype.names:
            x, y = a[name][field], b[name][field]
            if y.dtype.kind != "f":
                if not np.array_equal(x, y):
                    return f"{name} {field}: values differ"
            elif not values_close(x, y, FLOAT32_RTOL):
                worst = float(np.nanmax(np.abs(x.astype(float) - y)))
                return f"{name} {field}: values differ by up to {worst:.3g}"
    return None


def values_close(x: np.ndarray, y: np.ndarray, rtol: float) -> bool:
    """Equal within ``rtol`` of the largest magnitude among them (NaNs where NaNs are)."""
    x, y = np.asarray(x, float), np.asarray(y, float)
    scale = float(np.nanmax(np.abs(y), initial=0.0))
    return x.shape == y.shape and np.allclose(x, y, rtol=0.0, atol=rtol * scale, equal_nan=True)


# --- JSON ------------------------------------------------------------------------------------


def _json_differ(got: bytes, want: bytes) -> str | None:
    try:
        a, b = json.loads(got), json.loads(want)
    except (ValueError, UnicodeDecodeError):
        return "bytes differ"  # not JSON (a bad input): bytes are its data
    where = json_differ(a, b, "")
    return where and f"value differs at {where or '/'}"


def json_differ(a, b, where: str) -> str | None:
    """Where JSON value ``a`` is not ``b`` (floats within JSON_RTOL), None when it is."""
    if isinstance(b, float) or isinstance(a, float):
        ok = isinstance(a, int | float) and isinstance(b, int | float)
        return None if ok and math.isclose(a, b, rel_tol=JSON_RTOL) else where or "/"
    if type(a) is not type(b):
        return where or "/"
    if isinstance(b, dict):
        if list(a) != list(b):
            return f"{where}/ (keys)"
        return next((w for k in b if (w := json_differ(a[k], b[k], f"{where}/{k}"))), None)
    if isinstance(b, list):
        if len(a) != len(b):
            return f"{where}/ (length)"
        return next((w for i in range(len(b)) if (w := json_differ(a[i], b[i], f"{where}/{i}"))),
                    None)  # fmt: skip
    return None if a == b else where or "/"
