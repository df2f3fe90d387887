"""The expert's hand: opening and closing it, the arm held still.

``Jaws`` is a mixin of :class:`~embodied_envs.solvers.pick_place.PickPlaceSolver` (it holds the
env, the robot's hand entry ``robot_hand`` and gripper entry ``gripper_entry``, and the per-env
gripper actions ``gripper``). A hand whose jaw the arm's PD gains drive (the SO-100's) closes in
two steps (``_close_gently``); the others are commanded shut at once.
"""

from __future__ import annotations

import numpy as np

from embodied_envs.solvers.grasp_choice import asset_spec
from embodied_envs.solvers.grasps import object_points

JAW_REST = 1e-3  # action per control step: a jaw moving less is at rest on what it holds


class Jaws:
    """Opening and closing the hand in every env (a mixin of the solver)."""

    def _set_gripper(self, envs: np.ndarray, value: float, release: bool = False) -> None:
        """Open or close the gripper of ``envs`` (the others keep theirs), the arms held
        still: ``gripper_steps`` steps; closing ends as soon as every env of ``envs`` grasps
        the target (the env's ``is_grasped``) with its fingers at rest; opening to ``release``
        a placed mover as soon as the fingers of ``envs`` are open as the release rule counts it
        (``task_scene.open_fraction``)."""
        self.gripper[envs] = value
        self.gripping[envs] = False
        fingers = [self._fingers()]

        def gripped() -> bool:
            now = self._fingers()
            still = np.abs(now - fingers[0]).max(1) < self.cfg.finger_rest
            fingers[0] = now
            return bool(np.all((self._grasping() & still)[envs]))

        def opened() -> bool:  # open as the env's release rule counts it: nothing more to wait
            ts = self.base.task_scene
            lo, hi = ts.finger_span
            open_ = (self._fingers().sum(1) - lo) / (hi - lo) >= ts.open_fraction
            return bool(np.all((open_ & ~self._grasping())[envs]))

        closing = value == self.robot_hand.action_closed
        if closing and self.robot_hand.close_step:
            self._close_gently(envs)
            # not where the arm holds weakly: the jaw's lead there pushed the SO-100's arm off
            # its block (pd_joint_delta_pos: 11/12 -> 7/12; a target relative to the jaw)
            keeps = self.robot_hand.grip_lead > 0 and not self.mode_actions.holds_weakly
            self.gripping[envs] = self._pressing()[envs] & keeps
            return
        self._execute(
            [None] * self.num_envs,
            self.cfg.gripper_steps,
            until=gripped if closing else (opened if release else None),
        )

    def _close_gently(self, envs: np.ndarray) -> None:
        """Close the jaws of ``envs`` as a hand whose jaw the arm's PD gains drive must
        (``robots.Hand.close_gap``; shut at once, the SO-100's jaw meets the object with 100 N m and
        pushes the arm away): at once to the target's width across the jaws plus ``close_gap``, then
        the jaw's target ``close_step`` ahead of the jaw until both jaws press on the target
        (``_pressing``), where it stays ``squeeze`` past the jaw (``wedge_squeeze`` where they press
        at an angle the robot's grasp rule does not count; in an env whose grip slipped before,
        ``firm``: that far ahead of the jaw until the jaw rests,
        ``JAW_REST``: the grasp is seen at the first touch, and a squeeze set there is spent as the
        jaw closes on; pressing from the first grasp cost more episodes than it saved, its arm
        giving way under the squeeze: docs/robots.md, "Small objects"), the arm held
        ``settle_steps`` more (none in a mode whose arm holds weakly, ``ModeActions.holds_weakly``:
        the lift that follows ends the grasp's push on the table). In a mode whose drive moves the
        jaw slower than ``pd_joint_pos``'s, the lead is ``ModeActions.lead``'s (the Koch's delta
        modes: else its jaw, at 0.11 rad/s, stops ``close_steps`` short of the block). The first
        target is for the object's width between the jaws (``_width_between_jaws``). Then, where the
        hand has a ``grip_lead``, its target keeps that lead on the jaw while it holds
        (``_keep_grip``)."""
        hand = self.robot_hand
        way = np.sign(hand.action_closed - hand.action_open)
        per_qpos = self._per_qpos
        # the jaw's lead (action), as the jaw's joint (after the arm's) leads in the mode
        step = self.mode_actions.lead(self.arm_dof, hand.close_step / abs(per_qpos))
        step *= abs(per_qpos)

        width = self._width_between_jaws()
        near = np.array([hand.action(w + hand.close_gap) for w in width])
        self.gripper[envs] = near[envs]
        there = lambda: bool(np.all(np.abs(self._jaw_action() - self.gripper)[envs] < step))  # noqa: E731
        self._execute([None] * self.num_envs, self.cfg.close_steps, until=there)
        closing = envs & ~self._pressing()
        pressing = np.zeros_like(closing)  # firm envs: grasping, the jaw not yet at rest
        before = self._jaw_action()
        for _ in range(self.cfg.close_steps):
            if not (closing | pressing).any() or self.ended:
                break
            shut = before + way * step  # from where the jaw stands: no wind-up
            shut = np.minimum(shut, hand.action_closed) if way > 0 else np.maximum(
                shut, hand.action_closed
            )
            self.gripper[closing] = shut[closing]
            self._execute([None] * self.num_envs, 1)
            now = self._jaw_action()
            pressed = self._pressing()
            held = closing & pressed
            pressing = (pressing & (np.abs(now - before) >= JAW_REST)) | (held & self.firm)
            # a wedge: both jaws press at an angle the robot's grasp rule does not count (seen
            # mostly as a firm retry presses on: accept11's prism, carried at the second attempt)
            wedge = pressed & ~self._grasping() if hand.wedge_squeeze else np.zeros_like(held)
            lead = way * np.where(wedge, hand.wedge_squeeze, hand.squeeze)
            self.gripper[held | pressing] = (now + lead)[held | pressing]
            closing &= ~held & (self.gripper != hand.action_closed)
            before = now
        if not self.mode_actions.holds_weakly:
            self._execute([None] * self.num_envs, self.cfg.settle_steps)

    @property
    def _per_qpos(self) -> float:
        """The gripper action per radian (or metre) of the jaw's joint."""
        hand, grip = self.robot_hand, self.gripper_entry
        return (hand.action_closed - hand.action_open) / (grip.closed_qpos - grip.open_qpos)

    def _jaw_action(self) -> np.ndarray:
        """Per env, the jaw's position as a gripper action."""
        moved = self._fingers()[:, 0] - self.gripper_entry.open_qpos
        return self.robot_hand.action_open + moved * self._per_qpos

    def _keep_grip(self) -> None:
        """Before a control step: in the envs that hold their target (``gripping``), the jaw's
        target ``Hand.grip_lead`` past the jaw (a PD jaw presses only by its lead)."""
        if not self.gripping.any():
            return
        hand = self.robot_hand
        way = np.sign(hand.action_closed - hand.action_open)
        lead = self._jaw_action() + way * hand.grip_lead
        lead = np.minimum(lead, hand.action_closed) if way > 0 else np.maximum(
            lead, hand.action_closed)
        self.gripper[self.gripping] = lead[self.gripping]

    def _width_between_jaws(self) -> np.ndarray:
        """Per env, the mover's extent along the closing axis (the TCP's y) over its vertices
        and surface points between the jaws (``GripperModel.between``; ``grasps.object_points``,
        sampled once per asset): an L-shaped block's extent across the jaws is its other leg's
        3.8 cm, and a jaw closing from there at its gentle pace stopped 1.6 cm short of the
        1.6 cm bar."""
        tcp = self._tcp().to_transformation_matrix().cpu().numpy()
        obj = self.target.pose.to_transformation_matrix().cpu().numpy()
        rel = np.linalg.inv(tcp) @ obj  # (n, 4, 4) the mover in the TCP frame
        width = np.zeros(self.num_envs)
        for i, layout in enumerate(self.base.layouts):  # assets differ in their point counts
            points = object_points(asset_spec(layout, self._node(i)), self.cfg.obstacle_points)
            local = points @ rel[i, :3, :3].T + rel[i, :3, 3]
            y = local[self.gripper_model.between(local), 1]
            width[i] = y.max() - y.min()
        return width
