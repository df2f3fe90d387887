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
from embodied_envs.registration import CONTROL_FREQ, ENV_ID

RECORD_KEY = "embodied_envs"  # our entry in trajectory.json (ManiSkill's tools ignore it)


class DatasetError(RuntimeError):
    """A dataset that cannot be replayed here (names the file and the fix)."""


def has_splat(layout_file: str | Path) -> bool:
    """Whether a layout's background has a splat (videos are then hybrid)."""
    return load_layout(layout_file, check_poses=False).gs_model_path().is_file()


def layout_content_hash(layout_file: str | Path) -> str:
    """SHA-256 of a layout file and of every file in its asset folders (names and bytes)."""
    layout_file = Path(layout_file)
    layout = load_layout(layout_file, check_files=False)
    digest = hashlib.sha256(layout_file.read_bytes())
    for node in sorted(layout.assets):
        folder = layout.asset_dir(node)
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            digest.update(f"{node}/{path.relative_to(folder).as_posix()}\0".encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def scene_record(layout_file: str | Path) -> dict:
    """What a dataset records about its scene (``trajectory.json[RECORD_KEY]``)."""
    return {"layout_file": str(layout_file), "layout_sha256": layout_content_hash(layout_file)}


def lerobot_settings(traj_path: str | Path) -> dict:
    """ManiSkill's LeRobot converter's ``task_name``, ``fps`` and ``robot_type`` for one of our
    datasets: the episodes' instruction (or the layout's), the control rate, the robot uid.

    Raises:
        DatasetError: the episodes hold several instructions (the converter writes one task
            per dataset).
    """
    meta = json.loads(Path(traj_path).with_suffix(".json").read_text())
    kwargs = meta["env_info"]["env_kwargs"]
    layout = load_layout(kwargs["layout_file"], check_files=False)
    tasks = sorted({e.get("instruction") or layout.instruction for e in meta["episodes"]})
    if len(tasks) > 1:
        raise DatasetError(
            f"{traj_path}: its episodes hold {len(tasks)} instructions ({tasks[:3]}); ManiSkill's "
            "LeRobot converter writes one task per dataset. Fix: convert each layout's dataset"
        )
    robot = kwargs.get("robot_uids") or resolve_robot(layout.robot, None, str(layout.source))
    return dict(task_name=tasks[0] if tasks else layout.instruction, fps=CONTROL_FREQ,
                robot_type=str(robot))  # fmt: skip


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
    if layout is not None and not Path(layout).is_file():
        raise DatasetError(
            f"{meta_path}: the dataset's layout {layout} does not exist any more. Fix: restore "
            "it (with its assets), or edit env_info.env_kwargs.layout_file to its new place"
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
