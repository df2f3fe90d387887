"""Reading and writing 3DGS PLY files (the INRIA layout).

A file holds one binary little-endian ``vertex`` element with the properties ``x y z``,
optionally ``nx ny nz``, ``f_dc_0..2``, ``f_rest_0..(3*((d+1)^2-1)-1)`` (channel-major),
``opacity``, ``scale_0..2`` and ``rot_0..3`` (w x y z). Other elements may precede or follow it
as long as their properties are scalars.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from embodied_envs.paths import atomic_output
from embodied_envs.splat.sh import MAX_SH_DEGREE, sh_coeff_count

if TYPE_CHECKING:
    import torch

    from embodied_envs.splat.model import GaussianSplat

PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
REQUIRED = (
    "x",
    "y",
    "z",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
)
MAX_HEADER_BYTES = 1 << 20  # a header longer than this is not a PLY header


class SplatFileError(ValueError):
    """A splat PLY file is missing, malformed or not in the 3DGS layout; names file and fix."""

    def __init__(self, path: str | os.PathLike, problem: str, fix: str):
        self.path = Path(path)
        super().__init__(f"{self.path}: {problem}. Fix: {fix}")


def _read_header(path: Path, data: bytes) -> tuple[list[tuple[str, int, list]], int, str]:
    end = data.find(b"end_header\n", 0, MAX_HEADER_BYTES)
    if not data.startswith(b"ply\n") or end < 0:
        raise SplatFileError(
            path,
            "not a PLY file (no 'ply' magic line or no 'end_header')",
            "give a 3DGS PLY file, e.g. the point_cloud.ply a 3DGS training run writes",
        )
    elements: list[tuple[str, int, list]] = []
    fmt = ""
    for raw in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1] if len(words) > 1 else ""
        elif words[0] == "element" and len(words) == 3:
            if not words[2].isdigit():
                raise SplatFileError(
                    path,
                    f"element {words[1]!r} has count {words[2]!r}, not a non-negative integer",
                    "re-export the splat",
                )
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list":
                elements[-1][2].append((words[-1], None))
            elif len(words) == 3 and words[1] in PLY_TYPES:
                elements[-1][2].append((words[2], PLY_TYPES[words[1]]))
            else:
                raise SplatFileError(
                    path,
                    f"unknown PLY property line {raw!r}",
                    "re-export the file with standard PLY types",
                )
        else:
            raise SplatFileError(
                path, f"malformed PLY header line {raw!r}", "re-export the file as a standard PLY"
            )
    return elements, end + len(b"end_header\n"), fmt


MAX_SCALE = 1e3  # m: a Gaussian larger than this is a corrupt value, not a scene part
MAX_MEAN = 1e4  # m: a Gaussian centred farther from the origin is a corrupt value


CHECK_CHUNK = 1 << 18  # Gaussians checked at a time by check_ply (bounded memory)


def read_ply_arrays(path: str | os.PathLike) -> dict[str, np.ndarray | None]:
    """Read and check a 3DGS PLY file with numpy alone (no torch: ``layout validate`` uses it).

    Returns:
        float32 arrays: ``means (N, 3)``, ``quats_wxyz (N, 4)``, ``log_scales (N, 3)``,
        ``opacity_logits (N,)``, ``sh (N, K, 3)`` and ``normals (N, 3)`` or None.

    Raises:
        SplatFileError: the file is missing, not binary little-endian, has no ``vertex``
            element, lacks a required property, has an SH property count that is not a degree
            0..3 one, is shorter than its header promises, holds no Gaussians, or holds a NaN,
            a scale over ``MAX_SCALE``, a mean over ``MAX_MEAN`` or an all-zero quaternion.
    """
    path = Path(path)
    if not path.is_file():
        raise SplatFileError(
            path,
            "file does not exist",
            "check the path (a layout's background folder needs gs_model.ply)",
        )
    vertices, degree = _open_vertices(path)
    arrays = _columns(vertices, degree)
    _check_values(path, arrays)
    return arrays


def _open_vertices(path: Path) -> tuple[np.ndarray, int]:
    """The vertex element of a checked header, memory-mapped (nothing is read yet), and its
    SH degree."""
    with open(path, "rb") as fh:
        data = fh.read(MAX_HEADER_BYTES)
    size = path.stat().st_size
    elements, offset, fmt = _read_header(path, data)
    if fmt != "binary_little_endian":
        raise SplatFileError(
            path,
            f"PLY format is {fmt or 'missing'!r}, only binary_little_endian is read",
            "re-export the splat as binary little-endian PLY",
        )
    vertex = None
    for name, count, props in elements:
        if any(dtype is None for _, dtype in props):
            if name == "vertex" or vertex is None:
                raise SplatFileError(
                    path,
                    f"element {name!r} has list properties",
                    "give a 3DGS PLY whose vertex properties are scalars",
                )
            break  # after the vertex element: never read
        dtype = np.dtype([(p, "<" + t) for p, t in props])
        if name == "vertex":
            vertex = (count, dtype, offset)
            break
        offset += count * dtype.itemsize
    if vertex is None:
        raise SplatFileError(
            path, "no 'vertex' element", "give a 3DGS PLY whose Gaussians are the 'vertex' element"
        )
    count, dtype, offset = vertex
    if count == 0:
        raise SplatFileError(path, "it holds 0 Gaussians", "export a splat with Gaussians in it")
    names = set(dtype.names)
    missing = [p for p in REQUIRED if p not in names]
    if missing:
        raise SplatFileError(
            path,
            f"vertex element lacks the properties {missing}",
            "write every 3DGS property (x y z, f_dc_*, opacity, scale_*, rot_*)",
        )
    n_rest = sum(1 for p in names if p.startswith("f_rest_"))
    degrees = {3 * (sh_coeff_count(d) - 1): d for d in range(MAX_SH_DEGREE + 1)}
    if n_rest not in degrees or any(f"f_rest_{i}" not in names for i in range(n_rest)):
        raise SplatFileError(
            path,
            f"{n_rest} f_rest_* properties, not numbered 0.. or not a count for SH degree "
            "0..3 (0, 9, 24 or 45)",
            "write f_rest_0..f_rest_{3*((d+1)^2-1)-1} for one degree d",
        )
    need = offset + count * dtype.itemsize
    if size < need:
        have = max(0, (size - offset) // dtype.itemsize)
        raise SplatFileError(
            path,
            f"truncated: the header promises {count} vertices ({need} bytes) but the file "
            f"has {size} bytes ({have} whole vertices)",
            "re-copy or re-export the file; it was cut short",
        )
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=(count,)), degrees[n_rest]


def _columns(v: np.ndarray, degree: int) -> dict[str, np.ndarray | None]:
    """float32 arrays of (a slice of) the vertex element."""
    count, names = len(v), set(v.dtype.names)
    n_rest = 3 * (sh_coeff_count(degree) - 1)

    def cols(*props: str) -> np.ndarray:
        return np.stack([v[p].astype(np.float32) for p in props], axis=1)

    k = sh_coeff_count(degree)
    sh = cols("f_dc_0", "f_dc_1", "f_dc_2")[:, None, :]
    if k > 1:
        rest = cols(*(f"f_rest_{i}" for i in range(n_rest))).reshape(count, 3, k - 1)
        sh = np.concatenate([sh, rest.transpose(0, 2, 1)], axis=1)
    arrays = dict(
        means=cols("x", "y", "z"),
        quats_wxyz=cols("rot_0", "rot_1", "rot_2", "rot_3"),
        log_scales=cols("scale_0", "scale_1", "scale_2"),
        opacity_logits=cols("opacity")[:, 0],
        sh=np.ascontiguousarray(sh),
        normals=cols("nx", "ny", "nz") if {"nx", "ny", "nz"} <= names else None,
    )
    return arrays


def _check_values(path: Path, a: dict[str, np.ndarray | None], first: int = 0) -> None:
    """Refuse NaN, huge scales, far means and zero quaternions; vertex numbers count from
    ``first`` (the chunk's start)."""
    count = len(a["means"])
    values = [a["means"], a["quats_wxyz"], a["log_scales"], a["opacity_logits"][:, None]]
    bad = ~np.isfinite(np.concatenate([*values, a["sh"].reshape(count, -1)], 1)).all(1)
    if bad.any():
        raise SplatFileError(
            path,
            f"{int(bad.sum())} Gaussians have a NaN or infinite value (first: vertex "
            f"{first + int(bad.nonzero()[0][0])})",
            "remove them or re-export the splat",
        )
    huge = a["log_scales"].max(1) > math.log(MAX_SCALE)
    if huge.any():
        raise SplatFileError(
            path,
            f"{int(huge.sum())} Gaussians have a scale over {MAX_SCALE:g} m (first: vertex "
            f"{first + int(huge.nonzero()[0][0])}, scale "
            f"exp({float(a['log_scales'][huge][0].max()):.3g}))",
            "scale_* are natural logs of metres in a 3DGS PLY; remove those Gaussians",
        )
    far = np.abs(a["means"]).max(1) > MAX_MEAN
    if far.any():
        k = int(far.nonzero()[0][0])
        raise SplatFileError(
            path,
            f"{int(far.sum())} Gaussians lie over {MAX_MEAN:g} m from the origin (first: vertex "
            f"{first + k}, x y z = {a['means'][k].tolist()})",
            "x y z are metres in the splat's frame; remove those Gaussians or re-export the splat",
        )
    flat = np.linalg.norm(a["quats_wxyz"], axis=1) < 1e-8
    if flat.any():
        raise SplatFileError(
            path,
            f"{int(flat.sum())} Gaussians have an all-zero rotation quaternion (first: vertex "
            f"{first + int(flat.nonzero()[0][0])})",
            "write unit quaternions rot_0..3 (w x y z)",
        )


def check_ply(path: str | os.PathLike) -> int:
    """Check a 3DGS PLY file without torch; returns its number of Gaussians.

    Raises:
        SplatFileError: as :func:`read_ply_arrays`.
    """
    path = Path(path)
    if not path.is_file():
        read_ply_arrays(path)  # the missing-file error
    vertices, degree = _open_vertices(path)
    count, offset = len(vertices), vertices.offset
    with open(path, "rb") as fh:  # read chunk by chunk: memory bounded by the chunk, not N
        fh.seek(offset)
        for start in range(0, count, CHECK_CHUNK):
            chunk = np.fromfile(fh, dtype=vertices.dtype, count=min(CHECK_CHUNK, count - start))
            _check_values(path, _columns(chunk, degree), start)
    return count


def read_ply(path: str | os.PathLike) -> GaussianSplat:
    """Read a 3DGS PLY file into a :class:`GaussianSplat` (float32, CPU).

    Raises:
        SplatFileError: as :func:`read_ply_arrays`.
    """
    # torch only here: checking a PLY (layout validate) is numpy-only and starts without it
    import torch

    from embodied_envs.splat.model import GaussianSplat

    arrays = read_ply_arrays(path)
    return GaussianSplat(
        **{k: None if v is None else torch.from_numpy(v) for k, v in arrays.items()}
    )


def write_ply(splat: GaussianSplat, path: str | os.PathLike) -> Path:
    """Write a splat as a binary little-endian 3DGS PLY (float32, INRIA property order)."""
    path = Path(path)
    n, k = len(splat), splat.sh.shape[1]
    columns: list[tuple[str, np.ndarray]] = []

    def add(prefix_names: list[str], values: torch.Tensor) -> None:
        arr = values.detach().cpu().float().numpy().reshape(n, -1)
        columns.extend((name, arr[:, i]) for i, name in enumerate(prefix_names))

    add(["x", "y", "z"], splat.means)
    if splat.normals is not None:
        add(["nx", "ny", "nz"], splat.normals)
    add([f"f_dc_{i}" for i in range(3)], splat.sh[:, 0])
    if k > 1:
        add([f"f_rest_{i}" for i in range(3 * (k - 1))], splat.sh[:, 1:].transpose(1, 2))
    add(["opacity"], splat.opacity_logits)
    add([f"scale_{i}" for i in range(3)], splat.log_scales)
    add([f"rot_{i}" for i in range(4)], splat.quats_wxyz)
    table = np.empty(n, dtype=np.dtype([(name, "<f4") for name, _ in columns]))
    for name, col in columns:
        table[name] = col
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {name}" for name, _ in columns]
    header.append("end_header")
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(path) as tmp, tmp.open("wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(table.tobytes())
    return path
