#!/usr/bin/env python
"""Benchmark: making convex parts of collision meshes written as one object, on the shipped
concave assets (``layout/collision.py``).

Each asset is copied to a temporary folder twice, its collision mesh rewritten as one object:
``parts`` (its convex parts as shipped, written as one object: pieces, one hull each) and
``visual`` (its visual mesh as the collision mesh: closed concave pieces go to CoACD). Times
``parse_urdf`` + ``asset_geometry`` -- what loading an asset costs -- with an empty cache
(first load) and again with the cache filled (a new process: this process's memory cleared),
against the shipped asset (one object per part, nothing to decompose) in the same run. Prints
per asset and form the seconds, the ratios to the baseline, the parts, how far the parts' bounds
are from the mesh's, their volume over the mesh's, and for receptacles the floor's height at
the centre (parts minus mesh).

Usage: python tools/bench/bench_decompose.py [--assets table bowl ...] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import ConvexHull

from embodied_envs.layout import asset_geometry, parse_urdf
from embodied_envs.layout import collision as col
from embodied_envs.layout.assets import ASSET_FILES
from embodied_envs.paths import data_root

CONCAVE = ["table", "round_table", "tray", "bowl", "fruit_bowl", "mug", "banana"]
RECEPTACLES = ("bowl", "fruit_bowl", "mug")  # the floor at the centre is reported


def one_object(text: str) -> str:
    """An OBJ's text without its object, group and material lines: one object."""
    skip = ("o ", "g ", "mtllib", "usemtl")
    return "\n".join(x for x in text.splitlines() if not x.startswith(skip)) + "\n"


def load_seconds(urdf: Path, repeat: int) -> tuple[float, object]:
    """The least time of ``repeat`` loads, this process's memory of assets cleared each time."""
    best, spec = np.inf, None
    for _ in range(repeat):
        col._convex_collision.cache_clear()
        ASSET_FILES.clear()
        start = time.perf_counter()
        spec = parse_urdf(urdf)
        asset_geometry(spec)
        best = min(best, time.perf_counter() - start)
    return best, spec


def shape_numbers(name: str, original: Path, spec) -> str:
    mesh = trimesh.load(original, force="mesh", process=False)
    geom = asset_geometry(spec)
    raw = [np.asarray(p) for p in col.obj_objects(spec.collision.path)]
    allv = np.concatenate(raw)
    lo, hi = mesh.bounds
    gap = max(np.abs(allv.min(0) - lo).max(), np.abs(allv.max(0) - hi).max())
    pieces = col.pieces(mesh)
    volume = sum(p.mesh.volume for p in pieces) if all(p.ratio for p in pieces) else np.nan
    held = sum(ConvexHull(p).volume for p in raw) / volume
    text = f"{len(raw)} parts, bounds {gap * 1000:.3f} mm off, volume {held:.3f}x"
    if name in RECEPTACLES:
        # at the centre of the largest piece (a mug's body, not its handle)
        hulls = [spec.collision.to_link_frame(np.asarray(p.mesh.vertices)) for p in pieces]
        big = max(hulls, key=lambda v: np.prod(np.ptp(v, 0)))
        centre = (big.min(0) + big.max(0))[:2] / 2
        link = spec.collision.to_link_frame(np.asarray(mesh.vertices))
        axis = link[np.hypot(*(link[:, :2] - centre).T) < 1e-5, 2]
        floor = axis.max() if len(axis) else col.solid_top(hulls, centre)  # convex pieces
        top = col.solid_top(list(geom.parts), centre)
        text += f", floor {1000 * (top - floor):+.2f} mm"
    return text


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--assets", nargs="+", default=CONCAVE)
    ap.add_argument("--repeat", type=int, default=3, help="cached loads timed (the least)")
    args = ap.parse_args(argv)
    root = Path(tempfile.mkdtemp(prefix="bench_decompose_"))
    os.environ[col.CACHE_ENV] = str(root / "cache")
    os.environ.pop(col.OPT_OUT_ENV, None)
    print("| asset | form | first load | cached | shipped | first / shipped | cached / shipped |"
          " parts |")  # fmt: skip
    print("| --- | --- | --- | --- | --- | --- | --- | --- |")
    for name in args.assets:
        shipped = data_root() / "assets" / name / f"{name}.urdf"
        base, _ = load_seconds(shipped, args.repeat)
        for form in ("parts", "visual"):
            folder = root / form / name
            shutil.copytree(shipped.parent, folder)
            mesh = folder / "mesh"
            source = mesh / (f"{name}_collision.obj" if form == "parts" else f"{name}.obj")
            (mesh / f"{name}_collision.obj").write_text(one_object(source.read_text()))
            urdf = folder / f"{name}.urdf"
            first, _ = load_seconds(urdf, 1)
            cached, spec = load_seconds(urdf, args.repeat)
            numbers = shape_numbers(name, mesh / f"{name}_collision.obj", spec)
            print(
                f"| {name} | {form} | {first:.2f} s | {cached * 1000:.1f} ms | "
                f"{base * 1000:.1f} ms | {first / base:.0f}x | {cached / base:.2f}x | {numbers} |",
                flush=True,
            )
    shutil.rmtree(root)


if __name__ == "__main__":
    main()
