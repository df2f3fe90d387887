#!/usr/bin/env python
"""Make the small-arm zoo: objects sized for the SO-100's and the Koch's jaws, as
EmbodiedGen-format assets, and layouts in EmbodiedGen's form around each, one per arm.

Each layout is the shipped round table with the room background, ONE small object on it
(and, for a place task, its receptacle: a small bowl or a small tray), ``relation.robot`` the
arm, standing where the shipped ``round_table.json`` puts the Panda (the table's edge, facing
its centre). The objects (sizes across the jaws, not tuned on): cylinders lying (a marker, a
pen) and standing (a small can, a battery), cubes of 1.5, 2.2 and 3 cm, a flat eraser, a ball;
a 2 cm cube into a bowl and a 2.4 cm cube onto a tray. Assets as ``make_grasp_zoo.py`` writes
them (one OBJ object per convex part, Y-up turned Z-up by the URDF).

``--hidden`` writes the held-out set instead (``tests/data/small_zoo_hidden``): other sizes, none
of them tuned on (the issue's 2.2 cm marker, 2.5 cm cube and 3 cm can, a flat domino, the 2.5 cm
cube into a wider bowl), for a check apart from the zoo's.

Usage: python tools/make/make_small_zoo.py [--out tests/data/small_zoo] [--hidden]
then:  embodied-envs collect --num 6 --layout tests/data/small_zoo/layouts/so100_*.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path

import trimesh
from make_grasp_zoo import DATA, box, cylinder, write_asset

ROOT = Path(__file__).resolve().parents[2]
SMALL_ZOO = ROOT / "tests" / "data" / "small_zoo"
ARMS = {"so100": "so100", "koch": "koch-v1.1"}  # layout name -> the arm's relation.robot
TABLE_TOP = 0.74  # m, the round table's top (round_table.json)
# the shipped round table layout's robot spot (its edge, facing the centre) and room
ROUND = json.loads((DATA / "layouts" / "round_table.json").read_text())
SPOT = ROUND["position"]["franka"]


def ball(radius: float) -> trimesh.Trimesh:
    m = trimesh.creation.icosphere(subdivisions=3, radius=radius)
    m.apply_translation((0, 0, radius))
    return m


def bowl(radius: float, height: float, wall: float, n: int = 12) -> list[trimesh.Trimesh]:
    """A straight-walled bowl: a floor disc and ``n`` wall boxes around it."""
    parts = [cylinder(radius, wall, (0, 0, wall / 2))]
    chord = 2 * radius * math.sin(math.pi / n) + 0.004
    for k in range(n):
        a = (k + 0.5) * 2 * math.pi / n
        centre = (radius * math.cos(a), radius * math.sin(a), height / 2)
        parts.append(box((wall, chord, height), centre, yaw=a))
    return parts


def tray(size: tuple[float, float], rim: float, wall: float) -> list[trimesh.Trimesh]:
    """A flat tray: a plate and four low rims."""
    (sx, sy), t = size, wall
    return [
        box((sx, sy, t), (0, 0, t / 2)),
        box((t, sy, rim), (sx / 2 - t / 2, 0, rim / 2)),
        box((t, sy, rim), (-sx / 2 + t / 2, 0, rim / 2)),
        box((sx, t, rim), (0, sy / 2 - t / 2, rim / 2)),
        box((sx, t, rim), (0, -sy / 2 + t / 2, rim / 2)),
    ]


def cube(side: float) -> list[trimesh.Trimesh]:
    return [box((side, side, side), (0, 0, side / 2))]


def objects() -> dict[str, tuple[list[trimesh.Trimesh], float, str]]:
    """name -> (convex parts, mass kg, description): what a user brings to a small arm."""
    return {
        "marker": ([cylinder(0.01, 0.12, (0, 0, 0.01), axis="x")], 0.015, "a marker"),
        "pen": ([cylinder(0.0065, 0.14, (0, 0, 0.0065), axis="y")], 0.01, "a pen"),
        "small_can": ([cylinder(0.014, 0.05, (0, 0, 0.025))], 0.04, "a small can"),
        "battery": ([cylinder(0.0085, 0.05, (0, 0, 0.025))], 0.024, "a battery"),
        "cube_15": (cube(0.015), 0.008, "a small cube"),
        "cube_22": (cube(0.022), 0.02, "a cube"),
        "cube_30": (cube(0.03), 0.035, "a big cube"),
        "eraser": ([box((0.05, 0.022, 0.012), (0, 0, 0.006))], 0.02, "an eraser"),
        "ball": ([ball(0.014)], 0.02, "a ball"),
    }


def hidden_objects() -> dict[str, tuple[list[trimesh.Trimesh], float, str]]:
    """The held-out set's picks (``--hidden``): name -> (convex parts, mass kg, description)."""
    return {
        "marker_22": ([cylinder(0.011, 0.13, (0, 0, 0.011), axis="x")], 0.018, "a marker"),
        "cube_25": (cube(0.025), 0.025, "a cube"),
        "can_30": ([cylinder(0.015, 0.06, (0, 0, 0.03))], 0.05, "a can"),
        "domino": ([box((0.048, 0.024, 0.008), (0, 0, 0.004))], 0.01, "a domino"),
    }


RECEPTACLES = {  # name -> (convex parts, mass kg, description)
    "small_bowl": (bowl(0.045, 0.03, 0.005), 0.12, "the bowl"),
    "small_tray": (tray((0.13, 0.10), 0.012, 0.005), 0.15, "the tray"),
}
# place tasks: (layout stem, mover, receptacle, sentence)
PLACES = (
    ("cube_in_bowl", "cube_20", "small_bowl", "Put the cube in the bowl."),
    ("cube_on_tray", "cube_24", "small_tray", "Place the cube on the tray."),
)
PLACE_MOVERS = {
    "cube_20": (cube(0.02), 0.016, "a cube"),
    "cube_24": (cube(0.024), 0.025, "a cube"),
}
HIDDEN_RECEPTACLES = {"bowl_11": (bowl(0.055, 0.035, 0.005), 0.15, "the bowl")}
HIDDEN_PLACES = (("cube_into_bowl", "cube_25", "bowl_11", "Put the cube into the bowl."),)


@dataclass(frozen=True)
class Table:
    """The table a set's layouts stand on: its node, pose and description, the robot's spot on
    its edge (facing its centre, at the top's height ``top``) and whether its asset is shipped
    (else it lies in the set's own assets folder)."""

    node: str
    pose: list[float]
    desc: str
    spot: list[float]
    top: float
    shipped: bool = True


ROUND_TABLE = Table("round_table", ROUND["position"]["round_table"],
                    ROUND["objs_desc"]["round_table"], SPOT, TABLE_TOP)  # fmt: skip
OFFSETS = ((0.19, 0.05), (0.19, -0.09))  # the file's poses: (out from the spot, to its left)


def layout(robot: str, movers: dict[str, str], receptacle: str | None, task: str,
           assets: Path, out: Path, table: Table = ROUND_TABLE,
           others: dict[str, str] | None = None,
           offsets: tuple[tuple[float, float], ...] = OFFSETS,
           ships_at: Path = SMALL_ZOO / "layouts") -> dict:
    """A layout in EmbodiedGen's form on ``table`` (``movers``: node -> description; ``others``:
    the distractors' nodes -> descriptions, default the receptacle's; ``offsets``: each node's
    file pose, movers first, ahead of the spot and to its left; ``ships_at``: the folder the
    shipped assets' paths start from)."""
    rel_assets = Path(os.path.relpath(assets, out))
    # the shipped assets relative to where the layouts ship, wherever --out is (as
    # make_layouts.py does): the files do not depend on the folder they were written to
    shipped = Path(os.path.relpath(DATA / "assets", ships_at))
    if others is None:
        receptacles = {**RECEPTACLES, **HIDDEN_RECEPTACLES}
        others = {receptacle: receptacles[receptacle][2]} if receptacle else {}
    nodes = list(movers) + list(others)
    ctx, spot = table.node, table.spot
    position = {
        "background": ROUND["position"]["background"],
        ctx: table.pose,
        robot: spot,
    }
    # the file's own poses: in front of the spot, on the top (the env draws each episode's)
    heading = 2 * math.atan2(spot[5], spot[6])
    for node, (d, side) in zip(nodes, offsets[: len(nodes)], strict=True):
        x = spot[0] + d * math.cos(heading) - side * math.sin(heading)
        y = spot[1] + d * math.sin(heading) + side * math.cos(heading)
        position[node] = [round(x, 4), round(y, 4), table.top + 0.001, 0.0, 0.0, 0.0, 1.0]
    desc = {"background": ROUND["objs_desc"]["background"], ctx: table.desc, **movers,
            **others}  # fmt: skip
    return {
        "tree": {
            "background": [[ctx, "FLOOR"], [robot, "IN"]],
            ctx: [[n, "ON"] for n in nodes],
        },
        "relation": {
            "background": "background",
            "context": ctx,
            "distractor_objs": list(others),
            "manipulated_objs": list(movers),
            "robot": robot,
            "task_desc": task,
        },
        "objs_mapping": {
            "background": "background", ctx: "context",
            **{n: "manipulated_objs" for n in movers},
            **{n: "distractor_objs" for n in others},
        },
        "assets": {
            "background": str(shipped / "background"),
            ctx: str((shipped if table.shipped else rel_assets) / ctx),
            **{n: str(rel_assets / n) for n in nodes},
        },
        "position": position,
        "objs_desc": desc,
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=None, help="default: tests/data/small_zoo "
                    "(with --hidden: tests/data/small_zoo_hidden)")  # fmt: skip
    ap.add_argument("--hidden", action="store_true", help="the held-out set")
    args = ap.parse_args(argv)
    out = args.out or SMALL_ZOO.with_name("small_zoo_hidden" if args.hidden else "small_zoo")
    if args.hidden:  # the held-out set's place mover is one of its picks
        picks, places, movers = hidden_objects(), HIDDEN_PLACES, HIDDEN_RECEPTACLES
    else:
        picks, places, movers = objects(), PLACES, {**PLACE_MOVERS, **RECEPTACLES}
    movers = {**picks, **movers}
    assets, layouts = out / "assets", out / "layouts"
    for folder in (assets, layouts):
        if folder.exists():
            shutil.rmtree(folder)
        folder.mkdir(parents=True)
    for name, (parts, mass, _) in movers.items():
        write_asset(assets / name, name, parts, mass)
    files = 0
    for arm, robot in ARMS.items():
        for name, (_, _, desc) in picks.items():
            data = layout(robot, {name: desc}, None,
                          f"Pick up {desc} and hold it at the green goal.", assets, layouts)
            (layouts / f"{arm}_{name}.json").write_text(json.dumps(data, indent=4) + "\n")
            files += 1
        for stem, mover, receptacle, task in places:
            data = layout(robot, {mover: movers[mover][2]}, receptacle, task, assets, layouts)
            (layouts / f"{arm}_{stem}.json").write_text(json.dumps(data, indent=4) + "\n")
            files += 1
    print(f"wrote {files} layouts to {layouts} and their assets to {assets}")


if __name__ == "__main__":
    main()
