"""Joint-target actions (``pd_joint_pos``) as another joint controller's: for an arm with one
controller, and ``pd_joint_vel`` and ``pd_joint_delta_pos`` for any arm; and ``pd_joint_delta_pos``
actions as ``pd_joint_pos`` (:func:`joint_delta_to_pos`).

ManiSkill 3.0.1's converter (``mani_skill.trajectory.utils.actions.conversion
.from_pd_joint_pos``) reads an agent whose controller is combined from an ``arm`` and a
``gripper`` (``to_action_dict``); the SO-100's and the Koch's one controller drives every joint,
jaw included, and the converter stops with ``AttributeError``. :func:`joint_pos_to_joint` converts
for such an arm as ManiSkill's converter does for a combined one, on the whole controller (the
SO-100 and the Koch have no ``pd_joint_vel``), and hands combined controllers to ManiSkill's.
``embodied-envs replay -c`` uses it.

``pd_joint_vel`` follows the recorded run's measured joints, not its targets
(:func:`follow_recorded`). The expert's targets lead the arm by the PD drive's lag
(``solvers/follow.py``: 0.1 s of the joint's speed, 0.08 rad at its 0.8 rad/s), and at a move's
end they overshoot its last waypoint and come back. ManiSkill's converter asks the velocity
controller to reach each target in one step, so its arm runs up to 0.07 rad ahead of the
recorded one along that overshoot, clipped at 1 rad/s, and a held banana slips in the hand: on
round_table ``--fixed-hand`` 7 of 50 demos end with it 3-4.5 cm lower in the hand than recorded
(outside the goal's 2.5 cm) or with the arm still moving (0.2 rad/s).

``pd_joint_delta_pos`` asks the recorded targets, as ManiSkill's converter, and both modes then
hold the last action until the task succeeds (``JOINT_SETTLE_STEPS``): on place_bowl a banana let
go in the bowl still rocks at the recorded run's last step, and replayed it may turn faster than
``REST_ANG`` there (2 of 50 demos lost without the hold, the arm on the recorded joints).
"""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.utils import common, gym_utils

from embodied_envs.internals import ControllerState

# what each mode's action is relative to: the joints now, or the controller's last target
RELATIVE_TO = {"pd_joint_delta_pos": "qpos", "pd_joint_target_delta_pos": "target"}
# control steps at most toward one recorded target (ManiSkill's converter takes 2)
TRIES = 2
# modes converted by :func:`follow_recorded`: ``pd_joint_vel`` follows the recorded run's joints,
# the delta modes its targets (as ManiSkill's converter), all then settle
FOLLOWED = ("pd_joint_vel", *RELATIVE_TO)
# control steps at most that both runs hold the last action, until the task succeeds: a banana
# let go in place_bowl's bowl rocks past REST_ANG for up to 29 steps (measured, 2026-11-25)
JOINT_SETTLE_STEPS = 50


def mode_action(controller, target: np.ndarray, mode: str) -> np.ndarray:
    """The normalised action of ``controller`` (in ``mode``) that moves every joint's target to
    ``target`` (``(d,)`` for the first env, or ``(n, d)`` one per env), unclipped, as
    ManiSkill's ``qpos_to_pd_joint_*`` compute it (its bounds may be lists here, one per joint,
    which ManiSkill's functions do not take)."""
    cfg = controller.config
    if RELATIVE_TO[mode] == "target":
        now = ControllerState(controller).target_qpos
    else:
        now = controller.qpos
    now = now.cpu().numpy()
    delta = target - (now[0] if np.ndim(target) == 1 else now)
    low, high = np.asarray(cfg.lower, np.float32), np.asarray(cfg.upper, np.float32)
    return gym_utils.inv_scale_action(delta, low, high)


def one_controller(env) -> bool:
    """Whether ``env``'s agent has one controller for every joint (no ``to_action_dict``)."""
    return not hasattr(env.unwrapped.agent.controller, "to_action_dict")


def joint_pos_to_joint(
    output_mode: str,
    ori_actions,
    ori_env,
    env,
    render: bool = False,
    pbar=None,
    verbose: bool = False,
    combined=None,
) -> dict:
    """Replay ``pd_joint_pos`` actions in ``env``'s joint controller ``output_mode``.

    The signature is ManiSkill's ``from_pd_joint_pos``; ``combined`` is that function. The
    joint modes (``FOLLOWED``) are converted by :func:`follow_recorded`, for every arm (one
    controller, or an ``arm`` of combined ones); ``combined`` converts the rest (the
    end-effector modes) of an agent with combined controllers.

    Returns:
        The last step's info.
    """
    if output_mode in FOLLOWED:
        return follow_recorded(output_mode, ori_actions, ori_env, env, render, pbar)
    if not one_controller(env) or "ee" in output_mode:
        return combined(output_mode, ori_actions, ori_env, env, render, pbar, verbose)
    raise NotImplementedError(
        f"converting pd_joint_pos to {output_mode} for a one-controller arm: one of "
        f"{sorted(RELATIVE_TO)}"
    )


def _arm(env):
    """``env``'s arm controller: the ``arm`` of a combined controller, or the one controller."""
    controller = env.unwrapped.agent.controller
    return controller.controllers["arm"] if hasattr(controller, "to_action_dict") else controller


def velocity_action(arm, qpos: np.ndarray) -> np.ndarray:
    """The normalised ``pd_joint_vel`` action of ``arm`` that moves its joints to ``qpos`` in
    one control step, unclipped (ManiSkill's ``qpos_to_pd_joint_vel`` with per-joint bounds)."""
    cfg = arm.config
    qvel = (qpos - arm.qpos.cpu().numpy()[0]) * ControllerState(arm).control_freq
    low, high = np.asarray(cfg.lower, np.float32), np.asarray(cfg.upper, np.float32)
    return gym_utils.inv_scale_action(qvel, low, high)


def follow_recorded(
    output_mode: str,
    ori_actions,
    ori_env,
    env,
    render: bool = False,
    pbar=None,
    settle: int = JOINT_SETTLE_STEPS,
) -> dict:
    """Replay ``pd_joint_pos`` actions in ``env``'s ``pd_joint_vel`` or ``pd_joint_delta_pos``:
    each step, the action that takes the arm to where the recorded run's arm (``ori_env``,
    stepped with the recorded action) is now (``pd_joint_vel``), or to the recorded target
    (``pd_joint_delta_pos``, as ManiSkill's converter), in up to ``TRIES`` steps where it is
    farther than one step allows; the gripper gets the recorded action. After the last action
    both runs hold it, for at most ``settle`` steps, until the task succeeds: an object let go
    may still rock at the recorded run's last step (a banana in place_bowl's bowl), faster than
    ``REST_ANG`` in the converted run.

    Returns:
        The last step's info.
    """
    if output_mode not in FOLLOWED:
        raise NotImplementedError(f"following the recorded joints in {output_mode}")
    controller, arm, ori_arm = env.unwrapped.agent.controller, _arm(env), _arm(ori_env)
    ori_controller = ori_env.unwrapped.agent.controller
    combined = hasattr(controller, "to_action_dict")
    device = env.unwrapped.device
    info: dict = {}

    def follow(action) -> None:
        nonlocal info
        ori_env.step(action)
        parts = ori_controller.to_action_dict(action) if combined else {"arm": action}
        rest = {k: v for k, v in parts.items() if k != "arm"}
        target = np.asarray(parts["arm"], np.float32)
        goal = ori_arm.qpos.cpu().numpy()[0]
        for _ in range(TRIES):
            if output_mode == "pd_joint_vel":
                arm_action = velocity_action(arm, goal)
            else:
                arm_action = mode_action(arm, target, output_mode)
            clipped = np.max(np.abs(arm_action)) > 1 + 1e-3
            parts = common.to_tensor({**rest, "arm": np.clip(arm_action, -1, 1)}, device=device)
            _, _, _, _, info = env.step(
                controller.from_action_dict(parts) if combined else parts["arm"]
            )
            if render:
                env.render_human()
            if not clipped:
                break

    if pbar is not None:
        pbar.reset(total=len(ori_actions))
    for t in range(len(ori_actions)):
        if pbar is not None:
            pbar.update()
        follow(ori_actions[t])
    for _ in range(settle if len(ori_actions) else 0):
        if bool(torch.as_tensor(info["success"]).all()):
            break
        follow(ori_actions[-1])
    return info


def joint_delta_to_pos(
    output_mode: str,
    ori_actions,
    ori_env,
    env,
    render: bool = False,
    pbar=None,
    verbose: bool = False,
) -> dict:
    """Replay ``pd_joint_delta_pos`` actions in ``env``'s ``pd_joint_pos``: each step's targets
    are what the delta controller sets, the arm's joints now plus the scaled, clipped delta
    (ManiSkill's ``PDJointPosController`` with ``use_delta``), read from ``env`` itself, so the
    converted run drives the same targets as the recorded one; the gripper gets the recorded
    action. The signature is ManiSkill's ``from_pd_joint_delta_pos``, which ManiSkill 3.0.1
    cannot run on the CPU (it hands a numpy action to ``torch.clip``); for an arm with one
    controller (the SO-100, the Koch) every joint is the arm.

    Returns:
        The last step's info.
    """
    if output_mode != "pd_joint_pos":
        raise NotImplementedError(f"converting pd_joint_delta_pos to {output_mode}")
    controller, arm = env.unwrapped.agent.controller, _arm(env)
    ori_controller = ori_env.unwrapped.agent.controller
    combined = hasattr(controller, "to_action_dict")
    cfg = _arm(ori_env).config
    low, high = (torch.as_tensor(np.asarray(b, np.float32)) for b in (cfg.lower, cfg.upper))
    device = env.unwrapped.device
    info: dict = {}
    if pbar is not None:
        pbar.reset(total=len(ori_actions))
    for action in ori_actions:
        if pbar is not None:
            pbar.update()
        parts = ori_controller.to_action_dict(action) if combined else {"arm": action}
        delta = gym_utils.clip_and_scale_action(torch.as_tensor(parts["arm"]), low, high)
        parts = common.to_tensor({**parts, "arm": arm.qpos.cpu()[0] + delta}, device=device)
        step = controller.from_action_dict(parts) if combined else parts["arm"]
        _, _, _, _, info = env.step(step)
        if render:
            env.render_human()
    return info
