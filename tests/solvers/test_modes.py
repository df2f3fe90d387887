"""The expert in other control modes (`solvers/modes.py`, `collect --control-mode`): the same
run as its joint targets make, or one graded on its own; refused modes say which work."""

from types import SimpleNamespace

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import DATA, DEFAULT_LAYOUT

from embodied_envs.datasets.joint_actions import mode_action
from embodied_envs.pipelines.episodes import expert, run_episode
from embodied_envs.registration import ENV_ID
from embodied_envs.robots import EXPERT_MODES
from embodied_envs.solvers.modes import ModeError
from embodied_envs.solvers.pick_place import PickPlaceSolver

KOCH_SEED = 100  # the Koch's expert carries out seeds 100-104 in pd_joint_target_delta_pos


def expert_run(mode: str, seed: int = 0, layout=DEFAULT_LAYOUT, robot: str = "panda"):
    """The expert's episode in ``mode``: (episode, final joints, final mover position)."""
    env = gym.make(ENV_ID, layout_file=str(layout), control_mode=mode, robot_uids=robot)
    try:
        episode = run_episode(env, seed, expert)
        u = env.unwrapped
        qpos = u.agent.robot.get_qpos()[0].numpy()
        mover = u.task_scene.movers[0].pose.p[0].numpy()
        return episode, qpos, mover
    finally:
        env.close()


@pytest.fixture(scope="module")
def joint_pos_run():
    return expert_run("pd_joint_pos")


@pytest.mark.parametrize("mode", ["pd_joint_delta_pos", "pd_joint_target_delta_pos"])
def test_joint_delta_modes_make_the_joint_target_run(joint_pos_run, mode):
    """A delta of the targets from the joints (or the last targets) is the same drive target:
    the same steps, the same end, to float rounding."""
    (ref, ref_q, ref_mover), (ep, q, mover) = joint_pos_run, expert_run(mode)
    assert ref.success and ep.success
    assert ep.steps == ref.steps
    np.testing.assert_allclose(q, ref_q, atol=1e-4)
    np.testing.assert_allclose(mover, ref_mover, atol=1e-4)


def test_joint_velocity_mode_pushes_as_the_position_drive(joint_pos_run):
    """pd_joint_vel at ``k / d (target - q)``: the position drive's force at each step's start;
    the episode succeeds in about as many steps and leaves the can within 1 cm of the other."""
    (ref, _, ref_mover), (ep, _, mover) = joint_pos_run, expert_run("pd_joint_vel")
    assert ep.success
    assert abs(ep.steps - ref.steps) <= 0.1 * ref.steps
    assert np.linalg.norm(mover - ref_mover) < 0.01


@pytest.mark.parametrize("mode", ["pd_ee_delta_pos", "pd_ee_delta_pose"])
def test_end_effector_modes_grade_their_own_run(mode):
    """The hand driven to where the targets put it succeeds on seeds the joint run succeeds
    on; pd_ee_delta_pos keeps the 45-degree pitched hand of the rest pose the whole way."""
    for seed in (0, 3):
        ep, q, _ = expert_run(mode, seed)
        assert ep.success, (mode, seed, ep.plan_failures)
        assert ep.steps < 300


def test_one_controller_arm_catches_up_with_targets_a_step_cannot_reach():
    """The SO-100 (one controller, the jaw's target with the arm's; its expert plans at 1.5
    rad/s, past pd_joint_delta_pos's 0.1 rad a step) in pd_joint_delta_pos: each clipped step
    is followed by up to CATCH_UP more toward the same targets, and the episode succeeds (it
    fails without them: 418 steps, the jaw closed late)."""
    layout = DATA / "layouts" / "so100_block.json"
    ref = expert_run("pd_joint_pos", 0, layout, "so100")
    ep = expert_run("pd_joint_delta_pos", 0, layout, "so100")
    assert ref[0].success and ep[0].success, ep[0].plan_failures
    assert ref[0].steps < ep[0].steps < 500  # the catch-up steps


@pytest.mark.parametrize(
    "robot, layout, mode, lead",
    [
        ("koch-v1.1", "koch_block", "pd_joint_delta_pos", 0.05),  # 0.02 x 17.5, to its bound
        ("koch-v1.1", "koch_block", "pd_joint_target_delta_pos", 0.05),
        ("koch-v1.1", "koch_block", "pd_joint_pos", 0.02),
        ("so100", "so100_block", "pd_joint_delta_pos", 0.02),  # the same gains in every mode
    ],
)
def test_a_joint_leads_as_far_as_its_mode_drive_needs(robot, layout, mode, lead):
    """The Koch's jaw lags 0.175 s behind its target in its delta modes (damping 16.3,
    stiffness 93.3) and 0.01 s in pd_joint_pos: its gentle close leads it by the bound, 0.05
    rad, not 0.02 (else it moves at 0.11 rad/s and stops close_steps short of the block); the
    SO-100's modes share their gains, its lead is unchanged."""
    path = DATA / "layouts" / f"{layout}.json"
    env = gym.make(ENV_ID, layout_file=str(path), control_mode=mode, robot_uids=robot)
    try:
        env.reset(seed=0)
        solver = PickPlaceSolver(env)
        assert solver.mode_actions.lead(solver.arm_dof, 0.02) == pytest.approx(lead)
    finally:
        env.close()


def test_koch_closes_on_the_block_in_its_target_delta_mode():
    """The Koch in pd_joint_target_delta_pos (its drives 10 times softer than pd_joint_pos's,
    its jaw 17.5 times slower): the gentle close reaches the block and the episode succeeds
    within the env's 500 steps (0 of 5 seeds when the jaw led by 0.02 rad; 5 of 5 now)."""
    ep, q, _ = expert_run("pd_joint_target_delta_pos", KOCH_SEED,
                          DATA / "layouts" / "koch_block.json", "koch-v1.1")  # fmt: skip
    assert ep.success, ep.plan_failures
    assert ep.steps < 450
    assert q[5] < 0.4  # the jaw closed on the 2 cm block (0.33 rad), not short of it


def test_a_mode_the_expert_cannot_drive_is_refused_with_those_it_can():
    env = gym.make(ENV_ID, layout_file=str(DEFAULT_LAYOUT), control_mode="pd_joint_pos_vel")
    try:
        env.reset(seed=0)
        with pytest.raises(ModeError) as e:
            PickPlaceSolver(env)
        msg = str(e.value)
        assert "control_mode='pd_joint_pos_vel'" in msg and "embodied-envs replay -c" in msg
        assert all(m in msg for m in EXPERT_MODES)  # the Panda has every one of them
    finally:
        env.close()


def test_mode_actions_are_computed_for_every_env_at_once():
    """A delta mode's action over 3 envs (a GPU simulation's batch) is each env's own: the
    targets minus that env's joints (or last targets), scaled by the bounds, row by row."""
    rng = np.random.default_rng(0)
    qpos, last = (torch.as_tensor(rng.normal(size=(3, 7)), dtype=torch.float32) for _ in "ab")
    config = SimpleNamespace(lower=[-0.1] * 7, upper=[0.1] * 7)
    controller = SimpleNamespace(config=config, qpos=qpos, _target_qpos=last)
    targets = qpos.numpy() + rng.uniform(-0.1, 0.1, size=(3, 7))
    for mode, base in (("pd_joint_delta_pos", qpos), ("pd_joint_target_delta_pos", last)):
        out = mode_action(controller, targets, mode)
        assert out.shape == (3, 7)
        np.testing.assert_allclose(out, (targets - base.numpy()) / 0.1, rtol=1e-5, atol=1e-5)
        for i in range(3):  # the first env's alone, as the converters ask it
            row = base[i : i + 1]
            single = SimpleNamespace(config=config, qpos=row, _target_qpos=row)
            np.testing.assert_allclose(mode_action(single, targets[i], mode), out[i], atol=1e-6)
