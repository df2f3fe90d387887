#!/usr/bin/env python
"""Make the upright-mover test layouts in ``tests/data/upright/`` (deterministic): copies of
the shipped task layouts whose mover stands taller than its receptacle is deep (a can or a
bottle, upright, in a bowl or a tray), for the "in" rule and the expert
(``tests/envs/test_in_rule.py``, ``tools/bench/bench_solver.py --layout``).

Each entry names the layout it starts from (a shipped one, or the grasp zoo's shallow bowl: a
shape the "in" rule was not written from), the node that becomes the mover (a distractor there,
or a new node swapped in for one), the receptacle and the sentence; the file's poses are kept
(the env places the movers anew every episode). Asset folders are written relative to the
output folder's place under the checkout.

Usage: python tools/make/make_upright.py [--out tests/data/upright]
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from embodied_envs.paths import atomic_output

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "embodied_envs" / "data"
OUT = ROOT / "tests" / "data" / "upright"
TABLE_TOP = 0.76  # m: the task layouts' table top (a can's centre stands 0.06 above it)


@dataclass(frozen=True)
class Upright:
    """One test layout: ``base`` (a layout file under the checkout) with ``movers``
    manipulated, every other node a distractor, ``swap`` nodes replaced (old ->
    :class:`Swap`) and ``sentence`` its task."""

    name: str
    base: str
    movers: tuple[str, ...]
    sentence: str
    swap: dict[str, Swap] = field(default_factory=dict)


@dataclass(frozen=True)
class Swap:
    """A node put in another's place: its name (its asset's), half height and description."""

    node: str
    half_height: float
    desc: str


SHIPPED = "embodied_envs/data/layouts/"
CAN = Swap("can", 0.06, "a blue soda can with a silver lid")  # 12 cm tall
BOTTLE = Swap("bottle", 0.11, "a green glass bottle")  # the shipped bottle: 22 cm tall
FRUIT_BOWL = Swap("fruit_bowl", 0.0325, "a wide fruit bowl")  # its floor 5.9 cm under its rim
UPRIGHT = [
    Upright("can_in_bowl", SHIPPED + "place_bowl.json", ("can",), "Put the can in the fruit bowl."),
    Upright("bottle_in_bowl", SHIPPED + "place_bowl.json", ("bottle",),
            "Put the bottle in the fruit bowl.", {"can": BOTTLE}),
    Upright("can_in_small_bowl", SHIPPED + "place_box.json", ("can",), "Put the can in the bowl."),
    Upright("can_in_tray", SHIPPED + "place_tray.json", ("can",), "Put the can in the tray."),
    Upright("bottle_in_tray", SHIPPED + "place_tray.json", ("bottle",),
            "Put the bottle in the tray.", {"can": BOTTLE}),
    Upright("cans_in_bowl", SHIPPED + "place_two.json", ("can1", "can2"),
            "Put the cans in the fruit bowl.", {"tray": FRUIT_BOWL}),
    Upright("cans_in_tray", SHIPPED + "place_two.json", ("can1", "can2"),
            "Put the cans in the tray."),
    Upright("can_in_shallow_bowl", "tests/data/zoo/layouts/shallow_bowl.json", ("can",),
            "Put the can in the shallow bowl.", {"cracker_box": CAN}),
]  # fmt: skip


def upright_layout(spec: Upright, out: Path) -> dict:
    """``spec``'s layout, its asset folders relative to ``out``."""
    source = ROOT / spec.base
    base = json.loads(source.read_text())
    rename = {old: new.node for old, new in spec.swap.items()}
    relation, desc = base["relation"], base["objs_desc"]
    assets = {}
    for node, folder in base["assets"].items():
        where = DATA / "assets" / spec.swap[node].node if node in spec.swap else \
            (source.parent / folder).resolve()  # fmt: skip
        assets[rename.get(node, node)] = os.path.relpath(where, out)
    position = {}
    for node, pose in base["position"].items():
        if node in spec.swap:
            pose = [*pose[:2], round(TABLE_TOP + spec.swap[node].half_height, 4), *pose[3:]]
        position[rename.get(node, node)] = pose
    objects = [rename.get(n, n) for n in relation["manipulated_objs"] + relation["distractor_objs"]]
    tree = {rename.get(k, k): [[rename.get(n, n), how] for n, how in v]
            for k, v in base["tree"].items()}  # fmt: skip
    mapping = {rename.get(k, k): v for k, v in base["objs_mapping"].items()}
    for node in objects:
        mapping[node] = "manipulated_objs" if node in spec.movers else "distractor_objs"
    descs = {rename.get(k, k): v for k, v in desc.items()}
    descs |= {new.node: new.desc for new in spec.swap.values()}
    return {
        "tree": tree,
        "relation": {
            **relation,
            "manipulated_objs": list(spec.movers),
            "distractor_objs": [n for n in objects if n not in spec.movers],
            "task_desc": spec.sentence,
            # EmbodiedGen's task category (a hint, never the grade), as its prompt writes it
            **({"task": "pick and place"} if "task" in relation else {}),
        },
        "objs_mapping": mapping,
        "assets": assets,
        "position": position,
        "objs_desc": descs,
    }


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--out", type=Path, default=OUT)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    for spec in UPRIGHT:
        # relative to where the files ship, wherever --out is (as make_layouts.py does)
        data = upright_layout(spec, OUT)
        with atomic_output(args.out / f"{spec.name}.json") as tmp:
            tmp.write_text(json.dumps(data, indent=4) + "\n")


if __name__ == "__main__":
    main()
