"""LeRobot export: the settings ManiSkill's ``convert_to_lerobot`` is given for one of our
datasets (the task, the control rate, the robot), and each episode's own instruction put into
the LeRobot dataset it wrote (the converter writes one task for all).
"""

from __future__ import annotations

import json
from pathlib import Path

from embodied_envs.config import resolve_robot
from embodied_envs.datasets.records import episode_instructions
from embodied_envs.layout import load_layout
from embodied_envs.layout.sets import layout_files
from embodied_envs.paths import atomic_output
from embodied_envs.registration import CONTROL_FREQ


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
