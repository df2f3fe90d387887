"""What the expert's joint targets may do so that every arm controller can replay them.

The expert records ``pd_joint_pos`` actions (joint targets). ManiSkill's converter
(``mani_skill.trajectory.utils.actions.conversion``) turns each target into a
``pd_joint_delta_pos`` action ``(target - qpos) / upper`` and a ``pd_joint_vel`` action
``(target - qpos) * control_freq / upper``, clipped to [-1, 1]; the end-effector modes move the
hand to the target's pose within their own per-step limits (0.1 m and 0.1 rad for the Panda, a
joint target moving at most ``step`` rad a step moves the hand far less). A clipped action
leaves the replayed arm behind the recorded one, and the demo fails to convert. So the expert's
targets keep, with ``MARGIN`` to spare, to:

- ``step``: the most a joint target changes between two control steps, what ``pd_joint_vel``
  can follow in one step (its velocity limit over the control rate) and ``pd_joint_delta_pos``
  too (its delta limit);
- ``lead``: the most a target leads the measured joint position, ``pd_joint_delta_pos``'s limit;
- ``speed``: the joint speed plans are timed at, ``SPEED_SHARE`` of the same limits: a PD
  joint drive lags a target moving at ``v`` by ``damping / stiffness * v``, so ``speed`` keeps
  that lag within ``lead`` and the target's steps within ``step``, with room for the target to
  get ahead of its path by the lag (``PickPlaceSolver._commands``) and for the arm's inertia.

Every number is read from the robot's controller configs (``agent._controller_configs``), none
is written here but ``MARGIN`` and ``SPEED_SHARE``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from embodied_envs.internals import controller_configs

MARGIN = 0.9  # part of each controller's limit the expert's targets use at most
SPEED_SHARE = 0.8  # part of those limits the plans' joint speeds use: below MARGIN, so that a
# target can get ahead of its path by the lag while moving with it
JOINT_MODES = ("pd_joint_delta_pos", "pd_joint_vel")  # whose limits bound the targets
RECORDED_MODE = "pd_joint_pos"  # what the expert commands (its PD gains give the lag)


@dataclass(frozen=True)
class FollowLimits:
    """Per arm joint (rad, rad/s): see the module docstring."""

    step: np.ndarray  # rad, a joint target's change between two control steps
    lead: np.ndarray  # rad, a joint target ahead of the measured joint position
    speed: np.ndarray  # rad/s, the joint speed plans are timed at (at most)
    lag: np.ndarray  # s, how far a pd_joint_pos joint lags a moving target (damping/stiffness)


def arm_config(configs: dict, mode: str, arm_dof: int):
    """The controller config of ``mode`` that drives the arm's ``arm_dof`` joints (its
    ``"arm"`` entry, or the one config that drives every joint, as the SO-100's and Koch's do),
    or None when the robot has no such mode."""
    config = configs.get(mode)
    if isinstance(config, dict):
        config = config.get("arm")
    if config is None or len(config.joint_names) < arm_dof:
        return None
    return config


def _per_joint(values, dof: int) -> np.ndarray:
    """A config's number or per-joint list (over all its joints) for the first ``dof``."""
    values = np.asarray(values, dtype=np.float64)
    return np.broadcast_to(values, (dof,)) if values.ndim == 0 else values[:dof]


def action_bound(config, dof: int) -> np.ndarray:
    """Per joint of ``config`` (the first ``dof``), the most its action asks either way: a delta
    mode's rad per step, a velocity mode's rad/s (the smaller of its lower and upper bound)."""
    return np.minimum(np.abs(_per_joint(config.lower, dof)), _per_joint(config.upper, dof))


def drive_lag(config, dof: int) -> np.ndarray:
    """Per joint of ``config`` (the first ``dof``), how far (s) its PD drive lags a moving
    target: damping / stiffness (a drive moves its joint at stiffness / damping times the
    target's lead)."""
    return _per_joint(config.damping, dof) / _per_joint(config.stiffness, dof)


def follow_limits(agent, control_freq: float, arm_dof: int, margin: float = MARGIN) -> FollowLimits:
    """The limits for the first ``arm_dof`` joints of ``agent`` (a ManiSkill agent whose
    ``pd_joint_pos`` and ``pd_joint_delta_pos`` configs drive its arm, and ``pd_joint_vel``
    where it has one: the SO-100 and Koch have none)."""
    configs = controller_configs(agent)
    pos = arm_config(configs, RECORDED_MODE, arm_dof)
    delta_config = arm_config(configs, JOINT_MODES[0], arm_dof)
    if pos is None or delta_config is None:
        raise ValueError(
            f"{type(agent).__name__} has no arm controller in {RECORDED_MODE} or "
            f"{JOINT_MODES[0]}: the expert's targets are bounded by those controllers' limits"
        )
    delta = action_bound(delta_config, arm_dof)  # rad per step
    vel_config = arm_config(configs, JOINT_MODES[1], arm_dof)
    vel = np.full(arm_dof, np.inf)  # rad/s
    if vel_config is not None:
        vel = action_bound(vel_config, arm_dof)
    lag = drive_lag(pos, arm_dof)  # s
    step = margin * np.minimum(vel / control_freq, delta)
    lead = margin * delta
    speed = SPEED_SHARE * np.minimum(np.minimum(vel, delta * control_freq), delta / lag)
    return FollowLimits(step=step, lead=lead, speed=speed, lag=lag)


def shortened(move: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """``move`` (..., dof) scaled down, as a whole, until every joint's part is within
    ``bound``: the same direction (a target on a straight joint line stays on it)."""
    need = np.abs(move) / bound
    return move / np.maximum(np.maximum.reduce(need, axis=-1, keepdims=True), 1.0)


def rate_limited(targets: np.ndarray, start: np.ndarray, step: np.ndarray) -> np.ndarray:
    """``targets`` (T, dof) followed from ``start``, each change :func:`shortened` to
    ``step``; where the sequence has not reached the last target by then, steps toward it are
    appended until it has."""
    out, prev = [], np.asarray(start, dtype=np.float64)
    for target in targets:
        prev = prev + shortened(target - prev, step)
        out.append(prev)
    end = targets[-1]
    while not np.allclose(prev, end, rtol=0.0, atol=1e-9):
        prev = prev + shortened(end - prev, step)
        out.append(prev)
    return np.asarray(out)
