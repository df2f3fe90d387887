"""The one episode loop of demo, collect and eval (``pipelines/episodes.py``): what the tally
counts and films, what an episode records, and the video writer's temporary name; and the
datasets room's converter swap for ``replay`` (``datasets/replay.py``)."""

from types import SimpleNamespace

import imageio.v3 as iio
import numpy as np
import pytest
import torch

from embodied_envs.pipelines.episodes import Episode, Tally, run_episode, write_video


class FakeEnv:
    """A one-env stand-in for the gym env: step k (from 1) gives reward k / 10, ``fail`` at
    step 3, and renders an image whose pixels are the number of steps taken."""

    def __init__(self, varies: bool = False):
        self.t = 0
        self.resets = []
        self.unwrapped = SimpleNamespace(
            layout_set=SimpleNamespace(varies=varies),
            layouts=[SimpleNamespace(source="/x/drawn.json")],
            instructions=["pick up the can"],
            evaluate=lambda: {"success": torch.tensor([self.t >= 4])},
            task_reader=SimpleNamespace(unmet=lambda: [["can: not at the goal"]]),
        )
        self.spec = SimpleNamespace(max_episode_steps=9)

    def reset(self, seed=None, options=None):
        self.t = 0
        self.resets.append((seed, options))
        return "obs0", {}

    def step(self, action):
        self.t += 1
        info = {"fail": torch.tensor([self.t == 3])}
        return f"obs{self.t}", torch.tensor([self.t / 10]), False, False, info

    def render(self):
        return torch.full((1, 4, 6, 3), self.t, dtype=torch.uint8)


def test_the_tally_counts_steps_return_and_fail_and_films_every_kth_step():
    env = FakeEnv()
    tally = Tally(env, film_every=2)
    assert tally.spec.max_episode_steps == 9, "a pass-through of the env's interface"
    for _ in range(5):
        tally.step(None)
    assert tally.steps == 5 and tally.ret == pytest.approx(1.5) and tally.fail is True
    assert [int(f[0, 0, 0]) for f in tally.frames] == [2, 4]
    assert tally.frames[0].shape == (4, 6, 3)
    quiet = Tally(FakeEnv())
    quiet.film()
    quiet.step(None)
    assert quiet.frames == [] and quiet.fail is False


@pytest.mark.parametrize("varies", [False, True])
def test_an_episode_records_the_drive_graded_at_its_end(varies):
    env = FakeEnv(varies)

    def drive(tally, obs, seed):
        assert obs == "obs0" and seed == 7
        for _ in range(5):
            tally.step(None)
        return ["grasp: no reachable grasp"]

    ep = run_episode(env, 7, drive, film_every=2, closing_frame=True)
    assert env.resets == [(7, dict(reconfigure=True) if varies else None)]
    assert (ep.layout, ep.seed, ep.instruction) == ("/x/drawn.json", 7, "pick up the can")
    assert (ep.success, ep.fail, ep.steps, ep.episode_return) == (True, True, 5, 1.5)
    assert ep.plan_failures == ["grasp: no reachable grasp"] and ep.failure is None
    # the frame after the reset, after steps 2 and 4, and the closing one
    assert [int(f[0, 0, 0]) for f in ep.frames] == [0, 2, 4, 5]
    assert ep.unmet == []  # a success misses nothing
    failed = run_episode(FakeEnv(), 1, lambda t, o, s: [], film_every=0)
    assert failed.frames == [] and not failed.success
    assert failed.unmet == ["can: not at the goal"]
    assert failed.failure == "execution (can: not at the goal)"


def test_an_episodes_failure_is_the_first_failed_stage():
    ep = Episode("a.json", 0, False, False, 10, 0.0, plan_failures=["lift: far", "grasp: x"])
    assert ep.failure == "lift"
    assert Episode("a.json", 0, False, False, 10, 0.0).failure == "execution"
    assert Episode("a.json", 0, True, False, 10, 0.0, plan_failures=["lift: far"]).failure is None


def test_a_video_is_written_under_a_temporary_name_then_renamed(tmp_path):
    frames = [np.full((16, 16, 3), 10 * k, np.uint8) for k in range(6)]
    path = tmp_path / "v" / "ep.mp4"
    assert write_video(path, iter(frames), fps=10) == 6
    assert list(path.parent.iterdir()) == [path]
    assert iio.imread(path).shape == (6, 16, 16, 3)

    def broken():
        yield frames[0]
        raise RuntimeError("renderer died")

    with pytest.raises(RuntimeError, match="renderer died"):
        write_video(tmp_path / "v" / "bad.mp4", broken(), fps=10)
    assert list(path.parent.iterdir()) == [path], "no partial file, under any name"


def test_replay_converts_in_the_root_frame_only_within_the_call():
    from mani_skill.trajectory.utils.actions import conversion

    from embodied_envs.datasets.ee_actions import joint_pos_to_ee
    from embodied_envs.datasets.replay import root_frame_conversion

    original = conversion.from_pd_joint_pos_to_ee
    assert original is not joint_pos_to_ee
    with pytest.raises(KeyError), root_frame_conversion():
        assert conversion.from_pd_joint_pos_to_ee is joint_pos_to_ee
        raise KeyError("a replay that fails")
    assert conversion.from_pd_joint_pos_to_ee is original
