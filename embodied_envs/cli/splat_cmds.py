"""``embodied-envs splat render``: look at any 3DGS PLY from a camera; ``splat from-mesh``: make
one from a textured or coloured mesh."""

from __future__ import annotations

import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from embodied_envs.cli.args import image_side, positive_int, seed_int, unit_float
from embodied_envs.paths import atomic_output
from embodied_envs.splat import BACKENDS

DEPTH_PNG_SCALE = 1000.0  # 16-bit depth PNG units per metre (millimetres)


def add_parser(sub) -> None:
    p = sub.add_parser("splat", help="render Gaussian-splat PLY files, or make one from a mesh")
    ssub = p.add_subparsers(dest="splat_cmd", required=True)
    r = ssub.add_parser(
        "render",
        help="render a splat PLY to PNG",
        description="Render a 3DGS PLY (as stored, no pose applied) from a pinhole camera. "
        "Camera model: OpenCV pinhole, square pixels, fy = H / (2 tan(fovy/2)), principal "
        "point at the image centre.",
    )
    r.add_argument("ply", type=Path)
    r.add_argument("--eye", type=float, nargs=3, required=True, metavar=("X", "Y", "Z"))
    r.add_argument("--target", type=float, nargs=3, required=True, metavar=("X", "Y", "Z"))
    r.add_argument("--up", type=float, nargs=3, default=(0.0, 0.0, 1.0), metavar=("X", "Y", "Z"))
    r.add_argument("--width", type=image_side, default=256)
    r.add_argument("--height", type=image_side, default=256)
    r.add_argument("--fovy", type=float, default=60.0, help="vertical field of view, degrees")
    r.add_argument("--backend", choices=[b for b in BACKENDS], default="auto")
    r.add_argument(
        "--background",
        type=unit_float,
        nargs=3,
        default=(0.0, 0.0, 0.0),
        metavar=("R", "G", "B"),
        help="colour behind the splat, in [0, 1]",
    )
    r.add_argument("--out", type=Path, required=True, help="PNG to write")
    r.add_argument(
        "--depth-out",
        type=Path,
        help="also write the expected depth as a 16-bit PNG, in millimetres "
        "(0 where nothing is drawn)",
    )
    r.set_defaults(func=cmd_render)
    m = ssub.add_parser(
        "from-mesh",
        help="convert a textured or coloured mesh into a splat PLY",
        description="Sample flat Gaussians (SH degree 0) on a mesh's surface, area-weighted and "
        "coloured like it (texture, vertex or face colours); the mesh keeps its frame. A room "
        "background: give --visible-from a point inside it, so only faces facing it are sampled.",
    )
    m.add_argument("mesh", type=Path, help="a mesh file trimesh reads (PLY, OBJ, GLB, ...)")
    m.add_argument("--out", type=Path, required=True, help="splat PLY to write")
    m.add_argument("--count", type=positive_int, default=60_000, help="number of Gaussians")
    m.add_argument("--seed", type=seed_int, default=0)
    m.add_argument(
        "--visible-from",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        help="sample only faces facing this point (default: every face)",
    )
    m.add_argument(
        "--normals", action="store_true", help="also write nx ny nz (unused by renderers; +21%%)"
    )
    m.set_defaults(func=cmd_from_mesh)


def cmd_render(args) -> int:
    # the rasterizer imports torch: only when a splat is rendered, not for --help
    from embodied_envs.splat import PinholeCamera, read_ply, render

    camera = PinholeCamera.look_at(
        args.eye, args.target, args.up, args.width, args.height, args.fovy
    )
    splat = read_ply(args.ply)
    start = time.perf_counter()
    image = render(splat, camera, backend=args.backend, background=tuple(args.background))
    seconds = time.perf_counter() - start
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output(args.out) as tmp:
        iio.imwrite(tmp, image.rgb_uint8().cpu().numpy())
    print(f"wrote {args.out} ({len(splat)} Gaussians, {args.width}x{args.height}, {seconds:.2f} s)")
    if args.depth_out is not None:
        depth = image.surface_depth(min_alpha=0.5).cpu().numpy()
        depth = np.where(np.isfinite(depth), depth * DEPTH_PNG_SCALE, 0.0)
        args.depth_out.parent.mkdir(parents=True, exist_ok=True)
        with atomic_output(args.depth_out) as tmp:
            iio.imwrite(tmp, np.clip(np.round(depth), 0, 65535).astype(np.uint16))
        print(f"wrote {args.depth_out} (16-bit depth, mm)")
    return 0


def cmd_from_mesh(args) -> int:
    # trimesh and torch: only when a mesh is converted, not for --help
    from embodied_envs.splat import mesh_file_to_splat

    splat = mesh_file_to_splat(
        args.mesh, args.out, args.count, seed=args.seed, visible_from=args.visible_from,
        normals=args.normals,
    )  # fmt: skip
    size_mb = args.out.stat().st_size / 1e6
    print(f"wrote {args.out}: {len(splat)} Gaussians, {size_mb:.1f} MB")
    return 0
