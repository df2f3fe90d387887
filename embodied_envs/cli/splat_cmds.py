"""``embodied-envs splat render``: look at a Gaussian-splat PLY from a camera."""

from __future__ import annotations

from pathlib import Path


def add_parser(sub) -> None:
    p = sub.add_parser("splat", help="Gaussian-splat tools")
    ssub = p.add_subparsers(dest="splat_cmd", required=True)
    r = ssub.add_parser("render", help="render a gs_model.ply to PNG")
    r.add_argument("ply", type=Path)
    r.add_argument("--eye", type=float, nargs=3, required=True)
    r.add_argument("--target", type=float, nargs=3, required=True)
    r.add_argument("--up", type=float, nargs=3, default=[0.0, 0.0, 1.0])
    r.add_argument("--width", type=int, default=256)
    r.add_argument("--height", type=int, default=256)
    r.add_argument("--fovy", type=float, default=60.0, help="vertical field of view, degrees")
    r.add_argument("--backend", choices=["torch", "gsplat"], default="torch")
    r.add_argument("--out", type=Path, required=True)
    r.add_argument("--depth-out", type=Path, default=None, help="16-bit PNG of depth (mm)")
    r.set_defaults(func=cmd_render)


def cmd_render(args) -> int:
    from embodied_envs.splat.cli_render import render_to_png

    return render_to_png(args)
