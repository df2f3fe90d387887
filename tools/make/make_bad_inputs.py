#!/usr/bin/env python
"""Write the bad-input corpus ``tests/data/bad_inputs/`` from the shipped default layout.

Each case is a folder with ``case.json`` and usually a ``layout.json`` (plus any broken asset
folders it needs). ``case.json`` says what is wrong and what must happen:

- ``error``: the exception type the env raises at construction, before any simulation
  (``null`` when the input is fine and everything must work);
- ``words``: strings the message must contain;
- ``env_kwargs``: extra ``gym.make`` arguments;
- ``validate``: whether ``embodied-envs layout validate`` must report it (exit code 1).

Layouts point at the shipped assets with paths relative to their own folder, as users' do
(written relative to ``tests/data/bad_inputs/<case>/`` wherever ``--out`` is, so that a corpus
written elsewhere is byte for byte the shipped one: ``tests/test_shipped_data.py``).
Usage: python tools/make/make_bad_inputs.py [--out tests/data/bad_inputs]
"""

from __future__ import annotations

import argparse
import copy
import functools
import json
import re
import shutil
from pathlib import Path

import numpy as np
from PIL import Image

from embodied_envs.splat.ply import REQUIRED

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "tests" / "data" / "bad_inputs"
SHIPPED = "../../../../assets/"  # from tests/data/bad_inputs/<case>/ to the repo's assets


def base_layout() -> dict:
    data = json.loads((ROOT / "layouts" / "default.json").read_text())
    data["assets"] = {k: SHIPPED + Path(v).name for k, v in data["assets"].items()}
    return data


def copy_asset(case: Path, name: str, new_name: str) -> Path:
    dst = case / new_name
    shutil.copytree(ROOT / "assets" / name, dst)
    return dst


def write_case_to(
    out: Path,
    name: str,
    what: str,
    error: str | None,
    words: list[str],
    layout=None,
    env_kwargs=None,
    validate=True,
    raw_layout: str | None = None,
    setup=None,
):
    case = out / name
    case.mkdir(parents=True)
    if setup is not None:
        setup(case)
    if raw_layout is not None:
        (case / "layout.json").write_text(raw_layout)
    elif layout is not None:
        (case / "layout.json").write_text(json.dumps(layout, indent=2, allow_nan=True))
    spec = dict(what=what, error=error, words=words, env_kwargs=env_kwargs or {}, validate=validate)
    (case / "case.json").write_text(json.dumps(spec, indent=2) + "\n")


def tiny_ply(names: list[str], n: int = 4, cut: int = 0) -> bytes:
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {p}" for p in names] + ["end_header"]
    body = np.zeros((n, len(names)), np.float32).tobytes()
    return ("\n".join(header) + "\n").encode() + body[: len(body) - cut]


PLY_PROPS = list(REQUIRED)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", type=Path, default=OUT, help="the corpus folder (replaced)")
    out = ap.parse_args(argv).out
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    write_case = functools.partial(write_case_to, out)
    b = base_layout()

    def mutated(fn):
        d = copy.deepcopy(b)
        fn(d)
        return d

    write_case(
        "malformed_json",
        "a JSON syntax error",
        "LayoutError",
        ["layout.json", "JSON"],
        raw_layout=json.dumps(b)[:-40] + ",,}",
    )
    for field in ("tree", "relation", "objs_mapping", "assets", "position"):
        write_case(
            f"missing_{field}",
            f"required field {field} missing",
            "LayoutError",
            ["layout.json", field],
            layout=mutated(lambda d, f=field: d.pop(f)),
        )
    write_case(
        "pose_with_6_numbers",
        "a pose with 6 numbers",
        "LayoutError",
        ['position["mug"]', "6 numbers", "expected 7"],
        layout=mutated(lambda d: d["position"]["mug"].pop()),
    )

    def nan_pose(d):
        d["position"]["bowl"][1] = float("nan")

    write_case(
        "pose_with_nan",
        "NaN in a pose",
        "LayoutError",
        ['position["bowl"]', "finite"],
        layout=mutated(nan_pose),
    )

    def zero_quat(d):
        d["position"]["can"][3:] = [0.0, 0.0, 0.0, 0.0]

    write_case(
        "zero_quaternion",
        "a zero quaternion",
        "LayoutError",
        ['position["can"]', "quaternion"],
        layout=mutated(zero_quat),
    )

    def missing_dir(d):
        d["assets"]["mug"] = SHIPPED + "no_such_mug"

    write_case(
        "asset_dir_missing",
        "an asset directory that does not exist",
        "LayoutError",
        ["no_such_mug", "does not exist"],
        layout=mutated(missing_dir),
    )

    def drop_collision(asset: Path) -> None:
        urdf = (asset / "can.urdf").read_text()
        start, end = urdf.index("<collision>"), urdf.index("</collision>") + len("</collision>")
        (asset / "can.urdf").write_text(urdf[:start] + urdf[end:])

    def add_texture(asset: Path, content) -> None:
        mtl = asset / "mesh" / "mug.mtl"
        if content == "outside":
            Image.new("RGB", (4, 4)).save(asset.parent / "outside.png")
            mtl.write_text(mtl.read_text() + "map_Kd ../../outside.png\n")
            return
        mtl.write_text(mtl.read_text() + "map_Kd -s 1 1 1 tex.png\n")
        if content == "huge":
            Image.new("L", (9000, 1)).save(asset / "mesh" / "tex.png")
        elif content is not None:
            (asset / "mesh" / "tex.png").write_bytes(content)

    def two_collisions(asset: Path) -> None:
        urdf = (asset / "can.urdf").read_text()
        start, end = urdf.index("<collision>"), urdf.index("</collision>") + len("</collision>")
        (asset / "can.urdf").write_text(urdf[:end] + urdf[start:end] + urdf[end:])

    def mesh_outside(asset: Path) -> None:
        shutil.copy(asset / "mesh" / "bowl_collision.obj", asset.parent / "shared.obj")
        urdf = (asset / "bowl.urdf").read_text()
        (asset / "bowl.urdf").write_text(urdf.replace("mesh/bowl_collision.obj", "../shared.obj"))

    broken_assets = [  # case, what, shipped asset, words, how its copy is broken
        ("urdf_without_collision", "a URDF without a collision mesh", "can",
         ["can.urdf", "collision"], drop_collision),
        ("mesh_not_a_mesh", "a collision mesh file that is not a mesh", "mug",
         ["mug_collision.obj", "mesh"],
         lambda a: (a / "mesh" / "mug_collision.obj").write_bytes(b"\x00\x01PK not a mesh\n")),
        ("empty_collision_mesh", "an empty collision mesh", "bowl", ["bowl_collision.obj"],
         lambda a: (a / "mesh" / "bowl_collision.obj").write_text("# no geometry\n")),
        ("texture_missing", "a material naming a texture that does not exist", "mug",
         ["mug.mtl", "texture tex.png does not exist"], lambda a: add_texture(a, None)),
        ("texture_corrupt", "a texture that is not an image", "mug",
         ["mug.mtl", "texture tex.png is not a readable image"],
         lambda a: add_texture(a, b"\x89PNG not really")),
        ("texture_huge", "a texture over 8192 px a side", "mug",
         ["mug.mtl", "tex.png is 9000x1 px, over 8192 px"], lambda a: add_texture(a, "huge")),
        ("texture_outside_folder", "a texture reached through ../, outside the asset folder",
         "mug", ["mug.mtl", "texture ../../outside.png lies outside the asset folder"],
         lambda a: add_texture(a, "outside")),
        ("urdf_two_collisions", "a URDF link with two <collision> elements (one would be lost)",
         "can", ["can.urdf", "2 <collision> elements", "merge their meshes"], two_collisions),
        ("mesh_outside_folder", "a collision mesh reached through ../, outside the asset folder",
         "bowl", ["bowl.urdf", "lies outside the asset folder"], mesh_outside),
    ]  # fmt: skip
    for name, what, asset, words, damage in broken_assets:
        folder = f"{asset}_broken"
        write_case(
            name,
            what,
            "LayoutError",
            words,
            setup=lambda case, asset=asset, folder=folder, damage=damage: damage(
                copy_asset(case, asset, folder)
            ),
            layout=mutated(
                lambda d, asset=asset, folder=folder: d["assets"].update({asset: folder})
            ),
        )

    def robot(d):
        d["relation"]["robot"] = "ur5e_magic"
        d["position"]["ur5e_magic"] = d["position"].pop("franka")
        d["tree"]["background"] = [
            [c, r] if c != "franka" else ["ur5e_magic", r] for c, r in d["tree"]["background"]
        ]

    write_case(
        "robot_not_registered",
        "a robot name that is not registered",
        "LayoutError",
        ["ur5e_magic", "franka"],
        layout=mutated(robot),
    )

    def off_table(d):
        d["tree"]["table"] = [e for e in d["tree"]["table"] if e[0] != "can"]
        d["tree"]["background"].append(["can", "ON"])

    write_case(
        "manipulated_not_on_table",
        "a manipulated object not on the table in the tree",
        "LayoutError",
        ['"can"', "table"],
        layout=mutated(off_table),
    )

    def background_with(ply: bytes):
        def setup(case):
            (case / "background").mkdir()
            (case / "background" / "gs_model.ply").write_bytes(ply)

        return setup

    def background_without_splat(case):  # a file keeps the folder in git
        (case / "background").mkdir()
        (case / "background" / "README.txt").write_text("no gs_model.ply here, on purpose\n")

    write_case(
        "truncated_ply",
        "a truncated gs_model.ply",
        "SplatFileError",
        ["gs_model.ply", "truncated"],
        env_kwargs=dict(render_mode="hybrid"),
        setup=background_with(tiny_ply(PLY_PROPS, cut=10)),
        layout=mutated(lambda d: d["assets"].update(background="background")),
    )
    write_case(
        "ply_without_opacity",
        "a gs_model.ply without opacity",
        "SplatFileError",
        ["gs_model.ply", "opacity"],
        env_kwargs=dict(render_mode="hybrid"),
        setup=background_with(tiny_ply([p for p in PLY_PROPS if p != "opacity"])),
        layout=mutated(lambda d: d["assets"].update(background="background")),
    )
    write_case(
        "missing_ply_for_hybrid",
        "hybrid rendering without gs_model.ply",
        "SplatFileError",
        ["gs_model.ply", 'render_mode="hybrid"'],
        env_kwargs=dict(render_mode="hybrid"),
        validate=False,
        setup=background_without_splat,
        layout=mutated(lambda d: d["assets"].update(background="background")),
    )
    write_case(
        "unsupported_render_mode",
        "an unsupported render mode",
        "ValueError",
        ["render_mode='rgbd'", "hybrid"],
        env_kwargs=dict(render_mode="rgbd"),
        validate=False,
        layout=b,
    )
    write_case(
        "camera_zero_size",
        "a camera with zero size",
        "ValueError",
        ["image_hw", "positive"],
        env_kwargs=dict(camera_cfg=dict(image_hw=[0, 256])),
        validate=False,
        layout=b,
    )

    boxes = 3

    def box_folder(case):  # one folder, one URDF per node stem, shared meshes
        dst = copy_asset(case, "table", "boxes")  # as large as the table itself
        urdf = dst / "table.urdf"
        for i in range(boxes):
            (dst / f"box_{i}.urdf").write_text(urdf.read_text())
        urdf.unlink()

    def crowded(d):
        for i in range(boxes):
            node = f"box {i}"
            d["tree"]["table"].append([node, "ON"])
            d["relation"]["distractor_objs"].append(node)
            d["objs_mapping"][node] = "distractor_objs"
            d["assets"][node] = "boxes"
            d["position"][node] = [*d["position"]["cracker_box"][:2], 1.2, 0, 0, 0, 1]

    write_case(
        "objects_stacked_at_one_pose",
        "table-sized boxes floating at one pose: the file's poses cannot be simulated",
        "LayoutError",
        ['position["box 0"]', "not on the top", "overlap", "replace_objs=True"],
        setup=box_folder,
        layout=mutated(crowded),
    )
    write_case(
        "objects_cannot_be_placed",
        "the target cannot be placed within a reach band beyond the table",
        "PlacementError",
        ["layout.json", "cannot place", "can", "m of the robot base"],
        env_kwargs={"placement_limits": {"reach_min": 1.7, "reach_max": 1.95}},
        validate=False,
        layout=b,
    )
    write_case(
        "empty_reach_band",
        "an empty reach band is a range error before anything is placed",
        "ValueError",
        ["placement_limits.reach_max=0.3", "outside (0.3, 2.0]"],
        env_kwargs={"placement_limits": {"reach_min": 0.3, "reach_max": 0.3}},
        validate=False,
        layout=b,
    )
    # the robot's own pose: the task would be silently impossible
    table = b["position"]["table"]
    for name, what, xyz, words in (
        (
            "robot_floating",
            "the robot base 3 m above the table top",
            [None, None, 3.76],
            ["franka", "z = 3.760", "+3.000 m from the top", "set its z to 0.760"],
        ),
        (
            "robot_under_floor",
            "the robot base under the floor",
            [None, None, -0.5],
            ["franka", "z = -0.500", "set its z to 0.760"],
        ),
        (
            "robot_inside_table",
            "the robot base in the middle of the table top",
            [table[0], table[1], None],
            ["franka", "inside the edge", "move it to the table's edge"],
        ),
        (
            "robot_away_from_table",
            "the robot base 1.5 m from the table",
            [table[0] - 1.5, table[1], None],
            ["franka", "outside the edge"],
        ),
    ):

        def move(d, xyz=xyz):
            pos = d["position"]["franka"]
            pos[:3] = [old if new is None else new for old, new in zip(pos[:3], xyz, strict=True)]

        write_case(name, what, "LayoutError", ["layout.json", *words], layout=mutated(move))
    # numbers and nesting a JSON reader accepts and the checks must not choke on
    huge = mutated(lambda d: d["position"]["can"].__setitem__(0, int("7" * 400)))
    write_case(
        "pose_400_digits",
        "a 400-digit integer in a pose",
        "LayoutError",
        ["layout.json", 'position["can"]', "too large for a float"],
        layout=huge,
    )
    deep = json.dumps(b)[:-1] + ', "notes": ' + "[" * 50_000 + "]" * 50_000 + "}"
    write_case("json_nested_deeply", "JSON nested 50,000 levels deep", "LayoutError",
               ["layout.json", "nested too deeply"], raw_layout=deep)  # fmt: skip
    # JSON that would silently lose data
    text = json.dumps(b, indent=2)
    mug = json.dumps(b["position"]["mug"])
    write_case(
        "duplicate_key",
        'a duplicate key in "position" (a JSON reader keeps the last)',
        "LayoutError",
        ["layout.json", '"mug" appears twice', "Fix: keep one"],
        raw_layout=text.replace('"position": {', f'"position": {{\n    "mug": {mug},', 1),
    )

    def twice_in_tree(d):
        d["tree"]["table"].append(["mug", "ON"])

    write_case(
        "node_twice_in_tree",
        "a node listed twice in the tree",
        "LayoutError",
        ['tree lists "mug" twice', "one parent"],
        layout=mutated(twice_in_tree),
    )
    write_case(
        "node_twice_in_relation",
        "a node listed twice in relation",
        "LayoutError",
        ['relation lists "mug" 2 times', "list each object once"],
        layout=mutated(lambda d: d["relation"]["distractor_objs"].append("mug")),
    )

    def cycle(d):
        d["tree"]["table"] = [e for e in d["tree"]["table"] if e[0] not in ("mug", "bowl")]
        d["tree"]["mug"] = [["bowl", "ON"]]
        d["tree"]["bowl"] = [["mug", "ON"]]

    write_case(
        "tree_cycle",
        "a cycle in the tree",
        "LayoutError",
        ["tree has a cycle", "mug", "bowl"],
        layout=mutated(cycle),
    )

    # node names become file names
    def renamed(new):
        def fn(d):
            for table in (d["objs_mapping"], d["assets"], d["position"]):
                table[new] = table.pop("mug")
            d["relation"]["distractor_objs"] = [
                new if n == "mug" else n for n in d["relation"]["distractor_objs"]
            ]
            d["tree"]["table"] = [[new if c == "mug" else c, r] for c, r in d["tree"]["table"]]

        return fn

    for name, node in (("node_name_with_path", "../../../x/x"), ("node_name_300_chars", "m" * 300)):
        write_case(
            name,
            f"a node name that cannot name a file ({node[:20]})",
            "LayoutError",
            ["cannot name a URDF file", "Fix: rename the node"],
            layout=mutated(renamed(node)),
        )
    write_case(
        "node_named_like_the_goal_marker",
        "a node named goal_site, the env's own goal marker (ManiSkill asserted on the duplicate)",
        "LayoutError",
        ['node name "goal_site" is reserved', 'Fix: rename the node (e.g. "goal_site_1")'],
        layout=mutated(renamed("goal_site")),
    )

    # poses that validate as numbers but cannot be simulated as written
    def moved(node, index, value):
        def fn(d):
            d["position"][node][index] = value

        return fn

    for name, index, value, words in (
        ("pose_at_1e308", 0, 1e308, ['position["can"]', "more than 20 m from the origin"]),
        ("pose_1e6_up", 2, 1e6, ['position["can"]', "more than 20 m from the origin"]),
        ("pose_below_the_table", 2, -5.0, ['position["can"]', 'not on the top of "table"']),
        ("pose_off_the_table", 0, 3.0, ['position["can"]', 'stands off the top of "table"']),
    ):
        write_case(
            name,
            f"the can at position[{index}] = {value:g}",
            "LayoutError",
            [*words, "Fix"],
            layout=mutated(moved("can", index, value)),
            env_kwargs={"replace_objs": False},
        )
    for name, mass in (("mass_1e-12_kg", "1e-12"), ("mass_1e12_kg", "1e12")):

        def heavy(case, mass=mass):
            dst = copy_asset(case, "mug", "mug")
            urdf = dst / "mug.urdf"
            text = urdf.read_text()
            if "<mass" in text:
                text = re.sub(r'<mass value="[^"]*"', f'<mass value="{mass}"', text)
            else:
                text = text.replace(
                    "<visual>", f'<inertial><mass value="{mass}"/></inertial><visual>', 1
                )
            urdf.write_text(text)

        write_case(
            name,
            f"a URDF mass of {mass} kg",
            "LayoutError",
            ["mug.urdf", "inertial/mass", "outside the plausible", "Fix"],
            setup=heavy,
            layout=mutated(lambda d: d["assets"].update(mug="mug")),
        )

    def broken_mug(edit):
        def setup(case):
            edit(copy_asset(case, "mug", "mug"))

        return setup

    def nan_vertex(name):
        def edit(asset):
            obj = asset / "mesh" / name
            lines = obj.read_text().splitlines()
            i = next(k for k, line in enumerate(lines) if line.startswith("v "))
            lines[i] = "v nan 0.0 0.0"
            obj.write_text("\n".join(lines) + "\n")

        return edit

    def flat_collision(asset):
        (asset / "mesh" / "mug_collision.obj").write_text(
            "v -0.04 0 -0.04\nv 0.04 0 -0.04\nv 0.04 0 0.04\nv -0.04 0 0.04\nf 1 2 3\nf 1 3 4\n"
        )

    def one_object(edit_vertex):
        """The mug's collision parts written as one object, each vertex edited: what a broken
        export writes (a one-object mesh would otherwise be made of convex parts on load)."""

        def edit(asset):
            obj = asset / "mesh" / "mug_collision.obj"
            lines = []
            for line in obj.read_text().splitlines():
                if line.startswith("v "):
                    line = "v " + " ".join(edit_vertex(line.split()[1:4]))
                if not line.startswith(("o ", "g ")):
                    lines.append(line)
            obj.write_text("\n".join(lines) + "\n")

        return edit

    def with_joint(asset):
        urdf = asset / "mug.urdf"
        joint = '<joint name="handle_hinge" type="revolute"><parent link="x"/><child link="y"/>'
        urdf.write_text(urdf.read_text().replace("</robot>", joint + "</joint></robot>"))

    for name, what, edit, words in (
        ("collision_nan_vertex", "NaN in the collision mesh", nan_vertex("mug_collision.obj"),
         ["mug_collision.obj", "NaN or infinity", "vertex 0"]),
        ("visual_nan_vertex", "NaN in the visual mesh", nan_vertex("mug.obj"),
         ["mug.obj", "NaN or infinity"]),
        ("collision_flat", "a flat collision mesh (the mug would sink)", flat_collision,
         ["mug_collision.obj", "collision mesh is flat", "sink"]),
        ("collision_flat_one_object", "a one-object collision mesh flattened to a plane",
         one_object(lambda v: [v[0], "0.0", v[2]]),
         ["mug_collision.obj", "collision mesh is flat", "sink"]),
        ("collision_collapsed", "a one-object collision mesh collapsed to a point",
         one_object(lambda v: ["0.01", "0.02", "0.03"]),
         ["mug_collision.obj", "collision mesh is flat", "sink"]),
        ("urdf_with_joint", "a URDF joint that would be ignored", with_joint,
         ["mug.urdf", "handle_hinge", "ignored"]),
    ):  # fmt: skip
        write_case(
            name,
            what,
            "LayoutError",
            [*words, "Fix"],
            setup=broken_mug(edit),
            layout=mutated(lambda d: d["assets"].update(mug="mug")),
        )
    write_case(
        "two_contexts",
        "two context nodes",
        "LayoutError",
        ["context"],
        layout=mutated(lambda d: d["objs_mapping"].update(mug="context")),
    )
    write_case(
        "quaternion_not_unit",
        "a quaternion of norm 2",
        "LayoutError",
        ['position["mug"]', "quaternion"],
        layout=mutated(
            lambda d: d["position"].update(mug=[*d["position"]["mug"][:3], 0.0, 0.0, 0.0, 2.0])
        ),
    )
    write_case(
        "read_only_folder",
        "a valid layout in a folder the test makes read-only: "
        "everything works and nothing is written there",
        None,
        [],
        layout=b,
    )
    print(f"wrote {len(list(out.iterdir()))} cases to {out}")


if __name__ == "__main__":
    main()
