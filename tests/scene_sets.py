"""Layout sets and asset pools built from the shipped data, for the tests of issue 18.

``make_scene_set(root)`` writes, under ``root``:

- ``assets/``: the shipped assets, plus ``background_green`` (the shipped splat, every Gaussian
  coloured pure green: another room) and ``pool/`` (an asset pool of ``can``, ``bottle`` and
  ``cracker_box``);
- ``set/``: three layouts with different targets: ``default.json`` (can), ``round_table.json``
  (banana, 3 objects on a round table) and ``box.json`` (the default scene graded on the
  cracker box, in the green room, without a ``task_desc``);
- ``same_count/``: ``default.json``, ``box.json`` and ``mug.json`` (graded on the mug): three
  targets with as many objects each, for GPU sub-scenes;
- ``four/``: ``can.json`` and ``box.json`` (the default scene without its bowl, graded on the
  can and on the cracker box) and ``round_table.json``: three targets, two tables, three
  objects each but different node names, for GPU sub-scenes merged into generic slots;
- ``pooled/pool.json``: the default layout whose target's asset is the pool.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import torch

from embodied_envs.splat import read_ply, write_ply

SH_C0 = 0.28209479177387814  # the DC spherical harmonic's constant


def _graded_on(data: dict, target: str) -> dict:
    """The default layout graded on another of its objects (no task_desc: built from desc)."""
    data = json.loads(json.dumps(data))
    rel = data["relation"]
    rel["distractor_objs"] = [n for n in [*rel["distractor_objs"], *rel["manipulated_objs"]]
                              if n != target]  # fmt: skip
    rel["manipulated_objs"] = [target]
    rel.pop("task_desc", None)
    for node in data["objs_mapping"]:
        if data["objs_mapping"][node] in ("manipulated_objs", "distractor_objs"):
            kind = "manipulated_objs" if node == target else "distractor_objs"
            data["objs_mapping"][node] = kind
    return data


def _without(data: dict, node: str) -> dict:
    data = json.loads(json.dumps(data))
    for parent in data["tree"]:
        data["tree"][parent] = [c for c in data["tree"][parent] if c[0] != node]
    rel = data["relation"]
    rel["distractor_objs"] = [n for n in rel["distractor_objs"] if n != node]
    for key in ("objs_mapping", "assets", "position", "objs_desc"):
        data[key].pop(node, None)
    return data


def make_scene_set(root: Path, data: Path) -> dict[str, Path]:
    root = Path(root)
    shutil.copytree(data / "assets", root / "assets")
    green = root / "assets" / "background_green"
    green.mkdir()
    splat = read_ply(data / "assets" / "background" / "gs_model.ply")
    sh = splat.sh.clone()
    sh[:, 0] = torch.tensor([-0.5, 0.5, -0.5]) / SH_C0  # DC colour (0, 1, 0): pure green
    sh[:, 1:] = 0.0
    write_ply(dataclasses.replace(splat, sh=sh), green / "gs_model.ply")
    pool = root / "assets" / "pool"
    pool.mkdir()
    for member in ("can", "bottle", "cracker_box"):
        shutil.copytree(data / "assets" / member, pool / member)
    default = json.loads((data / "layouts" / "default.json").read_text())
    out = {}
    for folder in ("set", "same_count", "pooled", "four"):
        (root / folder).mkdir()
    shutil.copy(data / "layouts" / "default.json", root / "set" / "default.json")
    shutil.copy(data / "layouts" / "round_table.json", root / "set" / "round_table.json")
    box = _graded_on(default, "cracker_box")
    box["assets"]["background"] = "../assets/background_green"
    (root / "set" / "box.json").write_text(json.dumps(box, indent=2))
    shutil.copy(data / "layouts" / "default.json", root / "same_count" / "default.json")
    (root / "same_count" / "box.json").write_text(json.dumps(box, indent=2))
    mug = _graded_on(default, "mug")
    (root / "same_count" / "mug.json").write_text(json.dumps(mug, indent=2))
    (root / "four" / "can.json").write_text(json.dumps(_without(default, "bowl"), indent=2))
    box4 = _without(box, "bowl")
    (root / "four" / "box.json").write_text(json.dumps(box4, indent=2))
    shutil.copy(data / "layouts" / "round_table.json", root / "four" / "round_table.json")
    pooled = json.loads(json.dumps(default))
    pooled["assets"]["can"] = "../assets/pool"
    pooled["relation"].pop("task_desc")
    (root / "pooled" / "pool.json").write_text(json.dumps(pooled, indent=2))
    out.update(
        root=root,
        set=root / "set",
        same_count=root / "same_count",
        four=root / "four",
        pooled=root / "pooled" / "pool.json",
        pool=pool,
    )
    return out
