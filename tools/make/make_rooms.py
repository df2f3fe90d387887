"""Make the shipped splat rooms (``embodied_envs/data/rooms/<name>/gs_model.ply``) and, with
``--held-out``, rooms that are not shipped (for evaluating a visual policy in a room no
demonstration showed).

Each room is a vertex-coloured mesh drawn from a style (floor pattern and colours, wall colours,
a window, furniture on the walls, the light's tint and brightness), in the frame of the shipped
room ``assets/background`` (Y-up, metres, the floor at y = 0, 5 m x 5 m around the origin), then
sampled into Gaussians by the package's ``mesh_to_splat`` (as ``embodied-envs splat from-mesh``).
The shipped pool (``rooms="shipped"``) is the shipped layouts' own room and these.

    .venv/bin/python tools/make/make_rooms.py                 # the shipped rooms
    .venv/bin/python tools/make/make_rooms.py --held-out --out outputs/rooms_held_out
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from embodied_envs.paths import atomic_output
from embodied_envs.splat import mesh_to_splat, write_ply

sys.path.insert(0, str(Path(__file__).resolve().parent))
from make_assets import box, zup_to_yup  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
ROOMS = ROOT / "embodied_envs" / "data" / "rooms"  # package data
ROOM_INSIDE = (0.0, 1.3, 0.0)  # m, a point inside every room, Y-up (faces seen from it)
SIZE, WALL_H = 5.0, 2.6  # m, the rooms' floor side and wall height, as the shipped room's
COUNT = 40_000  # Gaussians per room (~2.2 MB)


@dataclass(frozen=True)
class Style:
    """How one room looks."""

    floor: tuple[tuple[int, int, int], tuple[int, int, int]]  # two floor colours
    pattern: str  # "checker", "stripes", "plain" or "tiles"
    walls: tuple[tuple[int, int, int], ...]  # +y, -y, +x, -x walls
    window_wall: str  # "-x", "+x" or "-y": where the window is
    window: tuple[int, int, int]  # the pane's colour (the sky outside)
    furniture: str  # "shelf", "paintings", "cabinets" or "plants"
    light: tuple[float, float, float]  # per-channel factor on every colour (tint, brightness)
    seed: int  # the furniture's random sizes and colours


SHIPPED_STYLES = {
    "loft": Style(((120, 120, 125), (135, 135, 140)), "tiles",
                  ((170, 80, 60), (235, 235, 235), (225, 225, 230), (230, 230, 235)), "+x",
                  (190, 215, 245), "cabinets", (0.95, 1.0, 1.08), 11),
    "gallery": Style(((200, 170, 120), (185, 155, 105)), "stripes",
                     ((40, 60, 110), (45, 65, 115), (50, 70, 120), (200, 200, 190)), "-y",
                     (150, 190, 230), "paintings", (1.08, 1.0, 0.9), 12),
    "attic": Style(((60, 50, 45), (80, 70, 60)), "checker",
                   ((110, 150, 110), (120, 160, 120), (230, 225, 200), (115, 155, 115)), "-x",
                   (250, 240, 200), "shelf", (1.1, 1.1, 1.1), 13),
}  # fmt: skip
HELD_OUT_STYLES = {
    "den": Style(((150, 60, 70), (150, 60, 70)), "plain",
                 ((230, 160, 60), (120, 70, 140), (240, 235, 225), (125, 75, 145)), "+x",
                 (170, 220, 250), "plants", (0.85, 0.85, 0.9), 21),
}  # fmt: skip


PATTERNS = ("checker", "stripes", "plain", "tiles")
WINDOW_WALLS = ("-x", "+x", "-y")
FURNITURE = ("shelf", "paintings", "cabinets", "plants")


def random_style(rng: np.random.Generator) -> Style:
    """A room drawn from the whole style space (any colours, pattern, window, furniture and
    light): the visual recipe's background swaps (``tools/recipes/perceive.py``)."""

    def colour() -> tuple[int, int, int]:
        return tuple(int(v) for v in rng.integers(20, 251, 3))

    return Style(
        floor=(colour(), colour()),
        pattern=str(rng.choice(PATTERNS)),
        walls=(colour(), colour(), colour(), colour()),
        window_wall=str(rng.choice(WINDOW_WALLS)),
        window=colour(),
        furniture=str(rng.choice(FURNITURE)),
        light=tuple(float(v) for v in rng.uniform(0.8, 1.15, 3)),
        seed=int(rng.integers(1 << 30)),
    )


def _tinted(colour, light) -> tuple[int, int, int]:
    return tuple(int(np.clip(c * f, 0, 255)) for c, f in zip(colour, light, strict=True))


def room_mesh(style: Style) -> trimesh.Trimesh:
    """The room of ``style`` (Z-up design, turned Y-up), vertex coloured."""
    rng = np.random.default_rng(style.seed)
    pieces = []

    def add(mesh, colour):
        rgba = np.array([*_tinted(colour, style.light), 255], np.uint8)
        mesh.visual.vertex_colors = np.tile(rgba, (len(mesh.vertices), 1))
        pieces.append(mesh)

    n = {"checker": 10, "tiles": 20, "stripes": 16, "plain": 1}[style.pattern]
    for i in range(n):
        for j in range(1 if style.pattern in ("stripes", "plain") else n):
            rows = 1 if style.pattern in ("stripes", "plain") else n
            centre = [-SIZE / 2 + (i + 0.5) * SIZE / n, -SIZE / 2 + (j + 0.5) * SIZE / rows, -0.01]
            tile = box([SIZE / n, SIZE / rows, 0.02], centre)
            add(tile, style.floor[(i + j) % 2])
    half = SIZE / 2
    walls = {
        "+y": ([SIZE, 0.05, WALL_H], [0, half, WALL_H / 2]),
        "-y": ([SIZE, 0.05, WALL_H], [0, -half, WALL_H / 2]),
        "+x": ([0.05, SIZE, WALL_H], [half, 0, WALL_H / 2]),
        "-x": ([0.05, SIZE, WALL_H], [-half, 0, WALL_H / 2]),
    }
    for (ext, centre), colour in zip(walls.values(), style.walls, strict=True):
        add(box(ext, centre), colour)
    # the window: a pane and a white frame, 4 cm in front of its wall
    axis, sign = (0, 1.0) if style.window_wall.endswith("x") else (1, 1.0)
    sign = -1.0 if style.window_wall.startswith("-") else 1.0
    inset = sign * (half - 0.04)

    def on_wall(depth, width, height, along, z, wall_axis=axis, at=inset):
        ext = [depth, width, height] if wall_axis == 0 else [width, depth, height]
        centre = [at, along, z] if wall_axis == 0 else [along, at, z]
        return box(ext, centre)

    add(on_wall(0.02, 1.6, 1.0, 0.3, 1.5), style.window)
    for dz in (-0.52, 0.52):
        add(on_wall(0.03, 1.7, 0.06, 0.3, 1.5 + dz), (250, 250, 250))
    for dy in (-0.82, 0.3, 1.12):
        add(on_wall(0.03, 0.06, 1.06, dy, 1.5), (250, 250, 250))
    # furniture on the +y wall
    back = half - 0.2
    if style.furniture == "shelf":
        for z in (0.5, 1.0, 1.5):
            add(box([1.6, 0.3, 0.03], [-0.8, back, z]), (120, 80, 50))
        for z in (0.5, 1.0):
            x = -1.55
            while x < -0.1:
                w, hgt = rng.uniform(0.03, 0.07), rng.uniform(0.18, 0.3)
                add(box([w, 0.2, hgt], [x + w / 2, back, z + 0.015 + hgt / 2]),
                    tuple(int(v) for v in rng.integers(40, 230, 3)))  # fmt: skip
                x += w + 0.005
    elif style.furniture == "paintings":
        for x in (-1.5, 0.0, 1.5):
            w, hgt = rng.uniform(0.6, 1.0), rng.uniform(0.5, 0.8)
            add(box([w + 0.08, 0.03, hgt + 0.08], [x, half - 0.04, 1.5]), (30, 30, 30))
            add(box([w, 0.03, hgt], [x, half - 0.06, 1.5]),
                tuple(int(v) for v in rng.integers(60, 250, 3)))  # fmt: skip
    elif style.furniture == "cabinets":
        for k, x in enumerate(np.linspace(-1.8, 1.8, 5)):
            add(
                box([0.7, 0.5, 0.9], [x, half - 0.3, 0.45]),
                (90, 60, 40) if k % 2 else (230, 220, 200),
            )
            add(
                box([0.7, 0.35, 0.6], [x, half - 0.2, 1.9]),
                (230, 220, 200) if k % 2 else (90, 60, 40),
            )
    elif style.furniture == "plants":
        for x in (-1.8, -0.6, 0.6, 1.8):
            hgt = rng.uniform(0.8, 1.5)
            add(box([0.35, 0.35, 0.4], [x, back, 0.2]), (160, 90, 50))
            add(
                box([0.5, 0.5, hgt], [x, back, 0.4 + hgt / 2]),
                (40, int(rng.integers(110, 170)), 50),
            )
    # the ceiling
    add(box([SIZE, SIZE, 0.02], [0, 0, WALL_H + 0.01]), (240, 240, 240))
    room = trimesh.util.concatenate(pieces)
    room.vertices = zup_to_yup(np.asarray(room.vertices))
    return room


def room_splat(style: Style, count: int = COUNT):
    """The room of ``style`` as ``count`` Gaussians (a ``GaussianSplat``)."""
    return mesh_to_splat(room_mesh(style), count, seed=style.seed, visible_from=ROOM_INSIDE)


def make_room(style: Style, out: Path, count: int = COUNT) -> Path:
    """Write the room of ``style`` as ``out/gs_model.ply``; returns its path."""
    out.mkdir(parents=True, exist_ok=True)
    splat = room_splat(style, count)
    path = out / "gs_model.ply"
    with atomic_output(path) as tmp:
        write_ply(splat, tmp)
    return path


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", type=Path, default=ROOMS, help="folder of the room folders")
    ap.add_argument("--held-out", action="store_true", help="the rooms that are not shipped")
    ap.add_argument("--count", type=int, default=COUNT, help="Gaussians per room")
    args = ap.parse_args(argv)
    for name, style in (HELD_OUT_STYLES if args.held_out else SHIPPED_STYLES).items():
        path = make_room(style, args.out / name, args.count)
        print(f"wrote {path}: {path.stat().st_size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
