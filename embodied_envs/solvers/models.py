"""The robot models the expert plans with, made once and shared by its episodes.

A solver is made per episode (``PickPlaceSolver``); what depends only on the env's robot is
made at the first one and kept: the mplib planners (per env object), the joints' levers (per
robot, and between runs: ``store.py``) and the limits the joint targets keep to (per agent).
Solvers of one env run one after another; each sets everything a plan reads (base pose, joint
limits, obstacle cloud, the robot's configuration) before planning.
"""

from __future__ import annotations

import dataclasses
import hashlib
import weakref
from pathlib import Path

import mplib
import numpy as np

from embodied_envs.robots import ROBOTS
from embodied_envs.solvers import follow
from embodied_envs.solvers.modes import ModeActions
from embodied_envs.solvers.motion import joint_levers, link_points
from embodied_envs.solvers.planner_urdf import planner_urdf
from embodied_envs.solvers.store import cached, result_name

# per env (the unwrapped env object), its mplib planners, one per parallel env: building one
# parses the URDF and its collision meshes (5 ms, an episode's 2%)
_PLANNERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
# per robot URDF, its joints' levers (motion.joint_levers: 0.1-0.3 s)
_LEVERS: dict[str, np.ndarray] = {}
LEVERS_BY = ("embodied_envs.solvers.motion", "embodied_envs.solvers.store")  # their code
# per agent, its follow limits (follow.follow_limits reads every controller config, which
# ManiSkill's agents build anew on each read: 2 ms an episode)
_FOLLOW: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
# per agent, its control mode's actions for the expert's targets (solvers/modes.py: reads every
# controller config, and a pinocchio model for the end-effector modes)
_MODES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def planners(base) -> list[mplib.Planner]:
    """``base``'s (an unwrapped env's) mplib planners, built at its first solver, for the link
    its robot's hand entry names."""
    if base not in _PLANNERS:
        robot = base.agent.robot
        _PLANNERS[base] = [
            mplib.Planner(
                urdf=(urdf := planner_urdf(base.agent.urdf_path)),
                srdf=urdf.replace(".urdf", ".srdf"),
                user_link_names=[link.get_name() for link in robot.get_links()],
                user_joint_names=[joint.get_name() for joint in robot.get_active_joints()],
                move_group=ROBOTS[base.agent.uid].hand.link,
            )
            for _ in range(base.num_envs)
        ]
    return _PLANNERS[base]


def levers(base) -> np.ndarray:
    """The levers of ``base``'s (an unwrapped env's) robot's arm joints, measured once per
    robot and kept between runs (``store.py``: named by the planner's URDF and SRDF, the
    links' collision vertices and the code)."""
    if base.agent.urdf_path not in _LEVERS:
        robot, planner = base.agent.robot, planners(base)[0]
        names, points = link_points(robot)
        shapes = hashlib.sha256(repr(names).encode())
        for p in points:
            shapes.update(np.ascontiguousarray(p).tobytes())
        urdf = planner_urdf(base.agent.urdf_path)
        srdf = Path(urdf).with_suffix(".srdf")
        name = result_name("levers", (urdf, srdf if srdf.is_file() else None),
                           (shapes.hexdigest(), planner.move_group), LEVERS_BY)  # fmt: skip
        _LEVERS[base.agent.urdf_path] = cached(
            name, lambda: joint_levers(robot, planner), np.ndarray
        )
    return _LEVERS[base.agent.urdf_path]


def mode_actions(base, arm_dof: int) -> ModeActions:
    """``base``'s (an unwrapped env's) :class:`~embodied_envs.solvers.modes.ModeActions` for
    its control mode, made at its first solver in that mode with that agent (a
    reconfiguration makes a new agent)."""
    per = _MODES.setdefault(base.agent, {})
    key = (base.control_mode, arm_dof)
    if key not in per:
        per[key] = ModeActions(base, arm_dof)
    return per[key]


def follow_limits(agent, control_freq: float, arm_dof: int) -> follow.FollowLimits:
    """``follow.follow_limits(agent, control_freq, arm_dof)``, once per agent (its arrays
    read-only: shared by every solver)."""
    per = _FOLLOW.setdefault(agent, {})
    if (control_freq, arm_dof) not in per:
        limits = follow.follow_limits(agent, control_freq, arm_dof)
        for f in dataclasses.fields(limits):
            getattr(limits, f.name).flags.writeable = False
        per[control_freq, arm_dof] = limits
    return per[control_freq, arm_dof]
