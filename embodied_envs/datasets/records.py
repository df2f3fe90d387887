"""What a dataset records about the scene it was made in.

``collect`` records, beside ManiSkill's own fields of ``trajectory.json``, an ``embodied_envs``
entry (:data:`RECORD_KEY`) with a content hash of the layout file and every file of its asset
folders (:func:`layout_content_hash`), and each episode's ``instruction`` and ``layout_file``
(:func:`episode_instructions` reads them back).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from embodied_envs.layout import load_layout
from embodied_envs.layout.sets import LayoutSet, layout_files

RECORD_KEY = "embodied_envs"  # our entry in trajectory.json (ManiSkill's tools ignore it)


class DatasetError(RuntimeError):
    """A dataset that cannot be replayed here (names the file and the fix)."""


def scene_folders(layout_file) -> list[tuple[Path, dict[str, Path]]]:
    """Each layout file of ``layout_file`` (one, or a set's, in order) with its asset folders
    (node -> folder, sorted by node): every file its episodes read."""
    out = []
    for file in layout_files(layout_file):
        layout = load_layout(file, check_files=False)
        out.append((file, {node: layout.asset_dir(node) for node in sorted(layout.assets)}))
    return out


def layout_content_hash(layout_file) -> str:
    """SHA-256 of the layout files (one, or a set's, in order) and of every file in their asset
    folders (names and bytes; an asset pool's members are files of its folder)."""
    digest = hashlib.sha256()
    for file, folders in scene_folders(layout_file):
        digest.update(file.read_bytes())
        for node, folder in folders.items():
            for path in sorted(p for p in folder.rglob("*") if p.is_file()):
                digest.update(f"{node}/{path.relative_to(folder).as_posix()}\0".encode())
                digest.update(path.read_bytes())
    return digest.hexdigest()


def scene_record(layout_file) -> dict:
    """What a dataset records about its scene (``trajectory.json[RECORD_KEY]``)."""
    files = [str(f) for f in layout_files(layout_file)]
    return {
        "layout_file": files[0] if len(files) == 1 else files,
        "layout_sha256": layout_content_hash(files),
    }


def episode_instructions(traj_path: str | Path) -> dict[int, str]:
    """Each episode's instruction (``episode_id`` -> text): the one ``collect`` recorded, else
    the one its seed draws from the dataset's layout set (a file ``replay`` wrote keeps the
    seeds and layouts, not our per-episode fields)."""
    meta = json.loads(Path(traj_path).with_suffix(".json").read_text())
    layouts = LayoutSet.load(meta["env_info"]["env_kwargs"]["layout_file"], check_poses=False)
    out = {}
    for e in meta["episodes"]:
        if e.get("instruction"):
            out[int(e["episode_id"])] = e["instruction"]
        else:
            out[int(e["episode_id"])] = layouts.draw(e["episode_seed"], 0).instruction
    return out
