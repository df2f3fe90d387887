"""The expert's demos convert (``solvers/follow.py``): its joint targets keep within what
``pd_joint_delta_pos`` and ``pd_joint_vel`` can follow, and ManiSkill's own
``replay_trajectory`` converts its demos to every delta and velocity controller with success."""

import copy
import re

import gymnasium as gym
import numpy as np
import pytest
from mani_skill.trajectory import replay_trajectory
from mani_skill.utils.wrappers.record import RecordEpisode

import embodied_envs  # noqa: F401
from embodied_envs.paths import default_layout
from embodied_envs.registration import CONTROL_FREQ, ENV_ID
from embodied_envs.solvers import PickPlaceSolver
from embodied_envs.solvers.follow import MARGIN, SPEED_SHARE, follow_limits, rate_limited, shortened

MODES = ("pd_joint_delta_pos", "pd_joint_vel", "pd_ee_delta_pos", "pd_ee_delta_pose")


@pytest.fixture(scope="module")
def env():
    e = gym.make(ENV_ID, layout_file=str(default_layout()), control_mode="pd_joint_pos")
    yield e
    e.close()


def test_limits_are_read_from_the_controllers(env):
    """The Panda's: pd_joint_delta_pos moves a target 0.1 rad a step, pd_joint_vel 1 rad/s
    (0.02 rad a step at 50 Hz), the PD lag is 0.1 s; halving the velocity controller's limit
    in its config halves the step and the speed."""
    agent = env.unwrapped.agent
    lim = follow_limits(agent, CONTROL_FREQ, 7)
    np.testing.assert_allclose(lim.step, np.full(7, MARGIN * 0.02))
    np.testing.assert_allclose(lim.lead, np.full(7, MARGIN * 0.1))
    np.testing.assert_allclose(lim.speed, np.full(7, SPEED_SHARE * 1.0))

    class Slow:  # the same agent with pd_joint_vel's limit halved
        _controller_configs = copy.deepcopy(agent._controller_configs)

    Slow._controller_configs["pd_joint_vel"]["arm"].upper = 0.5
    Slow._controller_configs["pd_joint_vel"]["arm"].lower = -0.5
    slow = follow_limits(Slow(), CONTROL_FREQ, 7)
    np.testing.assert_allclose(slow.step, lim.step / 2)
    np.testing.assert_allclose(slow.speed, lim.speed / 2)

    class Bare:
        _controller_configs = {"pd_joint_pos": agent._controller_configs["pd_joint_pos"]}

    with pytest.raises(ValueError, match=r"no arm controller in pd_joint_pos or pd_joint_delta"):
        follow_limits(Bare(), CONTROL_FREQ, 7)


def test_rate_limited_targets_step_at_most_the_limit_and_reach_the_end():
    targets = np.array([[0.0], [0.5], [0.5]])
    out = rate_limited(targets, np.array([0.0]), np.array([0.2]))
    np.testing.assert_allclose(out[:, 0], [0.0, 0.2, 0.4, 0.5])
    # a move is shortened as a whole: its direction kept
    np.testing.assert_allclose(shortened(np.array([0.4, 0.1]), np.array([0.2, 0.2])), [0.2, 0.05])


def test_the_experts_targets_and_speeds_stay_within_the_limits(env):
    """Over a whole expert episode: every joint target moves at most ``step`` between two
    control steps, leads the measured joint position by at most ``lead`` (below
    pd_joint_delta_pos's 0.1 rad), and no arm joint moves faster than pd_joint_vel's limit."""
    u = env.unwrapped
    lim = follow_limits(u.agent, CONTROL_FREQ, 7)
    targets, leads, speeds = [], [], []
    step = env.step

    def recorded(action):
        qpos = u.agent.robot.get_qpos()[0, :7].numpy()
        targets.append(np.asarray(action, np.float64)[:7])
        leads.append(np.abs(targets[-1] - qpos))
        out = step(action)
        speeds.append(np.abs(u.agent.robot.get_qvel()[0, :7].numpy()))
        return out

    env.step = recorded
    try:
        env.reset(seed=0)
        assert bool(PickPlaceSolver(env, seed=0).solve().success[0])
    finally:
        del env.step
    changes = np.abs(np.diff(np.array(targets), axis=0))
    assert changes.max() <= lim.step.max() + 1e-6, changes.max()
    assert np.max(leads) <= lim.lead.max() + 1e-6, np.max(leads)  # float32 actions
    vel_limit = u.agent._controller_configs["pd_joint_vel"]["arm"].upper
    assert np.max(speeds) < vel_limit, np.max(speeds)
    assert len(targets) > 100  # a whole episode: approach, grasp, lift, carry


def _collect(tmp_path, seeds) -> str:
    """The expert's successful demos of ``seeds`` on the default layout, recorded by
    ManiSkill's RecordEpisode as ``collect`` records them; the .h5 path."""
    e = gym.make(ENV_ID, layout_file=str(default_layout()), control_mode="pd_joint_pos")
    rec = RecordEpisode(e, str(tmp_path), save_video=False, trajectory_name="demos",
                        save_on_reset=False, source_type="motionplanning")  # fmt: skip
    try:
        for seed in seeds:
            rec.reset(seed=seed)
            assert bool(PickPlaceSolver(rec, seed=seed).solve().success[0])
            rec.flush_trajectory()
    finally:
        rec.close()
    return str(tmp_path / "demos.h5")


@pytest.fixture(scope="module")
def demos(tmp_path_factory):
    return _collect(tmp_path_factory.mktemp("demos"), seeds=(0, 1))


@pytest.mark.parametrize("mode", MODES)
def test_maniskills_replay_converts_the_experts_demos(demos, mode, capsys):
    """ManiSkill 3.0.1's ``replay_trajectory -c MODE`` (its own converter, no patch) replays
    both demos in MODE and each converted episode ends in success (what it counts as saved)."""
    replay_trajectory.main(replay_trajectory.parse_args(["--traj-path", demos, "-c", mode]))
    saved = re.findall(r"(\d+)/(\d+)=[\d.]+% demos saved", capsys.readouterr().out)
    assert saved == [("2", "2")], (mode, saved)
