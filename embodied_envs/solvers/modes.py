"""The expert's joint targets as actions of the env's control mode (``collect --control-mode``).

The expert plans joint paths and commands joint targets each step (the arm's targets and the
hand's ``pd_joint_pos`` action: ``ArmDriver._execute``). In any other mode :class:`ModeActions`
turns each step's targets into that mode's action from the state the env is in at that step, so
a dataset records the actions the env ran, graded on the run they made: nothing is lost to a
conversion afterwards.

- ``pd_joint_delta_pos``: the targets minus the joints now (the controller adds its action to
  them): the drive targets of ``pd_joint_pos`` itself, while within the controller's 0.1 rad
  (``solvers/follow.py`` keeps the expert's targets there).
- ``pd_joint_target_delta_pos``: the targets minus the controller's last targets.
- ``pd_joint_vel``: the velocity whose drive force is ``pd_joint_pos``'s at the step's start: a
  position drive pushes with ``k (target - q) - d qd``, a velocity drive with ``d_v (v - qd)``,
  so ``v = k / d_v (target - q)`` (the same arm damping: the same force).
- the end-effector modes (``pd_ee_delta_pose``, ``pd_ee_delta_pos``, ``pd_ee_pose``): the
  hand's pose the targets give (forward kinematics, the robot's root frame) as the controller's
  action (``datasets/ee_actions.ee_action``); the arm has arrived when the hand has
  (:meth:`ModeActions.arrived`). ``pd_ee_delta_pos`` keeps the hand's orientation (ManiSkill's
  IK solves for the orientation it has): the expert then plans on from its own joint targets
  (``ArmDriver.plans_from_targets``), and the hand takes the planned positions turned as it
  started.

The hand's action passes as it is where the mode's gripper controller is ``pd_joint_pos``'s (the
Panda's in every mode); on an arm with one controller for every joint (the SO-100, the Koch) the
jaw's target is turned into the mode's action with the arm's.
"""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils import gym_utils

from embodied_envs.datasets.ee_actions import ee_action, root_pose_of_target
from embodied_envs.datasets.joint_actions import RELATIVE_TO, mode_action
from embodied_envs.internals import controller_configs
from embodied_envs.robots import EXPERT_MODES
from embodied_envs.solvers.follow import (
    RECORDED_MODE,
    _per_joint,
    action_bound,
    arm_config,
    drive_lag,
)

JOINT_VEL = "pd_joint_vel"
EE_MODES = tuple(m for m in EXPERT_MODES if m.startswith("pd_ee"))


# m: an end-effector mode's hand this close to where the path's last targets put it has arrived
# (the joint modes: ``SolverConfig.settle_tolerance`` rad on every joint; 0.01 rad on the
# Panda's shoulder moves its hand about 8 mm); rad, the same for its orientation (pose modes)
EE_ARRIVED = 0.005


# control steps more at most toward the same targets while the mode's action had to be
# clipped (a jump one step of the controller cannot make: the SO-100's jaw closing at once)
CATCH_UP = 4
# each while a clipped joint still closes on its target by this much of the action's bound a
# step (a free joint of the SO-100 closes 0.18 of it): a joint a load holds off its target
# (the SO-100's wrist while its jaw squeezes, 0.1-0.2 rad) is not waited for, which made each
# step of its lift five in pd_joint_delta_pos
CATCH_UP_GAIN = 0.05


class ModeError(ValueError):
    """A control mode the expert cannot drive (names the modes it can)."""


def drivable_modes(agent) -> list[str]:
    """The robot's control modes the expert records natively."""
    return [m for m in EXPERT_MODES if m in controller_configs(agent)]


def target_bounds(agent, configs: dict, arm_dof: int) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` of the arm's ``pd_joint_pos`` targets: its config's bounds, or the
    joints' limits where it has none (ManiSkill's action space in that mode). ``configs``:
    ``controller_configs(agent)`` (ManiSkill builds them anew on each read)."""
    config = arm_config(configs, RECORDED_MODE, arm_dof)
    if config.lower is not None:
        return _per_joint(config.lower, arm_dof), _per_joint(config.upper, arm_dof)
    names = [j.name for j in agent.robot.get_active_joints()]
    index = [names.index(n) for n in config.joint_names[:arm_dof]]
    limits = agent.robot.get_qlimits()[0].cpu().numpy().astype(np.float64)[index]
    return limits[:, 0], limits[:, 1]


class ModeActions:
    """Turns the expert's ``(n, arm_dof + 1)`` joint-target actions into the env's control
    mode's ``(n, d)`` actions, one step at a time (every env at once)."""

    def __init__(self, base, arm_dof: int):
        agent, mode = base.agent, base.control_mode
        self.mode, self.arm_dof = mode, arm_dof
        configs = controller_configs(agent)
        self.bounds = target_bounds(agent, configs, arm_dof)  # of the expert's joint targets
        if mode not in EXPERT_MODES:
            raise ModeError(
                f"control_mode={mode!r}: the expert records {drivable_modes(agent)} for "
                f"{type(agent).__name__}. Fix: collect in one of them, or record pd_joint_pos "
                "and convert (embodied-envs replay -c)"
            )
        controller = agent.controller
        self.combined = hasattr(controller, "to_action_dict")
        self.controller = controller
        self.arm = controller.controllers["arm"] if self.combined else controller
        if self.combined and mode != RECORDED_MODE:
            ours, theirs = configs[RECORDED_MODE]["gripper"], configs[mode]["gripper"]
            if ours != theirs:
                raise ModeError(
                    f"control_mode={mode!r}: {type(agent).__name__}'s gripper controller "
                    "differs from its pd_joint_pos one, whose actions the expert gives. Fix: "
                    "record pd_joint_pos and convert (embodied-envs replay -c)"
                )
        self.gain = None
        if mode == JOINT_VEL:  # k / d_v per joint of the velocity controller
            pos, vel = configs[RECORDED_MODE], configs[mode]
            pos, vel = (pos["arm"], vel["arm"]) if self.combined else (pos, vel)
            dof = len(vel.joint_names)
            self.gain = _per_joint(pos.stiffness, dof) / _per_joint(vel.damping, dof)
        self.lead_scale = self.lead_bound = None  # per joint of one controller, delta modes
        if not self.combined and mode in RELATIVE_TO:
            pos, own = configs[RECORDED_MODE], configs[mode]
            dof = len(own.joint_names)
            self.lead_scale = drive_lag(own, dof) / drive_lag(pos, dof)
            self.lead_bound = action_bound(own, dof)
        self.robot = agent.robot
        self.clipped = False  # whether the last action had to be clipped, in any env
        self.excess = None  # |its action| per env and joint before clipping (joint modes)
        if mode in EE_MODES:
            self.model = agent.robot.create_pinocchio_model()
            self.arm_joints = self.arm.active_joint_indices.cpu().numpy()

    @property
    def joint_targets(self) -> bool:
        """Whether the mode's controller drives the arm's joints to targets (not the hand)."""
        return self.mode not in EE_MODES

    @property
    def holds_weakly(self) -> bool:
        """Whether the mode's arm holds its joints with at most its stiffness times the
        action's bound (its targets are the joints now plus the action: ``pd_joint_delta_pos``,
        50 N m on the SO-100's): a block wedged between its jaws and the table, pressed harder
        each step, pushed the arm off (SO-100 seed 7: 17 N on the table at the grasp, 110 N six
        steps later, the wrist 2.6 rad off)."""
        return self.joint_targets and RELATIVE_TO.get(self.mode) == "qpos"

    @property
    def keeps_orientation(self) -> bool:
        """Whether the mode moves the hand without turning it (``pd_ee_*_pos``)."""
        return self.mode in EE_MODES and not hasattr(self.arm.config, "rot_lower") and (
            self.arm.config.use_delta
        )

    def lead(self, joint: int, lead: float) -> float:
        """How far (rad) the target of ``joint`` (an index of the robot's active joints) leads
        it so that the joint moves in this mode as a target ``lead`` ahead moves it in
        ``pd_joint_pos``: a position drive moves a joint at ``stiffness / damping`` times its
        target's lead, so the lead is scaled by the mode's drive lag (damping / stiffness)
        over ``pd_joint_pos``'s, to at most the mode's per-step bound. The same lead where the
        hand's action passes as it is, and for an arm whose modes share their gains (the
        SO-100); the Koch's jaw lags 0.175 s in its delta modes and 0.01 s in pd_joint_pos:
        a gentle close (``solvers/jaws.py``) leads it by 0.05 rad, not 0.02."""
        if self.lead_scale is None:
            return lead
        return float(min(lead * self.lead_scale[joint], self.lead_bound[joint]))

    def arrived(self, qpos: np.ndarray, ends: np.ndarray, tolerance: float) -> bool:
        """Whether every env's arm, at joints ``qpos`` (the solver's read), is where the joint
        targets ``ends`` ``(n, arm_dof)`` put it:
        each joint within ``tolerance`` rad; in an end-effector mode, the hand within
        ``EE_ARRIVED`` of their hand pose (its position only, where the mode keeps the hand's
        orientation as it is)."""
        if self.joint_targets:
            return bool(np.abs(qpos[:, : self.arm_dof] - ends).max() < tolerance)
        p, q = self._hand(qpos, ends)
        now = self.arm.ee_pose_at_base
        far = np.linalg.norm(p - now.p.cpu().numpy(), axis=1).max() > EE_ARRIVED
        if hasattr(self.arm.config, "rot_lower"):  # the pose modes turn the hand too
            dot = np.abs(np.sum(q * now.q.cpu().numpy(), axis=1)).clip(max=1.0)
            far |= bool((2 * np.arccos(dot)).max() > EE_ARRIVED)
        return not far

    def gaining(self, excess: np.ndarray | None) -> bool:
        """Whether the last action, against ``excess`` (``self.excess`` one step before, for
        the same targets), brings a joint then clipped ``CATCH_UP_GAIN`` nearer its target
        (always where the mode gives none: the end-effector modes)."""
        if excess is None or self.excess is None:
            return True
        was = excess > 1 + 1e-6
        return bool(((excess - self.excess) > CATCH_UP_GAIN)[was].any())

    def __call__(self, action: np.ndarray) -> np.ndarray:
        """The mode's actions; ``clipped`` says whether one had to be clipped."""
        if self.mode == RECORDED_MODE:
            return action
        n = self.arm_dof
        if not self.combined:  # one controller: every joint's target, the jaw's last
            return self._joint(self.controller, action.astype(np.float64))
        targets = action[:, :n].astype(np.float64)
        arm = self._ee(targets) if self.mode in EE_MODES else self._joint(self.arm, targets)
        return np.concatenate([arm, action[:, n:]], axis=1).astype(np.float32)

    def _joint(self, controller, targets: np.ndarray) -> np.ndarray:
        if self.mode == JOINT_VEL:
            cfg = controller.config
            qvel = self.gain * (targets - controller.qpos.cpu().numpy())
            low, high = np.asarray(cfg.lower, np.float32), np.asarray(cfg.upper, np.float32)
            out = gym_utils.inv_scale_action(qvel, low, high)
        else:
            out = mode_action(controller, targets, self.mode)
        self.excess = np.abs(out)
        self.clipped = bool(self.excess.max() > 1 + 1e-6)
        return np.clip(out, -1, 1).astype(np.float32)

    def _hand(self, qpos: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per env, the hand's pose (root frame) with the arm's joints at ``targets``."""
        qpos = qpos.copy()
        qpos[:, self.arm_joints] = targets
        poses = [root_pose_of_target(self.model, q, self.arm.ee_link.index) for q in qpos]
        return np.array([pose.p for pose in poses]), np.array([pose.q for pose in poses])

    def _ee(self, targets: np.ndarray) -> np.ndarray:
        qpos = self.robot.get_qpos().cpu().numpy().astype(np.float64)
        out, self.clipped = ee_action(self.arm, *self._hand(qpos, targets))
        return torch.as_tensor(out).cpu().numpy()
