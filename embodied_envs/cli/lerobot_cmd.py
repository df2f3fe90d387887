"""``embodied-envs lerobot``: ManiSkill's LeRobot converter with the dataset's own task, control
rate and robot.

ManiSkill's ``convert_to_lerobot`` names the task after the env id, one for every episode, and
writes 30 fps unless told otherwise; this command tells it the env's control rate and the
robot's name, then gives each episode its own instruction (``trajectory.json``, or the one its
seed draws from the dataset's layout set), so a dataset over a layout set keeps its tasks.
"""

from __future__ import annotations

from pathlib import Path

from embodied_envs.datasets import (
    check_replayable,
    lerobot_settings,
    relabel_lerobot_tasks,
)


def add_parser(sub) -> None:
    p = sub.add_parser(
        "lerobot",
        help="a LeRobot dataset from a trajectory with observations (replay -o rgb first)",
        description=(
            "Runs ManiSkill's convert_to_lerobot (the lerobot extra) with the task from the "
            "episodes' instruction, fps from the env's control rate and the robot's name. "
            "Give it a trajectory with observations, e.g. the .rgb. file that "
            "`embodied-envs replay -o rgb --save-traj` writes."
        ),
    )
    p.add_argument("--traj-path", type=Path, required=True, help="trajectory .h5 (with obs)")
    p.add_argument("--output-dir", type=Path, required=True)
    p.add_argument("--image-size", default="640x480", help="WIDTHxHEIGHT or one side")
    p.add_argument("--chunks-size", type=int, default=1000, help="episodes per chunk")
    p.set_defaults(func=cmd_lerobot)


def cmd_lerobot(args) -> int:
    # ManiSkill's converter imports pandas and pyarrow: only when the command runs
    from mani_skill.trajectory import convert_to_lerobot

    for note in check_replayable(args.traj_path):
        print(note)
    settings = lerobot_settings(args.traj_path)
    code = convert_to_lerobot.main(
        convert_to_lerobot.Args(
            traj_path=str(args.traj_path),
            output_dir=str(args.output_dir),
            image_size=args.image_size,
            chunks_size=args.chunks_size,
            **settings,
        )
    )
    tasks = relabel_lerobot_tasks(args.traj_path, args.output_dir)  # one per episode
    print(f"{len(tasks)} task(s): {tasks[:3]}")
    return code
