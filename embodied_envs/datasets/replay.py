"""Whether a dataset can be replayed here, and the replay itself.

``replay`` checks a dataset before ManiSkill opens it (:func:`check_replayable`): the files are
readable, the env id is known, the layout exists, and its content is the one recorded; a changed
scene is said in one line, not discovered as "0/3 saved". :func:`replay` then runs ManiSkill's
``replay_trajectory`` with conversions from ``pd_joint_pos`` to end-effector control modes in
the robot's root frame (:mod:`embodied_envs.datasets.ee_actions`) and, for an arm with one
controller, to its other joint modes (:mod:`embodied_envs.datasets.joint_actions`).
"""

from __future__ import annotations

import contextlib
import functools
import json
from pathlib import Path

import gymnasium as gym

from embodied_envs.datasets.records import RECORD_KEY, DatasetError, layout_content_hash
from embodied_envs.layout.sets import layout_files
from embodied_envs.registration import ENV_ID


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


# the modes ManiSkill's replay_trajectory converts from (ours too: root_frame_conversion)
CONVERTED_FROM = ("pd_joint_pos", "pd_joint_delta_pos")


def check_conversion(traj_path: str | Path, target: str | None) -> None:
    """Refuse a conversion ManiSkill's ``replay_trajectory`` cannot make, before it starts: from
    a mode other than ``CONVERTED_FROM`` (a dataset ``collect --control-mode`` recorded in it),
    or from ``pd_joint_delta_pos`` to another mode than ``pd_joint_pos``.

    Raises:
        DatasetError: names the dataset's mode, the target and the fix.
    """
    meta_path = Path(traj_path).with_suffix(".json")
    mode = json.loads(meta_path.read_text())["env_info"]["env_kwargs"].get("control_mode")
    if target is None or mode is None or target == mode:
        return
    if mode == "pd_joint_delta_pos" and target != "pd_joint_pos":
        raise DatasetError(
            f"{meta_path}: its actions are {mode} (env_info.env_kwargs.control_mode); -c {target} "
            f"converts from pd_joint_pos, and {mode} converts to pd_joint_pos only. Fix: convert "
            f"to pd_joint_pos first and {target} from that, or collect the demos in {target} "
            f"(embodied-envs collect --control-mode {target})"
        )
    if mode in CONVERTED_FROM:
        return
    raise DatasetError(
        f"{meta_path}: its actions are {mode} (env_info.env_kwargs.control_mode); -c {target} "
        f"converts from {' or '.join(CONVERTED_FROM)} only. Fix: collect the demos in "
        f"{target} (embodied-envs collect --control-mode {target}), or in pd_joint_pos and "
        "convert those"
    )


@contextlib.contextmanager
def root_frame_conversion():
    """ManiSkill's ``replay_trajectory`` takes no converter argument and looks its converters
    up as module globals (``conversion.from_pd_joint_pos``, ``from_pd_joint_pos_to_ee``): ours
    are set there for the ``with`` block only, and the originals put back after: end-effector
    actions in the robot's root frame (``ee_actions``), and joint modes for an arm with one
    controller (``joint_actions``)."""
    # ManiSkill's conversion module and ours import torch: only when a replay runs
    from mani_skill.trajectory.utils.actions import conversion

    # ours import ManiSkill's conversion module too: only when a replay runs
    from embodied_envs.datasets.ee_actions import joint_pos_to_ee
    from embodied_envs.datasets.joint_actions import joint_delta_to_pos, joint_pos_to_joint

    to_ee, to_joint = conversion.from_pd_joint_pos_to_ee, conversion.from_pd_joint_pos
    from_delta = conversion.from_pd_joint_delta_pos
    conversion.from_pd_joint_pos_to_ee = joint_pos_to_ee
    conversion.from_pd_joint_pos = functools.partial(joint_pos_to_joint, combined=to_joint)
    conversion.from_pd_joint_delta_pos = joint_delta_to_pos
    try:
        yield
    finally:
        conversion.from_pd_joint_pos_to_ee = to_ee
        conversion.from_pd_joint_pos = to_joint
        conversion.from_pd_joint_delta_pos = from_delta


def replay(options) -> None:
    """ManiSkill's ``replay_trajectory.main(options)`` on a dataset checked first (its notes
    printed), with root-frame end-effector conversions."""
    # ManiSkill's replay tool imports the simulator: only when a replay runs
    from mani_skill.trajectory import replay_trajectory

    for note in check_replayable(options.traj_path):  # a dataset that cannot replay: one line
        print(note)
    check_conversion(options.traj_path, options.target_control_mode)
    with root_frame_conversion():
        replay_trajectory.main(options)
