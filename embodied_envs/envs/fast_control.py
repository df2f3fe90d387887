"""ManiSkill's ``BaseAgent.set_action`` on the CPU simulation, in numpy: the same result, faster.

On the CPU simulation (one env per process) ManiSkill's controllers compute on one-row torch
tensors and write each joint's drive target through ``ArticulationJoint``'s setter, which turns
the value into a tensor and back: 0.32 ms per call for the Panda's default controller and
0.64 ms for the Fetch's (four sub-controllers), against a recorded step of about 1.5 ms.
:func:`install` gives an agent a ``set_action`` that does ManiSkill's arithmetic in numpy
float32, in the same order, and writes the values straight to the SAPIEN joints. It gives
exactly ManiSkill's result (``tests/envs/test_fast_control.py`` compares both, bit for bit, for
every supported robot and joint control mode): the same drive and velocity targets, the same
controller state (``_start_qpos``, ``_target_qpos``, ``_step``, ``_step_size``,
``_target_qvel``, as the tensors ManiSkill keeps: new ones each call, the mimic controller's
``_target_qpos`` updated in place), NaN actions refused with ManiSkill's error. The env installs
it on the CPU simulation only; on the GPU ManiSkill's batched path stays.

Controller types covered (ManiSkill 3.0.1, the exact class; every flag of their configs:
``use_delta``, ``use_target``, ``interpolate``, ``normalize_action``):

- ``PDJointPosController`` (``pd_joint_pos``, ``pd_joint_delta_pos``,
  ``pd_joint_target_delta_pos``; the Fetch's body);
- ``PDJointPosMimicController`` (the Panda's and the Fetch's gripper);
- ``PDJointPosVelController`` (``pd_joint_pos_vel``, ``pd_joint_delta_pos_vel``);
- ``PDJointVelController`` (``pd_joint_vel``);
- ``PDBaseForwardVelController`` (the Fetch's base; its rotation's sine and cosine by torch,
  whose float32 values numpy's and ``math``'s do not always match);
- ``PassiveController`` (does nothing, as ManiSkill's).

Any other type (the end-effector controllers ``PDEEPosController``, ``PDEEPoseController``;
``PDBaseVelController``; a robot's own) keeps ManiSkill's ``set_action``, called with its slice
of the action as ``CombinedController`` calls it; so does an action that is not a float32 CPU
tensor of the controller's shape (a dict for ``DictController``), a controller whose
``_target_qpos`` is not a float32 ``(1, n)`` tensor (a state set from float64 data), and an
agent class with its own ``set_action``. ``before_simulation_step`` (an interpolating
controller's per-joint writes), ``reset``, ``get_state`` and ``set_state`` stay ManiSkill's,
reading the state this module sets. Where ManiSkill's targets are NaN (the Fetch's
``pd_joint_pos_vel`` scales its continuous joints' infinite limits), the NaNs' sign bits may
differ.

It reads ManiSkill internals through ``embodied_envs/internals.py`` (``px_joints``,
``px_articulations``, ``ControllerState``): the SAPIEN joints and articulation, and each covered
controller's attributes in :data:`CONTROLLER_ATTRIBUTES`; ``tests/envs/test_fast_reads.py``
checks them all, so an upgrade that renames one fails there, and one that changes the
controllers' arithmetic fails ``tests/envs/test_fast_control.py``.
"""

from __future__ import annotations

import numpy as np
import torch
from mani_skill.agents.base_agent import BaseAgent
from mani_skill.agents.controllers.base_controller import CombinedController
from mani_skill.agents.controllers.passive_controller import PassiveController
from mani_skill.agents.controllers.pd_base_vel import PDBaseForwardVelController
from mani_skill.agents.controllers.pd_joint_pos import (
    PDJointPosController,
    PDJointPosMimicController,
)
from mani_skill.agents.controllers.pd_joint_pos_vel import PDJointPosVelController
from mani_skill.agents.controllers.pd_joint_vel import PDJointVelController

from embodied_envs.internals import ControllerState, px_articulations, px_joints

F32 = np.float32
HALF, ONE, ZERO = F32(0.5), F32(1.0), F32(0.0)

# per covered controller class, the attributes (private and public) this module reads or sets
_JOINTS = ("joints", "active_joint_indices", "_normalize_action", "config")
_POS_STATE = ("_step", "_start_qpos", "_target_qpos", "_sim_steps")
CONTROLLER_ATTRIBUTES = {
    PDJointPosController: (*_JOINTS, *_POS_STATE),
    PDJointPosMimicController: (
        *_JOINTS,
        *_POS_STATE,
        "control_joint_indices",
        "mimic_joint_indices",
        "mimic_control_joint_indices",
        "_multiplier",
        "_offset",
    ),  # fmt: skip
    PDJointPosVelController: (*_JOINTS, *_POS_STATE, "_target_qvel"),
    PDJointVelController: _JOINTS,
    PDBaseForwardVelController: _JOINTS,
    PassiveController: (),
}
NORMALIZED_ATTRIBUTES = ("action_space_low", "action_space_high")  # where _normalize_action
CONFIG_FLAGS = ("use_delta", "use_target", "interpolate")  # of the PDJointPos configs


def _tensor(array: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(array)


def _indices(tensor) -> np.ndarray:
    return np.asarray(torch.as_tensor(tensor).cpu().numpy(), dtype=np.intp).reshape(-1)


class _Part:
    """One sub-controller's ``set_action`` on its columns ``cols`` of the agent's action."""

    def __init__(self, ctrl, cols: slice):
        self.ctrl, self.cols = ctrl, cols
        self.state = ControllerState(ctrl)  # its private fields

    def set(self, action: torch.Tensor, x: np.ndarray, qpos: np.ndarray) -> None:
        """The controller's ``set_action``: here ManiSkill's, on its columns of ``action``
        (``x``: the agent's action scaled as each part's controller scales it)."""
        self.ctrl.set_action(action[:, self.cols])


class _Passive(_Part):
    def set(self, action, x, qpos) -> None:
        pass  # PassiveController.set_action


class _Joints(_Part):
    """A joint controller: its SAPIEN joints, their qpos indices, its action's scaling."""

    def __init__(self, ctrl, cols: slice):
        super().__init__(ctrl, cols)
        self.px = [px_joints(joint)[0] for joint in ctrl.joints]
        self.idx = _indices(ctrl.active_joint_indices)
        self.scaling = None  # (clip low, clip high, centre, half range) of its columns
        if self.state.normalize_action:  # gym_utils.clip_and_scale_action, its constants once
            low, high = ctrl.action_space_low.cpu().numpy(), ctrl.action_space_high.cpu().numpy()
            with np.errstate(invalid="ignore"):  # infinite limits give NaN, as in torch
                self.scaling = (-ONE, ONE, HALF * (high + low), HALF * (high - low))
        cfg = ctrl.config
        self.delta, self.target, self.interpolate = (
            bool(getattr(cfg, flag, False)) for flag in CONFIG_FLAGS
        )

    def write_targets(self, targets: np.ndarray) -> None:
        for joint, value in zip(self.px, targets[0].tolist(), strict=True):
            joint.set_drive_target(value)

    def write_velocities(self, targets: np.ndarray) -> None:
        for joint, value in zip(self.px, targets[0].tolist(), strict=False):
            joint.set_drive_velocity_target(value)

    def own_target(self) -> np.ndarray | None:
        """``_target_qpos`` as a numpy view, where ManiSkill's arithmetic on it stays float32."""
        t = self.state.target_qpos
        if (
            type(t) is not torch.Tensor or t.dtype != torch.float32 or t.device.type != "cpu"
            or t.requires_grad or t.shape != (1, len(self.idx))
        ):  # fmt: skip
            return None
        return t.numpy()

    def start(self, qpos: np.ndarray) -> np.ndarray:
        start = qpos[self.idx][None]  # a new array: ManiSkill's ``self.qpos``
        self.state.step = 0
        self.state.start_qpos = _tensor(start)
        return start

    def finish(self, start: np.ndarray, target: np.ndarray) -> None:
        """ManiSkill's end of ``set_action``: interpolation steps, or the targets written."""
        if self.interpolate:
            self.state.step_size = _tensor((target - start) / F32(self.state.sim_steps))
        else:
            self.write_targets(target)


class _JointPos(_Joints):
    """``PDJointPosController.set_action``."""

    def set(self, action, x, qpos) -> None:
        if not self.positions(x[:, self.cols], qpos):
            super().set(action, x, qpos)

    def positions(self, x: np.ndarray, qpos: np.ndarray) -> bool:
        """The position targets from ``x`` (this controller's scaled position columns), set and
        written as ``set_action`` does; False (nothing set) where ManiSkill's must do it."""
        held = None
        if self.delta and self.target:
            held = self.own_target()
            if held is None:
                return False
        start = self.start(qpos)
        if self.delta:
            target = (held if self.target else start) + x
        else:
            target = np.array(x)  # ``broadcast_to(action, shape).clone()``
        self.state.target_qpos = _tensor(target)
        self.finish(start, target)
        return True


class _Mimic(_Joints):
    """``PDJointPosMimicController.set_action``: its ``_target_qpos`` changed in place."""

    def __init__(self, ctrl, cols: slice):
        super().__init__(ctrl, cols)
        self.control = _indices(ctrl.control_joint_indices)
        self.mimic = _indices(ctrl.mimic_joint_indices)
        self.mimic_control = _indices(ctrl.mimic_control_joint_indices)
        self.multiplier = self.state.multiplier.cpu().numpy()[None, :]
        self.offset = self.state.offset.cpu().numpy()[None, :]

    def set(self, action, x, qpos) -> None:
        target = self.own_target()
        if target is None:
            return super().set(action, x, qpos)
        x = x[:, self.cols]
        start = self.start(qpos)
        if self.delta and self.target:
            target[:, self.control] = target[:, self.control] + x
        elif self.delta:
            target[:, self.control] = start[:, self.control] + x
        else:
            target[:, self.control] = x
        target[:, self.mimic] = target[:, self.mimic_control] * self.multiplier + self.offset
        self.finish(start, target)


class _JointPosVel(_JointPos):
    """``PDJointPosVelController.set_action``: positions, then velocities."""

    def set(self, action, x, qpos) -> None:
        x = x[:, self.cols]
        nq = x.shape[1] // 2
        if not self.positions(x[:, :nq], qpos):
            return _Part.set(self, action, x, qpos)
        velocities = np.array(x[:, nq:])
        self.state.target_qvel = _tensor(velocities)
        self.write_velocities(velocities)


class _JointVel(_Joints):
    """``PDJointVelController.set_action``."""

    def set(self, action, x, qpos) -> None:
        self.write_velocities(x[:, self.cols])


class _BaseForwardVel(_Joints):
    """``PDBaseForwardVelController.set_action``: the forward speed turned by the base's yaw
    (its third joint). ManiSkill multiplies the 2x2 rotation by ``(forward, 0)`` in torch's
    ``bmm``, which sums each row from zero: ``(0 + r0 * a0) + r1 * 0``, kept here for the
    zeros' signs. The yaw's cosine and sine are kept while the yaw stays the same float."""

    yaw = cos_sin = None

    def set(self, action, x, qpos) -> None:
        x = x[:, self.cols]
        yaw = qpos[self.idx[2]]
        if yaw != self.yaw or self.cos_sin is None:  # NaN != NaN: computed anew
            turn = _tensor(qpos[self.idx[2:3]])
            self.yaw, self.cos_sin = yaw, (torch.cos(turn).numpy()[0], torch.sin(turn).numpy()[0])
        cos, sin = self.cos_sin
        forward = x[0, 0]
        vx = (ZERO + cos * forward) + (-sin) * ZERO
        vy = (ZERO + sin * forward) + cos * ZERO
        self.write_velocities(np.concatenate([np.array([[vx, vy]], F32), x[:, 1:]], axis=1))


PARTS = {  # exact class -> its fast set_action (a subclass may change what it does)
    PDJointPosController: _JointPos,
    PDJointPosMimicController: _Mimic,
    PDJointPosVelController: _JointPosVel,
    PDJointVelController: _JointVel,
    PDBaseForwardVelController: _BaseForwardVel,
    PassiveController: _Passive,
}


def _part(ctrl, cols: slice) -> _Part:
    return PARTS.get(type(ctrl), _Part)(ctrl, cols)


class _Plan:
    """An agent controller's parts, and the action shape they take."""

    def __init__(self, controller):
        self.controller = controller
        dim = int(np.prod(controller.action_space.shape)) if controller.action_space.shape else 0
        self.shape = (1, dim)
        if type(controller).set_action is CombinedController.set_action:
            mapping = controller.action_mapping
            self.parts = [
                _part(c, slice(*mapping[uid])) for uid, c in controller.controllers.items()
            ]
        else:
            self.parts = [_part(controller, slice(0, dim))]
        # every normalised column clipped and scaled in one pass; the others kept as they are
        # (-0.0 + 1 * x is x, signed zeros too)
        self.low, self.high = np.full(self.shape, -np.inf, F32), np.full(self.shape, np.inf, F32)
        self.center, self.half = np.full(self.shape, -0.0, F32), np.ones(self.shape, F32)
        for part in self.parts:
            if getattr(part, "scaling", None) is not None:
                for array, value in zip(
                    (self.low, self.high, self.center, self.half), part.scaling, strict=True
                ):
                    array[0, part.cols] = value
        self.finite = bool(np.isfinite(self.center).all() and np.isfinite(self.half).all())

    def scale(self, a: np.ndarray) -> np.ndarray:
        """Each part's ``_preprocess_action`` (``gym_utils.clip_and_scale_action``), at once."""
        if not self.finite:  # the Fetch's pd_joint_pos_vel: its continuous joints' NaN targets
            with np.errstate(invalid="ignore"):
                return self.center + self.half * np.minimum(np.maximum(a, self.low), self.high)
        return self.center + self.half * np.minimum(np.maximum(a, self.low), self.high)

    @property
    def covered(self) -> list[str]:
        """Each part's controller class, and whether this module does its ``set_action``."""
        return [f"{type(p.ctrl).__name__}: {type(p) is not _Part}" for p in self.parts]


class FastSetAction:
    """An agent's ``set_action`` (see the module's docstring); :func:`install` sets it."""

    def __init__(self, agent):
        self.agent = agent
        self.px = px_articulations(agent.robot)[0]
        self.plans: dict[str, _Plan] = {}

    def plan(self) -> _Plan:
        """The current control mode's plan, made anew if its controller was replaced."""
        agent = self.agent
        controller = agent.controller
        plan = self.plans.get(agent.control_mode)
        if plan is None or plan.controller is not controller:
            plan = self.plans[agent.control_mode] = _Plan(controller)
        return plan

    def __call__(self, action) -> None:
        plan = self.plan()
        if (
            type(action) is not torch.Tensor or action.dtype != torch.float32
            or not action.is_cpu or action.requires_grad or action.shape != plan.shape
        ):  # fmt: skip
            return BaseAgent.set_action(self.agent, action)
        a = action.numpy()
        if np.isnan(a).any():  # BaseAgent.set_action's check, its message
            raise ValueError("Action cannot be NaN. Environment received:", action)
        x = plan.scale(a)
        qpos = self.px.qpos  # read once: writing drive targets does not move the joints
        for part in plan.parts:
            part.set(action, x, qpos)


def install(agent) -> bool:
    """Give a CPU-simulation ``agent`` (one env) the fast ``set_action``; returns whether it
    did (not on the GPU simulation, several envs, or an agent class with its own
    ``set_action``)."""
    scene = agent.scene
    if scene.gpu_sim_enabled or scene.num_envs != 1:
        return False
    if type(agent).set_action is not BaseAgent.set_action:
        return False
    agent.set_action = FastSetAction(agent)
    return True


def uninstall(agent) -> None:
    """Give ``agent`` back ManiSkill's ``set_action`` (the tests compare the two)."""
    agent.__dict__.pop("set_action", None)


def installed(agent) -> bool:
    return isinstance(agent.__dict__.get("set_action"), FastSetAction)
