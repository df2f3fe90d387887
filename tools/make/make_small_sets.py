#!/usr/bin/env python
"""Draw a held-out set for the small arms: a new table, small objects of shapes the zoo lacks,
distractors, as layouts in EmbodiedGen's form (as ``make_small_zoo.py`` writes them).

``--draw SEED --out DIR`` writes ``DIR/assets``, ``DIR/layouts`` (``<arm>_<object>.json``, per
arm: six pick layouts and one place layout) and ``DIR/set.json`` (what was drawn: the table, each
object's family, size, dimensions, density and mass), all from one numpy Generator seeded by SEED,
the same bytes on every run. The set is written to a temporary folder beside ``DIR``, checked
(every layout read and its file poses checked; with ``--check`` each also made into the env and
reset), then renamed to ``DIR``: there is never a half-written set.

What is drawn:

- the table (a node of its own, never a shipped asset): rectangular on four legs, square on legs
  or a pedestal, or round on a pedestal; its top 0.68-0.80 m high and 2-4 cm thick, wide enough
  for both arms' reach band (60 deg either side of the heading, out to 0.30 m); the room is the
  shipped one. The robot's spot is on the edge (2 cm in, as the shipped round table's), at the
  top's height, facing the table, anywhere along a side that leaves the band on the top;
- six picks, each a family of ``FAMILIES`` without repeats (a hex pencil, a triangular prism
  and a dowel lying, a bottle cap and a tall block standing, a flat box, a cube, a ball, an
  L-shaped block, a truncated cone) and a size across the jaws (the footprint's narrowest width
  of its thinnest part) from six even strata of ``--sizes`` (default 1.5-4 cm), density
  300-1200 kg/m^3; and a place task: a cube of a size in the range into a bowl or onto a tray;
- one or two distractors (a globe on its stand, a cardboard box, a tin) in every layout.

Usage: python tools/make/make_small_sets.py --draw 1 --out tests/data/small_sets/dev1
then:  python tools/bench/bench_small_arms.py --layout tests/data/small_sets/dev1/layouts/*.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
from pathlib import Path

import numpy as np
import trimesh
from make_assets import Asset, Part
from make_assets import write_asset as write_table
from make_grasp_zoo import box, cylinder, write_asset
from make_small_zoo import ARMS, Table, ball, bowl, cube, layout, tray

REACH = 0.30  # m, the farther arm's (the SO-100's) reach band's far end from the spot
HEADING = math.radians(60)  # the band's half-angle about the heading
INSET = 0.02  # m, the spot inside the table's edge (as the shipped round table's)
PICKS = 6
# file poses ahead of the spot (out, to the left): the mover, the receptacle, the distractors
OFFSETS = ((0.19, 0.05), (0.19, -0.09), (0.40, 0.20), (0.40, -0.20))
TOPS = [(0.55, 0.36, 0.2), (0.85, 0.85, 0.8), (0.3, 0.3, 0.32), (0.7, 0.55, 0.4)]
FEET = [(0.35, 0.22, 0.12), (0.2, 0.2, 0.22), (0.6, 0.6, 0.62)]
TABLE_DESC = {
    "rect": "a rectangular table on four legs",
    "square": "a square table",
    "round": "a round table on a pedestal",
}


def r(x: float, digits: int = 4) -> float:
    return round(float(x), digits)


def hull(points) -> trimesh.Trimesh:
    return trimesh.Trimesh(vertices=np.asarray(points, dtype=float)).convex_hull


def prism(sides: int, width: float, length: float) -> trimesh.Trimesh:
    """A regular prism lying along x on one face, ``width`` its footprint across (y)."""
    half = math.pi / sides
    angles = [-math.pi / 2 + half + 2 * half * k for k in range(sides)]  # a face at the bottom
    radius = width / (max(map(math.cos, angles)) - min(map(math.cos, angles)))
    ring = [(radius * math.cos(a), radius * math.sin(a)) for a in angles]
    low = min(z for _, z in ring)
    return hull([(x, y, z - low) for x in (-length / 2, length / 2) for y, z in ring])


def frustum(bottom: float, top: float, height: float, n: int = 24) -> trimesh.Trimesh:
    ring = [(math.cos(2 * math.pi * k / n), math.sin(2 * math.pi * k / n)) for k in range(n)]
    return hull([(rr * c, rr * s, z) for rr, z in ((bottom, 0.0), (top, height)) for c, s in ring])


# family -> (description, sentence noun phrase): each drawn by ``pick(family, rng, s)``
FAMILIES = {
    "hex_pencil": "a hex pencil", "tri_prism": "a triangular prism", "dowel": "a dowel",
    "bottle_cap": "a bottle cap", "tall_block": "a tall block", "flat_box": "a flat box",
    "cube": "a cube", "ball": "a ball", "l_block": "an L-shaped block", "cone": "a small cone",
}  # fmt: skip


def pick(family: str, rng: np.random.Generator, s: float) -> tuple[list, dict]:
    """The family's convex parts (lowest point z = 0) at size ``s`` across the jaws, and its
    dimensions (m)."""
    u = rng.uniform
    if family == "hex_pencil":
        length = r(u(0.08, 0.16))
        return [prism(6, s, length)], {"across": s, "length": length}
    if family == "tri_prism":
        length = r(u(0.05, 0.12))
        return [prism(3, s, length)], {"side": s, "length": length}
    if family == "dowel":
        length = r(u(0.06, 0.14))
        return [cylinder(s / 2, length, (0, 0, s / 2), axis="x")], {"diameter": s, "length": length}
    if family == "bottle_cap":
        h = r(max(0.008, u(0.3, 0.6) * s))
        return [cylinder(s / 2, h, (0, 0, h / 2))], {"diameter": s, "height": h}
    if family == "tall_block":
        y, h = r(s * u(1.0, 1.2)), r(s * u(1.8, 2.2))
        return [box((s, y, h), (0, 0, h / 2))], {"x": s, "y": y, "height": h}
    if family == "flat_box":
        y, h = r(s * u(1.5, 2.5)), r(max(0.006, s * u(0.3, 0.5)))
        return [box((s, y, h), (0, 0, h / 2))], {"x": s, "y": y, "height": h}
    if family == "cube":
        return cube(s), {"side": s}
    if family == "ball":
        return [ball(s / 2)], {"diameter": s}
    if family == "l_block":
        h, a, b = r(max(0.01, s * u(0.6, 1.0))), r(max(2 * s, u(0.04, 0.08))), r(u(0.03, 0.06))
        b = r(max(b, 2 * s))
        # the footprint's box centred on the origin, as EmbodiedGen centres an asset (the
        # placement's reach check holds the origin, not the corner)
        parts = [box((a, s, h), (0, (s - b) / 2, h / 2)),
                 box((s, b - s, h), ((s - a) / 2, s / 2, h / 2))]  # fmt: skip
        return parts, {"width": s, "height": h, "leg_x": a, "leg_y": b}
    if family == "cone":
        top, h = r(s / 2 * u(0.4, 0.8)), r(s * u(0.8, 1.5))
        dims = {"bottom_diameter": s, "top_diameter": r(2 * top), "height": h}
        return [frustum(s / 2, top, h)], dims
    raise ValueError(family)


def distractor(kind: str, rng: np.random.Generator) -> tuple[list, float, dict, str]:
    """A distractor's parts, mass (kg), dimensions and description."""
    u = rng.uniform
    if kind == "globe":
        d, foot = r(u(0.10, 0.15)), r(u(0.04, 0.05))
        sphere = trimesh.creation.icosphere(subdivisions=2, radius=d / 2)
        sphere.apply_translation((0, 0, 0.035 + d / 2))
        parts = [cylinder(foot, 0.01, (0, 0, 0.005)), cylinder(0.006, 0.03, (0, 0, 0.02)), sphere]
        return parts, r(u(0.3, 0.6)), {"diameter": d, "stand": foot}, "a globe"
    if kind == "carton":
        x, y, z = r(u(0.08, 0.15)), r(u(0.06, 0.12)), r(u(0.05, 0.15))
        parts = [box((x, y, z), (0, 0, z / 2))]
        return parts, r(u(0.1, 0.4)), {"x": x, "y": y, "height": z}, "a cardboard box"
    rad, h = r(u(0.035, 0.045)), r(u(0.08, 0.11))
    dims = {"diameter": r(2 * rad), "height": h}
    return [cylinder(rad, h, (0, 0, h / 2))], r(u(0.2, 0.4)), dims, "a tin"


def table(rng: np.random.Generator) -> tuple[str, Asset, dict, tuple[float, float, float]]:
    """A drawn table: its node, asset (Z-up, the floor at z = 0) and dimensions, and the spot
    (x, y, inward heading) in its frame."""
    u = rng.uniform
    shape = ["rect", "square", "round"][rng.integers(3)]
    top_h, thick = r(u(0.68, 0.80), 3), r(u(0.02, 0.04), 3)
    colour, feet = TOPS[rng.integers(len(TOPS))], FEET[rng.integers(len(FEET))]
    mu = r(u(0.4, 0.7), 2)
    legs = shape == "rect" or (shape == "square" and rng.integers(2) == 0)
    z = top_h - thick
    if shape == "round":
        radius = r(u(0.40, 0.60), 3)
        parts = [Part(cylinder(radius, thick, (0, 0, top_h - thick / 2), sections=48), colour)]
        dims = {"radius": radius}
        spot_x, spot_y, heading = -(radius - INSET), 0.0, 0.0
        # rotated about the centre by the draw below: any point of the rim
    else:
        lx = r(u(0.8, 1.4), 3) if shape == "rect" else r(u(0.65, 0.9), 3)
        ly = r(u(0.55, 0.85), 3) if shape == "rect" else lx
        parts = [Part(box((lx, ly, thick), (0, 0, top_h - thick / 2)), colour)]
        dims = {"x": lx, "y": ly}
        # on the -y side (a long side), facing +y, along it as far as the band stays on the top
        free = lx / 2 - REACH * math.sin(HEADING) - 0.05
        spot_x, spot_y, heading = r(u(-free, free), 3), -(ly / 2 - INSET), math.pi / 2
    if legs:
        w, inset = r(u(0.04, 0.06), 3), r(u(0.05, 0.08), 3)
        for sx in (-1, 1):
            for sy in (-1, 1):
                c = (sx * (lx / 2 - inset), sy * (ly / 2 - inset), z / 2)
                parts.append(Part(box((w, w, z), c), feet))
        dims["legs"] = w
    else:
        post, foot = r(u(0.04, 0.07), 3), r(u(0.22, 0.3), 3)
        parts += [Part(cylinder(post, z - 0.03, (0, 0, 0.03 + (z - 0.03) / 2)), feet),
                  Part(cylinder(foot, 0.03, (0, 0, 0.015), sections=48), feet)]  # fmt: skip
        dims["pedestal"] = post
    dims.update(shape=shape, top=top_h, thickness=thick, mu=mu)
    node = f"{shape}_desk"
    return node, Asset(node, parts, mu=(mu, r(mu - 0.1, 2))), dims, (spot_x, spot_y, heading)


def quat_z(yaw: float) -> list[float]:
    return [0.0, 0.0, r(math.sin(yaw / 2)), r(math.cos(yaw / 2))]


def draw(seed: int, sizes: tuple[float, float], assets: Path, layouts: Path, final: Path) -> dict:
    """Write the set drawn by ``seed`` into ``assets`` and ``layouts`` (their paths written as
    from ``final``, where the set ends up); returns what was drawn."""
    rng = np.random.default_rng(seed)
    node, asset, dims, (sx, sy, inward) = table(rng)
    yaw = rng.uniform(-math.pi, math.pi)
    if dims["shape"] == "round":  # any point of the rim
        inward = yaw
        sx, sy = sx * math.cos(yaw), sx * math.sin(yaw)
    else:  # the table turned by yaw about its centre
        sx, sy = sx * math.cos(yaw) - sy * math.sin(yaw), sx * math.sin(yaw) + sy * math.cos(yaw)
        inward += yaw
    top = dims["top"]
    spot = [r(sx), r(sy), top, *quat_z(inward)]
    write_table(asset, assets)
    desk = Table(node, [0.0, 0.0, r(top / 2), *quat_z(yaw)], TABLE_DESC[dims["shape"]], spot, top,
                 shipped=False)  # fmt: skip
    lo, hi = sizes
    families = [str(f) for f in rng.permutation(list(FAMILIES))[:PICKS]]
    strata = rng.permutation(PICKS)
    drawn = {"seed": seed, "sizes": [lo, hi], "table": {"node": node, **dims}, "objects": {}}

    def add(name, family, parts, dims, desc, density=None, mass=None):
        volume = sum(p.volume for p in parts)
        mass = r(density * volume) if mass is None else mass
        write_asset(assets / name, name, parts, mass)
        drawn["objects"][name] = {"family": family, "desc": desc, **dims, "mass": mass,
                                  **({"density": density} if density else {})}  # fmt: skip

    picks = {}
    for family, k in zip(families, strata, strict=True):
        s = r(lo + (hi - lo) * (k + rng.uniform()) / PICKS)
        parts, dims_ = pick(family, rng, s)
        add(family, family, parts, dims_, FAMILIES[family], density=r(rng.uniform(300, 1200), 0))
        picks[family] = FAMILIES[family]
    s = r(rng.uniform(lo, hi))
    add("place_cube", "cube", cube(s), {"side": s}, "a cube", density=r(rng.uniform(300, 1200), 0))
    if rng.integers(2) == 0:
        rad, h = r(rng.uniform(0.045, 0.06)), r(rng.uniform(0.025, 0.04))
        receptacle, parts, rdims = "bowl", bowl(rad, h, 0.005), {"radius": rad, "height": h}
        stem, task = "cube_into_bowl", "Put the cube into the bowl."
    else:
        x, y = r(rng.uniform(0.12, 0.16)), r(rng.uniform(0.09, 0.12))
        rim = r(rng.uniform(0.01, 0.015))
        receptacle, parts, rdims = "tray", tray((x, y), rim, 0.005), {"x": x, "y": y, "rim": rim}
        stem, task = "cube_onto_tray", "Put the cube onto the tray."
    add(receptacle, receptacle, parts, rdims, f"the {receptacle}", mass=r(rng.uniform(0.1, 0.2)))
    others = {}
    for kind in rng.permutation(["globe", "carton", "tin"])[: 1 + rng.integers(2)]:
        parts, mass, ddims, desc = distractor(str(kind), rng)
        add(str(kind), str(kind), parts, ddims, desc, mass=mass)
        others[str(kind)] = desc
    ships_at = final / "layouts"
    for arm, robot in ARMS.items():
        for name, desc in picks.items():
            data = layout(robot, {name: desc}, None,
                          f"Pick up {desc} and hold it at the green goal.", assets, layouts,
                          desk, others, OFFSETS[:1] + OFFSETS[2:], ships_at)  # fmt: skip
            write_json(layouts / f"{arm}_{name}.json", data)
        data = layout(robot, {"place_cube": "a cube"}, None, task, assets, layouts, desk,
                      {receptacle: f"the {receptacle}", **others}, OFFSETS, ships_at)
        write_json(layouts / f"{arm}_{stem}.json", data)
    return drawn



def write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=4) + "\n")


def check(layouts: Path, simulate: bool) -> None:
    """Every layout read with its files and file poses checked (``load_layout``), its movers
    fit its arm (``check_graspable``); with ``simulate`` each made into the env and reset."""
    # the package only where a set is checked: drawing one needs trimesh alone
    from embodied_envs.envs.graspable import check_graspable
    from embodied_envs.layout import load_layout
    from embodied_envs.layout.sets import LayoutSet
    from embodied_envs.robots import ROBOTS

    for path in sorted(layouts.glob("*.json")):
        info = load_layout(path)
        check_graspable(LayoutSet.load(path), ROBOTS[info.robot])
        if simulate:
            os.environ.setdefault("MS_SKIP_ASSET_DOWNLOAD_PROMPT", "1")
            import gymnasium as gym  # the simulator only with --check

            import embodied_envs  # noqa: F401

            env = gym.make("PickEmbodiedGen-v1", layout_file=str(path),
                           control_mode="pd_joint_pos")  # fmt: skip
            env.reset(seed=0)
            env.close()


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--draw", type=int, required=True, help="the set's seed")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--sizes", type=float, nargs=2, default=(0.015, 0.04), metavar=("LO", "HI"),
                    help="sizes across the jaws, m (default 0.015 0.04)")
    ap.add_argument("--check", action="store_true", help="also make and reset each layout's env")
    args = ap.parse_args(argv)
    lo, hi = args.sizes
    if not 0 < lo <= hi:
        ap.error(f"--sizes {lo} {hi}: want 0 < LO <= HI (metres)")
    out = args.out.resolve()
    tmp = out.with_name(f".{out.name}.part")
    if tmp.exists():
        shutil.rmtree(tmp)
    (tmp / "layouts").mkdir(parents=True)
    try:
        drawn = draw(args.draw, (lo, hi), tmp / "assets", tmp / "layouts", out)
        write_json(tmp / "set.json", drawn)
        check(tmp / "layouts", args.check)
    except BaseException:
        shutil.rmtree(tmp)
        raise
    if out.exists():
        shutil.rmtree(out)
    tmp.rename(out)
    n = len(list((out / "layouts").glob("*.json")))
    print(f"wrote {n} layouts of the set drawn by {args.draw} to {out}")


if __name__ == "__main__":
    main()
