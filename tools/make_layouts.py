#!/usr/bin/env python
"""Generate the shipped layouts in ``layouts/`` (deterministic).

Each layout is built in EmbodiedGen's ``LayoutInfo`` format and placed with
``embodied_envs.layout.placement.place``; the first seed that puts the robot on the table's far
side (facing the default render camera at +x) is kept, so the default camera sees the arm
reaching towards it rather than its back.

Usage: python tools/make_layouts.py [--out layouts]
"""

from __future__ import annotations

import argparse
from pathlib import Path

from embodied_envs.layout import LayoutInfo
from embodied_envs.layout.placement import place

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "embodied_envs" / "data"  # package data; ./layouts and ./assets link here

SCENES = {
    "default": dict(
        context="table",
        manipulated=["can"],
        distractors=["cracker_box", "mug", "bowl"],
        task="Pick up the blue can and hold it at the green goal.",
    ),
    "round_table": dict(
        context="round_table",
        manipulated=["banana"],
        distractors=["bottle", "cracker_box"],
        task="Pick up the banana and hold it at the green goal.",
    ),
    # the task kinds beyond pick (layout/task.py reads them from the sentence)
    "place_box": dict(
        context="table",
        manipulated=["can"],
        distractors=["cracker_box", "mug", "bowl"],
        task="Put the can on the cracker box.",
    ),
    "place_bowl": dict(
        context="table",
        manipulated=["banana"],
        distractors=["fruit_bowl", "can", "cracker_box"],
        task="Put the banana in the fruit bowl.",
    ),
    "move_left": dict(
        context="table",
        manipulated=["can"],
        distractors=["cracker_box", "mug", "bowl"],
        task="Move the can to the left.",
    ),
}

DESCRIPTIONS = {
    "table": "a wooden rectangular table",
    "round_table": "a round white table on a grey pedestal",
    "can": "a blue soda can with a silver lid",
    "cracker_box": "a red cracker box with a yellow top",
    "mug": "an orange mug with a handle",
    "bowl": "a white bowl",
    "fruit_bowl": "a wide light-blue fruit bowl",
    "bottle": "a green bottle with a white cap",
    "banana": "a yellow banana",
    "background": "a room with a window and a bookshelf",
}


def base_layout(name: str, spec: dict, out_dir: Path) -> LayoutInfo:
    objs = spec["manipulated"] + spec["distractors"]
    mapping = {"background": "background", spec["context"]: "context"}
    mapping.update({o: "manipulated_objs" for o in spec["manipulated"]})
    mapping.update({o: "distractor_objs" for o in spec["distractors"]})
    rel = Path("..") / DATA.joinpath("assets").relative_to(out_dir.parent)
    data = {
        "tree": {
            "background": [[spec["context"], "FLOOR"], ["franka", "IN"]],
            spec["context"]: [[o, "ON"] for o in objs],
        },
        "relation": {
            "background": "background",
            "context": spec["context"],
            "distractor_objs": spec["distractors"],
            "manipulated_objs": spec["manipulated"],
            "robot": "franka",
            "task_desc": spec["task"],
        },
        "objs_mapping": mapping,
        "assets": {n: str(rel / n) for n in mapping},
        "position": {n: [0, 0, 0, 0, 0, 0, 1] for n in [*mapping, "franka"]},
        "objs_desc": {n: DESCRIPTIONS[n] for n in mapping},
    }
    return LayoutInfo.from_dict(data, source=out_dir / f"{name}.json")


def main() -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", type=Path, default=DATA / "layouts")
    ap.add_argument("--only", nargs="*", choices=list(SCENES), help="these scenes alone")
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    names = args.only or list(SCENES)
    for name in names:
        spec = SCENES[name]
        layout = base_layout(name, spec, args.out)
        for seed in range(10_000):
            placed = place(layout, seed)
            x, y = placed.pose("franka").p[:2]
            if x < -0.25 and abs(y) < 0.2 and placed.pose("background").yaw > 0:
                break
        path = placed.save(args.out / f"{name}.json")
        print(f"wrote {path} (placement seed {seed})")


if __name__ == "__main__":
    main()
