#!/usr/bin/env python
"""Generate the shipped layouts in ``embodied_envs/data/layouts/`` (deterministic).

Each entry of ``LAYOUTS`` is one layout in EmbodiedGen's ``LayoutInfo`` format; ``write_layouts``
writes them all. A layout's poses are pinned in its entry (``poses``), so the shipped files do not
move when the placement code changes (``tests/test_shipped_data.py`` checks that this script
writes them byte for byte). A new entry without ``poses`` is placed with
``embodied_envs.layout.placement.place``: the first seed that puts the robot on the table's far
side (facing the default render camera at +x), so that the camera sees the arm reaching towards
it rather than its back; the script prints the poses it found, to pin in the entry.

Asset folders are written relative to ``embodied_envs/data/layouts/`` (``../assets/<node>``),
where the files ship, wherever ``--out`` is.

Usage: python tools/make/make_layouts.py [--out embodied_envs/data/layouts]
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass, field
from pathlib import Path

from embodied_envs.layout import LayoutInfo
from embodied_envs.layout.placement import place
from embodied_envs.paths import atomic_output

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "embodied_envs" / "data"  # package data; ./layouts and ./assets link here
ROBOT = "franka"
MAX_SEEDS = 10_000  # placement seeds tried for a layout without pinned poses
# relation["task"]: EmbodiedGen's free task category, written as its layout designer writes it
# beside task_desc (never graded: the sentence is), by the kind the sentence states
CATEGORY = {"pick": "single-arm pick", "place": "pick and place", "move": "push"}


@dataclass(frozen=True)
class LayoutSpec:
    """One shipped layout: its objects, its task, and the file poses it ships with."""

    name: str  # the file stem
    context: str  # the table's asset (and node) name
    manipulated: tuple[str, ...]  # the first is the graded object
    distractors: tuple[str, ...]
    task: str
    # [x, y, z, qx, qy, qz, qw] of every node and the robot; empty: placed by this script
    poses: dict[str, list[float]] = field(default_factory=dict)
    # node -> its asset folder's name where they differ (two cans: can1, can2 -> can)
    asset_of: dict[str, str] = field(default_factory=dict)
    robot: str = ROBOT  # relation.robot (a name embodied_envs/robots.py knows)


# the room, table and robot the task layouts share (their objects differ)
TASK_ROOM = {
    "background": [0.0, 0.0, 0.0, 0.0, 0.0, 0.7727, 0.6347],
    "table": [0.0, 0.0, 0.38, 0.0, 0.0, 0.3264, 0.9452],
    ROBOT: [-0.412, 0.1598, 0.76, 0.0, 0.0, -0.1839, 0.9829],
}

LAYOUTS = [
    LayoutSpec(
        name="default",
        context="table",
        manipulated=("can",),
        distractors=("cracker_box", "mug", "bowl"),
        task="Pick up the blue can and hold it at the green goal.",
        poses={
            "background": [0.0, 0.0, 0.0, 0.0, 0.0, 0.4604, 0.8877],
            "table": [0.0, 0.0, 0.38, 0.0, 0.0, -0.9906, 0.1371],
            "can": [-0.163, 0.0399, 0.82, 0.0, 0.0, 0.2604, 0.9655],
            "cracker_box": [0.4826, 0.158, 0.825, 0.0, 0.0, 0.9518, 0.3066],
            "mug": [-0.2897, -0.2048, 0.805, 0.0, 0.0, -0.0339, 0.9994],
            "bowl": [0.3342, -0.1435, 0.785, 0.0, 0.0, 0.8751, 0.4839],
            "franka": [-0.6405, 0.1342, 0.76, 0.0, 0.0, -0.1031, 0.9947],
        },
    ),
    LayoutSpec(
        name="round_table",
        context="round_table",
        manipulated=("banana",),
        distractors=("bottle", "cracker_box"),
        task="Pick up the banana and hold it at the green goal.",
        poses={
            "background": [0.0, 0.0, 0.0, 0.0, 0.0, 0.4171, 0.9088],
            "round_table": [0.0, 0.0, 0.37, 0.0, 0.0, -0.6618, 0.7497],
            "banana": [-0.2837, 0.32, 0.756, 0.0, 0.0, 0.8328, 0.5536],
            "bottle": [-0.2965, 0.081, 0.85, 0.0, 0.0, 0.4931, 0.87],
            "cracker_box": [-0.0352, 0.3434, 0.805, 0.0, 0.0, -0.9733, 0.2296],
            "franka": [-0.5245, 0.0749, 0.74, 0.0, 0.0, -0.0709, 0.9975],
        },
    ),
    # the task kinds beyond pick (embodied_envs/layout/task.py reads them from the sentence)
    LayoutSpec(
        name="place_box",
        context="table",
        manipulated=("can",),
        distractors=("storage_box", "mug", "bowl"),
        task="Put the can on the storage box.",
        poses={
            **TASK_ROOM,
            "can": [0.3204, 0.4159, 0.82, 0.0, 0.0, 0.2549, 0.967],
            "storage_box": [-0.0381, 0.2461, 0.795, 0.0, 0.0, 0.9914, 0.1307],
            "mug": [0.3611, 0.1939, 0.805, 0.0, 0.0, 0.9094, 0.4158],
            "bowl": [0.2174, 0.04, 0.785, 0.0, 0.0, 0.6341, 0.7733],
        },
    ),
    LayoutSpec(
        name="place_bowl",
        context="table",
        manipulated=("banana",),
        distractors=("fruit_bowl", "can", "cracker_box"),
        task="Put the banana in the fruit bowl.",
        poses={
            **TASK_ROOM,
            "banana": [0.2174, 0.04, 0.776, 0.0, 0.0, 0.6341, 0.7733],
            "fruit_bowl": [-0.0381, 0.2461, 0.7925, 0.0, 0.0, 0.9914, 0.1307],
            "can": [0.3204, 0.4159, 0.82, 0.0, 0.0, 0.2549, 0.967],
            "cracker_box": [0.3611, 0.1939, 0.825, 0.0, 0.0, 0.9094, 0.4158],
        },
    ),
    LayoutSpec(
        name="move_left",
        context="table",
        manipulated=("can",),
        distractors=("cracker_box", "mug", "bowl"),
        task="Move the can to the left.",
        poses={
            **TASK_ROOM,
            "can": [0.3204, 0.4159, 0.82, 0.0, 0.0, 0.2549, 0.967],
            "cracker_box": [0.3611, 0.1939, 0.825, 0.0, 0.0, 0.9094, 0.4158],
            "mug": [0.2174, 0.04, 0.805, 0.0, 0.0, 0.6341, 0.7733],
            "bowl": [-0.0381, 0.2461, 0.785, 0.0, 0.0, 0.9914, 0.1307],
        },
    ),    LayoutSpec(
        name="place_tray",
        context="table",
        manipulated=("mug",),
        distractors=("tray", "can", "bowl"),
        task="Place the mug on the tray.",
        poses={
            **TASK_ROOM,
            "mug": [0.3611, 0.1939, 0.805, 0.0, 0.0, 0.9094, 0.4158],
            "tray": [-0.0381, 0.2461, 0.771, 0.0, 0.0, 0.9914, 0.1307],
            "can": [0.3204, 0.4159, 0.82, 0.0, 0.0, 0.2549, 0.967],
            "bowl": [0.2174, 0.04, 0.785, 0.0, 0.0, 0.6341, 0.7733],
        },
    ),
    LayoutSpec(
        name="place_two",
        context="table",
        manipulated=("can1", "can2"),
        distractors=("tray", "mug"),
        task="Put the cans on the tray.",
        poses={
            **TASK_ROOM,
            "can1": [0.3611, 0.1939, 0.82, 0.0, 0.0, 0.9094, 0.4158],
            "can2": [0.3204, 0.4159, 0.82, 0.0, 0.0, 0.2549, 0.967],
            "tray": [-0.0381, 0.2461, 0.771, 0.0, 0.0, 0.9914, 0.1307],
            "mug": [0.2174, 0.04, 0.805, 0.0, 0.0, 0.6341, 0.7733],
        },
        asset_of={"can1": "can", "can2": "can"},
    ),
    # the SO-100's layout: objects its jaws take (a 4 cm block), within its reach
    LayoutSpec(
        name="so100_block",
        context="table",
        manipulated=("block",),
        distractors=("can",),
        task="Pick up the block and hold it at the green goal.",
        poses={
            "background": TASK_ROOM["background"],
            "table": TASK_ROOM["table"],
            "so100": TASK_ROOM[ROBOT],
            "block": [-0.207, 0.08, 0.78, 0.0, 0.0, 0.0, 1.0],
            "can": [-0.125, 0.209, 0.82, 0.0, 0.0, 0.2549, 0.967],
        },
        robot="so100",
    ),
    # the Koch's layout: a 2 cm block its low-friction, slanted jaw holds, within its reach
    LayoutSpec(
        name="koch_block",
        context="table",
        manipulated=("small_block",),
        distractors=("can",),
        task="Pick up the block and hold it at the green goal.",
        poses={
            "background": TASK_ROOM["background"],
            "table": TASK_ROOM["table"],
            "koch": TASK_ROOM[ROBOT],
            "small_block": [-0.254, 0.098, 0.77, 0.0, 0.0, 0.0, 1.0],
            "can": [-0.242, 0.218, 0.82, 0.0, 0.0, 0.2549, 0.967],
        },
        robot="koch",
    ),
]

DESCRIPTIONS = {
    "table": "a wooden rectangular table",
    "round_table": "a round white table on a grey pedestal",
    "can": "a blue soda can with a silver lid",
    "cracker_box": "a red cracker box with a yellow top",
    "mug": "an orange mug with a handle",
    "bowl": "a white bowl",
    "bottle": "a green bottle with a white cap",
    "banana": "a yellow banana",
    "fruit_bowl": "a wide light-blue fruit bowl",
    "tray": "a red serving tray with low rims",
    "storage_box": "a low brown cardboard storage box",
    "background": "a room with a window and a bookshelf",
    "block": "a small orange wooden block",
    "small_block": "a small green wooden block",
}


def base_layout(spec: LayoutSpec) -> LayoutInfo:
    """The layout of ``spec`` with every node at the origin, read as if from its shipped place."""
    objs = [*spec.manipulated, *spec.distractors]
    mapping = {"background": "background", spec.context: "context"}
    mapping.update({o: "manipulated_objs" for o in spec.manipulated})
    mapping.update({o: "distractor_objs" for o in spec.distractors})
    data = {
        "tree": {
            "background": [[spec.context, "FLOOR"], [spec.robot, "IN"]],
            spec.context: [[o, "ON"] for o in objs],
        },
        "relation": {
            "background": "background",
            "context": spec.context,
            "distractor_objs": list(spec.distractors),
            "manipulated_objs": list(spec.manipulated),
            "robot": spec.robot,
            "task_desc": spec.task,
        },
        "objs_mapping": mapping,
        "assets": {n: f"../assets/{spec.asset_of.get(n, n)}" for n in mapping},
        "position": {n: [0, 0, 0, 0, 0, 0, 1] for n in [*mapping, spec.robot]},
        "objs_desc": {n: DESCRIPTIONS[spec.asset_of.get(n, n)] for n in mapping},
    }
    source = DATA / "layouts" / f"{spec.name}.json"
    kind = LayoutInfo.from_dict(data, source=source).task.kind
    data["relation"]["task"] = CATEGORY[kind]
    return LayoutInfo.from_dict(data, source=source)


def placed(spec: LayoutSpec) -> LayoutInfo:
    """The layout of ``spec`` placed by the first seed that puts the robot on the table's far
    side."""
    layout = base_layout(spec)
    for seed in range(MAX_SEEDS):
        candidate = place(layout, seed)
        x, y = candidate.pose(spec.robot).p[:2]
        if x < -0.25 and abs(y) < 0.2 and candidate.pose("background").yaw > 0:
            poses = json.dumps(candidate.to_dict()["position"])
            print(f"{spec.name}: placed by seed {seed}; pin these poses in its entry: {poses}")
            return candidate
    raise RuntimeError(f"{spec.name}: no seed under {MAX_SEEDS} puts the robot on the far side")


def layout_data(spec: LayoutSpec) -> dict:
    """The JSON object of ``spec``'s layout; pinned poses are written as they are pinned (a
    quaternion rounded to 4 decimals may be off unit by 1e-4, and normalising it again could
    change its last digit)."""
    if not spec.poses:
        return placed(spec).to_dict()
    data = base_layout(spec).to_dict()
    if set(spec.poses) != set(data["position"]):
        raise ValueError(f"{spec.name}: poses must name exactly {sorted(data['position'])}")
    LayoutInfo.from_dict(data | {"position": spec.poses})  # the pinned poses validate
    data["position"] = {n: [float(v) for v in spec.poses[n]] for n in data["position"]}
    return data


def write_layouts(out: Path, specs: list[LayoutSpec] = LAYOUTS) -> list[Path]:
    """Write every layout of ``specs`` to ``out/<name>.json`` (4-space JSON, as
    ``LayoutInfo.save`` writes it)."""
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for spec in specs:
        path = out / f"{spec.name}.json"
        with atomic_output(path) as tmp:
            tmp.write_text(json.dumps(layout_data(spec), indent=4) + "\n")
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("--out", type=Path, default=DATA / "layouts")
    for path in write_layouts(ap.parse_args(argv).out):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
