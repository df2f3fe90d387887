"""The visual recipe: ``collect --obs-mode rgb --hybrid-obs --rooms`` records what a
visuomotor learner needs, ``train_policy.py`` trains a policy from its frames in seconds, and
``eval --hybrid-obs`` runs it on the frames the dataset holds."""

import json
import sys
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch
from conftest import DEFAULT_LAYOUT
from mani_skill.utils.common import flatten_state_dict

from embodied_envs.cli.main import main
from embodied_envs.pipelines.policies import load_policy

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools" / "recipes"))
import perceive  # noqa: E402
import perturb  # noqa: E402
import train_policy  # noqa: E402
import visual  # noqa: E402

MODE = "pd_joint_delta_pos"
SIDE = 40  # px: the camera of these tests (the recipe's default is 64)
SEED = 5


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Two hybrid rgb demos over the shipped rooms, and a policy trained on them for seconds."""
    root = tmp_path_factory.mktemp("visual")
    code = main([
        "collect", "--layout", str(DEFAULT_LAYOUT), "--num", "2", "--seed", str(SEED),
        "--obs-mode", "rgb", "--hybrid-obs", "--rooms", "shipped", "--camera-size", str(SIDE),
        "--control-mode", MODE, "--out", str(root / "demos"),
    ])  # fmt: skip
    assert code == 0
    demos = root / "demos" / DEFAULT_LAYOUT.stem / "trajectory.h5"
    train_policy.main([
        "--demos", str(demos), "--out", str(root / "run"), "--minutes", "0.05", "--chunk", "4",
        "--hidden", "32", "--batch-size", "16",
    ])  # fmt: skip
    return demos, root / "run"


def test_the_dataset_holds_frames_joints_and_goal_and_no_object_poses(dataset):
    demos, _ = dataset
    meta = json.loads(demos.with_suffix(".json").read_text())
    kwargs = meta["env_info"]["env_kwargs"]
    assert kwargs["hybrid_obs"] is True and kwargs["rooms"] == ["shipped"]
    assert kwargs["sensor_configs"] == dict(width=SIDE, height=SIDE)
    with h5py.File(demos) as f:
        obs = f["traj_0/obs"]
        rgb = obs["sensor_data/base_camera/rgb"]
        assert rgb.dtype == np.uint8 and rgb.shape[1:] == (SIDE, SIDE, 3)
        assert rgb.compression == "gzip"
        assert set(obs["extra"]) == {"is_grasped", "tcp_pose", "goal_pos", "task_kind"}
        assert set(obs["agent"]) == {"qpos", "qvel"}
        assert "depth" not in obs["sensor_data/base_camera"]


def test_eval_hybrid_obs_gives_the_frames_the_dataset_holds(dataset):
    """The env eval makes for the dataset's flags, reset with a demo's seed, observes the
    dataset's first frame (the same room, the same composite)."""
    demos, _ = dataset
    meta = json.loads(demos.with_suffix(".json").read_text())
    kwargs = meta["env_info"]["env_kwargs"]
    env = gym.make("PickEmbodiedGen-v1", **kwargs)
    try:
        for ep in meta["episodes"]:
            obs, _ = env.reset(seed=ep["episode_seed"])
            with h5py.File(demos) as f:
                first = f[f"traj_{ep['episode_id']}/obs/sensor_data/base_camera/rgb"][0]
            got = obs["sensor_data"]["base_camera"]["rgb"][0].numpy()
            assert np.abs(got.astype(int) - first.astype(int)).max() <= 1
    finally:
        env.close()


def test_the_visual_policy_trains_exports_and_eval_runs_it(dataset, tmp_path, capsys):
    demos, out = dataset
    info = json.loads((out / "train.json").read_text())
    assert info["kind"] == "visual" and info["image_hw"] == [SIDE, SIDE]
    assert info["iterations"] > 0 and info["estimator_iterations"] > 0
    assert info["state_keys"] == list(perceive.STATE_KEYS)
    # the estimator's held-out error is measured on the values that vary: the can's position
    # (slot 0 of the state observation's movers, which start at 32) and its vector to the goal
    assert {"mover 0 x", "mover 0 y", "mover 0 z"} <= set(info["held_out_error_m"])
    assert all(0 <= v < 1 for v in info["held_out_error_m"].values())
    assert "mover 1 x" not in info["held_out_error_m"]  # empty in a one-can task
    # every recorded frame was found over one of the shipped rooms: its background can be swapped
    assert info["swap_rooms"] >= 1 and info["swappable_frames"] == 1.0
    module = torch.jit.load(str(out / "policy.pt"))
    assert module.camera == "base_camera" and list(module.image_hw) == [SIDE, SIDE]
    code = main([
        "eval", "--policy", str(out / "policy.pt"), "--obs-mode", "rgb", "--hybrid-obs",
        "--rooms", "shipped", "--camera-size", str(SIDE), "--control-mode", MODE,
        "--episodes", "1", "--seed", "100", "--max-episode-steps", "8",
        "--out", str(tmp_path / "ev"),
    ])  # fmt: skip
    assert code == 0, capsys.readouterr().out
    episodes = json.loads((tmp_path / "ev" / "episodes.json").read_text())
    assert episodes[0]["steps"] == 8


def test_the_policy_sees_the_frame_and_the_goal(dataset):
    """Its action depends on the image and on the goal (not on one input alone)."""
    _, out = dataset
    policy = load_policy(str(out / "policy.pt"), env=None)
    module = torch.jit.load(str(out / "policy.pt"))
    gen = torch.Generator().manual_seed(0)
    image = torch.randint(0, 255, (1, SIDE, SIDE, 3), dtype=torch.uint8, generator=gen)
    extra = {"is_grasped": torch.zeros(1, dtype=torch.bool), "tcp_pose": torch.zeros(1, 7),
             "task_kind": torch.tensor([[1.0, 0.0, 0.0]])}  # fmt: skip
    obs = {
        "agent": {"qpos": torch.zeros(1, 9), "qvel": torch.zeros(1, 9)},
        "extra": dict(extra, goal_pos=torch.zeros(1, 3)),
        "sensor_data": {"base_camera": {"rgb": image}},
    }

    def act(o):
        module.reset()
        return policy.act(o)

    base = act(obs)
    other_image = dict(obs, sensor_data={"base_camera": {"rgb": 255 - image}})
    other_goal = dict(obs, extra=dict(extra, goal_pos=torch.ones(1, 3)))
    assert not torch.allclose(base, act(other_image))
    assert not torch.allclose(base, act(other_goal))


def test_the_augmentation_shifts_and_jitters_within_its_bounds():
    gen = torch.Generator().manual_seed(0)
    images = torch.rand(64, 3, 16, 16, generator=gen)
    out = visual.augment(images, gen)
    assert out.shape == images.shape and out.min() >= 0 and out.max() <= 1
    assert not torch.allclose(out, images)
    # a constant image stays constant under shifts: only the colour jitter changes it
    flat = torch.full((64, 3, 16, 16), 0.5)
    jittered = visual.augment(flat, gen)
    assert torch.allclose(jittered, jittered[:, :, :1, :1].expand_as(jittered))
    gains = jittered[:, :, 0, 0] / 0.5
    low = (1 - visual.BRIGHTNESS) * (1 - visual.GAIN)
    high = (1 + visual.BRIGHTNESS) * (1 + visual.GAIN)
    assert gains.min() >= low - 1e-6 and gains.max() <= high + 1e-6
    assert gains.std() > 0.02  # jittered per image


def test_a_frames_background_is_found_and_swapped_and_its_foreground_kept():
    gen = torch.Generator().manual_seed(1)
    rooms = torch.randint(0, 256, (3, 12, 12, 3), dtype=torch.uint8, generator=gen)
    frames = rooms[[2, 0, 1, 2]].clone()
    frames[:, 3:7, 4:9] = torch.randint(0, 256, (4, 4, 5, 3), dtype=torch.uint8, generator=gen)
    frames[3] = torch.randint(0, 256, (12, 12, 3), dtype=torch.uint8, generator=gen)  # no room's
    masks = visual.foreground_masks(frames, rooms, least=0.2, batch=3)
    square = torch.zeros(12, 12, dtype=torch.bool)
    square[3:7, 4:9] = True
    assert torch.equal(masks[:3], square.expand(3, 12, 12)) and masks[3].all()
    images = frames.permute(0, 3, 1, 2).float() / 255
    others = torch.rand(2, 3, 12, 12, generator=gen)
    swapped = visual.swap_backgrounds(images, masks, others, gen, share=1.0)
    assert torch.equal(swapped[:, :, 3:7, 4:9], images[:, :, 3:7, 4:9])  # the foreground
    for k in range(3):  # each background is one of the other rooms, whole
        assert any(torch.equal(swapped[k, :, ~square], o[:, ~square]) for o in others)
    assert torch.equal(swapped[3], images[3])  # all foreground: kept
    assert torch.equal(visual.swap_backgrounds(images, masks, others, gen, 0.0), images)
    # share 0.5 swaps about half the frames
    many = images[:1].expand(400, -1, -1, -1)
    out = visual.swap_backgrounds(many, masks[:1].expand(400, -1, -1), others, gen, 0.5)
    changed = (out != many).flatten(1).any(1).float().mean()
    assert 0.4 < changed < 0.6


def test_random_rooms_are_seeded_and_differ():
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tools" / "make"))
    import make_rooms

    def styles(seed):
        rng = np.random.default_rng(seed)
        return [make_rooms.random_style(rng) for _ in range(8)]

    assert styles(3) == styles(3) and styles(3) != styles(4)
    drawn = styles(3)
    assert len({s.walls for s in drawn}) == 8 and len({s.pattern for s in drawn}) > 1
    colours = [c for s in drawn for c in s.walls]
    assert all(20 <= v <= 250 for c in colours for v in c)
    mesh = make_rooms.room_mesh(drawn[0])  # a room of the shipped rooms' size
    assert np.allclose(mesh.bounds[1] - mesh.bounds[0], [5.05, 2.64, 5.05], atol=0.06)


@pytest.mark.parametrize(
    "missing, words",
    [
        ("traj_0/obs/extra/goal_pos", "has no obs/extra/goal_pos. Fix: collect with --obs-mode"),
        ("traj_0/obs/sensor_param", "has no obs/sensor_param/base_camera/intrinsic_cv. Fix:"),
        ("traj_0/env_states", "traj_0 has no env_states"),
    ],
)
def test_a_dataset_without_a_field_the_policy_needs_is_refused_naming_it(
    dataset, tmp_path, missing, words
):
    demos, _ = dataset
    broken = tmp_path / "trajectory.h5"
    with h5py.File(demos) as src, h5py.File(broken, "w") as dst:
        for name in src:
            src.copy(name, dst)
        del dst[missing]
    broken.with_suffix(".json").write_text(demos.with_suffix(".json").read_text())
    assert visual.is_visual(demos) and visual.is_visual(broken)
    with pytest.raises(SystemExit, match=words):
        train_policy.main(
            ["--demos", str(broken), "--out", str(tmp_path / "r"), "--minutes", "0.01"]
        )
    assert not (tmp_path / "r" / "policy.pt").exists()


def test_a_visual_policy_on_state_observations_is_one_line(dataset, tmp_path, capsys):
    _, out = dataset
    code = main([
        "eval", "--policy", str(out / "policy.pt"), "--obs-mode", "state", "--control-mode", MODE,
        "--episodes", "1", "--max-episode-steps", "2", "--out", str(tmp_path / "ev"),
    ])  # fmt: skip
    text = capsys.readouterr().out
    assert code == 1 and "is a visual policy" in text and "--obs-mode rgb" in text
    code = main([
        "eval", "--policy", str(out / "policy.pt"), "--obs-mode", "rgb", "--camera-size", "32",
        "--control-mode", MODE, "--episodes", "1", "--max-episode-steps", "2",
        "--out", str(tmp_path / "ev2"),
    ])  # fmt: skip
    text = capsys.readouterr().out
    assert code == 1 and f"trained on {SIDE}x{SIDE} frames" in text
    assert f"--camera-size {SIDE}" in text


@pytest.mark.parametrize(
    "flags, words",
    [
        (["--obs-mode", "rgb", "--rooms", "shipped"], "--rooms are splat backgrounds"),
        (["--obs-mode", "state", "--hybrid-obs"], "--obs-mode state has none"),
        (["--obs-mode", "rgb", "--hybrid-obs", "--rooms", "/nowhere"], "holds no room"),
        (["--obs-mode", "rgb", "--robot-visual-faces", "10"], "--robot-visual-faces: "),
    ],
)
def test_bad_camera_flags_are_one_line(flags, words, tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["collect", "--layout", str(DEFAULT_LAYOUT), "--num", "1", *flags,
              "--out", str(tmp_path / "d")])  # fmt: skip
    assert words in str(e.value) and "\n" not in str(e.value)
    assert not (tmp_path / "d").exists()


def test_a_room_whose_splat_is_broken_is_refused_naming_the_file(tmp_path):
    room = tmp_path / "room"
    room.mkdir()
    (room / "gs_model.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nend_header\n")
    with pytest.raises(SystemExit) as e:
        main(["collect", "--layout", str(DEFAULT_LAYOUT), "--num", "1", "--obs-mode", "rgb",
              "--hybrid-obs", "--rooms", str(room), "--out", str(tmp_path / "d")])  # fmt: skip
    assert str(room / "gs_model.ply") in str(e.value) and "\n" not in str(e.value)


def state_env(demos):
    meta = json.loads(demos.with_suffix(".json").read_text())
    kwargs = dict(meta["env_info"]["env_kwargs"], obs_mode="state_dict", render_mode=None)
    return gym.make("PickEmbodiedGen-v1", **kwargs), meta


def test_the_estimators_labels_are_the_envs_observation_of_the_recorded_states(dataset):
    """Training only: per step, the state observation the env computes from the recorded env
    states; the groups the rgb observation holds are the recorded ones."""
    demos, _ = dataset
    env, meta = state_env(demos)
    try:
        slices = perturb.obs_slices(env)
        flats, actions, bases = perceive.flat_states(env, demos, meta["episodes"][:1])
    finally:
        env.close()
    with h5py.File(demos) as f:
        traj = f[f"traj_{meta['episodes'][0]['episode_id']}"]
        can = traj["env_states/actors/can"][:, :3]
        tcp = traj["obs/extra/tcp_pose"][:]
        grasped = traj["obs/extra/is_grasped"][:]
        np.testing.assert_array_equal(actions[0], traj["actions"][:])
        np.testing.assert_array_equal(bases[0], traj["env_states/articulations/panda"][:, :7])
    flat = flats[0]
    assert len(flat) == len(actions[0]) + 1
    np.testing.assert_allclose(flat[:, slices["mover_pose"]][:, :3], can, atol=1e-6)
    np.testing.assert_allclose(flat[:, slices["tcp_pose"]], tcp, atol=1e-6)
    np.testing.assert_allclose(flat[:, slices["tcp_to_mover_pos"]][:, :3], can - tcp[:, :3],
                               atol=1e-5)  # fmt: skip
    np.testing.assert_array_equal(flat[:, slices["is_grasped"]][:, 0], grasped)
    assert grasped.any() and not grasped.all()  # the demo grasps the can partway


def test_the_policy_acts_on_the_envs_state_with_the_perceived_values(dataset):
    """``assemble`` given the true perceived values is the env's own state observation, less the
    orientations the policy does not see: the TCP-to-mover vectors recomputed as the env
    computes them, the layout's constants in place."""
    demos, out = dataset
    module = torch.jit.load(str(out / "policy.pt"))
    env, _ = state_env(demos)
    try:
        slices = perturb.obs_slices(env)
        env.reset(seed=11)
        rows = []
        for _ in range(3):
            obs = env.step(env.action_space.sample())[0]
            rows.append(flatten_state_dict(obs, use_torch=True).float())
    finally:
        env.close()
    flat = torch.cat(rows)
    seen = torch.from_numpy(perceive.perceived_index(slices))
    got = module.assemble(flat[:, : slices["task_kind"].stop], flat[:, seen])
    shown = np.setdiff1d(np.arange(flat.shape[1]), perceive.orientation_index(slices))
    torch.testing.assert_close(got[:, shown], flat[:, shown], atol=1e-5, rtol=0)
    assert (got[:, perceive.orientation_index(slices)] == 0).all()
    # the estimator gives an empty slot its constant (zero), whatever the frame
    image = torch.randint(0, 255, (2, SIDE, SIDE, 3), dtype=torch.uint8)
    guess = module.estimator(image)
    assert (guess[:, 6:9] == 0).all()  # the third slot's position (perceived_index's order)
    assert (guess[:, :3] != 0).all()  # the can's


def test_pixel_targets_place_points_where_the_camera_sees_them():
    """OpenCV's camera (a pixel's centre at integer coordinates) into the soft-argmax's
    coordinates over a quarter-size map: -1 and 1 the first and last cells' centres."""
    h, w = 48, 64
    intrinsic = np.array([[50.0, 0, (w - 1) / 2], [0, 50.0, (h - 1) / 2], [0, 0, 1]])
    camera = perceive.projection(intrinsic[None], np.eye(3, 4)[None])
    first = (1.5 - (w - 1) / 2) / 50.0  # x at depth 1 of the first cell's centre (pixel 1.5)
    points = np.array([[[0, 0, 1], [first, 0, 1], [-first, 0, 1], [0, 0, -1], [5, 0, 1]]])
    coords, inside = perceive.pixel_targets(points, camera, (h, w))
    np.testing.assert_allclose(coords[0, 0], [0, 0], atol=1e-6)
    np.testing.assert_allclose(coords[0, 1, 0], -1, atol=1e-6)
    np.testing.assert_allclose(coords[0, 2, 0], 1, atol=1e-6)
    assert inside[0].tolist() == [True, True, True, False, False]  # behind, outside


def test_rendered_frames_show_other_placements_with_their_labels(dataset):
    """The estimator's extra frames: other placements (the can's labelled position varies), the
    arm near a demonstrated configuration, the can's projected pixel inside the frame."""
    demos, _ = dataset
    env, meta = state_env(demos)
    kwargs = dict(meta["env_info"]["env_kwargs"], render_mode=None)
    camera_env = gym.make("PickEmbodiedGen-v1", **kwargs)
    try:
        slices = perturb.obs_slices(env)
        flats, _, _ = perceive.flat_states(env, demos, meta["episodes"][:1])
        joints = flats[0][:, slices["qpos"]]
        frames, cameras, labels = perceive.rendered_frames(
            camera_env, env, 0.0, joints, 0.01, np.random.default_rng(0), least=4
        )
    finally:
        camera_env.close()
        env.close()
    assert len(frames) == 4 and frames.shape[1:] == (SIDE, SIDE, 3)
    can = labels[:, slices["mover_pose"]][:, :3]
    assert can[:, :2].std(0).min() > 0.01  # m: placements differ
    nearest = np.abs(labels[:, None, slices["qpos"]] - joints[None]).max(-1).min(1)
    assert nearest.max() < 0.1  # rad: 0.01 rad offsets, clipped to the limits
    points, there = perceive.keypoint_points(labels, slices)
    _, inside = perceive.pixel_targets(points, cameras, (SIDE, SIDE))
    assert inside[:, 0].all() and there[:, 0].all() and not there[:, 1].any()


def test_room_error_measures_the_estimator_in_each_room(dataset):
    import room_error

    demos, out = dataset
    errors = room_error.room_errors(out / "policy.pt", demos, ["shipped"], frames=3)
    assert list(errors) == ["own", "shipped"]
    for e in errors.values():  # one can per frame; a policy trained for seconds is off, not lost
        assert e["frames"] == 3 and 0 < e["median"] <= e["p90"] < 1.0 and 0 < e["mean"] < 1.0
