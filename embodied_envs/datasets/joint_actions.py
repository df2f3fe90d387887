"""Joint-target actions (``pd_joint_pos``) as another joint controller's, for an arm with one
controller.

ManiSkill 3.0.1's converter (``mani_skill.trajectory.utils.actions.conversion
.from_pd_joint_pos``) reads an agent whose controller is combined from an ``arm`` and a
``gripper`` (``to_action_dict``); the SO-100's and the Koch's one controller drives every joint,
jaw included, and the converter stops with ``AttributeError``. :func:`joint_pos_to_joint` converts
for such an arm as ManiSkill's converter does for a combined one, on the whole controller (the
SO-100 and the Koch have no ``pd_joint_vel``), and hands combined controllers to ManiSkill's.
``embodied-envs replay -c`` uses it.
"""

from __future__ import annotations

import numpy as np
from mani_skill.utils import common, gym_utils

# what each mode's action is relative to: the joints now, or the controller's last target
RELATIVE_TO = {"pd_joint_delta_pos": "qpos", "pd_joint_target_delta_pos": "target"}
# control steps at most toward one recorded target (ManiSkill's converter takes 2)
TRIES = 2


def mode_action(controller, target: np.ndarray, mode: str) -> np.ndarray:
    """The normalised action of ``controller`` (in ``mode``) that moves every joint's target to
    ``target``, unclipped, as ManiSkill's ``qpos_to_pd_joint_*`` compute it (its bounds may be
    lists here, one per joint, which ManiSkill's functions do not take)."""
    cfg = controller.config
    now = controller._target_qpos if RELATIVE_TO[mode] == "target" else controller.qpos
    delta = target - now.cpu().numpy()[0]
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

    The signature is ManiSkill's ``from_pd_joint_pos``; ``combined`` is that function, which
    converts for an agent with combined controllers (and to end-effector modes). For one
    controller, each recorded target is turned into the mode's action for every joint; a
    target farther than one step allows takes up to ``TRIES`` steps. ``ori_env`` steps
    alongside, as in ManiSkill's converter.

    Returns:
        The last step's info.
    """
    if not one_controller(env) or "ee" in output_mode:
        return combined(output_mode, ori_actions, ori_env, env, render, pbar, verbose)
    if output_mode not in RELATIVE_TO:
        raise NotImplementedError(
            f"converting pd_joint_pos to {output_mode} for a one-controller arm: one of "
            f"{sorted(RELATIVE_TO)}"
        )
    controller = env.unwrapped.agent.controller
    info: dict = {}
    if pbar is not None:
        pbar.reset(total=len(ori_actions))
    for t in range(len(ori_actions)):
        if pbar is not None:
            pbar.update()
        target = np.asarray(ori_actions[t], dtype=np.float32)
        ori_env.step(target)
        for _ in range(TRIES):
            action = mode_action(controller, target, output_mode)
            clipped = np.max(np.abs(action)) > 1 + 1e-3
            action = common.to_tensor(np.clip(action, -1, 1), device=env.unwrapped.device)
            _, _, _, _, info = env.step(action)
            if render:
                env.render_human()
            if not clipped:
                break
    return info
