"""Make the shipped room's splat: ``embodied-envs splat from-mesh`` with the room's defaults.

With no arguments it makes the shipped room background:

    .venv/bin/python tools/make/mesh_to_splat.py
      -> assets/background/gs_model.ply from assets/background/mesh_model.ply

The mesh keeps its frame (the shipped room is Y-up, metres, floor at y = 0). Only faces that
face ``--visible-from`` are sampled (a room seen from the inside) unless ``--all-faces``. The
conversion is the package's (``embodied_envs.splat.mesh_file_to_splat``), which the
``embodied-envs splat from-mesh`` command runs on any mesh.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from embodied_envs.splat import mesh_file_to_splat

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "embodied_envs" / "data"  # package data; ./layouts and ./assets link here
BACKGROUND = DATA / "assets" / "background"
ROOM_INSIDE = (0.0, 1.3, 0.0)  # m, a point inside the shipped room, Y-up


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("mesh", type=Path, nargs="?", default=BACKGROUND / "mesh_model.ply")
    ap.add_argument("--out", type=Path, default=BACKGROUND / "gs_model.ply")
    ap.add_argument("--count", type=int, default=60_000, help="number of Gaussians")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--visible-from",
        type=float,
        nargs=3,
        default=ROOM_INSIDE,
        metavar=("X", "Y", "Z"),
        help="sample only faces facing this point",
    )
    ap.add_argument("--all-faces", action="store_true", help="ignore --visible-from")
    ap.add_argument(
        "--normals", action="store_true", help="also write nx ny nz (unused by renderers; +21%%)"
    )
    args = ap.parse_args(argv)
    visible_from = None if args.all_faces else args.visible_from
    splat = mesh_file_to_splat(
        args.mesh, args.out, args.count, args.seed, visible_from, normals=args.normals
    )
    size_mb = args.out.stat().st_size / 1e6
    print(f"wrote {args.out}: {len(splat)} Gaussians, {size_mb:.1f} MB")


if __name__ == "__main__":
    main()
