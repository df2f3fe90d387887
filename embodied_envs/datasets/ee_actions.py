"""Joint-target actions (``pd_joint_pos``) as end-effector actions, in the robot's root frame.

ManiSkill's end-effector controllers (``pd_ee_pose``, ``pd_ee_delta_pose``, ``pd_ee_delta_pos``)
take poses in the robot's root frame. ManiSkill 3.0.1's trajectory converter
(``mani_skill.trajectory.utils.actions.conversion.from_pd_joint_pos_to_ee``) subtracts world
positions and takes world orientations, which is the root frame only when the robot base is not
rotated; every layout here yaws the base to face the table, so its conversions drift and clip.
:func:`joint_pos_to_ee` computes the same actions in the root frame: forward kinematics of each
joint target gives the wanted end-effector pose relative to the root, and the action moves the
controller's current end-effector pose there. ``embodied-envs replay -c pd_ee_*`` uses it.

A held object follows its recorded path, not only the hand: ``pd_ee_delta_pos`` leaves the
hand's orientation to the controller's IK, which turns it (50-120 degrees over an episode), so an
object held off the hand's origin ends centimetres from where the demo put it. While both the
recorded run (``ori_env``, stepped alongside as ManiSkill's converter steps it) and the
converted one grasp one of this env's movers, the hand's target is shifted by the difference of
the mover's offset from the hand in the two runs (:func:`held_shift`).
"""

from __future__ import annotations

import numpy as np
import sapien
import torch
from mani_skill.utils import common
from mani_skill.utils.geometry.rotation_conversions import (
    matrix_to_euler_angles,
    quaternion_invert,
    quaternion_multiply,
    quaternion_to_matrix,
)

from embodied_envs.internals import ControllerState

# steps at most that a converted demo holds its last target for its task to succeed (measured:
# 1-7 on the default layout's demos that needed any)
SETTLE_STEPS = 20
# metres at most that a held mover's shift moves the hand's target: a grasp this different from
# the recorded one is not corrected (the shifts seen on a default demo's end: 5-7 mm)
MAX_SHIFT = 0.1
# a settle step keeps chasing the last target while the hand's distance to it shrinks to at
# most this part of the step before's; otherwise the arm holds where it is (a lagging arm
# closes ~18 % of its gap a step; a wrist joint at its limit leaves the hand short of the
# target, and chasing it turns the arm on at 0.4 rad/s, never static: default seed 114)
STALL = 0.95


def _mover_offsets(env, ee_name: str) -> tuple[np.ndarray, np.ndarray] | None:
    """``(m, 3)`` each mover's origin minus the end-effector link's (world frame) and ``(m,)``
    whether the arm grasps it, as the env's task state reads them (``TaskReader``); ``None``
    for an env that is not this package's (no movers)."""
    u = env.unwrapped
    if getattr(u, "task_reader", None) is None:
        return None
    state, _ = u.task_rules()
    ee = common.to_numpy(u.main_agent.robot.links_map[ee_name].pose.p[0])
    return common.to_numpy(state.origins[0]) - ee, common.to_numpy(state.grasped[0])


def held_shift(ori_env, env, ee_name: str) -> np.ndarray:
    """``(3,)`` in the robot's root frame: how far to move the converted hand's target so that a
    mover held in both runs sits where the recorded run holds it (zero when none is held in
    both, or the shift is over ``MAX_SHIFT``)."""
    ori, now = _mover_offsets(ori_env, ee_name), _mover_offsets(env, ee_name)
    if ori is None or now is None:
        return np.zeros(3)
    both = ori[1] & now[1]
    if not both.any():
        return np.zeros(3)
    k = int(np.argmax(both))
    shift = ori[0][k] - now[0][k]
    if np.linalg.norm(shift) > MAX_SHIFT:
        return np.zeros(3)
    root = env.unwrapped.main_agent.robot.pose
    rot = quaternion_to_matrix(root.q[0].cpu()).numpy()
    return rot.T @ shift


def root_pose_of_target(pin_model, qpos: np.ndarray, ee_index: int):
    """The end-effector pose relative to the robot root for joint positions ``qpos``."""
    pin_model.compute_forward_kinematics(qpos)
    return pin_model.get_link_pose(ee_index)  # sapien.Pose in the root frame


def ee_action(arm, target_p: np.ndarray, target_q: np.ndarray) -> tuple[torch.Tensor, bool]:
    """The arm action of an end-effector controller that moves toward a root-frame pose.

    Args:
        arm: the env's ``PDEEPoseController`` / ``PDEEPosController`` (root-frame config).
        target_p, target_q: the wanted pose relative to the root (wxyz quaternion), ``(3,)``
            and ``(4,)`` or one per env, ``(n, 3)`` and ``(n, 4)``.

    Returns:
        The action ``(n, d)`` and whether it had to be clipped (the target is farther than one
        step of the controller allows).
    """
    device = arm.device
    p = torch.as_tensor(target_p, dtype=torch.float32, device=device).reshape(-1, 3)
    q = torch.as_tensor(target_q, dtype=torch.float32, device=device).reshape(-1, 4)
    cfg = arm.config
    pos_only = not hasattr(cfg, "rot_lower")
    if not cfg.use_delta:  # absolute pose: position and XYZ euler angles of the root frame
        return torch.cat([p, matrix_to_euler_angles(quaternion_to_matrix(q), "XYZ")], 1), False
    current = ControllerState(arm).target_pose if cfg.use_target else arm.ee_pose_at_base
    action = (p - current.p) / torch.as_tensor(cfg.pos_upper, device=device)
    clipped = bool((action.abs() > 1).any())
    action = action.clamp(-1, 1)
    if not pos_only:  # the controller applies delta * current; its rotation scale is rot_lower
        delta = quaternion_multiply(q, quaternion_invert(current.q))
        rot = matrix_to_euler_angles(quaternion_to_matrix(delta), "XYZ") / cfg.rot_lower
        norm = torch.linalg.vector_norm(rot, dim=1, keepdim=True)
        clipped |= bool((norm > 1).any())
        action = torch.cat([action, rot / norm.clamp_min(1.0)], 1)
    return action, clipped


def joint_pos_to_ee(
    output_mode: str,
    ori_actions,
    ori_env,
    env,
    render: bool = False,
    pbar=None,
    verbose: bool = False,
    substeps: int = 4,
    settle: int = SETTLE_STEPS,
) -> dict:
    """Replay ``pd_joint_pos`` actions in ``env`` with an end-effector controller.

    The signature is ManiSkill's converter's; ``ori_env`` (the original control mode) is
    stepped alongside for the held movers' recorded path (:func:`held_shift`); a ``pd_joint_pos``
    action holds the joint targets themselves. When a target is
    farther than one controller step, up to ``substeps`` steps are taken toward it. A demo
    ends at the first step its task succeeds, with the arm still slowing down and the object
    just inside the goal; the converted arm lags a little behind it, so after the last action
    it holds the last target until the task succeeds, for at most ``settle`` steps; once the
    hand stops closing its gap to that target (``STALL``) it holds the measured pose instead.

    Returns:
        The last step's info.
    """
    controller = env.unwrapped.agent.controller
    arm = controller.controllers["arm"]
    robot = env.unwrapped.agent.robot
    pin_model = robot.create_pinocchio_model()
    arm_joints = arm.active_joint_indices.cpu().numpy()
    ori_controller = ori_env.unwrapped.agent.controller
    info: dict = {}

    def toward(target, gripper) -> bool:  # one step toward the target; whether it clipped
        nonlocal info
        arm_action, clipped = ee_action(arm, target.p, target.q)
        action = controller.from_action_dict(
            {"arm": arm_action[0], "gripper": common.to_tensor(gripper).reshape(-1)}
        )
        _, _, _, _, info = env.step(action)
        if render:
            env.render_human()
        return clipped

    if pbar is not None:
        pbar.reset(total=len(ori_actions))
    for t in range(len(ori_actions)):
        if pbar is not None:
            pbar.update()
        ori = ori_controller.to_action_dict(
            common.to_tensor(ori_actions[t], device=env.unwrapped.device)
        )
        qpos = robot.get_qpos()[0].cpu().numpy().astype(np.float64)
        qpos[arm_joints] = common.to_numpy(ori["arm"]).reshape(-1)
        target = root_pose_of_target(pin_model, qpos, arm.ee_link.index)
        goal = target.p
        target.p = goal + held_shift(ori_env, env, arm.ee_link.name)
        ori_env.step(ori_actions[t])
        for _ in range(substeps):
            if not toward(target, ori["gripper"]):
                break
    gap, hold = np.inf, False
    for _ in range(settle if len(ori_actions) else 0):
        if bool(torch.as_tensor(info["success"]).all()):
            break
        target.p = goal + held_shift(ori_env, env, arm.ee_link.name)
        now = arm.ee_pose_at_base
        hand = common.to_numpy(now.p[0])
        hold = hold or float(np.linalg.norm(target.p - hand)) > STALL * gap
        gap = float(np.linalg.norm(target.p - hand))
        if hold:  # the measured pose: a delta controller's zero, the absolute one's pose now
            toward(sapien.Pose(hand, common.to_numpy(now.q[0])), ori["gripper"])
        else:
            toward(target, ori["gripper"])
    return info
