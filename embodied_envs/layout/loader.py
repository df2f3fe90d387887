"""Reading a layout file: parse, validate the schema, then the asset files and the file's own
poses (the checks that need the assets' geometry and the placement rules)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from embodied_envs.layout.assets import asset_geometry, node_stem, parse_urdf
from embodied_envs.layout.errors import LayoutError
from embodied_envs.layout.folders import check_folder
from embodied_envs.layout.placement.file_poses import check_file_poses
from embodied_envs.layout.pools import asset_pools, with_assets
from embodied_envs.layout.schema import LayoutInfo, label
from embodied_envs.layout.visual import check_visual_mesh

MAX_LAYOUT_BYTES = 1 << 20  # a layout file over this is refused before it is read


def check_asset_files(info: LayoutInfo) -> list[str]:
    """File checks: every asset folder exists and holds a loadable URDF with its meshes; every
    member of an asset pool is checked in its place, and a bad one is named."""
    pooled = asset_pools(info)
    problems = _check_nodes(info, [n for n in info.objs_mapping if n not in pooled])
    for node, members in pooled.items():
        try:  # the pool's own entries; each member is walked as an asset folder
            check_folder(info.asset_dir(node), recursive=False)
        except LayoutError as e:
            problems.extend(f'{label(info.source)}: assets["{node}"]: {p}' for p in e.problems)
            continue
        for member in members:
            problems += _check_nodes(with_assets(info, {node: member}), [node])
    return problems


def _check_nodes(info: LayoutInfo, nodes: list[str]) -> list[str]:
    f = label(info.source)
    problems = []
    for node in nodes:
        cat = info.objs_mapping[node]
        try:
            d = info.asset_dir(node)
        except LayoutError as e:
            problems.extend(e.problems)
            continue
        if not d.is_dir():
            problems.append(
                f'{f}: assets["{node}"] folder {info.assets[node]} does not exist (looked at {d}).'
                " Fix: make the path relative to the layout file's folder."
            )
            continue
        try:  # the folder as a whole first: a loop or an unreadable file is named by its path
            check_folder(d)
        except LayoutError as e:
            problems.extend(f'{f}: assets["{node}"]: {p}' for p in e.problems)
            continue
        if cat == "background":
            continue
        urdf = info.urdf_path(node)
        if not urdf.is_file():
            found = sorted(p.name for p in d.glob("*.urdf"))
            problems.append(
                f'{f}: assets["{node}"]: {node_stem(node)}.urdf not found in {d} (found {found}).'
                " Fix: name the URDF after the node (spaces replaced by underscores) or after its"
                " folder; a folder of such asset folders is an asset pool."
            )
            continue
        try:
            spec = parse_urdf(urdf)
            asset_geometry(spec)
            check_visual_mesh(spec)
        except LayoutError as e:
            problems.extend(f'{f}: assets["{node}"]: {p}' for p in e.problems)
    return problems


class DuplicateKeyError(ValueError):
    def __init__(self, key: str, values: tuple):
        super().__init__(key)
        self.key, self.values = key, values


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict:
    out: dict = {}
    for key, value in pairs:
        if key in out:
            raise DuplicateKeyError(key, (out[key], value))
        out[key] = value
    return out


def load_layout(path: Path | str, check_files: bool = True, check_poses: bool = True) -> LayoutInfo:
    """Read, parse and validate a layout file.

    Args:
        path: the ``layout.json``.
        check_files: also check every asset folder and its URDF and meshes.
        check_poses: with ``check_files``, also check that the file's own poses can be
            simulated (``placement.check_file_poses``); off where every pose is re-drawn.

    Returns:
        The validated layout; its ``source`` and ``asset_root`` point at the file.

    Raises:
        LayoutError: naming the file, node and field of every problem found.
    """
    path = Path(path)
    if not path.is_file():
        raise LayoutError(f"{path}: layout file does not exist. Fix: check the path.")
    size = path.stat().st_size
    if size > MAX_LAYOUT_BYTES:
        raise LayoutError(
            f"{path}: {size:,} bytes, over the {MAX_LAYOUT_BYTES:,} a layout may hold (it names"
            " nodes, assets and poses: a few kB; every generated variant would copy the rest)."
            " Fix: keep large data outside the layout file."
        )
    try:
        data = json.loads(path.read_text(), object_pairs_hook=_unique_keys)
    except DuplicateKeyError as e:
        raise LayoutError(
            f'{path}: the key "{e.key}" appears twice in one JSON object (with values '
            f"{e.values[0]!r} and {e.values[1]!r}); a JSON reader would silently keep the last."
            " Fix: keep one."
        ) from None
    except json.JSONDecodeError as e:
        raise LayoutError(
            f"{path}: not valid JSON ({e.msg} at line {e.lineno}, column {e.colno})."
            " Fix: repair the JSON syntax."
        ) from e
    except UnicodeDecodeError as e:
        raise LayoutError(f"{path}: not a UTF-8 text file ({e}).") from e
    except RecursionError:
        raise LayoutError(
            f"{path}: JSON nested too deeply to read (a layout is a few levels deep)."
            " Fix: remove the nested value."
        ) from None
    try:
        info = LayoutInfo.from_dict(data, source=path)
    except LayoutError as e:
        # report missing asset folders too, so that one run lists every problem
        if check_files and isinstance(data, dict) and isinstance(data.get("assets"), dict):
            for node, folder in data["assets"].items():
                if isinstance(folder, str) and not (path.parent / folder).is_dir():
                    e.problems.append(
                        f'{path}: assets["{node}"] folder {folder} does not exist.'
                        " Fix: make the path relative to the layout file's folder."
                    )
            raise LayoutError(e.problems) from None
        raise
    if check_files:
        problems = check_asset_files(info)
        if not problems and check_poses:
            problems = check_file_poses(info)
        if problems:
            raise LayoutError(problems)
    return info
