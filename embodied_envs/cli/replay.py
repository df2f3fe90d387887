"""``embodied-envs replay``: ManiSkill's ``replay_trajectory`` with this package's env registered.

Every option is ManiSkill's (``--traj-path``, ``-o``, ``-c``, ``--use-env-states``,
``--save-traj``, ``--save-video``, ``-n``, ...). Observations with ``hybrid_obs`` are composited
over the splat whatever ``--render-mode`` says: ``hybrid_obs`` is recorded in ``env_kwargs``.
Conversions from ``pd_joint_pos`` to end-effector control modes (``-c pd_ee_delta_pose`` ...)
use :func:`embodied_envs.datasets.ee_actions.joint_pos_to_ee`, which works in the robot's root
frame (ManiSkill's own converter assumes an unrotated robot base): see
:func:`embodied_envs.datasets.replay.replay`.
"""

from __future__ import annotations

import argparse

from embodied_envs.datasets.replay import replay


def add_parser(sub) -> None:
    p = sub.add_parser(
        "replay",
        help="ManiSkill's replay_trajectory (obs / control-mode conversion) for these datasets",
        add_help=False,
    )
    p.add_argument("options", nargs=argparse.REMAINDER, help="replay_trajectory's options")
    p.set_defaults(func=cmd_replay)


def cmd_replay(args) -> int:
    # ManiSkill's replay tool imports the simulator: only when the command runs
    from mani_skill.trajectory import replay_trajectory

    replay(replay_trajectory.parse_args(args.options or ["--help"]))
    return 0
