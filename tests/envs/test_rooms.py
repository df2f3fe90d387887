"""Room pools (``rooms``: each episode's splat background drawn by its seed) and the robot's
decimated visual meshes (``robot_visual_faces``)."""

from collections import Counter

import gymnasium as gym
import numpy as np
import pytest
import sapien
import torch
from conftest import DATA, DEFAULT_LAYOUT

import embodied_envs  # noqa: F401
from embodied_envs.layout.rooms import RoomError, resolve_rooms, shipped_rooms

ENV_ID = "PickEmbodiedGen-v1"
SIDE = 48  # px: a small sensor camera keeps these tests fast
FACES = 400


def make(**kw):
    kw.setdefault("obs_mode", "rgb")
    kw.setdefault("sensor_configs", dict(width=SIDE, height=SIDE))
    return gym.make(ENV_ID, layout_file=str(DEFAULT_LAYOUT), **kw)


@pytest.fixture(scope="module")
def env():
    e = make(hybrid_obs=True, rooms="shipped", robot_visual_faces=FACES)
    yield e
    e.close()


def room_of(env) -> str:
    return env.unwrapped.hybrid.rooms[0].parent.name


def frame(obs) -> torch.Tensor:
    return obs["sensor_data"]["base_camera"]["rgb"][0]


def test_the_shipped_pool_is_four_distinct_rooms_the_layouts_own_first():
    rooms = shipped_rooms()
    assert len(rooms) == 4 and rooms[0] == DATA / "assets" / "background"
    sizes = {(r / "gs_model.ply").read_bytes()[-4096:] for r in rooms}
    assert len(sizes) == 4  # four different splats, not copies
    assert resolve_rooms("shipped") == [r.resolve() for r in rooms]


def test_a_pool_is_named_by_folders_a_folder_of_them_globs_and_lists(tmp_path):
    for name in ("a", "b"):
        (tmp_path / "pool" / name).mkdir(parents=True)
        (tmp_path / "pool" / name / "gs_model.ply").write_bytes(b"ply\n")
    a, b = (tmp_path / "pool" / n for n in "ab")
    assert resolve_rooms(str(a)) == [a]
    assert resolve_rooms(str(tmp_path / "pool")) == [a, b]  # a folder of rooms
    assert resolve_rooms(str(tmp_path / "pool" / "*")) == [a, b]  # a glob
    assert resolve_rooms([str(b), str(a), str(b / "gs_model.ply")]) == [b, a]  # each once
    assert resolve_rooms(None) is None


@pytest.mark.parametrize(
    "value, words",
    [([], "names no room"), ("nowhere/at/all", "holds no room"), ([3], "not a path")],
)
def test_a_pool_naming_no_room_is_refused_in_one_line(value, words):
    with pytest.raises(RoomError, match=words) as e:
        resolve_rooms(value)
    assert "\n" not in str(e.value) and "Fix:" in str(e.value)


def test_a_room_that_is_not_a_ply_is_refused_naming_the_file(tmp_path):
    (tmp_path / "r").mkdir()
    (tmp_path / "r" / "gs_model.ply").write_bytes(b"\x89PNG....")
    with pytest.raises(RoomError, match=r"r/gs_model.ply: not a PLY file"):
        resolve_rooms(str(tmp_path / "r"))
    with pytest.raises(ValueError, match="r/gs_model.ply: not a PLY file"):  # at gym.make too
        make(hybrid_obs=True, rooms=str(tmp_path / "r"))


def test_rooms_without_hybrid_rendering_are_refused():
    with pytest.raises(RoomError, match="hybrid_obs=True"):
        make(rooms="shipped")


def test_each_episode_draws_its_room_by_its_seed(env):
    """The same seed, the same room (whatever ran before); over 40 seeds every room is drawn,
    none more than half the time (uniform: 10 each expected)."""
    drawn = {}
    for seed in range(40):
        env.reset(seed=seed)
        drawn[seed] = room_of(env)
    counts = Counter(drawn.values())
    assert set(counts) == {"background", "attic", "gallery", "loft"}, counts
    assert max(counts.values()) <= 20, counts
    for seed in (7, 3, 7, 31):  # again, in another order
        env.reset(seed=seed)
        assert room_of(env) == drawn[seed]


def test_the_room_changes_the_background_not_the_scene(env):
    """Two seeds whose rooms differ, with the objects and arm set to the same state: the
    foreground pixels are the same, the background differs."""
    u = env.unwrapped
    seeds = {}
    for seed in range(20):
        env.reset(seed=seed)
        seeds.setdefault(room_of(env), seed)
    (room_a, seed_a), (room_b, seed_b) = list(seeds.items())[:2]
    env.reset(seed=seed_a)
    state = u.get_state_dict()
    frame_a = frame(u.get_obs())
    mask_a = u.hybrid.foreground_mask(
        u.scene.sensors["base_camera"].get_obs(rgb=False, segmentation=True)["segmentation"],
        human=False,
    )[0]
    env.reset(seed=seed_b)
    assert room_of(env) == room_b != room_a
    u.set_state_dict(state)
    frame_b = frame(u.get_obs())
    assert mask_a.float().mean() > 0.2 and (~mask_a).float().mean() > 0.02
    diff = (frame_a.float() - frame_b.float()).abs().amax(-1)
    assert diff[mask_a].mean() < 2.0, "the robot, table and objects look the same"
    assert diff[~mask_a].mean() > 10.0, "the room behind them differs"


def test_the_robots_visual_meshes_are_decimated_within_the_budget(env):
    u = env.unwrapped
    counts = []
    for link in u.agent.robot.links:
        for obj in link._objs:
            body = obj.entity.find_component_by_type(sapien.render.RenderBodyComponent)
            for shape in body.render_shapes if body is not None else []:
                counts += [len(p.get_triangles()) for p in getattr(shape, "parts", [])]
    assert counts and max(counts) <= FACES
    assert sum(counts) < 135_548 / 5  # the Panda as shipped: 135,548 triangles


def test_decimated_frames_look_like_the_full_robot(env):
    """The same state seen with the robot as shipped and decimated: the robot's silhouette
    (its segmentation) agrees on almost every pixel, and the frames' mean colours agree."""
    full = make(hybrid_obs=True, rooms="shipped")
    try:
        obs_full, _ = full.reset(seed=2)
        obs_low, _ = env.reset(seed=2)
        env.unwrapped.set_state_dict(full.unwrapped.get_state_dict())
        obs_low = env.unwrapped.get_obs()

        def robot(u):
            seg = u.scene.sensors["base_camera"].get_obs(rgb=False, segmentation=True)
            ids = torch.tensor([int(link.per_scene_id[0]) for link in u.agent.robot.links])
            return torch.isin(seg["segmentation"][0, ..., 0].long(), ids)

        a, b = robot(full.unwrapped), robot(env.unwrapped)
        assert a.float().mean() > 0.01
        assert (a ^ b).float().mean() < 0.01  # silhouettes within 1% of the pixels
        mean_a, mean_b = (frame(o).float().mean((0, 1)) for o in (obs_full, obs_low))
        assert (mean_a - mean_b).abs().max() < 3.0
    finally:
        full.close()


@pytest.mark.parametrize("faces", [10, 2.5, "500"])
def test_a_face_budget_out_of_range_is_refused(faces):
    with pytest.raises(ValueError, match="robot_visual_faces"):
        make(robot_visual_faces=faces)


def test_an_unseeded_reset_draws_rooms_too(env):
    env.reset(seed=0)
    rooms = set()
    for _ in range(12):
        env.reset()
        rooms.add(room_of(env))
    assert len(rooms) > 1
    np.testing.assert_equal(len(env.unwrapped.room_pool), 4)
