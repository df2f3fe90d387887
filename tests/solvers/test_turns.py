"""The expert's turns that follow the arm's base joint: the top-down grasp the wrist reaches
without turning, and the IK start with the base joint turned toward the goal."""

import gymnasium as gym
import numpy as np
import pytest
from conftest import DATA

import embodied_envs  # noqa: F401
from embodied_envs.solvers import PickPlaceSolver


@pytest.fixture(scope="module")
def solver():
    env = gym.make("PickEmbodiedGen-v1", layout_file=DATA / "layouts" / "place_two.json",
                   obs_mode="state", control_mode="pd_joint_pos")  # fmt: skip
    env.reset(seed=0)
    yield PickPlaceSolver(env, seed=0)
    env.close()


def _about_base(solver, point, angle):
    """``point`` turned by ``angle`` about the robot base's vertical axis."""
    base = solver.base.agent.robot.pose.raw_pose[0, :3].cpu().numpy()
    c, s = np.cos(angle), np.sin(angle)
    rel = point[:2] - base[:2]
    return np.array(
        [base[0] + c * rel[0] - s * rel[1], base[1] + s * rel[0] + c * rel[1], point[2]]
    )


@pytest.mark.parametrize("angle", [0.0, 0.6, -1.2])
def test_the_grasp_closing_turns_with_the_base_joint(solver, angle):
    tcp = solver.base.agent.tcp.pose.to_transformation_matrix()[0].cpu().numpy()
    centre = _about_base(solver, tcp[:3, 3] - [0, 0, 0.2], angle)
    closing = solver._turned_closing(0, tcp, centre)
    y = tcp[:2, 1] / np.linalg.norm(tcp[:2, 1])
    c, s = np.cos(angle), np.sin(angle)
    assert closing == pytest.approx([c * y[0] - s * y[1], s * y[0] + c * y[1], 0.0], abs=1e-6)


def test_the_ik_start_turns_the_base_joint_toward_the_goal(solver):
    motion = solver.motion[0]
    qpos = solver._qpos()[0]
    model = motion.mp.pinocchio_model
    model.compute_forward_kinematics(qpos)
    hand = np.asarray(model.get_link_pose(motion.link))  # in the base frame
    c, s = np.cos(0.5), np.sin(0.5)
    goal = hand.copy()
    goal[:2] = [c * hand[0] - s * hand[1], s * hand[0] + c * hand[1]]
    start = motion._turned_start(goal, qpos)
    j = motion.idx[0]
    assert start[j] - qpos[j] == pytest.approx(0.5, abs=1e-6)
    others = np.delete(np.arange(len(qpos)), j)
    assert np.array_equal(start[others], qpos[others])  # the rest of the arm as it is
    far = goal.copy()
    far[:2] = -hand[:2]  # half a turn: within the joint's limits
    assert motion.lo[0] <= motion._turned_start(far, qpos)[j] <= motion.hi[0]
