"""The layout file model (EmbodiedGen's ``LayoutInfo``): lossless load/save and validation.

Validation runs at load, before any simulation object exists. Every problem names the file, the
node and the field, and says what to fix. Unknown keys are kept and written back unchanged.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from embodied_envs.layout.assets import AssetSpec, parse_urdf, urdf_path_for
from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.folders import resolve_path
from embodied_envs.layout.pose import QUAT_NORM_TOLERANCE, LayoutPose
from embodied_envs.layout.task import MAX_MOVERS, Task, resolve_task, structured_spec
from embodied_envs.paths import atomic_output
from embodied_envs.robots import ROBOT_NAMES, SUPPORTED_ROBOTS

CATEGORIES = ("background", "context", "manipulated_objs", "distractor_objs")
RELATIONS = ("ON", "IN", "INSIDE", "FLOOR")
REQUIRED_FIELDS = ("tree", "relation", "objs_mapping", "assets", "position")
KNOWN_FIELDS = (*REQUIRED_FIELDS, "objs_desc", "quality")
POSE_DECIMALS = 4  # poses are rounded to this many decimals when written (as EmbodiedGen does)
WORLD_BOUND = 20.0  # m: every position coordinate lies within +-WORLD_BOUND of the origin
MAX_NODE_NAME = 128  # characters: a node name names its URDF file
REST_TOLERANCE = 0.05  # m: a file's object rests this close to its parent's top (in height)
MAX_INTERPENETRATION = 0.01  # m: sibling footprints in a file may overlap at most this deep

# Layout robot names -> ManiSkill robot uids (embodied_envs/robots.py). An unknown name is an
# error unless the user passes robot_uids explicitly (EmbodiedGen silently fell back to panda).
ROBOT_REGISTRY = ROBOT_NAMES
# Slots of envs that hold different layouts (scene/layout_scene.py): the context, the graded
# object, and the others as OBJECT_SLOT + 1, 2, ...; the graded objects merged over envs.
CONTEXT_SLOT, TARGET_SLOT, OBJECT_SLOT, TARGET_ACTOR = "context", "target", "object", "target_obj"
# Names the env gives its own scene objects, slots and cameras, which a layout node must not
# take (ManiSkill asserts unique names, minutes into building the scene): the floor and the goal
# marker (envs/pick_embodiedgen.py), the slots and merged target above, the robots'
# articulations, the sensor and render cameras; and OBJECT_SLOT followed by digits. Per-env
# actors are named "env<i>/<node>", which no node can be: a node name holds no "/".
RESERVED_NAMES = (
    "ground", "goal_site", CONTEXT_SLOT, TARGET_SLOT, TARGET_ACTOR,
    *sorted(SUPPORTED_ROBOTS), "base_camera", "render_camera",
)  # fmt: skip


def is_reserved(node: str) -> bool:
    """Whether the env registers ``node`` itself (``RESERVED_NAMES``, ``object1``, ...)."""
    return node in RESERVED_NAMES or re.fullmatch(OBJECT_SLOT + "[0-9]+", node) is not None


@dataclass
class LayoutInfo:
    """A scene layout: scene tree, roles, asset folders and poses.

    ``source`` is the file it was read from; asset folders resolve against ``asset_root``
    (the directory of the original layout file), so a layout written elsewhere still
    finds its assets.
    """

    tree: dict[str, list[list[str]]]
    relation: dict[str, Any]
    objs_mapping: dict[str, str]
    assets: dict[str, str]
    position: dict[str, list[float]]
    objs_desc: dict[str, str] | None = None
    quality: dict[str, str] | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    source: Path | None = None
    asset_root: Path | None = None

    # --- roles ---------------------------------------------------------------------------
    @property
    def robot(self) -> str:
        return self.relation["robot"]

    @property
    def background(self) -> str:
        return self.relation["background"]

    @property
    def context(self) -> str:
        return self.relation["context"]

    @property
    def manipulated_objs(self) -> list[str]:
        return list(self.relation["manipulated_objs"])

    @functools.cached_property
    def task(self) -> Task:
        """The task graded in this layout (``layout/task.py``: ``relation.task_spec``, else the
        sentence ``relation.task_desc``, else picking the first manipulated object)."""
        return resolve_task(self, label(self.source), MAX_MOVERS)

    @property
    def reach_nodes(self) -> list[str]:
        """The objects placed within the robot's reach: the manipulated ones, the task's movers
        (the sentence may name a distractor: "the apples", "the mug") and its receptacle when
        it is an object (the movers go there)."""
        rec = self.task.receptacle
        extra = [*self.task.objects, *([rec] if rec is not None and rec != self.context else [])]
        return self.manipulated_objs + [n for n in dict.fromkeys(extra)
                                        if n not in self.manipulated_objs]  # fmt: skip

    @property
    def target_node(self) -> str:
        """The graded object's node name: the task's first mover."""
        return self.task.objects[0]

    @property
    def instruction(self) -> str:
        """The task in words, for language-conditioned policies (collect, the LeRobot export,
        eval and ``env.unwrapped.instructions`` all read this one): the sentence the grade was
        read from, ``relation.task_desc``; where the grade comes from the structured
        ``relation.task_spec`` (or there is no sentence), a sentence built from the task and
        the objects' ``objs_desc`` (or their node names)."""
        desc = self.relation.get("task_desc")
        graded_from_sentence = structured_spec(self.relation, label(self.source)) is None
        if graded_from_sentence and isinstance(desc, str) and desc.strip():
            return " ".join(desc.split())
        names = {
            n: " ".join(str((self.objs_desc or {}).get(n) or n).replace("_", " ").split())
            for n in self.objs_mapping
        }
        return self.task.sentence(names)

    def object_nodes(self) -> list[str]:
        """Simulated asset nodes (everything but the background), in ``objs_mapping`` order."""
        return [n for n, c in self.objs_mapping.items() if c != "background"]

    def pose(self, node: str) -> LayoutPose:
        return LayoutPose.from_layout(self.position[node])

    @property
    def asset_base(self) -> Path:
        """The folder asset paths resolve against: ``asset_root``, else the layout file's
        folder, else the working directory."""
        return self.asset_root or (self.source.parent if self.source else Path.cwd())

    def asset_dir(self, node: str) -> Path:
        """A node's asset folder, absolute (``LayoutError`` on a symbolic link loop)."""
        where = f'{label(self.source)}: assets["{node}"]'
        return resolve_path(self.asset_base / self.assets[node], where)

    def urdf_path(self, node: str) -> Path:
        return urdf_path_for(self.asset_dir(node), node)

    def asset_spec(self, node: str) -> AssetSpec:
        return parse_urdf(self.urdf_path(node))

    def gs_model_path(self) -> Path:
        return self.asset_dir(self.background) / "gs_model.ply"

    def children(self, parent: str) -> list[tuple[str, str]]:
        return [(c, r) for c, r in self.tree.get(parent, [])]

    def with_poses(self, poses: dict[str, LayoutPose]) -> LayoutInfo:
        """A copy with some node poses replaced."""
        position = {k: list(v) for k, v in self.position.items()}
        for node, pose in poses.items():
            position[node] = pose.to_layout()
        return dataclasses.replace(
            self,
            tree={k: [list(x) for x in v] for k, v in self.tree.items()},
            relation=copy.deepcopy(self.relation),
            objs_mapping=dict(self.objs_mapping),
            assets=dict(self.assets),
            position=position,
            objs_desc=dict(self.objs_desc) if self.objs_desc is not None else None,
            quality=dict(self.quality) if self.quality is not None else None,
            extra=copy.deepcopy(self.extra),
        )

    # --- serialisation -------------------------------------------------------------------
    @classmethod
    def from_dict(cls, data: dict, source: Path | None = None) -> LayoutInfo:
        """Build from a parsed JSON object and validate its structure and poses.

        Raises:
            LayoutError: listing every problem found.
        """
        problems = _check_structure(data, label(source))
        if problems:
            raise LayoutError(problems)
        data = copy.deepcopy(data)
        info = cls(
            tree={k: [list(x) for x in v] for k, v in data["tree"].items()},
            relation=data["relation"],
            objs_mapping=data["objs_mapping"],
            assets=data["assets"],
            position={k: [float(x) for x in v] for k, v in data["position"].items()},
            objs_desc=data.get("objs_desc"),
            quality=data.get("quality"),
            extra={k: v for k, v in data.items() if k not in KNOWN_FIELDS},
            source=Path(source).resolve() if source else None,
            asset_root=Path(source).resolve().parent if source else None,
        )
        # normalise quaternions within tolerance (rejected beyond it by _check_structure)
        for node, values in info.position.items():
            info.position[node] = LayoutPose.from_layout(values).to_layout()
        info.task  # noqa: B018 (a task the env cannot grade is refused at load)
        return info

    def to_dict(self, decimals: int | None = POSE_DECIMALS) -> dict:
        """The JSON object, unknown keys included; poses rounded to ``decimals``."""
        out: dict[str, Any] = {
            "tree": copy.deepcopy(self.tree),
            "relation": copy.deepcopy(self.relation),
            "objs_mapping": dict(self.objs_mapping),
            "assets": dict(self.assets),
            "position": {
                k: LayoutPose.from_layout(v).to_layout(decimals) for k, v in self.position.items()
            },
        }
        if self.objs_desc is not None:
            out["objs_desc"] = dict(self.objs_desc)
        if self.quality is not None:
            out["quality"] = dict(self.quality)
        out.update(copy.deepcopy(self.extra))
        return out

    def save(self, path: Path | str, asset_root: Path | None = None) -> Path:
        """Write to ``path``; asset folders are rewritten relative to the new file's folder.

        Args:
            path: destination file. Its folder is created.
            asset_root: where the asset folders are (default: this layout's ``asset_root``).
        """
        path = Path(path).resolve()
        path.parent.mkdir(parents=True, exist_ok=True)
        root = asset_root or self.asset_root
        data = self.to_dict()
        if root is not None:
            data["assets"] = {
                n: _relpath((Path(root) / d).resolve(), path.parent) for n, d in self.assets.items()
            }
        with atomic_output(path) as tmp:
            tmp.write_text(json.dumps(data, indent=4) + "\n")
        return path


def _relpath(target: Path, start: Path) -> str:

    return os.path.relpath(target, start)


def label(source: Path | str | None) -> str:
    return str(source) if source else "<layout>"


def _is_str_list(v) -> bool:
    return isinstance(v, list) and all(isinstance(x, str) for x in v)


def _check_pose(f: str, node: str, values) -> str | None:
    where = f'{f}: position["{node}"]'
    if not isinstance(values, list | tuple):
        return f"{where} is not a list. Fix: write [x, y, z, qx, qy, qz, qw]."
    if len(values) != 7:
        return (
            f"{where} has {len(values)} numbers, expected 7. "
            "Fix: write [x, y, z, qx, qy, qz, qw] (quaternion scalar-last)."
        )
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
        return f"{where} holds a non-number. Fix: use 7 numbers."
    if not all(isinstance(v, float) or abs(v) < 1e300 for v in values):
        return f"{where} holds an integer too large for a float. Fix: use metres."
    if not all(math.isfinite(v) for v in values):
        return f"{where} holds NaN or infinity. Fix: use 7 finite numbers."
    if max(abs(v) for v in values[:3]) > WORLD_BOUND:
        return (
            f"{where} position {list(values[:3])} lies more than {WORLD_BOUND:g} m from the "
            "origin. Fix: use metres, with the table at the origin."
        )
    norm = float(np.linalg.norm(values[3:]))
    if abs(norm - 1.0) > QUAT_NORM_TOLERANCE:
        return (
            f"{where} quaternion has norm {norm:.4g}, expected 1 (within {QUAT_NORM_TOLERANCE}). "
            "Fix: write a unit quaternion [qx, qy, qz, qw], e.g. [0, 0, 0, 1]."
        )
    return None


def _check_node_name(f: str, node: str) -> str | None:
    """A node name becomes a file name (its URDF): no paths, no hidden names, not too long."""
    bad = (
        not node
        or len(node) > MAX_NODE_NAME
        or any(c in node for c in "/\\\0")
        or node.startswith(".")
        or not node.isprintable()
    )
    if bad:
        shown = node if len(node) <= 60 else node[:57] + "..."
        return (
            f'{f}: node name "{shown}" cannot name a URDF file: it must be 1-{MAX_NODE_NAME} '
            "printable characters without '/', '\\' or a leading '.'. Fix: rename the node "
            "(and its URDF file)."
        )
    return None


def _check_reserved(f: str, node: str) -> str | None:
    """A node may not take a name the env gives its own scene objects (``RESERVED_NAMES``)."""
    if not is_reserved(node):
        return None
    return (
        f'{f}: node name "{node}" is reserved: the env names its own scene objects, slots and'
        f" cameras {list(RESERVED_NAMES)} and {OBJECT_SLOT}1, {OBJECT_SLOT}2, ... (ManiSkill"
        f' would fail on the duplicate). Fix: rename the node (e.g. "{node}_1") everywhere in'
        " the layout file; its URDF is found by the new name or by its folder's name."
    )


def _check_structure(data, f: str) -> list[str]:
    """Structural checks that need no files, in stages (a stage runs when the ones before it
    found nothing it depends on). Returns every problem found."""
    if not isinstance(data, dict):
        return [f"{f}: the top level must be a JSON object, got {type(data).__name__}."]
    problems = _check_fields(data, f) or _check_relation(data["relation"], f)
    if problems:
        return problems
    return _check_nodes(data, f) + _check_tree(data, f)


def _check_fields(data: dict, f: str) -> list[str]:
    """The required top-level fields exist and are JSON objects."""
    problems = []
    types = {"tree": dict, "relation": dict, "objs_mapping": dict, "assets": dict, "position": dict}
    for key in REQUIRED_FIELDS:
        if key not in data:
            problems.append(
                f'{f}: required field "{key}" is missing. Fix: add it (a layout has tree, '
                "relation, objs_mapping, assets and position)."
            )
        elif not isinstance(data[key], types[key]):
            problems.append(f'{f}: field "{key}" must be a JSON object.')
    for key in ("objs_desc", "quality"):
        if key in data and data[key] is not None and not isinstance(data[key], dict):
            problems.append(f'{f}: field "{key}" must be a JSON object when present.')
    return problems


def _check_relation(rel: dict, f: str) -> list[str]:
    """``relation`` names the robot, background and context and lists the objects."""
    problems = []
    for key in ("robot", "background", "context"):
        if not isinstance(rel.get(key), str) or not rel.get(key):
            problems.append(f'{f}: relation["{key}"] must be a node name (string). Fix: add it.')
    for key in ("manipulated_objs", "distractor_objs"):
        if key not in rel or not _is_str_list(rel[key]):
            problems.append(f'{f}: relation["{key}"] must be a list of node names. Fix: add it.')
    return problems


def _check_nodes(data: dict, f: str) -> list[str]:
    """Every node has a category that agrees with ``relation``, a valid name, an asset folder
    and a valid pose; no object is listed twice."""
    rel, mapping, assets, position = (
        data["relation"],
        data["objs_mapping"],
        data["assets"],
        data["position"],
    )
    problems = []
    if not rel["manipulated_objs"]:
        problems.append(
            f'{f}: relation["manipulated_objs"] is empty. Fix: name at least one object to pick.'
        )
    for node, cat in mapping.items():
        if cat not in CATEGORIES:
            problems.append(
                f'{f}: objs_mapping["{node}"] is "{cat}", expected one of {list(CATEGORIES)}.'
            )
    for cat in ("context", "background"):
        nodes = [n for n, c in mapping.items() if c == cat]
        if len(nodes) != 1:
            problems.append(
                f'{f}: objs_mapping has {len(nodes)} "{cat}" nodes {nodes}, expected exactly 1.'
            )
        elif nodes[0] != rel[cat]:
            problems.append(
                f'{f}: relation["{cat}"] is "{rel[cat]}" but objs_mapping marks "{nodes[0]}" as'
                f" {cat}. Fix: make them agree."
            )
    for cat in ("manipulated_objs", "distractor_objs"):
        for node in rel[cat]:
            if mapping.get(node) != cat:
                problems.append(
                    f'{f}: relation["{cat}"] lists "{node}" but objs_mapping["{node}"] is '
                    f'{mapping.get(node)!r}. Fix: set objs_mapping["{node}"] to "{cat}".'
                )
    robot = rel["robot"]
    for node in [*mapping, robot]:
        msg = _check_node_name(f, node)
        if msg:
            problems.append(msg)
    for node in mapping:  # not the robot: its node names the robot itself
        msg = _check_reserved(f, node)
        if msg:
            problems.append(msg)
    listed = rel["manipulated_objs"] + rel["distractor_objs"]
    for node in sorted({n for n in listed if listed.count(n) > 1}):
        problems.append(
            f'{f}: relation lists "{node}" {listed.count(node)} times (manipulated_objs and '
            "distractor_objs together). Fix: list each object once."
        )
    if robot in mapping:
        problems.append(f'{f}: the robot "{robot}" must not appear in objs_mapping.')
    for node in mapping:
        if node not in assets:
            problems.append(
                f'{f}: assets["{node}"] is missing. Fix: give the asset folder of "{node}"'
                " relative to the layout file."
            )
        elif not isinstance(assets[node], str):
            problems.append(f'{f}: assets["{node}"] must be a folder path (string).')
        if node not in position:
            problems.append(f'{f}: position["{node}"] is missing. Fix: add its pose.')
    if robot not in position:
        problems.append(f'{f}: position["{robot}"] (the robot) is missing. Fix: add its pose.')
    for node, values in position.items():
        msg = _check_pose(f, node, values)
        if msg:
            problems.append(msg)
    return problems


def _check_tree(data: dict, f: str) -> list[str]:
    """``tree``: known nodes, known relations, one parent per node, no cycle, the background
    first, and every object resting (through its parents) on the context."""
    rel, mapping, tree = data["relation"], data["objs_mapping"], data["tree"]
    robot = rel["robot"]
    problems = []
    known = set(mapping) | {robot}
    parent_of: dict[str, str] = {}
    for parent, kids in tree.items():
        if parent not in known:
            problems.append(f'{f}: tree has unknown parent node "{parent}". Fix: add it or remove.')
        if not isinstance(kids, list):
            problems.append(f'{f}: tree["{parent}"] must be a list of [child, relation] pairs.')
            continue
        for kid in kids:
            if not (isinstance(kid, list | tuple) and len(kid) == 2 and _is_str_list(list(kid))):
                problems.append(f'{f}: tree["{parent}"] entry {kid!r} is not [child, relation].')
                continue
            child, relation = kid
            if relation not in RELATIONS:
                problems.append(
                    f'{f}: tree["{parent}"] relation of "{child}" is "{relation}", expected one '
                    f"of {list(RELATIONS)}."
                )
            if child not in known:
                problems.append(f'{f}: tree["{parent}"] has unknown child node "{child}".')
            if child in parent_of:
                problems.append(
                    f'{f}: tree lists "{child}" twice (under "{parent_of[child]}" and '
                    f'"{parent}"). Fix: give each node one parent.'
                )
                continue
            parent_of[child] = parent
    if tree and next(iter(tree)) != rel["background"]:
        problems.append(
            f'{f}: the first key of "tree" must be the background "{rel["background"]}".'
        )
    cycles = set()
    for node in rel["manipulated_objs"] + rel["distractor_objs"]:
        chain, cur = [], node
        while cur in parent_of and cur not in chain:
            chain.append(cur)
            cur = parent_of[cur]
        if cur in chain:  # the walk came back: a cycle
            loop = chain[chain.index(cur) :]
            key = frozenset(loop)
            if key not in cycles:
                cycles.add(key)
                problems.append(
                    f"{f}: tree has a cycle: {' -> '.join(loop + [cur])}. Fix: every node has "
                    "one parent and the chain ends at the background."
                )
            continue
        if rel["context"] not in chain[1:] + [cur] or node == rel["context"]:
            problems.append(
                f'{f}: tree: "{node}" does not rest on the context "{rel["context"]}". Fix: add'
                f' ["{node}", "ON"] under "{rel["context"]}" (or under an object on it).'
            )
    return problems
