"""The state observation's task slots (envs/observation.py): per task kind the values are the
actors' poses and the task's vectors, padding slots are zero and masked, one shape over a mixed
layout set, the GPU's tensor path gives the CPU's values, a layout with more movers than
slots is refused in one line, and the RGB modes keep their keys."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import DATA

import embodied_envs  # noqa: F401
from embodied_envs.envs import agents, observation
from embodied_envs.envs.observation import MAX_MOVERS, STATE_KEYS, StateObservation
from embodied_envs.envs.tasks.scene import TaskReader
from embodied_envs.layout import LayoutError

ENV_ID = "PickEmbodiedGen-v1"
TOL = 1e-6  # m: the same float32 poses, differences of them rounded once more
SHIFT = 0.01  # m: each mover moved this much more than the one before it, then observed
# layout -> its task kind and movers: one per kind, a receptacle, two movers
KINDS = {
    "default": ("pick", 1), "place_box": ("place", 1), "place_two": ("place", 2),
    "move_left": ("move", 1),
}  # fmt: skip


def layout(name: str) -> str:
    return str(DATA / "layouts" / f"{name}.json")


@pytest.fixture(scope="module", params=list(KINDS))
def kind_env(request):
    e = gym.make(ENV_ID, layout_file=layout(request.param), obs_mode="state_dict")
    yield request.param, e
    e.close()


def expected(u) -> dict:
    """The task keys from ManiSkill's public reads and the task rules' state."""
    task, actors = u.tasks[0], u.env_actors["env0"]
    state, _ = u.task_rules()
    tcp = agents.tcp_pose(u.main_agent, u.robot_entry).p[0].numpy()
    out = {k: np.zeros(w, np.float32) for k, w in STATE_KEYS.items()}
    for k, node in enumerate(task.objects):
        pose = actors[node].pose.raw_pose[0].numpy()
        out["mover_pose"][7 * k : 7 * k + 7] = pose
        out["tcp_to_mover_pos"][3 * k : 3 * k + 3] = pose[:3] - tcp
        if task.kind == "pick":  # the goal less the origin, as pick's success measures it
            to_goal = u.goal_site.pose.p[0].numpy() - pose[:3]
        else:  # the destination less the centre, as place's and move's do
            to_goal = state.dest[0, k] - state.movers[0, k]
        out["mover_to_goal_pos"][3 * k : 3 * k + 3] = to_goal
        out["mover_mask"][k] = 1
    if task.receptacle is not None and task.receptacle != u.layouts[0].context:
        out["receptacle_pose"] = actors[task.receptacle].pose.raw_pose[0].numpy()
        ts = u.task_scene
        out["receptacle_geometry"] = ts.rec_geometry[0]
        out["receptacle_mask"][0] = 1
    return out


def assert_task_keys(obs: dict, want: dict) -> None:
    assert list(obs)[-len(STATE_KEYS) :] == list(STATE_KEYS)  # the documented order
    for key, width in STATE_KEYS.items():
        got = obs[key].numpy()
        assert got.shape == (1, width), key
        np.testing.assert_allclose(got[0], want[key], atol=TOL, err_msg=key)


def test_each_kind_observes_its_movers_and_receptacle(kind_env):
    name, e = kind_env
    u = e.unwrapped
    kind, movers = KINDS[name]
    obs, info = e.reset(seed=3)
    assert u.tasks[0].kind == kind and len(u.tasks[0].objects) == movers
    extra = obs["extra"]
    assert_task_keys(extra, expected(u))
    mask = extra["mover_mask"][0].numpy()
    assert mask.tolist() == [1.0] * movers + [0.0] * (MAX_MOVERS - movers)
    # padding slots: zero
    assert not extra["mover_pose"][0, 7 * movers :].any()
    assert not extra["mover_to_goal_pos"][0, 3 * movers :].any()
    # the first slot's vector to its goal is the info's (the current mover at the start)
    np.testing.assert_allclose(extra["mover_to_goal_pos"][0, :3], info["obj_to_goal_pos"][0],
                               atol=TOL)  # fmt: skip
    has_rec = kind == "place"  # every shipped place layout's receptacle is an object
    assert extra["receptacle_mask"].tolist() == [[float(has_rec)]]
    if has_rec:
        cx, cy, sx, sy, rim, floor = extra["receptacle_geometry"][0].tolist()
        assert sx > 0 and sy > 0 and rim >= floor
        assert rim == pytest.approx(float(u.task_scene.rim[0]))
        assert floor == pytest.approx(float(u.task_scene.floor[0]))
        # each mover's destination lies over the footprint's box
        dest = u.task_scene.dest_local[0, :movers, :2]
        assert (abs(dest - [cx, cy]) <= [sx / 2, sy / 2]).all()
    else:
        assert not extra["receptacle_pose"].any() and not extra["receptacle_geometry"].any()
    # moved movers (each by another shift) are observed where they now are
    for k, node in enumerate(u.tasks[0].objects):
        actor = u.env_actors["env0"][node]
        pose = actor.pose
        actor.set_pose(pose * pose.create_from_pq(p=[SHIFT * (k + 1), 0, 0]))
    moved = u.get_obs()["extra"]
    assert_task_keys(moved, expected(u))
    assert not np.allclose(moved["mover_pose"][0, :3], extra["mover_pose"][0, :3], atol=SHIFT / 2)


def test_the_tensor_path_gives_the_numpy_paths_values(kind_env):
    """The GPU simulation's reads (ManiSkill's structs, torch) on the CPU's env: the same."""
    _, e = kind_env
    u = e.unwrapped
    e.reset(seed=5)
    reader = TaskReader(u, u.task_scene, u.layout_scene.top_z, tensors=True)
    reader.dest = torch.as_tensor(u.task_reader.dest)  # the episode's, as begin_episode sets it
    tcp = agents.tcp_pose(u.main_agent, u.robot_entry).p
    tensors = StateObservation(u.task_scene, reader, u.device).extras(tcp)
    arrays = u.state_observation.extras(tcp)
    for key in STATE_KEYS:
        assert tensors[key].dtype == arrays[key].dtype == torch.float32, key
        torch.testing.assert_close(tensors[key], arrays[key], atol=TOL, rtol=0)


def test_a_mixed_layout_set_has_one_observation_shape():
    files = [layout(n) for n in ("default", "place_box", "place_two", "move_left")]
    e = gym.make(ENV_ID, layout_file=files, obs_mode="state", reconfiguration_freq=1)
    try:
        u, seen = e.unwrapped, {}
        shape = e.observation_space.shape
        for seed in range(8):
            obs, _ = e.reset(seed=seed)
            seen[u.layouts[0].source.stem] = obs.shape
        assert len(seen) >= 3, seen  # pick, place (one and two movers), move among them
        assert set(seen.values()) == {shape}, seen
    finally:
        e.close()


def test_a_layout_with_more_movers_than_slots_is_refused(monkeypatch):
    monkeypatch.setattr(observation, "MAX_MOVERS", 1)
    with pytest.raises(LayoutError) as err:
        gym.make(ENV_ID, layout_file=layout("place_two"))
    assert str(err.value) == (
        f"{layout('place_two')}: its task moves 2 objects ['can1', 'can2']; the env observes "
        'at most MAX_MOVERS=1 (envs/observation.py). Fix: name at most 1 in '
        'relation["task_spec"]["objects"].'
    )


def test_rgb_modes_keep_their_keys_and_rgb_with_state_flattens_for_maniskill():
    """``rgb``: the four keys every mode has; ``rgb+state`` through ManiSkill's
    FlattenRGBDObservationWrapper: the ``state`` mode's vector beside the image."""
    from mani_skill.utils.wrappers.flatten import FlattenRGBDObservationWrapper

    e = gym.make(ENV_ID, obs_mode="rgb")
    try:
        obs, _ = e.reset(seed=0)
        assert set(obs["extra"]) == {"is_grasped", "tcp_pose", "goal_pos", "task_kind"}
    finally:
        e.close()
    e = gym.make(ENV_ID, obs_mode="state")
    try:
        want = e.reset(seed=0)[0]
    finally:
        e.close()
    e = FlattenRGBDObservationWrapper(gym.make(ENV_ID, obs_mode="rgb+state"), depth=False)
    try:
        obs, _ = e.reset(seed=0)
        assert obs["rgb"].shape == (1, 128, 128, 3)
        torch.testing.assert_close(obs["state"], want, atol=TOL, rtol=0)
    finally:
        e.close()
