"""Asset pools: an ``assets`` entry naming a folder of asset folders.

The pool's folder holds no URDF of its own; each of its sub-folders holds one asset
(``<node>.urdf`` or ``<sub-folder>.urdf`` with its meshes). Adding an asset folder to the pool
adds it to the draw (``layout.sets.LayoutSet.draw``). Where one geometry is needed without a
draw (the file's own poses, ``place``), a pooled node stands as its first member.
"""

from __future__ import annotations

import copy
import dataclasses
import os
from pathlib import Path

from embodied_envs.layout.assets import ASSET_FILES, FileVersion, urdf_path_for
from embodied_envs.layout.schema import LayoutInfo, label
from embodied_envs.layout.task import TASK_FIELD, structured_spec


def pool_members(layout: LayoutInfo, node: str) -> list[str] | None:
    """The members of a node's asset pool as ``assets`` entries (relative to the layout's
    asset folder), sorted; None when the node's folder is one asset. Read once per version of
    the folder (``ASSET_FILES``: adding or removing an asset folder or URDF there re-reads it),
    so a placement pays one ``stat`` per node."""
    path = os.path.join(layout.asset_base, layout.assets[node])
    try:
        version = FileVersion.of(path)
        names = ASSET_FILES.get(("pool", version, node), lambda: _members(Path(path), node))
    except OSError:
        return None  # a missing or unreadable folder: load_layout names it
    return None if names is None else [f"{layout.assets[node].rstrip('/')}/{n}" for n in names]


def _members(folder: Path, node: str) -> tuple[str, ...] | None:
    if not folder.is_dir() or urdf_path_for(folder, node).is_file():
        return None
    names = tuple(
        sub.name
        for sub in sorted(folder.iterdir())
        if sub.is_dir() and urdf_path_for(sub, node).is_file()
    )
    return names or None  # no URDF anywhere: load_layout names the missing one


def with_assets(layout: LayoutInfo, choices: dict[str, str]) -> LayoutInfo:
    """A copy of a layout with some ``assets`` entries replaced by pool members.

    A drawn target is described by its member's folder name (``objs_desc``), and the layout's
    ``task_desc``, written for no asset in particular, gives way to that description, so the
    instruction names the object the env holds: the task read from it is kept as the
    structured ``relation["task_spec"]``, from which the instruction is built.
    """
    if not choices:
        return layout
    assets = dict(layout.assets) | choices
    desc = dict(layout.objs_desc or {})
    relation = copy.deepcopy(layout.relation)
    for node, member in choices.items():
        desc[node] = Path(member).name.replace("_", " ")
        if node == layout.target_node and "task_desc" in relation:
            # the grade stays the sentence's; the instruction is built from it (instruction)
            relation.pop("task_desc")
            if structured_spec(relation, label(layout.source)) is None:
                relation[TASK_FIELD] = layout.task.spec()
    return dataclasses.replace(layout, assets=assets, objs_desc=desc, relation=relation)


def asset_pools(layout: LayoutInfo) -> dict[str, list[str]]:
    """Each pooled node's members (``assets`` entries)."""
    return {n: m for n in layout.object_nodes() if (m := pool_members(layout, n))}


def with_first_members(layout: LayoutInfo) -> LayoutInfo:
    """The layout with each asset pool's first member in its place (or itself)."""
    return with_assets(layout, {n: ms[0] for n, ms in asset_pools(layout).items()})
