"""The datasets room: what a dataset records about its scene (:mod:`.records`), whether it
replays here and the replay itself (:mod:`.replay`), the conversion of joint-target actions to
end-effector actions in the robot's root frame (:mod:`.ee_actions`, imported on its own: it
needs torch), and the LeRobot export (:mod:`.lerobot`). Datasets are written by
``embodied_envs.pipelines.collect`` (ManiSkill's ``RecordEpisode``)."""

from embodied_envs.datasets.lerobot import lerobot_settings, relabel_lerobot_tasks
from embodied_envs.datasets.records import (
    RECORD_KEY,
    DatasetError,
    episode_instructions,
    layout_content_hash,
    scene_record,
)
from embodied_envs.datasets.replay import check_replayable, replay, root_frame_conversion

__all__ = [
    "RECORD_KEY",
    "DatasetError",
    "check_replayable",
    "episode_instructions",
    "layout_content_hash",
    "lerobot_settings",
    "relabel_lerobot_tasks",
    "replay",
    "root_frame_conversion",
    "scene_record",
]
