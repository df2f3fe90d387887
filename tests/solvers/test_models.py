"""The robot models the expert plans with (``solvers/models.py``): made once per env, robot and
agent and shared by the episodes' solvers; the joint levers read back from the cache folder
bit for bit; and the asset specs the solver reads once per URDF version
(``grasp_choice.asset_spec``)."""

import gymnasium as gym
import numpy as np
import pytest

import embodied_envs  # noqa: F401
from embodied_envs.layout import load_layout
from embodied_envs.layout.collision import CACHE_ENV
from embodied_envs.paths import default_layout
from embodied_envs.solvers import PickPlaceSolver, models
from embodied_envs.solvers.grasp_choice import asset_spec


@pytest.fixture(scope="module")
def env():
    e = gym.make("PickEmbodiedGen-v1", control_mode="pd_joint_pos")
    e.reset(seed=0)
    yield e
    e.close()


def test_solvers_of_one_env_share_its_models(env):
    a, b = PickPlaceSolver(env, seed=0), PickPlaceSolver(env, seed=1)
    assert a.planners is b.planners and a.follow is b.follow
    assert a.motion[0].levers is b.motion[0].levers
    assert not a.follow.step.flags.writeable, "shared: read-only"
    with pytest.raises(ValueError):
        a.follow.speed[0] = 9.0


def test_levers_are_read_back_from_the_cache_folder_bit_for_bit(env, tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_ENV, str(tmp_path))
    u = env.unwrapped
    monkeypatch.setattr(models, "_LEVERS", {})
    measured = models.levers(u)
    assert len(list((tmp_path / "expert").glob("levers-*.npz"))) == 1
    monkeypatch.setattr(models, "_LEVERS", {})  # a new process
    calls = []
    monkeypatch.setattr(models, "joint_levers", lambda *a: calls.append(a))
    again = models.levers(u)
    assert calls == [] and again.dtype == measured.dtype and np.array_equal(again, measured)
    assert measured.shape == (7,) and (measured > 0.05).all()


def test_an_asset_spec_is_read_again_when_its_urdf_changes(scene_copy):
    layout = load_layout(scene_copy / "layouts" / default_layout().name)
    node = layout.relation["manipulated_objs"][0]
    first = asset_spec(layout, node)
    assert first == layout.asset_spec(node) and asset_spec(layout, node) is first
    urdf = layout.urdf_path(node)
    text = urdf.read_text()
    assert "<mass value=" in text
    urdf.write_text(text.replace("<mass value=", "<mass value=\"0.321\" old=", 1))
    assert asset_spec(layout, node).mass == pytest.approx(0.321)
