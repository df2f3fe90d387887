"""Dataset checks shared by ``collect`` and ``replay``: what a dataset records about the scene
it was made in, and whether it can be replayed here.

``collect`` records, beside ManiSkill's own fields of ``trajectory.json``, an ``embodied_envs``
entry with a content hash of the layout file and every file of its asset folders
(:func:`layout_content_hash`). ``replay`` checks a dataset before ManiSkill opens it
(:func:`check_replayable`): the files are readable, the env id is known, the layout exists,
and its content is the one recorded; a changed scene is said in one line, not discovered as
"0/3 saved".
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import gymnasium as gym

from embodied_envs.config import resolve_robot
from embodied_envs.layout import load_layout
from embodied_envs.layout.sets import LayoutSet, layout_files
from embodied_envs.paths import atomic_output
from embodied_envs.registration import CONTROL_FREQ, ENV_ID

RECORD_KEY = "embodied_envs"  # our entry in trajectory.json (ManiSkill's tools ignore it)


class DatasetError(RuntimeError):
    """A dataset that cannot be replayed here (names the file and the fix)."""


def has_splat(layout_file) -> bool:
    """Whether every layout's background has a splat (videos are then hybrid)."""
    return all(
        load_layout(f, check_poses=False).gs_model_path().is_file()
        for f in layout_files(layout_file)
    )


def layout_content_hash(layout_file) -> str:
    """SHA-256 of the layout files (one, or a set's, in order) and of every file in their asset
    folders (names and bytes; an asset pool's members are files of its folder)."""
    digest = hashlib.sha256()
    for file in layout_files(layout_file):
        layout = load_layout(file, check_files=False)
        digest.update(file.read_bytes())
        for node in sorted(layout.assets):
            folder = layout.asset_dir(node)
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


def lerobot_settings(traj_path: str | Path) -> dict:
    """ManiSkill's LeRobot converter's ``task_name``, ``fps`` and ``robot_type`` for one of our
    datasets: the first episode's instruction, the control rate, the robot uid (the others'
    instructions are set per episode by :func:`relabel_lerobot_tasks`)."""
    meta = json.loads(Path(traj_path).with_suffix(".json").read_text())
    kwargs = meta["env_info"]["env_kwargs"]
    layout = load_layout(layout_files(kwargs["layout_file"])[0], check_files=False)
    tasks = episode_instructions(traj_path)
    robot = kwargs.get("robot_uids") or resolve_robot(layout.robot, None, str(layout.source))
    return dict(task_name=next(iter(tasks.values()), layout.instruction), fps=CONTROL_FREQ,
                robot_type=str(robot))  # fmt: skip


def relabel_lerobot_tasks(traj_path: str | Path, root: str | Path) -> list[str]:
    """Give each episode of a LeRobot dataset that ManiSkill's converter wrote from
    ``traj_path`` its own instruction (the converter writes one task for all): the frames'
    ``task`` and ``task_index``, ``meta/tasks.parquet``, the episodes' ``tasks`` and
    ``info.json``'s ``total_tasks``. Returns the tasks in index order."""
    import h5py  # only where a dataset is opened: `embodied-envs --help` starts without it
    import pandas as pd  # the lerobot extra's

    root = Path(root)
    by_id = episode_instructions(traj_path)
    with h5py.File(traj_path, "r") as f:  # the converter's episode order
        ids = [int(k[len("traj_") :]) for k in f.keys() if k.startswith("traj_")]
    texts = [by_id[i] for i in ids]
    tasks = list(dict.fromkeys(texts))
    index = {t: i for i, t in enumerate(tasks)}
    for part in sorted((root / "data").rglob("*.parquet")):
        frames = pd.read_parquet(part)
        frames["task"] = [texts[int(e)] for e in frames["episode_index"]]
        frames["task"] = frames["task"].astype("string")
        frames["task_index"] = [index[t] for t in frames["task"]]
        frames["task_index"] = frames["task_index"].astype("int64")
        with atomic_output(part) as tmp:
            frames.to_parquet(tmp, index=False)
    for part in sorted((root / "meta" / "episodes").rglob("*.parquet")):
        episodes = pd.read_parquet(part)
        episodes["tasks"] = [[texts[int(e)]] for e in episodes["episode_index"]]
        with atomic_output(part) as tmp:
            episodes.to_parquet(tmp, index=False)
    table = pd.DataFrame({"task_index": range(len(tasks))}, index=tasks)
    with atomic_output(root / "meta" / "tasks.parquet") as tmp:
        table.to_parquet(tmp, index=True)
    info_path = root / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    info["total_tasks"] = len(tasks)
    with atomic_output(info_path) as tmp:
        tmp.write_text(json.dumps(info, indent=2))
    return tasks


def check_replayable(traj_path: str | Path) -> list[str]:
    """Refuse a dataset that cannot be replayed here; the notes to print otherwise.

    Raises:
        DatasetError: a missing or corrupt ``.h5`` / ``.json``, an env id that is not
            registered, or a layout file that no longer exists.
    """
    import h5py  # only where a dataset is opened: `embodied-envs --help` starts without it

    h5 = Path(traj_path)
    meta_path = h5.with_suffix(".json")
    if not h5.is_file():
        raise DatasetError(f"{h5}: no such trajectory file. Fix: check --traj-path")
    try:
        with h5py.File(h5, "r"):
            pass
    except OSError as e:
        raise DatasetError(f"{h5}: not a readable HDF5 trajectory file ({e})") from None
    try:
        meta = json.loads(meta_path.read_text())
        env_id, kwargs = meta["env_info"]["env_id"], meta["env_info"]["env_kwargs"]
    except FileNotFoundError:
        raise DatasetError(
            f"{meta_path}: missing; ManiSkill's replay needs the .json beside the .h5"
        ) from None
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise DatasetError(
            f"{meta_path}: not a ManiSkill trajectory JSON (env_info.env_id and env_kwargs: "
            f"{type(e).__name__} {e})"
        ) from None
    ours = env_id.split(":")[-1] == ENV_ID
    if not ours:
        try:
            gym.spec(env_id)
        except gym.error.Error:
            raise DatasetError(
                f"{meta_path}: env_info.env_id {env_id!r} is not a registered env. Fix: "
                f"install the package that registers it (this one registers {ENV_ID})"
            ) from None
        return []
    layout = kwargs.get("layout_file")
    for file in [] if layout is None else layout_files(layout):
        if not file.is_file():
            raise DatasetError(
                f"{meta_path}: the dataset's layout {file} does not exist any more. Fix: "
                "restore it (with its assets), or edit env_info.env_kwargs.layout_file to its "
                "new place"
            )
    # by file name: a dataset whose layouts moved (env_kwargs edited to the new place) is fine
    held = {f.name for f in layout_files(layout)} if layout is not None else set()
    strays = [
        e
        for e in meta.get("episodes", [])
        if e.get("layout_file") and Path(e["layout_file"]).name not in held
    ]
    if layout is not None and strays:
        e = strays[0]
        raise DatasetError(
            f"{meta_path}: episode {e.get('episode_id')} was recorded in {e['layout_file']}, "
            f"which env_info.env_kwargs.layout_file does not hold ({len(strays)} such episodes):"
            " merged datasets of different layouts would replay in the first one's. Fix: "
            "collect over a layout set (--layout FOLDER or GLOB): one dataset whose episodes "
            "replay each in its own layout"
        )
    record = meta.get(RECORD_KEY) or {}
    if layout is not None and record.get("layout_sha256"):
        now = layout_content_hash(layout)
        if now != record["layout_sha256"]:
            return [
                f"note: {layout} or its asset files changed since this dataset was recorded "
                f"(content hash {record['layout_sha256'][:12]} then, {now[:12]} now): replayed "
                "episodes may diverge and fail. Fix: restore the files the dataset was made "
                "with, or collect again"
            ]
    return []
